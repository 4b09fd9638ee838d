"""The stages composed: `FramePipeline` runs the foreground, detector, tracker and IK stages
(`core.stages`) on one frame, in that order, for one person (the paper's) or for several
(`core.people`); what the `pipeline` node and `pose4d eval`, `bench` and `demo` run.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import (
    Intrinsics,
)
from pose4d_ros.core.foreground import (
    ForegroundResult,
)
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people import PeopleDetector, PeopleIk, PeopleTracker, TrackingConfig
from pose4d_ros.core.skeleton import SKELETON_14
from pose4d_ros.core.stages import DetectorStage, ForegroundStage, IkStage, TrackerStage
from pose4d_ros.core.sync import TIME_JUMP_S, StampJumps
from pose4d_ros.core.warm_up import warm_up_frame

# One person, as the paper (`FramePipeline` without `people`): the several-person path with one
# candidate searched, whose skeleton is published whatever its size (the least span,
# `TrackingConfig.min_span_m`, tells pieces of bodies from people where several are tracked)
ONE_PERSON = TrackingConfig(max_people=1, min_span_m=0.0, max_shoulders_m=0.0)

# The stages of `FramePipeline.step`, in order (the keys of `FrameResult.cpu_s` and `wall_s`)
STAGES = ('foreground', 'detector', 'tracker', 'ik')


@dataclass(frozen=True)
class FrameResult:
    """Everything one frame produced, stage by stage (the foreground and the masked images are
    None for a frame without depth), and each stage's time per name of `STAGES`: `cpu_s`,
    seconds of this process's CPU (`time.process_time`), and `wall_s`. Several people: every
    person's skeleton (`people`), each candidate's detection (`detections`, scored or not) and
    each confirmed track's tracked parts (`tracks`), and the jump of the input stamps before
    this frame (`jump_s`, seconds, negative: back; None: none) at which every stage started
    anew, as a node does (`core.sync.StampJumps`)."""

    foreground: ForegroundResult | None
    color_masked: NDArray[np.uint8]
    depth_masked: NDArray[np.float32] | None
    parts: JointSet
    tracked: JointSet
    skeleton: JointSet
    cpu_s: dict[str, float]
    wall_s: dict[str, float]
    people: tuple[JointSet, ...] = ()
    foregrounds: tuple[ForegroundResult, ...] = ()
    candidates: int = 0
    born: tuple[int, ...] = ()
    ended: tuple[int, ...] = ()
    detections: tuple[JointSet, ...] = ()
    tracks: tuple[JointSet, ...] = ()
    jump_s: float | None = None


class FramePipeline:
    """Foreground, detector, tracker and IK on one frame, in that order.

    Parameters
    ----------
    detector : the detector stage (holds the part model).
    foreground, tracker, ik : the other stages (defaults if None).
    people : how several people are told apart (`core.people`): every candidate of the
        foreground searched, each person tracked and completed on their own (the stages above
        are the templates of every person's, `spawn`); `FrameResult.people` holds every
        confirmed track's skeleton and `skeleton` the primary person's. None: one person, as
        the paper: the same path with `ONE_PERSON` (one candidate searched). Against the
        single-person path it replaced (`make results`, PCK@0.1 average of `rgbd_kf_ik`):
        valid30, test, test30 and the demo bag the same to the digit; test30_arms 98.19 ->
        98.13 and test30_msr 90.10 -> 90.02 (a stamp jump between two videos now starts
        the detector's person scale anew as well, as the nodes always did).

    Attributes
    ----------
    profilers : None, or per name of `STAGES` an object with ``enable()`` and ``disable()``
        (a `cProfile.Profile`), enabled only while that stage runs.
    """

    def __init__(self, detector: DetectorStage, *, foreground: ForegroundStage | None = None,
                 tracker: TrackerStage | None = None, ik: IkStage | None = None,
                 people: TrackingConfig | None = None) -> None:
        self.foreground = foreground or ForegroundStage()
        self.detector = detector
        self.tracker = tracker or TrackerStage()
        self.ik = ik or IkStage()
        self.multi = PeopleStages(self.detector, self.tracker, self.ik, people or ONE_PERSON)
        # stamps that jump start every stage anew, as the nodes do
        self._jumps = StampJumps(TIME_JUMP_S)
        # per name of `STAGES`, a profiler (enable(), disable(): `cProfile.Profile`) that runs
        # only while that stage does (`pose4d bench` counts the Python calls of each stage)
        self.profilers: Mapping[str, Any] | None = None

    def configure(self, *, foreground: Mapping[str, Any] | None = None,
                  detector: Mapping[str, Any] | None = None,
                  tracker: Mapping[str, Any] | None = None, ik: Mapping[str, Any] | None = None,
                  people: TrackingConfig | None = None) -> None:
        """New settings of the stages (each stage's `configure` keywords; several people:
        every person's stages too) and of how people are told apart, used from the next frame
        on; None leaves a stage as it is."""
        if foreground is not None:
            self.foreground.configure(**foreground)
        multi = self.multi
        for many, settings in ((multi.detector, detector), (multi.tracker, tracker),
                               (multi.ik, ik)):
            if settings is not None:
                many.configure(**settings)
        if people is not None:
            multi.config = multi.detector.config = multi.tracker.config = people

    def reset(self) -> None:
        """Forget the previous frames (the next one starts a new track)."""
        self.foreground.reset()
        self.detector.reset()
        self.tracker.reset()
        self.ik.reset()
        self.multi.reset()

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating] | None,
             intrinsics: Intrinsics | None, stamp_s: float) -> FrameResult:
        """Run every stage on one frame (depth: float32 metres, NaN = no reading).

        Without depth (an RGB-only model's source) there is no foreground and one person: the
        detector searches the whole colour image.
        """
        if depth_m is not None:
            return self._step_people(color, depth_m, intrinsics, stamp_s)
        clock = self._lap([])
        self._lap(clock)  # no foreground: its time is nil
        parts = self.detector.step(color, None, intrinsics, stamp_s=stamp_s)
        self._lap(clock)
        tracked = self.tracker.step(parts, stamp_s, intrinsics)
        self._lap(clock)
        skeleton = self.ik.step(tracked, None, intrinsics)
        self._lap(clock)
        cpu_s, wall_s = _stage_times(clock)
        return FrameResult(None, color, None, parts, tracked, skeleton, cpu_s, wall_s)

    def _step_people(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating],
                     intrinsics: Intrinsics, stamp_s: float) -> FrameResult:
        multi = self.multi
        jump_s = self._jumps.jump_s(round(stamp_s * 1e9))
        if jump_s is not None:
            self.reset()
        clock = self._lap([])
        found, n, color_m, depth_mm = self.foreground.step_people(
            color, depth_m, intrinsics, multi.config.max_people)
        self._lap(clock)
        parts = multi.detector.step(color, np.asarray(depth_m, np.float32), intrinsics, found,
                                    stamp_s=stamp_s)
        self._lap(clock)
        tracked = multi.tracker.step(parts, stamp_s, intrinsics, depth_m)
        self._lap(clock)
        skeletons = multi.ik.step(tracked, depth_mm, intrinsics)
        self._lap(clock)
        cpu_s, wall_s = _stage_times(clock)
        fg = found[0] if found else None
        return FrameResult(
            fg, color_m, depth_mm,
            parts[0] if parts else JointSet.missing(self.detector.names),
            tracked[0] if tracked else JointSet.missing(self.tracker.tree.names),
            skeletons[0] if skeletons else JointSet.missing(SKELETON_14), cpu_s, wall_s,
            people=tuple(skeletons), foregrounds=tuple(found), candidates=n,
            born=tuple(multi.tracker.born), ended=tuple(multi.tracker.ended),
            detections=tuple(parts), tracks=tuple(tracked), jump_s=jump_s)

    def _lap(self, clock: list[tuple[float, float]]) -> list[tuple[float, float]]:
        """`clock` with the times (CPU, wall) at a boundary between stages appended; with
        `profilers`, the profiler of the stage that ends is stopped first and the one of the
        stage that starts started after."""
        if self.profilers is not None and clock:
            self.profilers[STAGES[len(clock) - 1]].disable()
        clock.append((time.process_time(), time.perf_counter()))
        if self.profilers is not None and len(clock) <= len(STAGES):
            self.profilers[STAGES[len(clock) - 1]].enable()
        return clock

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Compile the kernels on a synthetic frame, twice (the second frame guided by the
        first, `SearchConfig.arm_prior`), then forget it (`warm_up_frame`). The IK's solver
        too: the 14-part model measures the synthetic person's elbows and knees, and the
        first frame where it misses one would otherwise compile it."""
        self.foreground.warm_up(intrinsics)
        self.ik.warm_up(intrinsics)
        color, depth, _ = warm_up_frame(intrinsics)
        for stamp_s in (0.0, 1.0 / 30.0):
            self.step(color, depth, intrinsics, stamp_s)
        self.reset()
        self.multi.tracker.next_id = 1  # the warm-up's person was nobody: ids start at 1


class PeopleStages:
    """The several-person stages (`core.people`), each person served by a copy (`spawn`) of
    the single-person stages given, which stay the templates of every person's."""

    def __init__(self, detector: DetectorStage, tracker: TrackerStage, ik: IkStage,
                 config: TrackingConfig) -> None:
        self.config = config
        self.detector = PeopleDetector(detector, config)
        self.tracker = PeopleTracker(tracker, config)
        self.ik = PeopleIk(ik)

    def reset(self) -> None:
        self.detector.reset()
        self.tracker.reset()
        self.ik.reset()


def _stage_times(clock: list[tuple[float, float]]) -> tuple[dict[str, float], dict[str, float]]:
    """Each stage's CPU and wall seconds from the (CPU, wall) times at their boundaries."""
    return tuple({stage: clock[k + 1][c] - clock[k][c] for k, stage in enumerate(STAGES)}
                 for c in (0, 1))
