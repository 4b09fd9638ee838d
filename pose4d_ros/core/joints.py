"""A set of named joints of one person in one frame: the core-side twin of JointArray.

`wire` reads it from a `pose4d_msgs/JointArray` (the message or its bytes) and writes its
bytes, `nodes/convert.py` builds the rclpy message; everything else works on this dataclass.
Unknown values are NaN. Source codes equal the message's constants (a test checks it).
`check_joints` is the physical-sense check of a JointSet that came from outside.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import MAX_DEPTH_M, Intrinsics
from pose4d_ros.core.skeleton import MIDPOINTS, ground_truth_name

DETECTED = 0  # measured by the part detector in this frame
TRACKED = 1  # estimated by the tracker
INFERRED = 2  # inferred by inverse kinematics
MISSING = 3  # no estimate

SOURCE_NAMES = {DETECTED: 'detected', TRACKED: 'tracked', INFERRED: 'inferred', MISSING: 'missing'}


@dataclass(frozen=True, eq=False)
class JointSet:
    """Joints of one person in one image.

    Attributes
    ----------
    names : J joint names (core.skeleton).
    uv : (J, 2) float64 pixel (u, v) in the colour image; NaN = unknown.
    xyz : (J, 3) float64 metres, camera optical frame; NaN = no depth.
    confidence : (J,) float32 in [0, 1].
    source : (J,) uint8, DETECTED / TRACKED / INFERRED / MISSING.
    covariance : (J, 3, 3) float64 square metres; zeros = unknown.
    score : whole-pose score (model score for detections, 0..1 for tracks); NaN = unknown.
    track_id : 0 = untracked.
    """

    names: tuple[str, ...]
    uv: NDArray[np.float64]
    xyz: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    confidence: NDArray[np.float32] = field(default=None)  # type: ignore[assignment]
    source: NDArray[np.uint8] = field(default=None)  # type: ignore[assignment]
    covariance: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    score: float = float('nan')
    track_id: int = 0

    def __post_init__(self) -> None:
        n = len(self.names)
        uv = np.array(self.uv, dtype=np.float64).reshape(n, 2)
        xyz = (np.full((n, 3), np.nan) if self.xyz is None
               else np.array(self.xyz, dtype=np.float64).reshape(n, 3))
        finite = np.isfinite(uv).all(axis=1)
        conf = (finite.astype(np.float32) if self.confidence is None
                else np.array(self.confidence, dtype=np.float32).reshape(n))
        src = (np.where(finite, DETECTED, MISSING).astype(np.uint8) if self.source is None
               else np.array(self.source, dtype=np.uint8).reshape(n))
        cov = (np.zeros((n, 3, 3)) if self.covariance is None
               else np.array(self.covariance, dtype=np.float64).reshape(n, 3, 3))
        if np.any(src > MISSING):
            raise ValueError(f'unknown joint source code(s) {sorted(set(src[src > MISSING]))}')
        for name, arr in (('uv', uv), ('xyz', xyz), ('confidence', conf), ('source', src),
                          ('covariance', cov)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, 'names', tuple(self.names))

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def get(self, name: str) -> int | None:
        """Index of a joint, None if absent."""
        return self.names.index(name) if name in self.names else None

    def labelled(self, names: Sequence[str]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                     NDArray[np.bool_]]:
        """This set as the ground truth of the named joints: (P, 2) pixels, (P, 3) positions
        and (P,) labelled flags (confidence > 0 and a finite pixel); a name the set lacks is
        looked up under its ground-truth alias (`skeleton.ground_truth_name`: a `left_wrist`
        is CAD-60's `left_hand`); a limb's midpoint (`skeleton.MIDPOINTS`) it lacks is the mean
        of the limb's two joints, labelled when both are; NaN / False for joints it has under
        neither name."""
        uv = np.full((len(names), 2), np.nan)
        xyz = np.full((len(names), 3), np.nan)
        labelled = np.zeros(len(names), bool)
        for i, name in enumerate(names):
            if name in MIDPOINTS and self.get(name) is None:  # a limb's midpoint: its joints'
                ends = self.labelled(MIDPOINTS[name])
                uv[i], xyz[i] = ends[0].mean(axis=0), ends[1].mean(axis=0)
                labelled[i] = bool(ends[2].all())
                continue
            k = self.get(name)
            k = self.get(ground_truth_name(name)) if k is None else k
            if k is not None:
                uv[i], xyz[i] = self.uv[k], self.xyz[k]
                labelled[i] = bool(self.confidence[k] > 0) and bool(np.isfinite(uv[i]).all())
        return uv, xyz, labelled

    def with_(self, **changes: object) -> JointSet:
        """A copy with some fields replaced."""
        return replace(self, **changes)

    @classmethod
    def of_arrays(cls, names: tuple[str, ...], uv: NDArray[np.float64],
                  xyz: NDArray[np.float64], confidence: NDArray[np.float32],
                  source: NDArray[np.uint8], covariance: NDArray[np.float64], *,
                  score: float = float('nan'), track_id: int = 0) -> JointSet:
        """A JointSet that takes over arrays made for it, without the constructor's copies:
        the per-frame path of the stages. The arrays must have the shapes and dtypes of the
        attributes, and no other user that writes to them (they are made read-only, as the
        constructor's; another JointSet's arrays may be shared)."""
        self = object.__new__(cls)
        # the flag set as an attribute: `setflags` is a Python-level call an array a frame
        uv.flags.writeable = xyz.flags.writeable = confidence.flags.writeable = False
        source.flags.writeable = covariance.flags.writeable = False
        self.__dict__.update(names=names, uv=uv, xyz=xyz, confidence=confidence, source=source,
                             covariance=covariance, score=score, track_id=track_id)
        return self

    @classmethod
    def missing(cls, names: tuple[str, ...] | list[str]) -> JointSet:
        """All joints MISSING."""
        n = len(names)
        return cls(tuple(names), np.full((n, 2), np.nan), confidence=np.zeros(n),
                    source=np.full(n, MISSING))


# More joints than any skeleton has (CAD-60 15, COCO 17, Kinect v2 25, MediaPipe 33).
MAX_JOINTS = 64
# Largest pixel coordinate accepted without a camera to compare with.
_MAX_PIXEL = 1e5


# `ndarray.all` without its Python wrapper (the per-frame checks)
_all = np.logical_and.reduce


def _pixel_bounds(intrinsics: Intrinsics | None) -> tuple[NDArray, NDArray, str]:
    """(lo, hi) of the pixels accepted as on or near the image (read-only), and the rule in
    words."""
    if intrinsics is None:
        return _ANYWHERE
    # cached by the image size: two ints hash in C (the dataclass's __hash__ and __eq__ are
    # Python-level calls, every frame)
    return _near_image_of_size(intrinsics.width, intrinsics.height)


@functools.lru_cache(maxsize=16)
def _near_image_of_size(width: int, height: int) -> tuple[NDArray, NDArray, str]:
    size = np.array([width, height], np.float64)
    lo, hi = -size, 2 * size
    lo.setflags(write=False)
    hi.setflags(write=False)
    return lo, hi, (f'on or near the {width}x{height} image '
                    f'({-size[0]:g}..{2 * size[0]:g}, {-size[1]:g}..{2 * size[1]:g})')


_ANYWHERE = (np.array([-_MAX_PIXEL] * 2), np.array([_MAX_PIXEL] * 2),
             f'within +-{_MAX_PIXEL:g} px')
for _a in _ANYWHERE[:2]:
    _a.setflags(write=False)


def near_image(uv: NDArray[np.floating], intrinsics: Intrinsics | None) -> NDArray[np.bool_]:
    """(N,) which pixels (N, 2) are on the image or within one image size of it (within
    +-1e5 px without intrinsics): the pixels `check_joints` accepts. NaN is not near."""
    lo, hi, _ = _pixel_bounds(intrinsics)
    return _all((uv >= lo) & (uv <= hi), axis=-1)  # NaN compares False, quietly


def check_joints(joints: JointSet, intrinsics: Intrinsics | None = None) -> None:
    """Refuse joints that no camera could have seen (ValueError naming the joint and value).

    Accepted: at most `MAX_JOINTS` distinct names; pixels unknown (NaN) or on the image or
    near it (within one image size of it, room for a tracker coasting out of view; within
    +-1e5 px without intrinsics); 3-D components unknown or finite within `MAX_DEPTH_M` of the
    camera; confidences in [0, 1]; finite covariances within (`MAX_DEPTH_M` m)^2; a finite or
    NaN score.
    """
    names = joints.names
    lo, hi, where = _pixel_bounds(intrinsics)
    uv, xyz, conf, cov = joints.uv, joints.xyz, joints.confidence, joints.covariance
    # every rule at once (ufuncs; comparisons with NaN are quietly False, no np.errstate
    # needed): the details below only for a set that breaks one
    fine = (_all(np.isnan(uv) | ((uv >= lo) & (uv <= hi)), axis=None)
            & _all(np.isnan(xyz) | (np.abs(xyz) <= MAX_DEPTH_M), axis=None)
            & _all((conf >= 0) & (conf <= 1), axis=None)
            & _all(np.abs(cov) <= MAX_DEPTH_M ** 2, axis=None))
    if fine and len(names) <= MAX_JOINTS and len(set(names)) == len(names) \
            and not np.isinf(joints.score):
        return
    if len(names) > MAX_JOINTS:
        raise ValueError(f'{len(names)} joints, more than the {MAX_JOINTS} any skeleton has')
    if len(set(names)) != len(names):
        repeated = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f'joint name(s) repeated: {", ".join(map(repr, repeated))}')

    def first_bad(values: NDArray, ok: NDArray, what: str) -> None:
        bad = np.flatnonzero(~ok.reshape(len(names), -1).all(axis=1)) if names else ()
        if len(bad):
            i = int(bad[0])
            raise ValueError(f'joint {names[i]!r}: {what}, got {values[i].tolist()}')

    with np.errstate(invalid='ignore'):
        first_bad(uv, np.isnan(uv) | ((uv >= lo) & (uv <= hi)), f'pixel must be NaN or {where}')
        first_bad(xyz, np.isnan(xyz) | (np.abs(xyz) <= MAX_DEPTH_M),
                  f'position must be NaN or within {MAX_DEPTH_M:g} m of the camera')
        first_bad(conf, (conf >= 0) & (conf <= 1), 'confidence must be in [0, 1]')
        first_bad(cov, np.abs(cov) <= MAX_DEPTH_M ** 2,
                  f'covariance must be finite, within {MAX_DEPTH_M ** 2:g} m^2')
    if np.isinf(joints.score):
        raise ValueError(f'score must be finite or NaN, got {joints.score}')
