"""From real Kinect motion (UTKinect takes, MSR Action3D sequences) to synthetic CAD-60 videos.

A take (or an MSR Action3D sequence, `load_msr_takes`) is resampled to 30 fps
(`utkinect.resample`) and moved into a floor frame: the floor is the plane through the lower
foot joint of each frame (robust least squares), which removes the recording camera's height
and tilt; the lower foot is then put on it in every frame. A
video is a window of a take (every `stride`-th frame), posed by that motion on a fresh random
body (`render.random_body`) in a fresh random room (`scene.random_scene`): the walk keeps its
shape and its heading towards the camera but is turned by up to +-25 degrees and moved so that
the person stands 2.4-3.4 m from the camera, clear of the furniture and behind any occluder
(`Staging` sets other statures, distances and turns: a person seen from the side, or near).
Windows in which the person sits get a chair under the hips. The light's strength drifts
slowly during a video (auto-exposure).

Output (`write_video`): one CAD-60 video per window, `<id>.txt`, `<id>/RGB_<k>.png`,
`<id>/Depth_<k>.png`, `<id>/Mask_<k>.png`, k = 1 + the frame's index at 30 fps in the window
(frame numbers keep the 30 fps clock: with stride 3 they are 1, 4, 7, ...).
Video ids (10 digits): subject (2), take (2), window (2), seed modulo 10000 (4).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.datasets import cad60, msraction3d
from pose4d_ros.datasets.utkinect import read_actions, read_take, resample, to_optical
from pose4d_ros.synth import render
from pose4d_ros.synth import scene as rooms
from pose4d_ros.synth import textures as tex
from pose4d_ros.synth.render import (
    HC,
    LAN,
    LFT,
    RAN,
    RFT,
    Body,
    Rendered,
    RenderedPeople,
)
from pose4d_ros.synth.scene import Scene

FPS = 30.0
SIT_ACTIONS = ('sitDown', 'standUp')
SEAT_HIP_FRACTION = 0.88  # sitting: hip centre below this fraction of its standing height
# Several people: a person of whom fewer pixels than this (at 320x240, scaled with the image
# area; a hand at 3 m is about 80) are seen counts as unseen in that frame (confidences 0).
MIN_SEEN_PX = 40


@dataclass(frozen=True)
class Staging:
    """Who stands where: each video draws its body's stature, its distance and its turn
    uniformly from these ranges (equal ends fix a value).

    Attributes
    ----------
    stature_m : (lo, hi) the body's standing height, metres.
    distance_m : (lo, hi) the mean hip position's distance ahead of the camera, metres.
    turn_deg : (lo, hi) the turn of the motion about the vertical, degrees: 0 = as recorded
        (UTKinect's subjects face the Kinect), 90 = the person's left side towards the camera.
    arm_jitter_deg : arms posed away from the recorded motion by up to this much (`jitter_arms`),
        degrees; 0 = the motion as recorded.
    camera_height_m, camera_pitch_deg : (lo, hi) the camera's height above the floor, metres,
        and its pitch down, degrees, both given or neither; None: the camera at chest height,
        aimed at the person's middle (`scene.random_scene`).
    """

    stature_m: tuple[float, float] = render.STATURE_M
    distance_m: tuple[float, float] = (2.4, 3.4)
    turn_deg: tuple[float, float] = (-25.0, 25.0)
    arm_jitter_deg: float = 0.0
    camera_height_m: tuple[float, float] | None = None
    camera_pitch_deg: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if (self.camera_height_m is None) != (self.camera_pitch_deg is None):
            raise ValueError('camera_height_m and camera_pitch_deg go together, got '
                             f'{self.camera_height_m} and {self.camera_pitch_deg}')
        if self.camera_height_m is not None:
            for name, (lo, hi), bounds in (
                    ('camera_height_m', self.camera_height_m, (0.5, 3.5)),
                    ('camera_pitch_deg', self.camera_pitch_deg, (-10.0, 50.0))):
                if not bounds[0] <= lo <= hi <= bounds[1]:
                    raise ValueError(f'{name} must be lo <= hi within {bounds[0]:g}-'
                                     f'{bounds[1]:g}, got {lo:g}-{hi:g}')
        for name, (lo, hi), bounds in (('stature_m', self.stature_m, (1.0, 2.3)),
                                       ('distance_m', self.distance_m, (0.8, 6.0)),
                                       ('turn_deg', self.turn_deg, (-180.0, 180.0))):
            if not bounds[0] <= lo <= hi <= bounds[1]:
                raise ValueError(f'{name} must be lo <= hi within {bounds[0]:g}-{bounds[1]:g}, '
                                 f'got {lo:g}-{hi:g}')
        if not 0.0 <= self.arm_jitter_deg <= 90.0:
            raise ValueError(f'arm_jitter_deg must be within 0-90 degrees, got '
                             f'{self.arm_jitter_deg:g}')

    @property
    def person_zone(self) -> tuple[float, float, float, float]:
        """The room's free zone for the person's hips (`scene.PERSON_ZONE` by default)."""
        x0, x1, y0, y1 = rooms.PERSON_ZONE
        return (x0, x1, self.distance_m[0] - 0.2, self.distance_m[1] + 0.3)

    @property
    def mount(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """`scene.random_scene`'s camera mount: None for the default camera."""
        if self.camera_height_m is None:
            return None
        return self.camera_height_m, self.camera_pitch_deg


@dataclass(frozen=True)
class TakeMotion:
    """A UTKinect take (or an MSR Action3D sequence) at 30 fps in its floor frame.

    Attributes
    ----------
    name : 'sNN_eMM' (MSR Action3D: 'aAA_sSS_eEE'); subject, take : NN, MM (MSR Action3D:
        SS, and `msr_take_number` AA, EE: 21-80, apart from UTKinect's takes 1-2, so that
        the video ids of a set made from both stay distinct).
    joints : (T, 20, 3) float64 metres, floor frame (X right, Y forward, Z up, floor Z = 0 at
        the lower foot joint), `UTKINECT_JOINTS` order.
    actions : {action: (first, last)} frame indices into `joints`.
    """

    name: str
    subject: int
    take: int
    joints: NDArray[np.float64]
    actions: dict[str, tuple[int, int]]


def fit_floor(joints: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """The floor under a Kinect take, from the lower foot joint of each frame.

    Parameters
    ----------
    joints : (T, 20, 3) metres, optical frame.

    Returns
    -------
    up : (3,) unit vector, optical frame; height : camera height above the fitted plane, so
        that a point p is `p @ up + height` above the floor.
    """
    feet = joints[:, [LAN, LFT, RAN, RFT], :]
    low = feet[np.arange(len(joints)), np.argmax(feet[:, :, 1], axis=1)]  # y down: largest
    keep = np.all(np.isfinite(low), axis=1)
    if keep.sum() < 10:
        raise ValueError(f'only {int(keep.sum())} frames with feet: cannot fit the floor')
    for _ in range(4):  # trimmed least squares: y = a x + c z + d
        a = np.column_stack([low[keep, 0], low[keep, 2], np.ones(keep.sum())])
        # a weak prior a = c = 0 (a level camera) keeps the fit stable for takes in which the
        # person hardly moves in x or z
        a = np.vstack([a, [[0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]])
        coef, *_ = np.linalg.lstsq(a, np.r_[low[keep, 1], 0.0, 0.0], rcond=None)
        res = low[:, 1] - (coef[0] * low[:, 0] + coef[1] * low[:, 2] + coef[2])
        mad = float(np.median(np.abs(res[keep]))) + 1e-3
        keep = np.all(np.isfinite(low), axis=1) & (np.abs(res) < 3.0 * mad)
    normal = np.array([-coef[0], 1.0, -coef[1]])
    scale = float(np.linalg.norm(normal))
    up = -normal / scale  # the plane's normal points down (+y); up is its opposite
    height = float(coef[2] / scale)  # distance from the camera to the plane
    return up, height


def to_floor_frame(joints: NDArray[np.float64], up: NDArray[np.float64],
                   height: float) -> NDArray[np.float64]:
    """Optical-frame joints -> floor frame (X right, Y forward along the ground, Z up)."""
    fwd = np.array([0.0, 0.0, 1.0]) - up[2] * up
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    rot = np.stack([right, fwd, up])
    out = joints @ rot.T
    out[..., 2] += height
    return out


def load_take(path: str | Path, actions: dict[str, dict[str, tuple[int, int]]] | None = None
              ) -> TakeMotion:
    """Read a UTKinect take, resample it to 30 fps and move it into its floor frame."""
    take = read_take(path)
    _, joints = resample(take, fps=FPS)
    optical = to_optical(joints)
    up, height = fit_floor(optical)
    spans = {}
    for action, (first, last) in (actions or {}).get(take.name, {}).items():
        a, b = first - take.frames[0], last - take.frames[0]
        if b >= 0 and a < len(joints):
            spans[action] = (max(int(a), 0), min(int(b), len(joints) - 1))
    return TakeMotion(take.name, take.subject, int(take.name[-2:]),
                      to_floor_frame(optical, up, height), spans)


def load_takes(directory: str | Path, names: list[str]) -> list[TakeMotion]:
    """Load the named takes ('sNN_eMM') of a UTKinect directory (with its actionLabel.txt)."""
    directory = Path(directory)
    labels_path = directory / 'actionLabel.txt'
    actions = read_actions(labels_path) if labels_path.is_file() else {}
    out = []
    for name in names:
        path = directory / f'joints_{name}.txt'
        if not path.is_file():
            raise ValueError(f'{path}: UTKinect take not found')
        out.append(load_take(path, actions))
    return out


def msr_take_number(action: int, take: int) -> int:
    """`TakeMotion.take` of MSR Action3D sequence aAA_sSS_eEE: 20 + 3 (AA - 1) + EE, 21-80
    (two digits of the video id, apart from UTKinect's 1-2)."""
    if not (1 <= action <= len(msraction3d.ACTIONS) and 1 <= take <= 3):
        raise ValueError(f'MSR Action3D action {action} take {take}: expected 1-20 and 1-3')
    return 20 + 3 * (action - 1) + take


def load_msr_take(path: str | Path, *, max_gap_s: float = 0.5, min_frames: int = 8
                  ) -> TakeMotion | None:
    """Read an MSR Action3D sequence, keep its longest piece without a gap over `max_gap_s`
    (`msraction3d.pieces`), resample it to 30 fps and move it into its floor frame. The whole
    window is the sequence's action. None if no piece has `min_frames` frames (15 fps): the
    dataset's empty and broken sequences."""
    seq = msraction3d.read_sequence(path)
    parts = msraction3d.pieces(seq, max_gap_s=max_gap_s)
    if not parts or max(len(p.frames) for p in parts) < min_frames:
        return None
    piece = max(parts, key=lambda p: len(p.frames))
    _, joints = msraction3d.resample(piece, fps=FPS)
    optical = to_optical(joints)
    up, height = fit_floor(optical)
    return TakeMotion(seq.name, seq.subject, msr_take_number(seq.action, seq.take),
                      to_floor_frame(optical, up, height),
                      {seq.action_name: (0, len(joints) - 1)})


def load_msr_takes(directory: str | Path, names: Sequence[str]
                   ) -> tuple[list[TakeMotion], list[str]]:
    """Load the named sequences ('aAA_sSS_eEE') of an MSR Action3D directory.

    Returns the motions and the names skipped as empty or too short (`load_msr_take`).
    """
    directory = Path(directory)
    out, skipped = [], []
    for name in names:
        path = directory / f'{name}_skeleton3D.txt'
        if not path.is_file():
            raise ValueError(f'{path}: MSR Action3D sequence not found')
        motion = load_msr_take(path)
        if motion is None:
            skipped.append(name)
        else:
            out.append(motion)
    return out, skipped


@dataclass(frozen=True)
class VideoPlan:
    """One synthetic video: a window of a take and the seed of its body and room.

    Attributes
    ----------
    take : 'sNN_eMM' or 'aAA_sSS_eEE'; subject, take_no : `TakeMotion.subject`, `.take`;
    window : index of the window in the take.
    start : first frame index (30 fps) in the take; n_frames : frames written; stride : step.
    seed : the run's seed; video_id : 10 digits; activity : the UTKinect action covering most
        of the window, or 'random' (CAD-60's name for unscripted activity).
    """

    take: str
    subject: int
    take_no: int
    window: int
    start: int
    n_frames: int
    stride: int
    seed: int
    video_id: str
    activity: str

    @property
    def indices(self) -> NDArray[np.int64]:
        return self.start + self.stride * np.arange(self.n_frames)

    @property
    def frame_numbers(self) -> NDArray[np.int64]:
        """CAD-60 frame numbers k (1 + index at 30 fps within the window)."""
        return 1 + self.stride * np.arange(self.n_frames)


def plan_videos(motion: TakeMotion, *, seed: int, videos: int = 1, frames: int = 60,
                stride: int = 1, start_s: float = 0.0,
                actions: Sequence[str] | None = None) -> list[VideoPlan]:
    """Split a take into `videos` windows of `frames` frames (every `stride`-th at 30 fps),
    spread evenly from `start_s` seconds to the end (windows shrink if the take is short).
    With `actions`, `videos` windows are spread over each named action of the take instead
    (from `start_s` on; actions the take lacks give none), numbered one after the other."""
    if videos < 1 or frames < 1 or stride < 1:
        raise ValueError(f'videos, frames and stride must be >= 1, got {videos}, {frames}, '
                         f'{stride}')
    if start_s < 0:
        raise ValueError(f'start must be >= 0 seconds, got {start_s}')
    total = len(motion.joints)
    first = int(round(start_s * FPS))
    if first >= total:
        raise ValueError(f'{motion.name}: start {start_s} s is beyond the take '
                         f'({total / FPS:.1f} s)')
    spans = [(first, total - 1)] if actions is None else [
        (max(a0, first), b) for a in actions if a in motion.actions
        for a0, b in [motion.actions[a]] if b >= max(a0, first)]
    plans: list[VideoPlan] = []
    for lo, hi in spans:
        n = min(frames, (hi - lo) // stride + 1)
        span = (n - 1) * stride + 1
        free = hi + 1 - lo - span
        for k in range(videos):
            w = len(plans)
            start = lo + (int(round(k * free / (videos - 1))) if videos > 1 else 0)
            window = (start, start + span - 1)
            overlap = {a: min(b, window[1]) - max(a0, window[0]) + 1
                       for a, (a0, b) in motion.actions.items()}
            best = max(overlap, key=overlap.get, default=None)
            activity = best if best is not None and overlap[best] > 0 else 'random'
            vid = f'{motion.subject:02d}{motion.take:02d}{w % 100:02d}{seed % 10000:04d}'
            plans.append(VideoPlan(motion.name, motion.subject, motion.take, w, start, n,
                                   stride, seed, vid, activity))
    return plans


def video_rng(plan: VideoPlan, what: int) -> np.random.Generator:
    """The random stream of one part (`what`) of one video: independent of other videos."""
    return np.random.default_rng([plan.seed, plan.subject, plan.take_no, plan.window, what])


def subject_body(seed: int, subject: int, *,
                 stature_m: tuple[float, float] = render.STATURE_M) -> Body:
    """One body for all videos of a subject (`pose4d synth --body-per subject`)."""
    return render.random_body(np.random.default_rng([seed, subject, 0, 0, 0]),
                              stature_m=stature_m)


@dataclass(frozen=True, eq=False)
class Companion:
    """Person k >= 2 of a several-person video (`synth.people`): another window of real motion
    on another body, in the same room as person 1 (`VideoJob.body`, `VideoJob.poses`).

    Attributes
    ----------
    take : 'sNN_eMM' the motion comes from; start : its first frame index (30 fps) in the take.
    body : the person's body.
    poses : (F, 20, 3) float64 metres, the scene camera's optical frame.
    """

    take: str
    start: int
    body: Body
    poses: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class VideoJob:
    """Everything needed to render a planned video.

    `companions` are persons 2..N of a several-person video (`synth.people`), none for a video
    of one person; `crossing` marks a video in which one person walks past in front of another.
    """

    plan: VideoPlan
    body: Body
    scene: Scene
    poses: NDArray[np.float64]  # (F, 20, 3) metres, scene camera's optical frame
    gains: NDArray[np.float64]  # (F,) light gain per frame
    intrinsics: Intrinsics
    kinect_noise: bool
    companions: tuple[Companion, ...] = ()
    crossing: bool = False


def alone(job: VideoJob, k: int) -> VideoJob:
    """The several-person video `job` with person `k` (1 = `job.body`, 2.. the companions)
    alone in it: the same room, light, placement and motion, the others left out."""
    if not 1 <= k <= 1 + len(job.companions):
        raise ValueError(f'person {k} of a video of {1 + len(job.companions)}')
    if k == 1:
        return replace(job, companions=(), crossing=False)
    other = job.companions[k - 2]
    return replace(job, body=other.body, poses=other.poses, companions=(), crossing=False)


def prepare_video(plan: VideoPlan, motion: TakeMotion, intrinsics: Intrinsics, *,
                  body: Body | None = None, occluder_prob: float = 0.3,
                  kinect_noise: bool = True, staging: Staging = Staging()) -> VideoJob:
    """Draw the body (unless given) and the room, place the motion, add a chair if needed."""
    if body is None:
        body = render.random_body(video_rng(plan, 1), stature_m=staging.stature_m)
    rng = video_rng(plan, 2)
    scene = rooms.random_scene(rng, intrinsics, occluder_prob=occluder_prob,
                                person_zone=staging.person_zone, mount=staging.mount)
    room = motion.joints[plan.indices].copy()
    if staging.arm_jitter_deg > 0:
        room = jitter_arms(room, video_rng(plan, 4), staging.arm_jitter_deg)
    # The lower foot joint sits a shoe's radius above the floor in every frame: Kinect's foot
    # joints scatter by centimetres (decimetres when mis-tracked) about the fitted floor, and
    # nobody jumps in UTKinect.
    low = room[:, [LAN, LFT, RAN, RFT], 2].min(axis=1)
    room[..., 2] += (body.radii['foot'] - low)[:, None]
    room = place_in_room(room, scene, rng, staging=staging)
    window_actions = [a for a, (a0, b) in motion.actions.items()
                      if a0 <= plan.indices[-1] and b >= plan.indices[0]]
    if any(a in SIT_ACTIONS for a in window_actions):
        standing = float(np.median(motion.joints[:, HC, 2]))
        scene = _add_seat(scene, room, body, standing, rng)
    t = plan.frame_numbers / FPS
    gains = 1.0 + 0.05 * np.sin(2 * np.pi * t / rng.uniform(4.0, 10.0) + rng.uniform(0, 6.3))
    return VideoJob(plan, body, scene, scene.to_optical(room), gains, intrinsics, kinect_noise)


# Elbow flexion (0 = straight arm) kept within what an elbow does, radians.
ELBOW_FLEXION_RAD = (0.0, np.deg2rad(150.0))


def _rotate(v: NDArray[np.float64], axis: NDArray[np.float64], angle: NDArray[np.float64]
            ) -> NDArray[np.float64]:
    """Rodrigues: rotate the (F, 3) vectors `v` about the (F, 3) unit `axis` by `angle` (F,)."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=1, keepdims=True) * (1 - c)


def _unit_rows(v: NDArray[np.float64], fallback: NDArray[np.float64]) -> NDArray[np.float64]:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(n > 1e-6, v / np.maximum(n, 1e-12), fallback)


def jitter_arms(joints: NDArray[np.float64], rng: np.random.Generator, max_deg: float
                ) -> NDArray[np.float64]:
    """Pose both arms of a window of motion away from the recording: arm poses its subjects
    never made, for training data (`pose4d synth --arm-jitter`).

    Per arm, the whole arm turns about the shoulder (about an axis drawn at random) and the
    elbow bends or straightens about its own hinge; both angles are drawn within +-`max_deg`
    at the window's first and last frames and vary linearly between, so the motion stays
    smooth. The elbow's flexion stays within `ELBOW_FLEXION_RAD`; bone lengths are kept.

    Parameters
    ----------
    joints : (F, 20, 3) metres, Kinect joints (`render` indices), any frame.
    rng : the video's random stream.
    max_deg : degrees.

    Returns
    -------
    (F, 20, 3) float64, a new array.
    """
    out = np.array(joints, dtype=np.float64)
    n = len(out)
    t = np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)
    lim = np.deg2rad(max_deg)
    for sh, el, wr, ha in ((render.LSH, render.LEL, render.LWR, render.LHA),
                           (render.RSH, render.REL, render.RWR, render.RHA)):
        axis = rng.normal(size=3)
        axis = np.broadcast_to(axis / np.linalg.norm(axis), (n, 3))
        a0, a1, f0, f1 = rng.uniform(-lim, lim, size=4)
        turn = a0 + (a1 - a0) * t
        bend = f0 + (f1 - f0) * t
        arm = out[:, [el, wr, ha]] - out[:, sh, None]
        arm = np.stack([_rotate(arm[:, k], axis, turn) for k in range(3)], axis=1)
        upper = arm[:, 0]
        fore = arm[:, 1:] - upper[:, None]
        u = _unit_rows(upper, np.array([0.0, 0.0, -1.0]))
        # the hinge: perpendicular to upper arm and forearm (any perpendicular for a straight arm)
        side = np.cross(u, np.array([1.0, 0.0, 0.0]))
        hinge = _unit_rows(np.cross(u, fore[:, 0]), _unit_rows(side, np.array([0.0, 1.0, 0.0])))
        flex = np.arctan2(np.linalg.norm(np.cross(u, fore[:, 0]), axis=1),
                          np.sum(u * fore[:, 0], axis=1))
        delta = np.clip(flex + bend, *ELBOW_FLEXION_RAD) - flex
        fore = np.stack([_rotate(fore[:, k], hinge, delta) for k in range(2)], axis=1)
        out[:, el] = out[:, sh] + upper
        out[:, [wr, ha]] = out[:, el, None] + fore
    return out


def place_in_room(joints: NDArray[np.float64], scene: Scene, rng: np.random.Generator, *,
                  staging: Staging = Staging(), tries: int = 80) -> NDArray[np.float64]:
    """Turn and move a window of floor-frame motion into the room's person zone.

    The motion is turned about the vertical through its mean hip position by an angle drawn
    from `staging.turn_deg` and moved to a random spot `staging.distance_m` ahead; the spot
    that keeps the hips inside `staging.person_zone`, 0.35 m clear of furniture and 0.45 m
    behind any occluder in the most frames wins (the first that does so in all frames).

    Parameters
    ----------
    joints : (F, 20, 3) metres, floor frame.

    Returns
    -------
    (F, 20, 3) metres, room frame.
    """
    hips = joints[:, HC, :2]
    centre = hips.mean(axis=0)
    furniture = scene.footprints(('furniture',))
    occluders = scene.footprints(('occluder',))
    x0, x1, y0, y1 = staging.person_zone
    best = None
    for _ in range(tries):
        yaw = np.deg2rad(rng.uniform(*staging.turn_deg))
        target = np.array([rng.uniform(-0.5, 0.5), rng.uniform(*staging.distance_m)])
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s], [s, c]])
        p = (hips - centre) @ rot.T + target
        bad = ~((p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1))
        for fx0, fx1, fy0, fy1 in furniture:
            bad |= ((p[:, 0] > fx0 - 0.35) & (p[:, 0] < fx1 + 0.35) & (p[:, 1] > fy0 - 0.35)
                    & (p[:, 1] < fy1 + 0.35))
        for _, _, _, oy1 in occluders:
            bad |= p[:, 1] < oy1 + 0.45
        cost = int(bad.sum())
        if best is None or cost < best[0]:
            best = (cost, rot, target)
        if cost == 0:
            break
    _, rot, target = best
    out = joints.copy()
    out[..., :2] = (joints[..., :2] - centre) @ rot.T + target
    return out


def _add_seat(scene: Scene, room: NDArray[np.float64], body: Body, standing_hip: float,
              rng: np.random.Generator) -> Scene:
    """A chair under the hips at the lowest hip position of the window, if the person sits
    there (hip centre below `SEAT_HIP_FRACTION` of its standing height); the chair faces where
    the knees point and its seat meets the retargeted body's pelvis."""
    k = int(np.argmin(room[:, HC, 2]))
    if room[k, HC, 2] > SEAT_HIP_FRACTION * standing_hip:
        return scene
    j = render.retarget(room[k], body, up=np.array([0.0, 0.0, 1.0]))
    knees = 0.5 * (j[render.LKN, :2] + j[render.RKN, :2])
    fwd = knees - j[HC, :2]
    if np.linalg.norm(fwd) < 0.05:  # knees above the hips: fall back on the trunk's front
        fwd = render.body_frame(j)[2][:2]
    fwd = fwd / max(float(np.linalg.norm(fwd)), 1e-6)
    yaw = float(np.arctan2(-fwd[0], fwd[1]))  # the chair's local +y = its front = fwd
    # the pelvis ellipsoid hangs 1.5 cm below the hip centre (render.body_primitives)
    seat_top = float(np.clip(j[HC, 2] - 0.015 - 0.9 * body.pelvis_axes[1], 0.3, 0.6))
    pos = j[HC, :2] - 0.05 * fwd
    tile, scale, _ = tex.furniture_tile(rng, str(rng.choice(['wood', 'metal', 'fabric'])))
    mat = len(scene.materials)
    parts = rooms.table((float(pos[0]), float(pos[1])), (0.22, 0.22), seat_top, mat, yaw,
                         'furniture')
    back = pos - 0.2 * fwd  # the backrest stands behind the seat
    parts.append(rooms.Box((float(back[0]), float(back[1]), seat_top + 0.22),
                           (0.22, 0.02, 0.22), mat, yaw, 'furniture'))
    return scene.with_boxes(parts, (('seat', tile, scale),))


def render_video(job: VideoJob) -> Iterator[tuple[int, Rendered | RenderedPeople]]:
    """Yield (frame number k, rendered frame) for every frame of a prepared video: `Rendered`
    for one person, `RenderedPeople` (person 1 = `job.body`, then the companions) for several."""
    rng = video_rng(job.plan, 3)
    bodies = [job.body] + [c.body for c in job.companions]
    poses = np.stack([job.poses] + [c.poses for c in job.companions], axis=1)  # (F, N, 20, 3)
    for k, pose, gain in zip(job.plan.frame_numbers, poses, job.gains, strict=True):
        scene = job.scene.with_light(gain=float(gain))
        if job.companions:
            yield int(k), render.render_people(pose, bodies, scene, job.intrinsics, rng=rng,
                                               kinect_noise=job.kinect_noise)
        else:
            yield int(k), render.render(pose[0], job.body, scene, job.intrinsics, rng=rng,
                                       kinect_noise=job.kinect_noise)


def write_video(job: VideoJob, person_dir: str | Path, *,
                progress: Callable[[int], object] | None = None) -> int:
    """Render a video into `person_dir` as `<id>.txt` and `<id>/{RGB,Depth,Mask}_<k>.png`.

    A several-person video adds `<id>_p<k>.txt` for persons k = 2..N and `<id>/People_<k>.png`
    (`cad60.write_people`); its `Mask_<k>.png` is every person's pixels, and a person's
    confidences are 0 in the frames where fewer than `MIN_SEEN_PX` pixels of it are seen (out
    of view or hidden), 1 elsewhere.
    `progress(1)` is called after each frame. Returns the bytes written. The skeleton files are
    written last (person 1's after the others), so a video without `<id>.txt` is incomplete.
    """
    person_dir = Path(person_dir)
    frame_dir = person_dir / job.plan.video_id
    frame_dir.mkdir(parents=True, exist_ok=False)
    n_people = 1 + len(job.companions)
    joints_mm: list[list[NDArray]] = [[] for _ in range(n_people)]
    rots: list[list[NDArray]] = [[] for _ in range(n_people)]
    seen: list[NDArray[np.bool_]] = []
    for k, frame in render_video(job):
        cad60.write_frame(frame_dir, k, frame.rgb, frame.depth_mm, frame.mask)
        if isinstance(frame, RenderedPeople):
            cad60.write_people(cad60.people_path(frame_dir, k), frame.labels)
            area = frame.labels.size / (320 * 240)
            seen.append(frame.visible_px() >= MIN_SEEN_PX * area)
            all_joints = frame.joints
        else:
            all_joints = frame.joints[None]
        for p, joints in enumerate(all_joints):
            jm, rot = render.cad60_ground_truth(joints)
            joints_mm[p].append(jm)
            rots[p].append(rot)
        if progress is not None:
            progress(1)
    n = len(joints_mm[0])
    # one person: always confident, as the single-person sets have always been written
    conf = np.array(seen, dtype=np.float64).T if job.companions else np.ones((1, n))
    paths = [cad60.person_skeleton_path(person_dir, job.plan.video_id, p + 1)
             for p in range(n_people)]
    for p in reversed(range(n_people)):
        skeleton = cad60.Skeleton(
            frames=job.plan.frame_numbers.astype(np.int64), joints_mm=np.array(joints_mm[p]),
            joint_conf=np.repeat(conf[p][:, None], 15, axis=1),
            orientations=np.array(rots[p]),
            orientation_conf=np.repeat(conf[p][:, None], 11, axis=1))
        cad60.write_skeleton(paths[p], skeleton)
    return sum(p.stat().st_size for p in frame_dir.iterdir()) + \
        sum(path.stat().st_size for path in paths)


def load_motions(utkinect: Path | None, msraction3d: Path | None, takes: str,
                 actions: str | None) -> tuple[list[TakeMotion], list[str], list[str]]:
    """The motion of `pose4d synth --takes T --actions A` over a UTKinect and/or an MSR
    Action3D directory: the motions, their names, and the MSR Action3D sequences skipped as
    empty or too short."""
    from pose4d_ros.datasets.msraction3d import list_sequences
    from pose4d_ros.datasets.utkinect import list_takes
    from pose4d_ros.synth.takes import parse_takes, select_sources

    ut = [] if utkinect is None else [
        p.name[len('joints_'):-len('.txt')] for p in list_takes(utkinect)]
    if msraction3d is None:  # as it always was
        names = parse_takes(takes, ut)
        return load_takes(utkinect, names), names, []
    msr = [p.name[:-len('_skeleton3D.txt')] for p in list_sequences(msraction3d)]
    if not msr:
        raise ValueError(f'--msraction3d {msraction3d}: no aAA_sSS_eEE_skeleton3D.txt files')
    ut_names, msr_names = select_sources(takes, actions, ut, msr)
    motions = load_takes(utkinect, ut_names) if ut_names else []
    msr_motions, skipped = load_msr_takes(msraction3d, msr_names)
    return motions + msr_motions, ut_names + [m.name for m in msr_motions], skipped


def video_record(job: VideoJob, person_dir: Path) -> dict:
    """synth.json's account of a video: its take, window, body, distance, room; of a
    several-person video also the crossing and per person its take, window, body, distance
    and the frames in which it is not seen."""
    plan = job.plan
    record = {
        'video': f'data{plan.subject}/{plan.video_id}', 'take': plan.take,
        'activity': plan.activity, 'start_frame_30fps': plan.start,
        'stride': plan.stride, 'frames': plan.n_frames,
        'stature_m': round(job.body.stature_m, 3),
        'distance_m': round(float(np.median(job.poses[:, HC, 2])), 3),
        'occluder': any(b.kind == 'occluder' for b in job.scene.boxes),
        'camera_height_m': round(job.scene.cam_height_m, 3),
    }
    if not job.companions:
        return record
    persons = [(plan.take, plan.start, job.body, job.poses)] + [
        (c.take, c.start, c.body, c.poses) for c in job.companions]
    people = []
    for k, (take, start, body, poses) in enumerate(persons, start=1):
        skeleton = cad60.read_skeleton(cad60.person_skeleton_path(person_dir, plan.video_id, k))
        people.append({'person': k, 'take': take, 'start_frame_30fps': int(start),
                       'stature_m': round(body.stature_m, 3),
                       'distance_m': round(float(np.median(poses[:, HC, 2])), 3),
                       'unseen_frames': int((skeleton.joint_conf[:, 0] == 0).sum())})
    return {**record, 'crossing': job.crossing, 'people': people}
