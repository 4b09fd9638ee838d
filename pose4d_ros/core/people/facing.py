"""Which way a tracked person faces, from the way they walk (`Facing`).

The part model was trained on renders of people facing the camera (the Kinect's skeletons,
which assume it), so it names the parts by the image's sides: the part on the image's left is
the person's right. For someone seen from behind that is the wrong way round, and every left
and right joint lies a shoulder's width from where a reference that knows the person's own
sides puts it (the real lab_walk: a man walking away, 14 % of his joints within 0.1 of his
height of MediaPipe's, 100 % with the sides exchanged).

People walk forwards. A track whose torso went at least `TrackingConfig.facing_away_m` away
from the camera over the last `facing_window_s` (at least half of it seen; the median of the
window's last third against its first third's), more away than
across (the optical axis' z against x: a camera looking down from above the heads sees walking
away as z growing too), faces away from it, and its published skeletons have their left and
right joints exchanged (`swapped`). It faces the camera again once it goes half as far
towards it, or as far across as away (seen from the side, the model's sides are as good as
any). A torso that moves faster than a walk has jumped to another body: facing the camera,
the model's prior. Standing still, a person keeps the way they were last seen walking
(facing the camera at first). The tracker's own state and the detector keep the image's
sides: only what the tracker publishes is exchanged.
"""

from __future__ import annotations

import functools
from collections import deque

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.skeleton import mirror_index

MAX_WALK_MPS = 2.5  # faster is a track jumping between bodies, not a walk


@functools.cache
def _mirror(names: tuple[str, ...]) -> list[int]:
    """`mirror_index` of a skeleton's names, made once per set of names (every frame asks)."""
    return mirror_index(names)


def swapped(joints: JointSet) -> JointSet:
    """`joints` with every left joint and its right twin exchanged (names kept in place)."""
    perm = _mirror(joints.names)
    return JointSet.of_arrays(joints.names, joints.uv[perm], joints.xyz[perm],
                              joints.confidence[perm], joints.source[perm],
                              joints.covariance[perm], score=joints.score,
                              track_id=joints.track_id)


class Facing:
    """One track's way of facing (module docstring): `update` with its torso point each frame
    it is seen, `of` its skeleton to publish. `away_m` 0: always facing the camera."""

    def __init__(self, away_m: float = 0.0, window_s: float = 0.6) -> None:
        self.away_m, self.window_s = away_m, window_s
        self.away = False
        self._points: deque[tuple[float, NDArray[np.float64]]] = deque()

    def update(self, stamp_s: float, point: NDArray[np.float64]) -> None:
        """The torso point (camera's optical frame, metres) seen at `stamp_s`."""
        if not self.away_m > 0:
            return
        points = self._points
        if points and np.hypot(*(point - points[-1][1])[[0, 2]]) > MAX_WALK_MPS * max(
                stamp_s - points[-1][0], 0.1):
            # a torso jumping between bodies, not a walk: whoever it is now faces the camera
            points.clear()
            self.away = False
        while points and stamp_s - points[0][0] > self.window_s:
            points.popleft()
        points.append((stamp_s, point))
        if stamp_s - points[0][0] < self.window_s / 2:
            return
        # from the window's first third to its last, medians: one frame's torso is no walk
        third = max(len(points) // 3, 1)
        xz = np.array([p[1][[0, 2]] for p in points])
        dx, dz = np.median(xz[-third:], axis=0) - np.median(xz[:third], axis=0)
        if self.away and (dz <= -self.away_m / 2 or abs(dx) >= max(self.away_m, abs(dz))):
            # towards the camera (facing it, on less evidence) or across it
            self.away = False
        elif not self.away and dz >= self.away_m and dz > abs(dx):
            self.away = True

    def of(self, joints: JointSet) -> JointSet:
        """The skeleton as published: the sides exchanged while the person faces away."""
        return swapped(joints) if self.away else joints
