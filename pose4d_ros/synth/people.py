"""Several people in one synthetic video (`pose4d synth --people N`, issue 34).

Person 1 of a video is its plan's window of real motion (`video.VideoPlan`), exactly as in a
single-person video; persons 2..N are companions (`video.Companion`): each another window of
real motion, from another take where the run has one (other subjects' takes first), else from
another stretch of the same take (`companion_windows`), each on its own random body. All of
them stand in one room (`scene.random_scene` with a zone `people_zone` wide enough for all),
placed together by `place_people`: side by side 1-4 m apart laterally (at most what the view
holds), at different distances from the camera (the distance range cut into N strata, one
each), no two closer than 0.55 m on the floor, each inside the view and clear of the furniture
in as many frames as can be had.

A crossing video (a share of them, `crossing_videos`, `pose4d synth --crossing`) has one
person walk past in front of its lateral neighbour: a lateral drift at a slow walking pace
(0.25-0.6 m/s) added to the nearer person's recorded motion carries it from one side of the
farther person to the other, with a stop of up to 0.8 s in line with it (the same image
column) about the middle of the video; the two are at least 1 m apart in depth. The farther
person is then hidden, mostly or wholly, for up to about a second, and comes back.

Random streams (`video.video_rng(plan, what)`): person 1 as in `video.prepare_video` (1 body,
2 room, 3 render noise, 4 arm jitter); 5 placement and crossing; person k >= 2: 10 k its
window, 10 k + 1 its body, 10 k + 4 its arm jitter.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.synth import render
from pose4d_ros.synth import scene as rooms
from pose4d_ros.synth.render import HC, LAN, LFT, RAN, RFT, Body
from pose4d_ros.synth.scene import Scene
from pose4d_ros.synth.video import (
    FPS,
    SIT_ACTIONS,
    Companion,
    Staging,
    TakeMotion,
    VideoJob,
    VideoPlan,
    _add_seat,
    jitter_arms,
    video_rng,
)

MAX_PEOPLE = 3
# The distances of several people unless told otherwise (`pose4d synth --distance`), metres:
# deeper than one person's, so that 2-3 people side by side fit the view.
PEOPLE_DISTANCE_M = (2.5, 4.0)
# Lateral gap between neighbours, metres (the upper end shrinks so that N people fit the view).
GAP_M = (1.0, 4.0)
VIEW_SPAN_M = 3.4  # about the view's width at 3 m: N people spread over at most this
MIN_APART_M = 0.55  # hips of two people on the floor, in every frame
HALF_WIDTH_M = 0.3  # a person's half width, for "in view"
CROSS_SPEED_M_S = (0.25, 0.6)  # the crossing person's lateral drift
CROSS_DEPTH_M = 1.2  # the crossing person is at least this much nearer
CROSS_HOLD_S = (0.2, 1.0)  # ... and stops in front of the other this long


def people_zone(staging: Staging) -> tuple[float, float, float, float]:
    """The room's free zone for several people's hips: room-frame (x0, x1, y0, y1) metres, as
    deep as `staging.person_zone` and wide enough for people side by side."""
    _, _, y0, y1 = staging.person_zone
    return (-1.9, 1.9, y0, y1)


def companion_windows(plan: VideoPlan, motions: Sequence[TakeMotion], people: int,
                      rng: Sequence[np.random.Generator]
                      ) -> list[tuple[TakeMotion, int, NDArray[np.int64]]]:
    """The motion of persons 2..`people` of a video: (take, start, frame indices) each.

    Each takes a take not yet used in the video, other subjects' takes first (in a random
    order), and a random window of the plan's length and stride in it; when the run has no
    unused take left, a window of one already used, as far from that take's windows as can
    be. A take shorter than the window holds its last frame (the person stands still).

    Parameters
    ----------
    plan : person 1's plan. motions : every take of the run. people : N (2-3).
    rng : one random stream per companion (N - 1).
    """
    by_name = {m.name: m for m in motions}
    used: dict[str, list[int]] = {plan.take: [plan.start]}
    span = (plan.n_frames - 1) * plan.stride + 1
    out = []
    for k in range(people - 1):
        r = rng[k]
        subjects = {by_name[t].subject for t in used if t in by_name} | {plan.subject}
        fresh = [m for m in motions if m.name not in used]
        other_subject = [m for m in fresh if m.subject not in subjects]
        pool = other_subject or fresh or [m for m in motions if m.name in used]
        motion = pool[int(r.integers(len(pool)))]
        free = max(len(motion.joints) - span, 0)
        starts = r.integers(0, free + 1, size=16)
        taken = used.get(motion.name, [])
        # the candidate farthest from the windows already taken from this take
        start = int(max(starts, key=lambda s: min((abs(int(s) - t) for t in taken),
                                                  default=0)))
        used.setdefault(motion.name, []).append(start)
        idx = np.minimum(start + plan.stride * np.arange(plan.n_frames), len(motion.joints) - 1)
        out.append((motion, start, idx))
    return out


def place_people(joints: Sequence[NDArray[np.float64]], scene: Scene, rng: np.random.Generator,
                 *, staging: Staging, crossing: bool,
                 times: NDArray[np.float64] | None = None, tries: int = 200
                 ) -> list[NDArray[np.float64]]:
    """Turn and move N windows of floor-frame motion side by side into the room.

    Each try draws every person's turn (`staging.turn_deg`), a distance in its own stratum of
    `staging.distance_m` (strata in a random order), and lateral gaps between neighbours
    (`GAP_M`, the upper end at most `VIEW_SPAN_M / (N - 1)`); a crossing video then replaces the
    nearer person's lateral place, in one random neighbouring pair, by a drift at
    `CROSS_SPEED_M_S` that puts it in line with the farther one about 35-65 % into the video,
    where it stays for `CROSS_HOLD_S` (at most 30 % of the video) before it walks on. A try
    costs a frame for each person whose hips leave `people_zone`, come within 0.35 m of
    furniture or 0.45 m behind an occluder, or whose body (`HALF_WIDTH_M`) leaves the view, and
    five for each pair closer than `MIN_APART_M` (or a crossing pair less than `CROSS_DEPTH_M`
    apart in depth); the cheapest try wins (the first that costs nothing).

    Parameters
    ----------
    joints : N arrays (F, 20, 3) metres, floor frame.
    times : (F,) seconds of the frames (default: 30 fps from 0).

    Returns
    -------
    N arrays (F, 20, 3) metres, room frame.
    """
    n = len(joints)
    f = len(joints[0])
    hips = [j[:, HC, :2] for j in joints]
    centres = [h.mean(axis=0) for h in hips]
    hip_z = float(np.median(np.concatenate([j[:, HC, 2] for j in joints])))
    furniture = scene.footprints(('furniture',))
    occluders = scene.footprints(('occluder',))
    x0, x1, y0, y1 = people_zone(staging)
    t = np.arange(f) / FPS if times is None else np.asarray(times, dtype=np.float64)
    d_lo, d_hi = staging.distance_m
    edges = np.linspace(d_lo, d_hi, n + 1)
    gap_hi = max(GAP_M[0], min(GAP_M[1], VIEW_SPAN_M / max(n - 1, 1)))
    best = None
    for _ in range(tries):
        yaws = np.deg2rad(rng.uniform(*staging.turn_deg, size=n))
        strata = rng.permutation(n)
        dist = rng.uniform(edges[strata], edges[strata + 1])
        order = rng.permutation(n)  # left to right
        gaps = rng.uniform(GAP_M[0], gap_hi, size=n - 1)
        xs = np.concatenate([[0.0], np.cumsum(gaps)])
        xs += rng.uniform(-0.3, 0.3) - xs.mean()
        lateral = np.empty(n)
        lateral[order] = xs
        drift = np.zeros((n, f))
        cost = 0
        if crossing:
            i = int(rng.integers(n - 1))
            a, b = int(order[i]), int(order[i + 1])
            near, far = (a, b) if dist[a] < dist[b] else (b, a)
            hold = min(rng.uniform(*CROSS_HOLD_S), 0.3 * t[-1])  # walks on in short videos
            tc = max(rng.uniform(0.35, 0.65) * t[-1] - hold / 2, 0.0)
            speed = rng.uniform(*CROSS_SPEED_M_S)
            # in line with the farther person (the same bearing from the camera) from tc for
            # `hold` seconds: it stops there a moment, as people do when they meet
            in_line = lateral[far] * dist[near] / dist[far]
            sign = 1.0 if lateral[near] < lateral[far] else -1.0
            walked = np.where(t < tc, t - tc, np.maximum(t - tc - hold, 0.0))
            drift[near] = in_line - lateral[near] + sign * speed * walked
            if dist[far] - dist[near] < CROSS_DEPTH_M:
                cost += 5 * f
        placed = []
        for k in range(n):
            c, s = np.cos(yaws[k]), np.sin(yaws[k])
            rot = np.array([[c, -s], [s, c]])
            p = (hips[k] - centres[k]) @ rot.T + np.array([lateral[k], dist[k]])
            p[:, 0] += drift[k]
            cost += _misplaced(p, (x0, x1, y0, y1), furniture, occluders, scene, hip_z)
            placed.append((rot, p))
        for a in range(n):
            for b in range(a + 1, n):
                apart = np.linalg.norm(placed[a][1] - placed[b][1], axis=1)
                cost += 5 * int((apart < MIN_APART_M).sum())
        if best is None or cost < best[0]:
            best = (cost, yaws, lateral, dist, drift)
        if cost == 0:
            break
    _, yaws, lateral, dist, drift = best
    out = []
    for k in range(n):
        c, s = np.cos(yaws[k]), np.sin(yaws[k])
        rot = np.array([[c, -s], [s, c]])
        room = joints[k].copy()
        room[..., :2] = (joints[k][..., :2] - centres[k]) @ rot.T + [lateral[k], dist[k]]
        room[..., 0] += drift[k][:, None]
        out.append(room)
    return out


def _misplaced(p: NDArray[np.float64], zone: tuple[float, float, float, float],
               furniture: list, occluders: list, scene: Scene, hip_z: float) -> int:
    """Frames in which a person's hips `p` ((F, 2) room x, y) leave `zone`, come within
    0.35 m of furniture or 0.45 m behind an occluder, or their body leaves the view."""
    x0, x1, y0, y1 = zone
    intr = scene.intrinsics
    bad = ~((p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1))
    for fx0, fx1, fy0, fy1 in furniture:
        bad |= ((p[:, 0] > fx0 - 0.35) & (p[:, 0] < fx1 + 0.35)
                & (p[:, 1] > fy0 - 0.35) & (p[:, 1] < fy1 + 0.35))
    for _, _, _, oy1 in occluders:
        bad |= p[:, 1] < oy1 + 0.45
    for side in (-HALF_WIDTH_M, HALF_WIDTH_M):
        edge = np.column_stack([p[:, 0] + side, p[:, 1], np.full(len(p), hip_z)])
        o = scene.to_optical(edge)
        u = intr.cx + intr.fx * o[:, 0] / np.maximum(o[:, 2], 1e-3)
        bad |= (o[:, 2] < 0.5) | (u < 0) | (u > intr.width - 1)
    return int(bad.sum())


def _on_floor(joints: NDArray[np.float64], body: Body) -> NDArray[np.float64]:
    """The lower foot joint a shoe's radius above the floor in every frame (as
    `video.prepare_video` does for one person)."""
    low = joints[:, [LAN, LFT, RAN, RFT], 2].min(axis=1)
    out = joints.copy()
    out[..., 2] += (body.radii['foot'] - low)[:, None]
    return out


def _sits(motion: TakeMotion, indices: NDArray[np.int64]) -> bool:
    return any(a in SIT_ACTIONS for a, (a0, b) in motion.actions.items()
               if a0 <= indices[-1] and b >= indices[0])


def prepare_people_video(plan: VideoPlan, motions: Sequence[TakeMotion],
                         intrinsics: Intrinsics, *, people: int, crossing: bool,
                         body: Body | None = None, occluder_prob: float = 0.3,
                         kinect_noise: bool = True, staging: Staging) -> VideoJob:
    """A video of `people` (2-3) persons: person 1 the plan's window on `body` (or a random
    body), persons 2..N from `companion_windows` on random bodies, placed by `place_people`
    (`crossing`: one walks past in front of another); chairs under whoever sits.

    Parameters
    ----------
    plan : person 1's window. motions : every take of the run (person 1's among them).
    """
    if not 2 <= people <= MAX_PEOPLE:
        raise ValueError(f'people must be 2-{MAX_PEOPLE} for a several-person video, got '
                         f'{people}')
    by_name = {m.name: m for m in motions}
    if plan.take not in by_name:
        raise ValueError(f'{plan.take}: the plan\'s take is not among the motions')
    if body is None:
        body = render.random_body(video_rng(plan, 1), stature_m=staging.stature_m)
    rng = video_rng(plan, 2)
    scene = rooms.random_scene(rng, intrinsics, occluder_prob=occluder_prob,
                               person_zone=people_zone(staging), mount=staging.mount)
    windows = [(by_name[plan.take], plan.start, plan.indices)] + companion_windows(
        plan, motions, people, [video_rng(plan, 10 * k) for k in range(2, people + 1)])
    bodies = [body] + [render.random_body(video_rng(plan, 10 * k + 1),
                                          stature_m=staging.stature_m)
                       for k in range(2, people + 1)]
    floor = []
    for k, ((motion, _, idx), b) in enumerate(zip(windows, bodies, strict=True)):
        room = motion.joints[idx].copy()
        if staging.arm_jitter_deg > 0:
            what = 4 if k == 0 else 10 * (k + 1) + 4
            room = jitter_arms(room, video_rng(plan, what), staging.arm_jitter_deg)
        floor.append(_on_floor(room, b))
    placed = place_people(floor, scene, video_rng(plan, 5), staging=staging,
                          crossing=crossing, times=(plan.frame_numbers - 1) / FPS)
    for (motion, _, idx), b, room in zip(windows, bodies, placed, strict=True):
        if _sits(motion, idx):
            standing = float(np.median(motion.joints[:, HC, 2]))
            scene = _add_seat(scene, room, b, standing, rng)
    t = plan.frame_numbers / FPS
    gains = 1.0 + 0.05 * np.sin(2 * np.pi * t / rng.uniform(4.0, 10.0) + rng.uniform(0, 6.3))
    companions = tuple(Companion(motion.name, start, b, scene.to_optical(room))
                       for (motion, start, _), b, room in zip(windows[1:], bodies[1:],
                                                              placed[1:], strict=True))
    return VideoJob(plan, body, scene, scene.to_optical(placed[0]), gains, intrinsics,
                    kinect_noise, companions=companions, crossing=crossing)


def crossing_videos(plans: Sequence[VideoPlan], fraction: float) -> list[bool]:
    """Which videos have a crossing: round(`fraction` x videos) of them, those whose own random
    key is the smallest (so a video's lot does not depend on the order of the others)."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f'crossing fraction must be in [0, 1], got {fraction}')
    keys = np.array([video_rng(p, 6).random() for p in plans])
    chosen = set(np.argsort(keys, kind='stable')[:int(round(fraction * len(plans)))].tolist())
    return [i in chosen for i in range(len(plans))]
