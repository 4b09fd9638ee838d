"""One SLQE per person with stable ids (`PeopleTracker`): detections assigned to tracks each
frame, tracks born, confirmed, held behind a nearer person and ended (`free_space`: where the
depth image sees through an unseen person's place), the primary person first (the design: the
package's docstring, `core.people`)."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics, project
from pose4d_ros.core.foreground.person import seen_edges
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people.assignment import (
    _mahalanobis2_all,
    assign,
    shoulders_m,
    span_m,
    torso,
    torso_px,
    yielded,
)
from pose4d_ros.core.people.config import TrackingConfig
from pose4d_ros.core.people.facing import Facing
from pose4d_ros.core.skeleton import tree_for
from pose4d_ros.core.stages import TrackerStage


@dataclass
class _Track:
    stage: object
    id: int = 0  # 0 while tentative
    hits: int = 0
    seen_s: float = -math.inf
    point: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))
    cov: NDArray[np.float64] = field(default_factory=lambda: np.zeros((3, 3)))
    pixel: NDArray[np.float64] = field(default_factory=lambda: np.full(2, np.nan))
    size_px: float = math.nan
    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    names: tuple[str, ...] = ()
    last: JointSet | None = None
    held: bool = False  # hidden behind another person: `last` is their last pose, kept
    held_s: float = math.nan  # since when
    behind: int = 0  # while held: the id of the track of the person hiding them
    shoulders_m: list[float] = field(default_factory=list)  # every frame's, in 3-D
    facing: Facing = field(default_factory=Facing)


class _FrameDepth:
    """A frame's depth image for `PeopleTracker.step` (an array, None, or a function giving
    it), read at most once, when first asked (`__call__`), and the row one past its last row
    of readings (`bottom`, `seen_edges`: a depth image registered to the colour camera has
    none in a band along its bottom), measured at most once a frame."""

    def __init__(self, depth_m: NDArray[np.floating] | Callable[[], NDArray[np.floating] | None]
                 | None) -> None:
        self._source = depth_m

    @functools.cached_property
    def image(self) -> NDArray[np.floating] | None:
        return self._source() if callable(self._source) else self._source

    def __call__(self) -> NDArray[np.floating] | None:
        return self.image

    @functools.cached_property
    def bottom(self) -> int | None:
        image = self.image
        return None if image is None else seen_edges(np.isfinite(np.asarray(image)))[2]


class PeopleTracker:
    """One SLQE per person (`core.pipeline.TrackerStage`), detections assigned to tracks each
    frame (module docstring).

    Parameters
    ----------
    template : the `core.stages.TrackerStage` whose copy (`spawn`) each new track gets.
    config : `TrackingConfig`.

    Attributes
    ----------
    born, ended : ids of the tracks confirmed and ended by the last `step`.
    next_id : the id the next confirmed track gets (ids are never reused).
    """

    def __init__(self, template: TrackerStage, config: TrackingConfig | None = None) -> None:
        self.template = template
        self.config = config or TrackingConfig()
        self.tracks: list[_Track] = []
        self.last_s: float | None = None
        self._previous_s: float | None = None
        self._spare: object | None = None
        self.next_id = 1
        self.born: list[int] = []
        self.ended: list[int] = []

    def configure(self, **settings: object) -> None:
        """New stage settings (`TrackerStage.configure`) for the template and every track,
        from the next frame on."""
        for stage in [self.template, *(t.stage for t in self.tracks), *[self._spare] * bool(
                self._spare)]:
            stage.configure(**settings)

    def reset(self) -> None:
        """End every track (ids still count on)."""
        self.ended = [t.id for t in self.tracks if t.id]
        self.tracks = []
        self.last_s = None

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Track two people for a few frames (the first frames' paths run once), then forget
        them: ids start at 1."""
        from pose4d_ros.core.skeleton import PARTS_10

        base = np.array([[0.0, -0.7 + 0.17 * k, 2.8] for k in range(len(PARTS_10))])
        for k in range(4):
            people = []
            for dx in (-0.6, 0.6):
                xyz = base + [dx, 0.0, 0.0]
                people.append(JointSet(PARTS_10.names, project(xyz, intrinsics), xyz,
                                       source=np.full(len(xyz), cj.DETECTED, np.uint8),
                                       confidence=np.full(len(xyz), 0.9), score=10.0))
            self.step(people, k / 30, intrinsics)
        self.reset()
        self.next_id = 1
        self.born, self.ended = [], []

    def step(self, detections: Sequence[JointSet], stamp_s: float,
             intrinsics: Intrinsics | None,
             depth_m: NDArray[np.floating] | Callable[[], NDArray[np.floating] | None]
             | None = None) -> list[JointSet]:
        """Track one frame: the tracked parts of every confirmed track (its `track_id` set),
        primary first, then by id. `depth_m` (the camera's depth, metres, NaN = no reading):
        an unseen track whose person it shows is not there ends (`free_space`), a detection
        reaching its last row of readings is partly seen (`_partly_seen`); or a function
        giving it (None: none), called once, only when a track went unseen or a detection
        scored under `birth_score` (a node reads the image only then)."""
        cfg = self.config
        depth = _FrameDepth(depth_m)
        # every detection checked before anything changes: a frame with one the SLQE would
        # refuse is refused whole (ValueError), and the tracks are untouched
        checker = self.tracks[0].stage if self.tracks else self._checker()
        for det in detections:
            checker.check(det, intrinsics)
        self.born, self.ended = [], []
        # a gap in the stream (over `max_gap_s`: a new video, a paused camera) ends every
        # track, as the SLQE restarts after one; so does being unseen over `max_unseen_s`
        # (`max_hidden_s` held behind another) while frames came
        gap = self.last_s is not None and not 0.0 <= stamp_s - self.last_s <= cfg.max_gap_s
        self._previous_s, self.last_s = self.last_s, stamp_s
        ended = [t for t in self.tracks if gap or stamp_s - t.seen_s > (
            cfg.max_hidden_s if t.held else cfg.max_unseen_s)]
        self.ended = [t.id for t in ended if t.id]
        self.tracks = [t for t in self.tracks if t not in ended]
        points = [torso(d) for d in detections]
        cost = self._cost(detections, points, stamp_s)
        matched, trusted, emerging, refused = self._match(detections, points, cost, intrinsics,
                                                          depth)
        while refused:
            # a pair the track refuses takes no part: the detection goes to the next track
            # that fits, a tentative one too (a person held behind another, offered the
            # detection of someone walking by, would else take it from their young track
            # frame after frame: the person never confirmed); each round removes a pair
            cost[tuple(np.array(refused).T)] = np.nan
            matched, trusted, emerging, refused = self._match(detections, points, cost,
                                                              intrinsics, depth)
        # no pair left is refused (`_match`): each detection is its track's, or may start one
        for j, det in enumerate(detections):
            born = self._born(det, self._partly_seen(det, j in emerging, depth, intrinsics))
            if j not in matched and (_finite(points[j][0]) or _finite(torso_px(det)[0])) \
                    and (j in trusted or born):
                stage = self.template.spawn()
                self.tracks.append(_Track(stage, names=stage.check(det, intrinsics).names,
                                          facing=Facing(cfg.facing_away_m, cfg.facing_window_s)))
                matched[j] = len(self.tracks) - 1
        seen = {i: j for j, i in matched.items()}
        gone: list[_Track] = []
        # the tracks seen first: a track unseen behind one of them is held (`_behind`)
        for i in sorted(range(len(self.tracks)), key=lambda i: i not in seen):
            track = self.tracks[i]
            if i not in seen and track.held and self._released(track, stamp_s):
                gone.append(track)
                continue
            if i not in seen and track.id and (track.held or (
                    behind := self._behind(track, stamp_s))):
                # its last pose kept until seen again (its SLQE then restarts) or ended
                if not track.held:
                    track.held, track.held_s, track.behind = True, stamp_s, behind
                track.last = _held(track.last)
                if self._left(track.last, depth, intrinsics) or self._duplicate(track.last,
                                                                                stamp_s):
                    gone.append(track)
                continue
            if i in seen and track.held:
                track.stage.reset()
                track.held = False
            det = detections[seen[i]] if i in seen else JointSet.missing(track.names)
            hidden = None
            if i in seen and track.id and cfg.hold_occluded and track.last is not None:
                hidden = self._hidden(det, points[seen[i]][0], [
                    (detections[j], points[j][0]) for j in seen.values() if j != seen[i]],
                    intrinsics)
            if hidden is not None:
                # the joints on a nearer person's body: their last estimates kept
                det = _without(det, hidden)
            # checked above (`_without` and `JointSet.missing` only make joints MISSING)
            out = track.stage.step(det, stamp_s, intrinsics, checked=True)
            if hidden is not None:
                out = _kept(out, track.last, hidden)
            track.names = out.names
            if i not in seen and track.id and (self._left(out, depth, intrinsics)
                                               or self._duplicate(out, stamp_s)):
                gone.append(track)
                continue
            if i in seen:
                self._seen(track, out, stamp_s)
                if not track.id and (track.hits >= cfg.confirm_frames or seen[i] in trusted):
                    track.id, self.next_id = self.next_id, self.next_id + 1
                    self.born.append(track.id)
            track.last = _with_track_id(out, track.id)
        # a tentative track must be matched every frame (a confirmed one: `max_unseen_s`)
        self.tracks = [t for t in self.tracks
                       if (t.id or t.seen_s == stamp_s) and t not in gone]
        self.ended += [t.id for t in gone]
        return self._published(stamp_s, intrinsics)

    def _released(self, track: _Track, stamp_s: float) -> bool:
        """`held_needs_front`: a held track unseen with nobody seen in front of it any more
        is not hidden, only unseen: no longer held; whether it has ended (unseen longer than
        `max_unseen_s`)."""
        cfg = self.config
        if not cfg.held_needs_front or self._behind(track, stamp_s):
            return False
        track.held = False
        return stamp_s - track.seen_s > cfg.max_unseen_s

    def _published(self, stamp_s: float, intrinsics: Intrinsics | None) -> list[JointSet]:
        """The skeletons published (by their person's sides: `facing`), primary first; kept,
        not published: a pose held too long (mostly where nobody is), a span over `max_span_m`
        or (with 3-D) under `min_span_m`, a second skeleton on one body (`one_body_m`),
        shoulders `max_shoulders_m` apart, unseen at the image's side (`max_unseen_at_side_s`)."""
        cfg, has_3d = self.config, intrinsics is not None
        least = cfg.min_span_m if has_3d else 0.0
        published: list[_Track] = []
        for t in self._ordered(stamp_s):
            wide = has_3d and self._too_wide(t)
            out = has_3d and not t.held and stamp_s - t.seen_s > cfg.max_unseen_at_side_s \
                and not _clear_of_sides(t.last, intrinsics)  # most often walked out
            if not (t.held and stamp_s - t.held_s > cfg.max_held_s or wide or out) \
                    and least <= span_m(t.last) <= cfg.max_span_m \
                    and not self._on_body(t, published):
                published.append(t)
        return [t.facing.of(t.last) for t in published]

    def _too_wide(self, track: _Track) -> bool:
        """Whether the track's shoulders have lain over `max_shoulders_m` apart in 3-D, the
        median over its frames (this one's counted)."""
        if not self.config.max_shoulders_m > 0:
            return False
        if math.isfinite(width := shoulders_m(track.last)):
            track.shoulders_m.append(width)
        return bool(track.shoulders_m) and \
            float(np.median(track.shoulders_m)) > self.config.max_shoulders_m

    def _on_body(self, track: _Track, others: list[_Track]) -> bool:
        """Whether `track`'s torso lies where a piece of the body of one of `others` would:
        below their torso in the image and no nearer the camera, within `one_body_m` of their
        body's axis in 3-D and at most `LEGS_M` below their hips along it (`axis_position`).
        Seen from above, a person's legs lie there (`one_body_m`)."""
        if not self.config.one_body_m > 0 or not others:
            return False
        point, _ = torso(track.last)
        pixel, _ = torso_px(track.last)
        if not (_finite(point) and _finite(pixel)):
            return False
        for other in others:
            theirs, _ = torso(other.last)
            theirs_px, _ = torso_px(other.last)
            if _finite(theirs) and point[2] >= theirs[2] and pixel[1] > theirs_px[1]:
                off, below = axis_position(point, other.last)
                if off <= self.config.one_body_m and below <= LEGS_M:
                    return True
        return False

    def _left(self, joints: JointSet | None,
              depth: Callable[[], NDArray[np.floating] | None],
              intrinsics: Intrinsics | None) -> bool:
        """Whether an unseen track's person has left: the depth image shows free space where
        `joints` put them (`free_space`; never without depth or with `free_space_m` 0)."""
        return (joints is not None and self.config.free_space_m > 0
                and (depth_m := depth()) is not None
                and free_space(joints, depth_m, intrinsics, self.config))

    def _duplicate(self, joints: JointSet | None, stamp_s: float) -> bool:
        """Whether an unseen track's person is one seen this frame under another id: its torso
        pixel in the box of a confirmed track seen this frame (`_in_box`; an unseen track is
        not one) and its torso's depth within `same_person_m` of theirs."""
        if joints is None or not self.config.same_person_m > 0:
            return False
        point, _ = torso(joints)
        pixel, _ = torso_px(joints)
        if not (_finite(point) and _finite(pixel)):
            return False
        return any(other.id and other.seen_s == stamp_s and other.last is not None
                   and _finite(other.point)
                   and abs(point[2] - other.point[2]) <= self.config.same_person_m
                   and _in_box(other.last, pixel) for other in self.tracks)

    def _match(self, detections: Sequence[JointSet], points: list[tuple[NDArray, NDArray]],
               cost: NDArray[np.float64], intrinsics: Intrinsics | None, depth: _FrameDepth
               ) -> tuple[dict[int, int], set[int], dict[int, set[int]], list[tuple[int, int]]]:
        """The assignment on `cost` ({detection: track}), the detections trusted at once,
        those emerging from behind a nearer person, and the pairs (track, detection) whose
        track refuses the detection (`_refuses`)."""
        matched = {j: i for i, j in self._assign(cost)}
        trusted = self._trusted(detections, matched)
        emerging = self._emerging(detections, points, matched)
        refused = [(i, j) for j, i in matched.items() if self._refuses(
            self.tracks[i], self._born(detections[j], self._partly_seen(
                detections[j], j in emerging, depth, intrinsics)), emerging.get(j))]
        return matched, trusted, emerging, refused

    def _refuses(self, track: _Track, born: bool, fronts: set[int] | None) -> bool:
        """Whether `track` refuses a detection assigned to it (`born`: it may start a track;
        `fronts`: the ids of the people it comes out from behind): a held track one away
        from where its person would come out (`_elsewhere`), a tentative track or one
        unseen beside another person one that could not start a track (`_continues`)."""
        out = _out_from_behind(track, fronts, self.config.held_own_front)
        return self._elsewhere(track, out) or (not born and not self._continues(track, out))

    def _assign(self, cost: NDArray[np.float64]) -> list[tuple[int, int]]:
        """`assign` for the confirmed tracks first, then for the tentative ones on the
        detections left: a track just started beside a confirmed one never takes its person's
        detection from it (the confirmed one would go on unseen, predicted where nobody is),
        unless it fits it far better (`yielded`: `tentative_margin`)."""
        gate = self.config.gate_chi2
        tentative = [i for i, t in enumerate(self.tracks) if not t.id]
        if not (self.config.confirmed_first and tentative):
            return assign(cost, gate)
        rows = [i for i, t in enumerate(self.tracks) if t.id]
        first = yielded(cost[rows], cost[tentative], self.config.tentative_margin)
        pairs = [(rows[r], c) for r, c in assign(first, gate)]
        taken = {c for _, c in pairs}
        left = [c for c in range(cost.shape[1]) if c not in taken]
        if left:
            pairs += [(tentative[r], left[c])
                      for r, c in assign(cost[np.ix_(tentative, left)], gate)]
        return pairs

    def _trusted(self, detections: Sequence[JointSet], matched: dict[int, int]) -> set[int]:
        """The detections confirmed at their first frame: none while a track is confirmed;
        with nobody tracked, every one scoring at least `trust_score`, or, when none does, the
        first not matched (the foreground's best region), as the single-person tracker trusts
        its one detection, if it scores at least `birth_score` (a desk in an empty room,
        trusted at the first frame, was a ghost on real recordings: lab_walk with the
        photograph network 111 -> 94 ghosts; validation renders unchanged)."""
        if any(t.id for t in self.tracks):
            return set()
        free = [j for j in range(len(detections)) if j not in matched]
        sure = {j for j in free if detections[j].score >= self.config.trust_score}
        return sure or {j for j in free[:1] if not detections[j].score < self.config.birth_score}

    def _hidden(self, det: JointSet, point: NDArray[np.float64],
                others: list[tuple[JointSet, NDArray[np.float64]]],
                intrinsics: Intrinsics | None) -> NDArray[np.bool_] | None:
        """(J,) the joints of `det` that lie on a nearer person's body: within
        `occluded_width_m` (at that person's depth) of one of their bones in the image, that
        person's torso nearer by over `torso_std_m`; None when there is none."""
        cfg = self.config
        if intrinsics is None or not _finite(point):
            return None
        hidden = np.zeros(len(det.names), bool)
        for other, q in others:
            if not (_finite(q) and q[2] < point[2] - cfg.torso_std_m):
                continue
            ok = (other.source != cj.MISSING) & np.isfinite(other.uv).all(axis=1)
            r = cfg.occluded_width_m * intrinsics.fx / q[2]
            for a, b in tree_for(other.names).edges():
                if ok[a] and ok[b]:
                    hidden |= _near_segment(det.uv, other.uv[a], other.uv[b], r)
        return hidden if hidden.any() else None

    def _checker(self) -> object:
        """A stage to check detections with while there is no track (made once)."""
        if self._spare is None:
            self._spare = self.template.spawn()
        return self._spare

    def _born(self, det: JointSet, emerging: bool = False) -> bool:
        """Whether a detection may start or grow a tentative track (`birth_score`, or
        `emerging_score` where it comes out from behind a nearer person)."""
        cfg = self.config
        least = min(cfg.birth_score, cfg.emerging_score) if emerging else cfg.birth_score
        return not det.score < least  # NaN: no score to judge by

    def _partly_seen(self, det: JointSet, emerging: bool, depth: _FrameDepth,
                     intrinsics: Intrinsics | None) -> bool:
        """Whether `det` is of a person partly seen, who starts or grows a tentative track from
        `emerging_score` (`_born`): coming out from behind a nearer person (`emerging`), or
        too near to be seen whole, cut by the image's bottom edge (a located joint at or below
        where the depth image's readings end, `seen_edges`; the depth is read only for a
        detection under `birth_score`), and clear of the image's sides (`_clear_of_sides`)."""
        if not (emerging or (det.score < self.config.birth_score
                             and _below_seen(det, depth.bottom))):
            return False
        return _clear_of_sides(det, intrinsics)

    def _continues(self, track: _Track, emerging: bool = False) -> bool:
        """Whether a confirmed track takes any detection: no other confirmed track exists (one
        person is tracked as the single-person tracker tracks them), or it was seen at the
        last frame, or it is held behind another and the detection is `emerging` from
        behind a nearer person (`held_continues`; elsewhere it takes none, `_elsewhere`).
        Otherwise only a detection that could start a track (`birth_score`) is its: what the
        gate of a track unseen beside another person reaches is often a part of the room."""
        if not track.id:
            return False
        if not any(t.id for t in self.tracks if t is not track):
            return True
        # a person held behind another comes out partly seen, and scores low meanwhile
        return track.seen_s == self._previous_s or (
            track.held and emerging and self.config.held_continues)

    def _elsewhere(self, track: _Track, emerging: bool) -> bool:
        """Whether a track held behind a nearer person is offered a detection away from where
        they would come out (`held_continues`), whatever its score."""
        return self.config.held_continues and track.held and not emerging

    def _emerging(self, detections: Sequence[JointSet], points: list[tuple[NDArray, NDArray]],
                  matched: dict[int, int]) -> dict[int, set[int]]:
        """The detections whose torso pixel lies in the box of a nearer person matched to a
        confirmed track (`_in_box`), farther by over `torso_std_m` in 3-D, each with the ids
        of those tracks: where a person hidden behind them comes out (a held track takes
        only a detection coming out from behind the person hiding it, `_out_from_behind`:
        its gate, grown with the time unseen, also reaches the room's clutter metres away,
        coming out from behind someone else), and where a tentative track may grow from
        `emerging_score`."""
        cfg = self.config
        if not ((cfg.held_continues and any(t.held for t in self.tracks))
                or (cfg.emerging_score < cfg.birth_score and len(detections) > 1)):
            return {}
        fronts = [(k, self.tracks[i].id, detections[k], points[k][0])
                  for k, i in matched.items() if self.tracks[i].id and _finite(points[k][0])]
        out: dict[int, set[int]] = {}
        for j, (point, _) in enumerate(points):
            pixel = torso_px(detections[j])[0]
            if not (_finite(pixel) and _finite(point)):
                continue
            ids = {t for k, t, other, q in fronts if k != j and point[2] > q[2] + cfg.torso_std_m
                   and _in_box(other, pixel)}
            if ids:
                out[j] = ids
        return out

    def _behind(self, track: _Track, stamp_s: float) -> int:
        """The id of the track of a person seen this frame whom an unseen track's person is
        hidden behind (0: nobody): their last torso pixel within that person's box (its
        located joints, grown by a tenth of its height) and their torso farther by over
        `torso_std_m` (both in 3-D)."""
        if not (_finite(track.pixel) and _finite(track.point)):
            return 0
        for other in self.tracks:
            if other is track or not other.id or other.seen_s != stamp_s or other.last is None \
                    or not _finite(other.point) \
                    or not track.point[2] > other.point[2] + self.config.torso_std_m:
                continue
            if _in_box(other.last, track.pixel):
                return other.id
        return 0

    def _cost(self, detections: Sequence[JointSet], points: list[tuple[NDArray, NDArray]],
              stamp_s: float) -> NDArray[np.float64]:
        """Squared Mahalanobis torso distances (tracks x detections) in 3-D; where a track or a
        detection has no 3-D torso, in the image, the spread a quarter of the person's height
        growing as in 3-D (at 2.5 m)."""
        cfg = self.config
        cost = np.full((len(self.tracks), len(points)), np.nan)
        seen = [j for j, (p, _) in enumerate(points) if _finite(p)]
        pairs, d, s = [], [], []
        for i, t in enumerate(self.tracks):
            if not _finite(t.point):
                continue
            dt = max(stamp_s - t.seen_s, 0.0)
            predicted = t.point + t.velocity * min(dt, cfg.max_unseen_s)
            spread = (cfg.torso_std_m ** 2 + (cfg.max_speed_mps * dt) ** 2) * _EYE3
            for j in seen:
                p, c = points[j]
                pairs.append((i, j))
                d.append(p - predicted)
                s.append(t.cov + c + spread)
        if pairs:
            rows, cols = zip(*pairs, strict=True)
            cost[rows, cols] = _mahalanobis2_all(np.array(d), np.array(s))
        # where a track or a detection has no 3-D torso: in the image
        pixels = [torso_px(d) for d in detections]
        for i, t in enumerate(self.tracks):
            if t.size_px > 0 and _finite(t.pixel):
                dt = max(stamp_s - t.seen_s, 0.0)
                sigma = 0.25 * t.size_px * (1.0 + cfg.max_speed_mps * dt / 0.5)
                for j, (uv, _) in enumerate(pixels):
                    if np.isnan(cost[i, j]) and _finite(uv):
                        cost[i, j] = float(np.sum((uv - t.pixel) ** 2)) / sigma ** 2
        return cost

    def _seen(self, track: _Track, out: JointSet, stamp_s: float) -> None:
        pixel, size = torso_px(out)
        if np.isfinite(pixel).all():
            track.pixel = pixel
            track.size_px = size if size > 0 else track.size_px
        point, cov = torso(out)
        if _finite(point):
            dt = stamp_s - track.seen_s
            if _finite(track.point) and 0 < dt <= self.config.max_unseen_s:
                track.velocity = 0.7 * track.velocity + 0.3 * (point - track.point) / dt
            track.point, track.cov = point, cov
            track.facing.update(stamp_s, point)
        track.hits += 1
        track.seen_s = stamp_s

    def _ordered(self, stamp_s: float) -> list[_Track]:
        confirmed = sorted((t for t in self.tracks if t.id), key=lambda t: t.id)
        seen = [t for t in confirmed if t.seen_s == stamp_s]
        # the longest tracked: seen in most frames (the first confirmed on a tie)
        primary = sorted(seen or confirmed, key=lambda t: -t.hits)[:1]
        return primary + [t for t in confirmed if t not in primary]


def free_space(joints: JointSet, depth_m: NDArray[np.floating], intrinsics: Intrinsics | None,
               config: TrackingConfig) -> bool:
    """Whether the depth image shows that nobody is where `joints` (an unseen track's
    prediction) puts a person: its torso point projects outside the image, or at least
    `free_share` of the depth readings in a square of the torso's size (0.3 m) around it lie
    over `free_space_m` beyond it (the camera sees through where the person would be). A person
    hidden behind something nearer, or in a hole of the depth image, is not free space."""
    point, _ = torso(joints)
    if intrinsics is None or not _finite(point) or point[2] <= 0:
        return False
    u, v = project(point[None], intrinsics)[0]
    h, w = depth_m.shape
    if not (0 <= u < w and 0 <= v < h):
        return True
    r = max(int(0.15 * intrinsics.fx / point[2]), 1)
    x, y = int(u), int(v)
    window = depth_m[max(y - r, 0):y + r + 1, max(x - r, 0):x + r + 1]
    readings = window[np.isfinite(window)]
    if readings.size < 0.25 * window.size:
        return False
    return bool(np.count_nonzero(readings > point[2] + config.free_space_m)
                >= config.free_share * readings.size)


def _out_from_behind(track: _Track, fronts: set[int] | None, own_front: bool) -> bool:
    """Whether a detection coming out from behind the people of the track ids `fronts`
    (`PeopleTracker._emerging`; None: from behind nobody) comes out where `track`'s person
    would: with `own_front`, for a track held behind a person, from behind that person only
    (not seen this frame, nobody comes out from behind them); otherwise from behind anyone."""
    return bool(fronts) and (not (own_front and track.held) or track.behind in fronts)


def _finite(v: NDArray[np.float64]) -> bool:
    """Every value finite (`np.isfinite(v).all()` without its Python wrapper)."""
    return bool(np.logical_and.reduce(np.isfinite(v), axis=None))


# a detection reaching this share of the image's width from its left or right edge starts no
# track from `emerging_score` (`_clear_of_sides`)
SIDE_SHARE = 0.04
# how far below a person's hips a piece of their body may lie (`_on_body`): a tall person's
# legs, hip to sole, with room for a skeleton's hips placed high
LEGS_M = 1.3


def _below_seen(det: JointSet, bottom: int | None) -> bool:
    """Whether a located joint of `det` lies at or below `bottom`, the depth image's last row
    of readings (`_FrameDepth.bottom`): the person is cut by the image's bottom edge. False
    without depth (None)."""
    if bottom is None:
        return False
    v = det.uv[det.source != cj.MISSING, 1]
    return bool(np.any(v >= bottom - 1))


def _clear_of_sides(det: JointSet, intrinsics: Intrinsics | None) -> bool:
    """Whether every located joint of `det` lies farther than `SIDE_SHARE` of the image's
    width from its left and right edges. Behind a person near the image's side, a wall's edge
    or furniture cut by the border is a candidate that scores as a partly seen person does
    (on validation, `valid60_people3` and `valid60_people3b`: 3.5-4, where people coming out
    from behind another score 3.4-5), and the foreground already counts a region cut by the
    side borders as more often no person (`PersonConfig.border_penalty`)."""
    if intrinsics is None:
        return False
    u = det.uv[det.source != cj.MISSING, 0]
    margin = SIDE_SHARE * intrinsics.width
    return bool(u.size) and bool(np.all((u > margin) & (u < intrinsics.width - 1 - margin)))


def axis_position(point: NDArray[np.float64], joints: JointSet) -> tuple[float, float]:
    """Where `point` lies from the axis of the body of `joints` (the line through the mean of
    its located hips and that of its located shoulders and neck), in 3-D: its distance from
    the axis and how far below the hips along it (negative above them), metres. Without an
    axis (hips, or shoulders and neck, missing): the distance to the torso point and 0 (inf
    and 0 without one). Seen from above, a person's legs lie on that line, below the hips."""
    located = (joints.source != cj.MISSING) & np.logical_and.reduce(np.isfinite(joints.xyz),
                                                                    axis=1)
    hips, top = (_mean_of(joints, located, rows) for rows in _axis_rows(joints.names))
    if not (_finite(hips) and _finite(top)) or not (length := float(np.linalg.norm(
            top - hips))) > 0:
        theirs, _ = torso(joints)
        return (float(np.linalg.norm(point - theirs)) if _finite(theirs) else math.inf), 0.0
    v = point - hips
    along = float(v @ (top - hips)) / length
    return math.sqrt(max(float(v @ v) - along * along, 0.0)), -along


@functools.lru_cache(maxsize=16)
def _axis_rows(names: tuple[str, ...]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The rows of the hips and those of the shoulders and neck in `names`."""
    return (tuple(names.index(n) for n in ('left_hip', 'right_hip') if n in names),
            tuple(names.index(n) for n in ('left_shoulder', 'right_shoulder', 'neck')
                  if n in names))


def _mean_of(joints: JointSet, located: NDArray[np.bool_],
             rows: tuple[int, ...]) -> NDArray[np.float64]:
    """The mean 3-D position of the located joints among `rows` (NaN if none)."""
    rows = [r for r in rows if located[r]]
    return joints.xyz[rows].mean(axis=0) if rows else np.full(3, np.nan)


def _in_box(joints: JointSet, pixel: NDArray[np.float64]) -> bool:
    """Whether `pixel` lies in the box of the located joints (at least two), grown by a tenth
    of its height."""
    uv = joints.uv[(joints.source != cj.MISSING) & np.isfinite(joints.uv).all(axis=1)]
    if len(uv) < 2:
        return False
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    grow = 0.1 * (hi[1] - lo[1])
    return bool(np.all(pixel >= lo - grow) and np.all(pixel <= hi + grow))


def _near_segment(p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64],
                  r: float) -> NDArray[np.bool_]:
    """(N,) points of p (N, 2) within r of the segment a-b."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-9), 0.0, 1.0)
    d = p - (a + t[:, None] * ab)
    with np.errstate(invalid='ignore'):
        return (d * d).sum(axis=1) <= r * r


def _without(det: JointSet, hidden: NDArray[np.bool_]) -> JointSet:
    """`det` with the joints `hidden` MISSING."""
    uv, xyz = det.uv.copy(), det.xyz.copy()
    source, conf = det.source.copy(), det.confidence.copy()
    uv[hidden], xyz[hidden], source[hidden], conf[hidden] = np.nan, np.nan, cj.MISSING, 0.0
    return JointSet.of_arrays(det.names, uv, xyz, conf, source, det.covariance,
                              score=det.score, track_id=det.track_id)


def _kept(out: JointSet, last: JointSet, hidden: NDArray[np.bool_]) -> JointSet:
    """The tracker's output `out` with the joints `hidden` at their estimate of `last`
    (TRACKED) where it has one."""
    keep = hidden & (last.source != cj.MISSING)
    if out.names != last.names or not keep.any():
        return out
    uv, xyz, source = out.uv.copy(), out.xyz.copy(), out.source.copy()
    uv[keep], xyz[keep], source[keep] = last.uv[keep], last.xyz[keep], cj.TRACKED
    return JointSet.of_arrays(out.names, uv, xyz, out.confidence, source, out.covariance,
                              score=out.score, track_id=out.track_id)


def _held(joints: JointSet | None) -> JointSet | None:
    """A track's last pose kept while its person is hidden: every located joint TRACKED."""
    if joints is None:
        return None
    source = np.where(joints.source == cj.MISSING, cj.MISSING, cj.TRACKED).astype(np.uint8)
    return JointSet.of_arrays(joints.names, joints.uv, joints.xyz, joints.confidence, source,
                              joints.covariance, score=joints.score, track_id=joints.track_id)


def _with_track_id(joints: JointSet, track_id: int) -> JointSet:
    """`joints` with another `track_id`, sharing its (read-only) arrays."""
    return JointSet.of_arrays(joints.names, joints.uv, joints.xyz, joints.confidence,
                              joints.source, joints.covariance, score=joints.score,
                              track_id=track_id)


_EYE3 = np.eye(3)
_EYE3.setflags(write=False)
