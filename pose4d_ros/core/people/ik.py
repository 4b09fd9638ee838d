"""One IK per person (`PeopleIk`): each track its own `core.pipeline.IkStage`, with its own
learned bone lengths."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.joints import JointSet


class PeopleIk:
    """One `core.pipeline.IkStage` per track id (each track its own learned bone lengths);
    a track's IK ends when its id is no longer given."""

    def __init__(self, make: Callable[[], object]) -> None:
        self.make = make
        self.stages: dict[int, object] = {}

    def reset(self) -> None:
        self.stages = {}

    def step(self, tracked: Sequence[JointSet], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None) -> list[JointSet]:
        """The 14-joint skeleton of each tracked person, in the order given."""
        stages = {t.track_id: self.stages.get(t.track_id) or self.make() for t in tracked}
        self.stages = stages
        return [stages[t.track_id].step(t, depth_m, intrinsics) for t in tracked]
