"""Scoring on real recordings without joint labels: agreement with a reference (MediaPipe Pose on
the same colour frames) and, where hand labels exist, people found and ghosts.

- **Agreement.** In every frame where the reference found a person, its confident joints
  (visibility >= `MIN_REFERENCE_CONFIDENCE`) are compared with the skeleton of ours that agrees
  with it best (most joints within the threshold, then the smallest median distance): the share
  of those joints where ours lies within `alpha` x the person's height in pixels (0.1 and 0.2).
  The person's height is the hand-labelled head-to-feet distance of the labelled person around
  the reference's torso where there is one, else the reference's own chain head - shoulders'
  midpoint - hips' midpoint - knees' midpoint - ankles' midpoint (about 0.85 of a standing
  person's stature: a stricter threshold than the stature's). A frame whose reference person
  has neither is not scored (counted in `no_height`). MediaPipe Pose finds one person a frame:
  the agreement covers that person only.
- **People and ghosts** (hand labels: `read_labels`, a box around every person seen). A
  skeleton is on a labelled person when its torso centre (the mean of its shoulders and hips
  present) lies in the person's box grown by `BOX_MARGIN` of its size; a skeleton on nobody is
  a ghost. A labelled person is found when a skeleton is on them (one skeleton finds one
  person: the nearest box centre). The same for the reference's one skeleton.

- **3-D steadiness** (`bone_steadiness`): with no 3-D truth, how steady each person's limb
  bones are in 3-D over their track (upper arms, forearms, thighs, shins: a real bone keeps
  its length): the median over bones and tracks of the bones' median absolute deviation from
  their median length, relative to it, and the share of lengths within 25 % of the track's
  median. MediaPipe's joints are lifted as its peer row lifts them (the depth at the pixel),
  its one person a frame taken as one track per video (MediaPipe may switch between people
  within it, which counts against it). Steadiness is not accuracy: the IK completes our
  elbows and knees on each person's learned bone lengths, so ours is steadier by design where
  it infers them; a skeleton can be steady and wrong.

Hand labels are JSON: {"source": ..., "frames": {name: [{"box": [x0, y0, x1, y1],
"visible": "full" | "partial", "seated": bool, "head": [u, v] | null, "feet": [u, v] |
null}, ...]}}, a frame's name being its `Frame.key` after the folder ('lab_walk/0001' ->
'0001').
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.draw import draw_people, draw_skeleton
from pose4d_ros.core.files import write_atomic
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.skeleton import JOINT_GROUPS, LIMBS, SKELETON_14, limb_bones
from pose4d_ros.datasets.frame import Frame

MIN_REFERENCE_CONFIDENCE = 0.5
ALPHAS = (0.1, 0.2)
BOX_MARGIN = 0.1
TORSO = ('left_shoulder', 'right_shoulder', 'left_hip', 'right_hip')
# The reference's chain whose length in pixels stands for the person's height
HEIGHT_CHAIN = (('head',), ('left_shoulder', 'right_shoulder'), ('left_hip', 'right_hip'),
                ('left_knee', 'right_knee'), ('left_ankle', 'right_ankle'))


@dataclass(frozen=True)
class PersonLabel:
    """One hand-labelled person: a box around what is seen of them (pixels x0, y0, x1, y1),
    whether the whole body is in view, seated, and the head's and feet's pixels (or None)."""

    box: tuple[float, float, float, float]
    visible: str = 'full'
    seated: bool = False
    head: tuple[float, float] | None = None
    feet: tuple[float, float] | None = None

    def holds(self, uv: NDArray[np.floating]) -> bool:
        """True when pixel `uv` lies in the box grown by `BOX_MARGIN` of its size."""
        x0, y0, x1, y1 = self.box
        mx, my = BOX_MARGIN * (x1 - x0), BOX_MARGIN * (y1 - y0)
        return bool(x0 - mx <= uv[0] <= x1 + mx and y0 - my <= uv[1] <= y1 + my)

    @property
    def centre(self) -> NDArray[np.float64]:
        x0, y0, x1, y1 = self.box
        return np.array([(x0 + x1) / 2, (y0 + y1) / 2])

    @property
    def height_px(self) -> float | None:
        """Head to feet in pixels, None unless both are labelled."""
        if self.head is None or self.feet is None:
            return None
        return float(np.hypot(self.head[0] - self.feet[0], self.head[1] - self.feet[1]))


def read_labels(path: str | Path) -> dict[str, list[PersonLabel]]:
    """Hand labels (see the module's format): {frame name: [PersonLabel]}; ValueError naming
    the file and the frame on a malformed entry."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        frames = doc['frames']
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f'{path}: not a labels file ({exc})') from exc
    out = {}
    for name, people in frames.items():
        try:
            out[str(name)] = [PersonLabel(
                box=tuple(float(v) for v in p['box']), visible=str(p.get('visible', 'full')),
                seated=bool(p.get('seated', False)),
                head=None if p.get('head') is None else tuple(float(v) for v in p['head']),
                feet=None if p.get('feet') is None else tuple(float(v) for v in p['feet']))
                for p in people]
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f'{path}: frame {name}: malformed person ({exc})') from exc
        for p in out[str(name)]:
            x0, y0, x1, y1 = p.box
            if not (x0 < x1 and y0 < y1) or p.visible not in ('full', 'partial'):
                raise ValueError(f'{path}: frame {name}: box {p.box} visible {p.visible!r}: '
                                 'needs x0 < x1, y0 < y1 and visible full or partial')
    return out


def frame_name(frame: Frame) -> str:
    """A frame's name in its hand labels: its key after the folder."""
    return frame.key.rsplit('/', 1)[-1]


def _point(joints: JointSet, names: Sequence[str], ok: NDArray[np.bool_]
           ) -> NDArray[np.float64] | None:
    idx = [i for n in names if (i := joints.get(n)) is not None and ok[i]]
    return joints.uv[idx].mean(axis=0) if idx else None


def present(joints: JointSet, min_confidence: float = 0.0) -> NDArray[np.bool_]:
    """The joints with a pixel (not MISSING), at least `min_confidence` confident."""
    return (np.isfinite(joints.uv).all(axis=1) & (joints.source != cj.MISSING)
            & (joints.confidence >= min_confidence))


def torso_centre(joints: JointSet, min_confidence: float = 0.0) -> NDArray[np.float64] | None:
    """The mean pixel of the shoulders and hips present (None if none is)."""
    return _point(joints, TORSO, present(joints, min_confidence))


def chain_height(joints: JointSet, min_confidence: float = MIN_REFERENCE_CONFIDENCE
                 ) -> float | None:
    """The length in pixels of `HEIGHT_CHAIN` through the joints, None unless all of it is
    present and confident."""
    ok = present(joints, min_confidence)
    pts = []
    for names in HEIGHT_CHAIN:
        idx = [joints.get(n) for n in names]
        if any(i is None or not ok[i] for i in idx):
            return None
        pts.append(joints.uv[idx].mean(axis=0))
    return float(sum(np.hypot(*(b - a)) for a, b in zip(pts[:-1], pts[1:], strict=True)))


def assign(people: Sequence[JointSet], labels: Sequence[PersonLabel]) -> list[int | None]:
    """For each skeleton, the labelled person it is on (index into `labels`) or None (a
    ghost): torso centre inside the grown box, one skeleton per person, nearest centres first."""
    pairs = []
    for i, p in enumerate(people):
        c = torso_centre(p)
        if c is None:
            continue
        for j, lab in enumerate(labels):
            if lab.holds(c):
                pairs.append((float(np.hypot(*(c - lab.centre))), i, j))
    out: list[int | None] = [None] * len(people)
    taken = set()
    for _, i, j in sorted(pairs):
        if out[i] is None and j not in taken:
            out[i] = j
            taken.add(j)
    return out


def _best_match(reference: JointSet, ours: Sequence[JointSet], names: Sequence[str],
                tolerance_px: float) -> tuple[NDArray[np.float64], JointSet | None]:
    """The distances (px; inf where ours has no pixel) of the reference's joints `names` to
    the skeleton of ours agreeing best, and that skeleton (None if we have none)."""
    ref = np.array([reference.uv[reference.index(n)] for n in names])
    best, best_key = np.full(len(names), np.inf), None
    chosen = None
    for p in ours:
        ok = present(p)
        uv = np.array([p.uv[i] if (i := p.get(n)) is not None and ok[i] else (np.nan, np.nan)
                       for n in names])
        d = np.hypot(*(uv - ref).T)
        d = np.where(np.isfinite(d), d, np.inf)
        key = (-(d <= tolerance_px).sum(), float(np.median(d)))
        if best_key is None or key < best_key:
            best, best_key, chosen = d, key, p
    return best, chosen


def agreement(frames: Sequence[Frame], ours: Sequence[Sequence[JointSet]],
              reference: Sequence[JointSet],
              labels: dict[str, list[PersonLabel]] | None = None) -> dict:
    """The agreement table of our skeletons (every person's, a tuple a frame) with the
    reference's (one a frame) and, with `labels`, people found and ghosts (module docstring)."""
    names = [n for n in SKELETON_14 if n in reference[0].names] if reference else []
    group = {n: g for g, members in JOINT_GROUPS.items() for n in members}
    within = {a: [] for a in ALPHAS}
    groups: dict[str, list[bool]] = {g: [] for g in JOINT_GROUPS}
    offsets: dict[str, list[NDArray[np.float64]]] = {g: [] for g in JOINT_GROUPS}
    per_frame, no_height, scored = [], 0, 0
    people = {'ours': [], 'reference': [], 'labelled': []}
    found = {'ours': 0, 'reference': 0, 'labelled': 0, 'labelled_full': 0, 'ours_full': 0,
             'reference_full': 0}
    ghosts = {'ours': 0, 'reference': 0}
    ghost_frames = []
    for frame, mine, ref in zip(frames, ours, reference, strict=True):
        mine = tuple(mine)
        ref_ok = present(ref, MIN_REFERENCE_CONFIDENCE)
        ref_people = (ref,) if ref_ok.any() else ()
        people['ours'].append(len(mine))
        people['reference'].append(len(ref_people))
        labs = None if labels is None else labels.get(frame_name(frame))
        if labels is not None and labs is None:
            raise ValueError(f'{frame.key}: no hand labels for frame {frame_name(frame)!r}')
        entry = {'frame': frame.key, 'ours': len(mine), 'reference': len(ref_people)}
        if labs is not None:
            people['labelled'].append(len(labs))
            found['labelled'] += len(labs)
            found['labelled_full'] += sum(lab.visible == 'full' for lab in labs)
            for who, skeletons in (('ours', mine), ('reference', ref_people)):
                on = assign(skeletons, labs)
                hit = [j for j in on if j is not None]
                found[who] += len(hit)
                found[f'{who}_full'] += sum(labs[j].visible == 'full' for j in hit)
                ghosts[who] += on.count(None)
                if who == 'ours' and None in on:
                    ghost_frames.append(frame.key)
            entry['labelled'] = len(labs)
        if ref_people:
            height = None
            if labs:
                c = torso_centre(ref, MIN_REFERENCE_CONFIDENCE)
                on = [lab for lab in labs if c is not None and lab.holds(c)]
                if on:
                    height = min(on, key=lambda lab: np.hypot(*(c - lab.centre))).height_px
            height = height or chain_height(ref)
            if height is None:
                no_height += 1
            else:
                scored += 1
                idx = [n for n in names if ref_ok[ref.index(n)]]
                d, chosen = _best_match(ref, mine, idx, ALPHAS[0] * height)
                if chosen is not None:
                    for n, dist in zip(idx, d, strict=True):
                        if np.isfinite(dist):
                            offsets[group[n]].append(
                                (chosen.uv[chosen.index(n)] - ref.uv[ref.index(n)]) / height)
                for a in ALPHAS:
                    within[a].extend(d <= a * height)
                for n, ok in zip(idx, d <= ALPHAS[0] * height, strict=True):
                    groups[group[n]].append(bool(ok))
                entry['agree'] = round(100 * float(np.mean(d <= ALPHAS[0] * height)), 1)
                entry['height_px'] = round(height, 1)
        per_frame.append(entry)

    def pct(v: list) -> float | None:
        return round(100 * float(np.mean(v)), 1) if v else None

    table = {
        'frames': len(frames), 'scored_frames': scored, 'no_height': no_height,
        'joints': len(within[ALPHAS[0]]),
        **{f'agree@{a}': pct(within[a]) for a in ALPHAS},
        'agree@0.1_by_group': {g: pct(v) for g, v in groups.items()},
        # where ours lie from the reference's, (dx, dy) over the person's height (image y
        # down), medians over the joints of the skeleton of ours agreeing best
        'offset_by_group': {g: [round(float(x), 3) for x in np.median(v, axis=0)]
                            for g, v in offsets.items() if v},
        'people_per_frame': {k: round(float(np.mean(v)), 3) for k, v in people.items() if v},
        'per_frame': per_frame,
    }
    if labels is not None:
        table['labels'] = {**found, 'ghosts': ghosts, 'ghost_frames': ghost_frames}
    return table


# the bones whose 3-D length `bone_steadiness` follows: (root, middle) and (middle, end) of
# every limb
STEADY_BONES = tuple(pair for root, middle, end in LIMBS.values()
                     for pair in ((root, middle), (middle, end)))
STEADY_SHARE = 0.25


def bone_steadiness(frames: Sequence[Frame], people: Sequence[Sequence[JointSet]]) -> dict:
    """How steady the people's limb bones are in 3-D over their tracks (module docstring):
    `mad_rel` the median relative deviation of a bone's length from its track's median,
    `within` the share of lengths within `STEADY_SHARE` of it (%), `lengths` how many were
    measured. A skeleton's track is its `track_id` within its video (0: one track a video)."""
    lengths: dict[tuple[str, int, tuple[str, str]], list[float]] = {}
    for frame, skeletons in zip(frames, people, strict=True):
        for p in skeletons:
            ok = present(p) & np.isfinite(p.xyz).all(axis=1)
            for a, b in STEADY_BONES:
                i, j = p.get(a), p.get(b)
                if i is not None and j is not None and ok[i] and ok[j]:
                    lengths.setdefault((frame.video, int(p.track_id), (a, b)), []).append(
                        float(np.linalg.norm(p.xyz[i] - p.xyz[j])))
    rel, within, n = [], [], 0
    for values in lengths.values():
        v = np.asarray(values)
        if len(v) < 3 or not np.median(v) > 0:
            continue
        m = float(np.median(v))
        rel.append(float(np.median(np.abs(v - m))) / m)
        within.extend(np.abs(v - m) <= STEADY_SHARE * m)
        n += len(v)
    return {'mad_rel': round(float(np.median(rel)), 4) if rel else None,
            'within': round(100 * float(np.mean(within)), 1) if within else None,
            'lengths': n}


def draw_frames(frames: Sequence[Frame], ours: Sequence[Sequence[JointSet]],
                reference: Sequence[JointSet], out_dir: Path,
                labels: dict[str, list[PersonLabel]] | None = None) -> list[Path]:
    """Every frame as a JPEG in `out_dir`: ours (each person in their track's colour) on the
    left, the reference on the right (its confident joints), hand-labelled boxes in both."""
    out_dir.mkdir(parents=True, exist_ok=True)
    bones = limb_bones()
    paths = []
    for frame, mine, ref in zip(frames, ours, reference, strict=True):
        mine = [_on_14(p) for p in mine]
        conf = present(ref, MIN_REFERENCE_CONFIDENCE)
        ref14 = _on_14(JointSet(ref.names, np.where(conf[:, None], ref.uv, np.nan),
                                source=np.where(conf, cj.DETECTED, cj.MISSING)))
        left = draw_people(frame.color, mine, bones, scale=1)
        right = draw_skeleton(frame.color, ref14, bones, scale=1)
        for img in (left, right):
            for lab in (labels or {}).get(frame_name(frame), []):
                x0, y0, x1, y1 = (int(round(v)) for v in lab.box)
                cv2.rectangle(img, (x0, y0), (x1, y1),
                              (255, 255, 255) if lab.visible == 'full' else (160, 160, 160), 1)
        for img, text in ((left, f'pose4d: {len(mine)} people'), (right, 'reference')):
            for c, w in (((0, 0, 0), 3), ((255, 255, 255), 1)):
                cv2.putText(img, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, c, w,
                            cv2.LINE_AA)
        path = out_dir / (frame.key.replace('/', '_') + '.jpg')
        ok, jpg = cv2.imencode('.jpg', np.hstack([left, right])[:, :, ::-1],
                               [cv2.IMWRITE_JPEG_QUALITY, 85])
        if not ok:
            raise ValueError(f'{path}: could not encode')
        write_atomic(path, jpg.tobytes())
        paths.append(path)
    return paths


def _on_14(joints: JointSet) -> JointSet:
    """The joints laid out as `SKELETON_14` (absent ones MISSING), for drawing its bones; a
    missing neck is the shoulders' midpoint."""
    uv = np.full((len(SKELETON_14), 2), np.nan)
    src = np.full(len(SKELETON_14), cj.MISSING, np.uint8)
    ok = present(joints)
    for k, n in enumerate(SKELETON_14):
        i = joints.get(n)
        if i is not None and ok[i]:
            uv[k], src[k] = joints.uv[i], joints.source[i]
    if src[1] == cj.MISSING and (src[[2, 5]] != cj.MISSING).all():
        uv[1], src[1] = uv[[2, 5]].mean(axis=0), cj.INFERRED
    return JointSet(SKELETON_14, uv, source=src, track_id=joints.track_id)
