"""The stages of the tracker as objects with one per-frame call, shared by nodes and tools.

The ROS nodes (`foreground`, `detector`, `tracker`, `ik`) and the offline tools call these same
objects (composed in `core.pipeline`), so an offline evaluation and a live run of the graph give
the same answers on the same frames.

- `ForegroundStage`: the person's mask from the depth image (`core.foreground`: floor removal
  and MSER), applied to colour and depth.
- `DetectorStage`: the 4D deformable part model (`core.dpm`) on the masked frame; each part's
  pixel is lifted to 3-D with the robust depth of the person's pixels around it, plus the
  model's learned depth offset from the visible surface to the joint centre.
- `TrackerStage`: the SLQE Kalman filter (`core.slqe`, eqs. 6-16) on the detected parts' pixels,
  plus each part's depth carried from its last detection, so tracked parts have a 3-D position
  too (back-projected with the camera's intrinsics).
- `IkStage`: inverse kinematics (`core.kinematics`, or the paper's Denavit-Hartenberg chains,
  `core.dh`, eqs. 17-24) completing elbows and knees from shoulders/hips and wrists/ankles in
  3-D, the swivel chosen by the depth image; output the 14-joint skeleton
  (`skeleton.SKELETON_14`).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Mapping
from dataclasses import replace

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import (
    Intrinsics,
    backproject,
    project,
)
from pose4d_ros.core.dh import DhLimits, infer_middle_joints_dh
from pose4d_ros.core.dpm.infer import Detector, SearchConfig
from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.dpm.net_unary import NetUnary
from pose4d_ros.core.dpm.scale import PersonScale, ScaleConfig
from pose4d_ros.core.foreground import (
    ForegroundConfig,
    ForegroundResult,
    apply_mask,
    hold,
    segment,
    segment_people,
)
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.kinematics import (
    NOTHING_SOLVED,
    IkConfig,
    IkFlag,
    IkResult,
    LimbLengths,
    infer_middle_joints,
)
from pose4d_ros.core.lifting import lift_parts, medoid_parts, person_scale_px, valid_xyz
from pose4d_ros.core.skeleton import LIMBS, PARTS_10, SKELETON_14, PartTree, tree_for
from pose4d_ros.core.slqe import ConstantVelocityTracker, CvConfig, SlqeConfig, SlqeTracker
from pose4d_ros.core.warm_up import warm_up_frame

# The previous frame's parts guide the detector's arms (`SearchConfig.arm_prior`) when it is
# at most this old, seconds (a 30 fps camera that drops a few frames; 10 fps recordings)
PRIOR_MAX_GAP_S = 0.25


def check_known(joints: JointSet, names: tuple[str, ...], intrinsics: Intrinsics | None
                ) -> None:
    """`joints.check_joints`, and ValueError when none of `joints` is one of `names`."""
    cj.check_joints(joints, intrinsics)
    if not set(joints.names) & set(names):
        given = ', '.join(joints.names[:4]) + (', ...' if len(joints) > 4 else '')
        raise ValueError(f'none of the {len(joints)} joints ({given or "none"}) is one of '
                         f'{", ".join(names[:3])}, ...')


def reorder(joints: JointSet, names: tuple[str, ...]) -> JointSet:
    """`joints` in the order of `names`; names it lacks are MISSING (`joints` itself when it
    is in that order already: a JointSet is immutable)."""
    if joints.names == names:
        return joints
    return JointSet.of_arrays(names, *reordered_arrays(joints, names), score=joints.score,
                              track_id=joints.track_id)


def reordered_arrays(joints: JointSet, names: tuple[str, ...]) -> tuple[NDArray, ...]:
    """New arrays (uv, xyz, confidence, source, covariance) of `joints` in the order of
    `names`, MISSING rows for names it lacks: `reorder`'s, for a stage that changes them."""
    if joints.names == names:
        return (joints.uv.copy(), joints.xyz.copy(), joints.confidence.copy(),
                joints.source.copy(), joints.covariance.copy())
    rows, found, empty = _reordering(joints.names, names)
    uv, xyz, conf, src, cov = (empty[0].copy(), empty[1].copy(), empty[2].copy(),
                               empty[3].copy(), empty[4].copy())
    uv[rows], xyz[rows], conf[rows], src[rows], cov[rows] = (
        joints.uv[found], joints.xyz[found], joints.confidence[found], joints.source[found],
        joints.covariance[found])
    return uv, xyz, conf, src, cov


@functools.lru_cache(maxsize=64)
def _reordering(given: tuple[str, ...], names: tuple[str, ...]
                ) -> tuple[NDArray[np.intp], NDArray[np.intp], tuple[NDArray, ...]]:
    """The rows of `names` that `given` has, where `given` has them, and the arrays of
    `names` all MISSING (uv, xyz, confidence, source, covariance) to fill (read-only)."""
    pairs = [(i, given.index(name)) for i, name in enumerate(names) if name in given]
    rows, found = (np.array([p[k] for p in pairs], np.intp) for k in (0, 1))
    n = len(names)
    empty = (np.full((n, 2), np.nan), np.full((n, 3), np.nan), np.zeros(n, np.float32),
             np.full(n, cj.MISSING, np.uint8), np.zeros((n, 3, 3)))
    for a in (rows, found, *empty):
        a.setflags(write=False)
    return rows, found, empty


def _read_only(a: NDArray) -> NDArray:
    """A read-only view of `a`, as an array made on a message's buffer is."""
    view = a.view()
    view.flags.writeable = False
    return view


class ForegroundStage:
    """The person's mask from the depth image, applied to colour and depth.

    Parameters
    ----------
    config : the foreground configuration (`core.foreground.ForegroundConfig`).
    temporal : pass each frame's result (its floor and its box) to the next frame, and hold
        the person (`core.foreground.hold`) for up to `HOLD_FRAMES` frames in which
        `segment` finds none.
    """

    HOLD_FRAMES = 2
    TEMPORAL = True  # the default of `temporal` (and of the foreground node's parameter)

    def __init__(self, config: ForegroundConfig | None = None, *,
                 temporal: bool = TEMPORAL) -> None:
        self.configure(config, temporal=temporal)
        self.previous: ForegroundResult | None = None
        self.held = 0
        self.previous_people: list[ForegroundResult] = []
        self.held_people = 0

    def configure(self, config: ForegroundConfig | None = None, *, temporal: bool = TEMPORAL
                  ) -> None:
        """New settings (as in the constructor), used from the next frame on."""
        self.config = config or ForegroundConfig()
        self.temporal = temporal

    def reset(self) -> None:
        self.previous = None
        self.held = 0
        self.previous_people, self.held_people = [], 0

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Run on `warm_up_frame` twice (the second time with a previous frame), at the
        camera's size and at twice it (the working-resolution path of larger images), then
        forget it, so the kernels are compiled."""
        for k in (intrinsics, intrinsics.scaled(2 * intrinsics.width, 2 * intrinsics.height)):
            color, depth, mask = warm_up_frame(k)
            for _ in range(2):
                self.step(color, depth, k)
                self.step_people(color, depth, k, 4)
            self.reset()
        # the blanking kernel for the arrays a node gets: views of a message's buffer are
        # read-only (a new numba signature each, else compiled at the first camera frame)
        millimetres = np.nan_to_num(depth * 1000).astype(np.uint16)
        for c, d in itertools.product((color, _read_only(color)),
                                      (depth, _read_only(depth), millimetres,
                                       _read_only(millimetres))):
            apply_mask(c, d, mask)
        # and for the detector's crops of them (`dpm.infer`: views, not contiguous)
        for c, d, m in itertools.product((color, _read_only(color)), (depth, _read_only(depth)),
                                         (mask, _read_only(mask))):
            apply_mask(c[:, 1:], d[:, 1:], m[:, 1:])

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating],
             intrinsics: Intrinsics
             ) -> tuple[ForegroundResult, NDArray[np.uint8], NDArray[np.float32]]:
        """The foreground of one frame, and the colour and depth (float32 metres, NaN = no
        reading) blanked outside it."""
        color, depth_m = np.asarray(color), np.asarray(depth_m, np.float32)
        if color.shape[:2] != depth_m.shape:
            raise ValueError(f'colour is {color.shape[1]}x{color.shape[0]} but depth is '
                             f'{depth_m.shape[1]}x{depth_m.shape[0]} (not registered?)')
        fg = segment(depth_m, intrinsics, config=self.config,
                     previous=self.previous if self.temporal else None)
        if fg.found or not self.temporal:
            self.previous, self.held = (fg if fg.found else None), 0
        elif self.previous is not None and self.held < self.HOLD_FRAMES:
            fg = hold(self.previous, depth_m)
            self.held += 1
        else:
            self.previous = None
        return (fg, *apply_mask(color, depth_m, fg.mask))

    def step_people(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating],
                    intrinsics: Intrinsics, max_people: int
                    ) -> tuple[list[ForegroundResult], int, NDArray[np.uint8],
                               NDArray[np.float32]]:
        """Every person of one frame (`core.foreground.segment_people`, at most `max_people`,
        best first), how many the rules found, and the colour and depth blanked outside all
        of them. Held like `step`'s person when a frame finds nobody."""
        color, depth_m = np.asarray(color), np.asarray(depth_m, np.float32)
        if color.shape[:2] != depth_m.shape:
            raise ValueError(f'colour is {color.shape[1]}x{color.shape[0]} but depth is '
                             f'{depth_m.shape[1]}x{depth_m.shape[0]} (not registered?)')
        people, found = segment_people(depth_m, intrinsics, config=self.config,
                                       previous=self.previous_people if self.temporal else (),
                                       max_people=max_people)
        if people or not self.temporal:
            self.previous_people, self.held_people = people, 0
        elif self.previous_people and self.held_people < self.HOLD_FRAMES:
            people = [hold(p, depth_m) for p in self.previous_people]
            self.held_people += 1
        else:
            self.previous_people = []
        union = np.zeros(depth_m.shape, bool)
        for person in people:
            union |= person.mask
        return (people, found, *apply_mask(color, depth_m, union))


class DetectorStage:
    """Part detection in one frame: the best pose of the part model, lifted to 3-D.

    Parameters
    ----------
    model : a trained part model (`core.dpm.model.load_model`); its channels say whether the
        depth HOG is used ('rgbd') or not ('rgb', the Yang & Ramanan baseline).
    search : where and at which scales to search (`core.dpm.infer.SearchConfig`).
    scale : how the person's own scale is chosen per track (`core.dpm.scale`; with an RGB
        model, or without depth, the depth-free search covers every scale anyway).
    min_confidence : parts less confident than this are reported MISSING.
    unary : the photograph network as a colour unary of the part model's tree
        (`core.dpm.net_unary.NetUnary`); None = the model's HOG filters alone.
    """

    MIN_CONFIDENCE = 0.0  # the default of `min_confidence` (and of the detector node's)

    def __init__(self, model: PartModel, *, search: SearchConfig | None = None,
                 scale: ScaleConfig | None = None, min_confidence: float = MIN_CONFIDENCE,
                 unary: NetUnary | None = None) -> None:
        self.model = model
        self.detector = Detector(model, search, unary)
        self.person_scale = PersonScale(scale)
        self.last_flags: tuple[str, ...] = ()
        self._previous: tuple[NDArray[np.float64], float] | None = None  # parts' uv, stamp
        self.configure(search=search, scale=scale, min_confidence=min_confidence)

    def configure(self, *, search: SearchConfig | None = None, scale: ScaleConfig | None = None,
                  min_confidence: float = MIN_CONFIDENCE) -> None:
        """New settings (as in the constructor), used from the next frame on (new person scale
        settings start the choice of scale anew)."""
        if not 0.0 <= min_confidence <= 1.0:
            raise ValueError(f'min_confidence must be in [0, 1], got {min_confidence}')
        self.detector.config = search or SearchConfig()
        if (scale or ScaleConfig()) != self.person_scale.config:
            self.person_scale = PersonScale(scale)
        self.min_confidence = min_confidence

    def spawn(self) -> DetectorStage:
        """A new stage with this one's settings as they are now and the same model, knowing
        nobody yet: another person's (`core.people`)."""
        return DetectorStage(self.model, search=self.detector.config,
                             scale=self.person_scale.config, min_confidence=self.min_confidence,
                             unary=self.detector.unary)

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.part_names

    def reset(self) -> None:
        """Forget the person (the next frame starts a new track)."""
        self.person_scale.reset()
        self._previous = None

    def _prior(self, stamp_s: float | None) -> NDArray[np.float64] | None:
        """The previous frame's parts when they are recent enough to guide this frame's arms."""
        if stamp_s is None or self._previous is None:
            return None
        uv, last = self._previous
        return uv if 0.0 < stamp_s - last <= PRIOR_MAX_GAP_S else None

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Run on a synthetic frame (`warm_up_frame`) twice, the second time guided by the
        first (`SearchConfig.arm_prior`), so the kernels are compiled and loaded, then forget
        it."""
        color, depth, mask = warm_up_frame(intrinsics)
        # and on read-only views, as a node's frames are (arrays on a message's buffer): each
        # kernel's signature for them loaded in this process now, not at the first frame
        for c, d, m in ((color, depth, mask),
                        (_read_only(color), _read_only(depth), _read_only(mask))):
            for stamp_s in (0.0, 1.0 / 30.0):
                self.step(c, d, intrinsics, mask=m, stamp_s=stamp_s)
            self.reset()

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None, *, mask: NDArray[np.bool_] | None = None,
             stamp_s: float | None = None, blanked: bool = False,
             occluder: NDArray[np.bool_] | None = None) -> JointSet:
        """The detected parts of one frame (all MISSING when there is no person to search).

        `blanked`: colour and depth are already blanked outside `mask` (as `ForegroundStage`
        returns them), so the detector need not blank them again. `occluder`: the pixels of
        nearer people, where a part may lie hidden (`SearchConfig.occluded_quantile`).

        `stamp_s` (the frame's time, seconds) tells the person's scale when a new track starts
        (`core.dpm.scale.PersonScale`: the person unseen for a while); without it, only
        `reset` does. While the scale is undecided (every factor searched), each part is the
        medoid of the factors' poses (`medoid_parts`). With it, the previous frame's parts,
        if at most `PRIOR_MAX_GAP_S` old, guide this frame's arms (`SearchConfig.arm_prior`).
        `last_flags` tells why a result is doubtful ('no_person', 'low_score', 'no_depth').
        ValueError when `intrinsics` are for another image size.
        """
        color = np.asarray(color)
        if intrinsics is not None:
            intrinsics.check_size(color.shape)
        scaled = depth_m is not None and self.model.channels == 'rgbd'
        factors = self.person_scale.factors(stamp_s) if scaled else (1.0,)
        prior = self._prior(stamp_s)
        found = {f: self.detector.detect(color, depth_m, mask=mask, intrinsics=intrinsics,
                                         scale=f, blanked=blanked, prior=prior,
                                         occluder=occluder)
                 for f in factors}
        if not any(found.values()):
            self.last_flags = ('no_person',)
            self._previous = None
            return JointSet.missing(self.names)
        if scaled:
            chosen = self.person_scale.update(
                {f: poses[0].rank if poses else math.nan for f, poses in found.items()})
            pose = found[chosen][0]
            poses = [v[0] for v in found.values()
                     if v and np.logical_and.reduce(np.isfinite(v[0].uv), axis=None)]
            if len(poses) >= 3:
                # the person's scale still undecided (a track's first frames): each part where
                # the poses found at the factors agree most, not where the leading one put it
                pose = replace(pose, uv=medoid_parts([p.uv for p in poses]))
        else:
            pose = found[1.0][0]
        self.last_flags = pose.flags
        conf = pose.confidence.astype(np.float32)
        src = np.where(conf >= self.min_confidence, cj.DETECTED, cj.MISSING).astype(np.uint8)
        # a part the model places beyond the image's edge (its filter hanging over the border)
        # is put on the edge: a detection is a pixel of the image
        h, w = color.shape[:2]
        # np.clip's values, without its Python wrapper
        on_image = np.minimum(np.maximum(pose.uv, 0.0), _image_max(w, h))
        uv = np.where(src[:, None] == cj.DETECTED, on_image, np.nan)
        self._previous = None if stamp_s is None else (uv, float(stamp_s))
        xyz = np.full((len(self.names), 3), np.nan)
        if depth_m is not None and intrinsics is not None:
            z = lift_parts(self.model, depth_m, uv, intrinsics, mask)
            if self.model.refiner is not None:
                # where the joints really are, learned (`core.refine`); still on the image
                uv, z = self.model.refiner.apply(self.names, self.model.parents, uv, z, conf,
                                                 depth_m, intrinsics, mask)
            xyz = backproject(uv, z, intrinsics)
        return JointSet(self.names, uv, xyz, confidence=np.where(src == cj.DETECTED, conf, 0),
                        source=src, score=float(pose.score))


class TrackerStage:
    """SLQE tracking of the detected parts (or the constant-velocity filter, `kind='cv'`).

    Parameters
    ----------
    kind : 'slqe' (the paper's filter) or 'cv' (plain per-part constant velocity, comparison).
    slqe, cv : their configurations.
    tree : the part tree; None = the tree of the parts received (`skeleton.tree_for`: the
        10-part model's, or the 14-part model's once elbows and knees come; a change of tree
        starts a new track).
    depth_std_m : standard deviation put on a tracked part's depth in its covariance, metres.
    """

    DEPTH_STD_M = 0.05  # the default of `depth_std_m` (and of the tracker node's)

    def __init__(self, *, kind: str = 'slqe', slqe: SlqeConfig | None = None,
                 cv: CvConfig | None = None, tree: PartTree | None = None,
                 depth_std_m: float = DEPTH_STD_M) -> None:
        if kind not in ('slqe', 'cv'):
            raise ValueError(f"tracker kind must be 'slqe' or 'cv', got {kind!r}")
        self.kind = kind
        self.fixed_tree = tree
        self.track_id = 0
        self.configure(slqe=slqe, cv=cv, depth_std_m=depth_std_m)
        self._use(tree or PARTS_10)

    def configure(self, *, slqe: SlqeConfig | None = None, cv: CvConfig | None = None,
                  depth_std_m: float = DEPTH_STD_M) -> None:
        """New settings (as in the constructor), used from the next frame on; the track goes
        on under them."""
        if not depth_std_m >= 0:
            raise ValueError(f'depth_std_m must be >= 0, got {depth_std_m}')
        self.slqe_config = slqe or SlqeConfig()
        self.cv_config = cv or CvConfig()
        self.depth_std_m = depth_std_m
        if hasattr(self, 'filter'):
            self.filter.config = (self.slqe_config if self.kind == 'slqe'
                                  else self.cv_config.to_slqe())

    def spawn(self) -> TrackerStage:
        """A new stage with this one's settings as they are now, tracking nobody yet: another
        person's (`core.people`)."""
        return TrackerStage(kind=self.kind, slqe=self.slqe_config, cv=self.cv_config,
                            tree=self.fixed_tree, depth_std_m=self.depth_std_m)

    def _use(self, tree: PartTree) -> None:
        """A new filter (no track) on `tree`."""
        self.tree = tree
        self.filter: SlqeTracker = (SlqeTracker(self.slqe_config, tree) if self.kind == 'slqe'
                                    else ConstantVelocityTracker(self.cv_config, tree))
        self.depth = np.full(len(tree), np.nan)

    def reset(self) -> None:
        self.filter.reset()
        self.depth[:] = np.nan

    def check(self, parts: JointSet, intrinsics: Intrinsics | None) -> PartTree:
        """The tree `step` would track `parts` on; ValueError for parts it would refuse."""
        tree = self.fixed_tree or _tree_for(parts.names)
        check_known(parts, tree.names, intrinsics)
        return tree

    def step(self, parts: JointSet, stamp_s: float, intrinsics: Intrinsics | None, *,
             checked: bool = False) -> JointSet:
        """Track one frame of detected parts; returns the tracked parts in the tree's order.

        Parts the detector missed are predicted (TRACKED); parts lost for too long are MISSING.
        3-D positions: the tracked pixel back-projected at the part's depth, which is the depth
        of its detection in this frame when the filter accepts it, else that of its last
        accepted detection (a rejected detection lies elsewhere in the image).
        ValueError (and the track untouched) for parts no camera could have seen
        (`joints.check_joints`) or none of which the tree has. `checked`: the caller has
        passed `parts` through `check` already (the several-person tracker checks a frame's
        detections before any track changes).
        """
        tree = (self.fixed_tree or _tree_for(parts.names)) if checked \
            else self.check(parts, intrinsics)
        if tree is not self.tree:
            self._use(tree)
        parts = reorder(parts, self.tree.names)
        state = self.filter.state
        cfg = self.filter.config
        new_track = not _any(state.active) or (
            state.stamp is not None and not 0.0 <= stamp_s - state.stamp <= cfg.max_dt_s)
        if new_track:
            self.depth[:] = np.nan
        detected = parts.source == cj.DETECTED
        # np.where's arrays, without its Python wrapper (the per-frame path)
        uv, conf = parts.uv.copy(), parts.confidence.copy()
        uv[~detected], conf[~detected] = np.nan, 0.0
        out = self.filter.step(uv, conf, stamp_s,
                               person_scale_px(parts.xyz[detected], intrinsics))
        if new_track and _any(self.filter.state.active):
            self.track_id += 1
        positions, source, confidence = out.positions, out.source, out.confidence
        covariances = out.covariances
        # a part's depth is its accepted detection's: a rejected one lies elsewhere
        measured = detected & (source == cj.DETECTED) & valid_xyz(parts.xyz)
        self.depth[measured] = parts.xyz[measured, 2]
        # an accepted detection lies on the image, and so does its filtered estimate (the
        # prediction may overshoot an edge the part moves towards); np.clip's values
        if intrinsics is not None:
            held = np.minimum(np.maximum(positions, 0.0),
                              _image_max(intrinsics.width, intrinsics.height))
            accepted = source == cj.DETECTED
            positions[accepted] = held[accepted]  # `output`'s own array
        # a part predicted off the image (coasting away) is lost: no stage takes such pixels
        lost = (source != cj.MISSING) & ~cj.near_image(positions, intrinsics)
        if _any(lost):
            positions = np.where(lost[:, None], np.nan, positions)
            covariances = np.where(lost[:, None, None], np.nan, covariances)
            confidence = np.where(lost, 0, confidence).astype(np.float32)
            source = np.where(lost, cj.MISSING, source).astype(np.uint8)
        missing = source == cj.MISSING
        self.depth[missing] = np.nan
        n = len(self.tree)
        if intrinsics is not None:
            xyz = backproject(positions, self.depth, intrinsics)
            # pixel covariance -> metric x/y at the part's depth; z from the depth parameter
            scale = np.empty((n, 2))
            scale[:, 0] = self.depth / intrinsics.fx
            scale[:, 1] = self.depth / intrinsics.fy
            cov = np.zeros((n, 3, 3))
            cov[:, :2, :2] = covariances * scale[:, :, None] * scale[:, None, :]
            cov[:, 2, 2] = self.depth_std_m ** 2
            cov[~valid_xyz(xyz)] = 0.0
            if not _all(np.isfinite(cov), axis=None):
                cov = np.nan_to_num(cov)
        else:
            xyz, cov = np.full((n, 3), np.nan), np.zeros((n, 3, 3))
        live = confidence[~missing]
        # np.mean's value (float32 sum over the count), without its Python wrapper
        score = float(np.add.reduce(live) / len(live)) if len(live) else float('nan')
        return JointSet.of_arrays(self.tree.names, positions, xyz, confidence, source, cov,
                                  score=score, track_id=self.track_id if len(live) else 0)


# each limb and the row of its middle joint in SKELETON_14
_MIDDLE_ROWS = tuple((limb, SKELETON_14.index(middle)) for limb, (_, middle, _) in LIMBS.items())
# `ndarray.any` and `ndarray.all` without their Python wrappers (the per-frame path)
_any = np.logical_or.reduce
_all = np.logical_and.reduce
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


@functools.lru_cache(maxsize=16)
def _tree_for(names: tuple[str, ...]) -> PartTree:
    """`skeleton.tree_for`, remembered per set of names (the same parts every frame)."""
    return tree_for(names)


@functools.lru_cache(maxsize=16)
def _image_max(width: int, height: int) -> NDArray[np.float64]:
    """The largest pixel (u, v) of an image of that size (read-only; cached by two ints,
    whose hash is C's, not by the intrinsics, whose dataclass hash is a Python call)."""
    hi = np.array([width - 1, height - 1], np.float64)
    hi.setflags(write=False)
    return hi


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
