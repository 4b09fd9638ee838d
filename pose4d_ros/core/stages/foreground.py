"""`ForegroundStage`: the person's mask from the depth image (`core.foreground`: floor removal
and MSER), applied to colour and depth."""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics
from pose4d_ros.core.foreground import (
    ForegroundConfig,
    ForegroundResult,
    apply_mask,
    hold,
    segment,
    segment_people,
)
from pose4d_ros.core.stages._shared import _read_only
from pose4d_ros.core.warm_up import warm_up_frame


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
                self.step_people(None, depth, k, 4)
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

    def step_people(self, color: NDArray[np.uint8] | None, depth_m: NDArray[np.floating],
                    intrinsics: Intrinsics, max_people: int
                    ) -> tuple[list[ForegroundResult], int, NDArray[np.uint8] | None,
                               NDArray[np.float32]]:
        """Every person of one frame (`core.foreground.segment_people`, at most `max_people`,
        best first), how many the rules found, and the colour and depth blanked outside all
        of them. Held like `step`'s person when a frame finds nobody. The people are found on
        the depth alone: `color` None gives None for the blanked colour."""
        depth_m = np.asarray(depth_m, np.float32)
        without = color is None
        # no colour: a colour image of no channels, blanked by the same kernel at no cost
        color = np.empty((*depth_m.shape, 0), np.uint8) if without else np.asarray(color)
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
        color_m, depth_masked = apply_mask(color, depth_m, union)
        return people, found, None if without else color_m, depth_masked
