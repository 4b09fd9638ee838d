"""One IK per person (`PeopleIk`): each track its own `core.pipeline.IkStage`, with its own
learned bone lengths."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.stages import IkStage


class PeopleIk:
    """One `core.pipeline.IkStage` per track id (each track its own learned bone lengths);
    a track's IK ends when its id is no longer given."""

    def __init__(self, template: IkStage) -> None:
        self.template = template  # whose copy (`IkStage.spawn`) each new track gets
        self.stages: dict[int, IkStage] = {}

    def configure(self, **settings: object) -> None:
        """New stage settings (`IkStage.configure`) for the template and every person, from
        the next frame on."""
        for stage in [self.template, *self.stages.values()]:
            stage.configure(**settings)

    def reset(self) -> None:
        self.stages = {}

    def step(self, tracked: Sequence[JointSet], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None) -> list[JointSet]:
        """The 14-joint skeleton of each tracked person, in the order given."""
        stages = {t.track_id: self.stages.get(t.track_id) or self.template.spawn()
                  for t in tracked}
        self.stages = stages
        return [stages[t.track_id].step(t, depth_m, intrinsics) for t in tracked]
