"""`IkStage`: inverse kinematics (`core.kinematics`, or the paper's Denavit-Hartenberg chains,
`core.dh`, eqs. 17-24) completing elbows and knees from shoulders/hips and wrists/ankles in
3-D, the swivel chosen by the depth image; output the 14-joint skeleton
(`skeleton.SKELETON_14`)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics, project
from pose4d_ros.core.dh import DhLimits, infer_middle_joints_dh
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.kinematics import (
    NOTHING_SOLVED,
    IkConfig,
    IkFlag,
    IkResult,
    LimbLengths,
    infer_middle_joints,
)
from pose4d_ros.core.lifting import valid_xyz
from pose4d_ros.core.skeleton import LIMBS, SKELETON_14
from pose4d_ros.core.stages._shared import _all, _any, check_known, reordered_arrays
from pose4d_ros.core.warm_up import warm_up_frame

# each limb and the row of its middle joint in SKELETON_14
_MIDDLE_ROWS = tuple((limb, SKELETON_14.index(middle)) for limb, (_, middle, _) in LIMBS.items())
# the 3 x 3 identity of the inferred joints' covariance (np.eye is a Python call a joint)
_EYE3 = np.eye(3)
_EYE3.setflags(write=False)
_DOWN = np.array([0.0, 1.0, 0.0])
_LEG_ROWS = {side: tuple(SKELETON_14.index(f'{side}_{j}') for j in ('hip', 'knee', 'ankle'))
             for side in ('left', 'right')}
# the knees and ankles, each with its hip, and the pixels around a joint that `_hidden_leg_joints`
# looks at (2 each way)
_KNEES_ANKLES = np.array([r for hip, knee, ankle in _LEG_ROWS.values() for r in (knee, ankle)])
_THEIR_HIPS = np.array([hip for hip, _, _ in _LEG_ROWS.values() for _ in range(2)])
_WINDOW = 2
_MISSING = cj.MISSING
_NONE_HIDDEN = np.zeros(0, np.int64)
_NONE_HIDDEN.setflags(write=False)


@nb.njit(cache=True)
def _hidden_leg_joints(uv: NDArray[np.float64], src: NDArray[np.uint8],
                       depth: NDArray[np.floating]) -> NDArray[np.int64]:
    """Rows of the knees and ankles below their hip in the image with no depth reading within
    `_WINDOW` pixels: no pixel of the person there (the depth is the person's masked depth),
    so what the part model put there is a guess (legs hidden by a table, the image's bottom
    edge). Located: not MISSING, u finite; below: v greater (NaN is not); the window's pixels
    on the image only."""
    h, w = depth.shape
    out = np.empty(len(_KNEES_ANKLES), np.int64)
    n = 0
    for j in range(len(_KNEES_ANKLES)):
        k = _KNEES_ANKLES[j]
        u, v = uv[k, 0], uv[k, 1]
        if src[k] == _MISSING or not v > uv[_THEIR_HIPS[j], 1] or not math.isfinite(u):
            continue
        seen = False
        if math.isfinite(v):
            r0, c0 = int(np.rint(v)), int(np.rint(u))
            for r in range(max(r0 - _WINDOW, 0), min(r0 + _WINDOW + 1, h)):
                for c in range(max(c0 - _WINDOW, 0), min(c0 + _WINDOW + 1, w)):
                    seen = seen or math.isfinite(depth[r, c])
        if not seen:
            out[n] = k
            n += 1
    return out[:n]



class IkStage:
    """Complete the skeleton: elbows and knees by inverse kinematics, 14 joints in 3-D.

    Parameters
    ----------
    config : the IK parameters (`core.kinematics.IkConfig`).
    lengths : (upper, lower) bone lengths per limb, metres (default: the UTKinect medians).
    learn : learn each track's bone lengths from its observed reach (`LimbLengths`), starting
        from `lengths`; False = always `lengths`.
    use_depth : choose the swivel angle with the depth image (else the joint-limit prior).
    method : 'geometric' (`kinematics.infer_middle_joints`: the elbow/knee on the law-of-cosines
        circle) or 'dh' (`dh.infer_middle_joints_dh`: the paper's Denavit-Hartenberg chains,
        eqs. 17-24, the same swivel choice, joint limits as angles, bones of the learned lengths
        exactly, joint angles computed).
    limits : the DH chains' joint limits (method 'dh').
    hidden_legs : a knee or ankle below the hip where the person's masked depth has no pixel
        (legs hidden by a table or cut by the image's edge) is not measured: its detection is
        a guess. The ankle is then placed by the leg's learned lengths (a shin below a seen
        knee along the thigh, else the leg straight down the camera's y axis from the hip),
        the knee solved by IK. Chosen on validation (`rgbd_kf_ik` average7, ankles): valid30
        98.85 -> 98.90 (94.2 -> 94.6), valid30_msr 91.14 -> 91.41 (77.3 -> 79.2),
        valid30_near 84.40 -> 84.49, valid60_people2 87.27 -> 87.57.

    Notes
    -----
    The default method stays 'geometric', chosen on the validation subjects only (UTKinect
    s01-s06, `pose4d track-eval --train 1-3 --test 4-6 --no-tracking`, seed 0, mean elbow and
    knee error): with depth from capsules on the real Kinect skeletons (the truth the IK was
    tuned against) 'dh' is worse, 74.6 vs 50.7 mm (s01-s03) and 81.2 vs 52.9 mm (s04-s06),
    because it keeps the bones at the learned lengths while Kinect's own bones stretch from
    frame to frame and the geometric depth search follows them (`IkConfig.length_scales`);
    with the prior alone the two agree within 3 mm. 'dh' wins where the truth's bones are rigid:
    on the synthetic body, whose bones are exactly the learned lengths (28.6 vs 33.6, 34.5 vs
    40.5 mm), and by a little on MSR Action3D's s01-s06 with capsule depth (37.7 vs 39.5, 44.9
    vs 45.4 mm: better elbows, worse knees). Not better on validation as a whole, so not the
    default.
    """

    LEARN = True  # the defaults of `learn`, `use_depth` and `method` (and of the ik node's)
    USE_DEPTH = True
    METHODS = ('geometric', 'dh')
    METHOD = 'geometric'
    HIDDEN_LEGS = True

    def __init__(self, config: IkConfig | None = None, *,
                 lengths: Mapping[str, tuple[float, float]] | None = None, learn: bool = LEARN,
                 use_depth: bool = USE_DEPTH, method: str = METHOD,
                 limits: DhLimits | None = None, hidden_legs: bool = HIDDEN_LEGS) -> None:
        if method not in self.METHODS:
            raise ValueError(f"IK method must be one of {self.METHODS}, got {method!r}")
        self.config = config or IkConfig()
        self.use_depth = use_depth
        self.method = method
        self.limits = limits or DhLimits()
        self.hidden_legs = hidden_legs
        self.track_id: int | None = None
        self.configure(lengths=lengths, learn=learn)

    def configure(self, *, lengths: Mapping[str, tuple[float, float]] | None = None,
                  learn: bool = LEARN) -> None:
        """New settings (as in the constructor), used from the next frame on; new `lengths`
        restart the learning from them."""
        defaults = dict(lengths) if lengths is not None else None
        if not hasattr(self, 'learner') or defaults != self.defaults:
            self.learner = LimbLengths(defaults)
        self.defaults = defaults
        self.learn = learn

    def spawn(self) -> IkStage:
        """A new stage with this one's settings as they are now, having learned nothing yet:
        another person's (`core.people`)."""
        return IkStage(self.config, lengths=self.defaults, learn=self.learn,
                       use_depth=self.use_depth, method=self.method, limits=self.limits,
                       hidden_legs=self.hidden_legs)

    def lengths(self) -> dict[str, tuple[float, float]]:
        return self.learner.as_dict() if self.learn else dict(self.learner.defaults)

    def reset(self) -> None:
        """Forget the learned bone lengths (the next frame starts a new person)."""
        self.learner = LimbLengths(self.defaults)
        self.track_id = None

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Run on the person of `warm_up_frame` so the kernels are compiled, with its depth
        and with none (the joint-limit prior's path, which a frame whose depth cannot place an
        elbow takes); what it learned is forgotten."""
        _, depth, mask = warm_up_frame(intrinsics)
        # shoulders, wrists, hips and ankles of the synthetic person 2.8 m away (camera frame)
        xyz = np.array([[x, y, 2.8] for x, y in ((0.2, -0.35), (0.25, 0.15), (0.1, 0.3),
                                                  (0.1, 1.0))], float)
        names, points = [], []
        for side, sign in (('left', 1.0), ('right', -1.0)):
            for joint, p in zip(('shoulder', 'wrist', 'hip', 'ankle'), xyz, strict=True):
                names.append(f'{side}_{joint}')
                points.append(p * [sign, 1.0, 1.0])
        points = np.array(points)
        source = np.full(len(names), cj.DETECTED, np.uint8)
        joints = JointSet(tuple(names), project(points, intrinsics), points, source=source,
                          confidence=np.ones(len(names), np.float32))
        self.step(joints, depth, intrinsics, mask=mask)
        self.step(joints, None, intrinsics)
        self.reset()

    @staticmethod
    def _place_hidden_ankles(hidden: NDArray[np.int64], uv: NDArray, xyz: NDArray,
                             conf: NDArray, src: NDArray, cov: NDArray, points: NDArray,
                             intrinsics: Intrinsics,
                             lengths: Mapping[str, tuple[float, float]]) -> None:
        """A hidden ankle (`_hidden_leg_joints`) placed by the leg's learned lengths: a shin
        below the knee along the thigh where the knee is seen, else a leg straight down (the
        camera's y axis) from the hip; INFERRED, its standard deviation 10 cm. In place."""
        for side, (hip, knee, ankle) in _LEG_ROWS.items():
            if ankle not in hidden or not _all(np.isfinite(points[hip])):
                continue
            thigh, shin = lengths[f'{side}_leg']
            if knee not in hidden and _all(np.isfinite(points[knee])):
                d = points[knee] - points[hip]
                p = points[knee] + shin * d / max(math.sqrt(float(d @ d)), 1e-6)
            else:
                p = points[hip] + (thigh + shin) * _DOWN
            xyz[ankle] = points[ankle] = p
            uv[ankle] = project(p[None], intrinsics)[0]
            conf[ankle], src[ankle], cov[ankle] = 0.5, cj.INFERRED, _EYE3 * 0.1 ** 2

    def _solve(self, limbs: list[str], depth_m: NDArray[np.floating] | None,
               points: NDArray[np.float64], intrinsics: Intrinsics | None,
               mask: NDArray[np.bool_] | None,
               lengths: Mapping[str, tuple[float, float]]) -> IkResult:
        """The middle joints of `limbs` by the chosen solver."""
        extra = {'limits': self.limits} if self.method == 'dh' else {}
        solver = infer_middle_joints_dh if self.method == 'dh' else infer_middle_joints
        return solver(depth_m if self.use_depth else None, points, intrinsics, lengths,
                      names=SKELETON_14, mask=mask if self.use_depth else None,
                      config=self.config, limbs=limbs, **extra)

    def step(self, tracked: JointSet, depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None, *, mask: NDArray[np.bool_] | None = None
             ) -> JointSet:
        """The 14-joint skeleton of one frame (`skeleton.SKELETON_14` order).

        Joints of `tracked` are copied (a 3-D position behind the camera or not finite makes the
        joint MISSING); elbows and knees `tracked` does not have (or has MISSING) are INFERRED
        where IK finds them, MISSING otherwise (root or end unknown). ValueError for joints no
        camera could have seen (`joints.check_joints`), or a depth image of another size than
        the intrinsics'.
        """
        check_known(tracked, SKELETON_14, intrinsics)
        if depth_m is not None:
            depth_m = np.asarray(depth_m)
            if intrinsics is not None:
                intrinsics.check_size(depth_m.shape, 'depth image')
        if tracked.track_id != self.track_id:  # a new person: learn their limbs anew
            self.learner = LimbLengths(self.defaults)
            self.track_id = tracked.track_id
        uv, xyz, conf, src, cov = reordered_arrays(tracked, SKELETON_14)
        valid = valid_xyz(xyz)
        bad = (src != cj.MISSING) & ~valid & _any(np.isfinite(xyz), axis=1)
        # a 3-D position behind the camera is never passed on as valid
        uv[bad], xyz[bad], conf[bad], src[bad], cov[bad] = np.nan, np.nan, 0.0, cj.MISSING, 0.0
        points = xyz.copy()
        points[~valid] = np.nan
        hidden = _NONE_HIDDEN
        if self.hidden_legs and depth_m is not None and intrinsics is not None:
            hidden = _hidden_leg_joints(uv, src, depth_m)
            # a guess where no pixel of the person is: not measured
            points[hidden] = np.nan
            uv[hidden], xyz[hidden], conf[hidden], src[hidden], cov[hidden] = \
                np.nan, np.nan, 0.0, cj.MISSING, 0.0
        if self.learn:
            self.learner.observe_skeleton(SKELETON_14, points)
        # elbows and knees measured by a 14-part detector are kept: only the others are solved
        # (placing a hidden ankle changes no elbow or knee)
        measured = (src != cj.MISSING) & valid
        unmeasured = [limb for limb, k in _MIDDLE_ROWS if not measured[k]]
        # the learned lengths read once, and only for a frame that uses them
        lengths = self.lengths() if len(hidden) or unmeasured else None
        if len(hidden):
            self._place_hidden_ankles(hidden, uv, xyz, conf, src, cov, points, intrinsics,
                                      lengths)
        result = self._solve(unmeasured, depth_m, points, intrinsics, mask, lengths) \
            if unmeasured else NOTHING_SOLVED
        for k, name in enumerate(result.names):
            i = SKELETON_14.index(name)
            if result.flags[k] in (IkFlag.MISSING, IkFlag.BEHIND_CAMERA) or \
                    not _all(np.isfinite(result.positions[k])):
                uv[i], xyz[i], conf[i], src[i] = np.nan, np.nan, 0.0, cj.MISSING
                continue
            xyz[i] = result.positions[k]
            uv[i] = result.pixels[k] if intrinsics is not None else np.nan
            if intrinsics is not None and not _all(np.isfinite(uv[i])):
                uv[i] = project(xyz[i][None], intrinsics)[0]
            conf[i], src[i] = result.confidence[k], cj.INFERRED
            # kinematics' confidence is exp(-sigma / confidence_scale_m): invert it for sigma
            sigma = -self.config.confidence_scale_m * math.log(max(float(conf[i]), 1e-3))
            cov[i] = _EYE3 * sigma ** 2
        live = conf[src != cj.MISSING]
        n_live = len(live)
        # np.mean's value (float32 sum over the count), without its Python wrapper
        score = float(np.add.reduce(live) / n_live) if n_live else math.nan
        return JointSet.of_arrays(SKELETON_14, uv, xyz, conf, src, cov, score=score,
                                  track_id=tracked.track_id)
