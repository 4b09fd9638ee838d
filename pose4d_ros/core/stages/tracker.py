"""`TrackerStage`: the SLQE Kalman filter (`core.slqe`, eqs. 6-16) on the detected parts'
pixels, plus each part's depth carried from its last detection, so tracked parts have a 3-D
position too (back-projected with the camera's intrinsics)."""

from __future__ import annotations

import functools

import numpy as np

from pose4d_ros.core import joints as cj
from pose4d_ros.core.camera import Intrinsics, backproject
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.lifting import person_scale_px, valid_xyz
from pose4d_ros.core.skeleton import PARTS_10, PartTree, tree_for
from pose4d_ros.core.slqe import ConstantVelocityTracker, CvConfig, SlqeConfig, SlqeTracker
from pose4d_ros.core.stages._shared import _all, _any, _image_max, check_known, reorder


@functools.lru_cache(maxsize=16)
def _tree_for(names: tuple[str, ...]) -> PartTree:
    """`skeleton.tree_for`, remembered per set of names (the same parts every frame)."""
    return tree_for(names)


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
