"""One part-model search per person candidate, each person with their own detector state
(`PeopleDetector`): slots matched to the foreground's candidates by the 3-D centre of their
regions, a still region that scored low kept without a search (`quiet_frames`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.camera import Intrinsics, backproject
from pose4d_ros.core.foreground import ForegroundResult, apply_mask
from pose4d_ros.core.joints import JointSet
from pose4d_ros.core.people.assignment import assign
from pose4d_ros.core.people.config import TrackingConfig
from pose4d_ros.core.stages import DetectorStage

# A candidate region has not moved when its pixels overlap those of the last one searched by
# at least this share (intersection over union) and its median depth is within this many metres
# of that one's (`quiet_frames`). Its box is not compared: a wall's edge at the image's border
# is cut at a height that flickers from frame to frame (its box's top 0-56 px on the demo bag,
# its pixels 91-97 % the same), and a depth step of the renders' quantisation (2 cm at 2.7 m)
# moved it too, so it was searched every other frame
STILL_M = 0.05
STILL_IOU = 0.9


@dataclass
class _Slot:
    """One person's detector state, where their region last was, and its last search: the
    region's pixels and depth, the detection, and the frames it has been kept since."""

    stage: object
    centre: NDArray[np.float64]
    seen_s: float
    depth_m: float = math.nan
    mask: NDArray[np.bool_] | None = None
    last: JointSet | None = None
    kept: int = 0


class PeopleDetector:
    """One part-model search per person candidate, each person with their own detector state.

    Parameters
    ----------
    template : the `core.stages.DetectorStage` whose copy (`spawn`, sharing the model) each new
        person gets.
    config : `TrackingConfig` (max_people, max_speed_mps, torso_std_m; a person's state is
        kept unseen as long as a track can be, the longer of max_unseen_s and max_hidden_s,
        or `detector_keep_s`: a person held behind a nearer one comes back to their person
        scale and arm prior, not to a new track's three-scale warm-up). Chosen on validation
        (`pose4d eval data/synth/<set> --model rgbd_14 --no-single-frame`, `rgbd_kf_ik`
        average7, max_unseen_s before): valid60_people3 86.78 -> 86.87; valid60_people2
        (88.64) and valid30_people2b (86.26) and every tracking figure unchanged.
    """

    def __init__(self, template: DetectorStage, config: TrackingConfig | None = None) -> None:
        self.template = template
        self.config = config or TrackingConfig()
        self.slots: list[_Slot] = []

    def configure(self, **settings: object) -> None:
        """New stage settings (`DetectorStage.configure`) for the template and every person,
        from the next frame on."""
        for stage in [self.template, *(slot.stage for slot in self.slots)]:
            stage.configure(**settings)

    def reset(self) -> None:
        self.slots = []

    def step(self, color: NDArray[np.uint8], depth_m: NDArray[np.floating],
             intrinsics: Intrinsics | None, people: Sequence[ForegroundResult], *,
             stamp_s: float) -> list[JointSet]:
        """The detected parts of each candidate in `people` (at most `max_people`, in their
        order), each searched in its own mask with its person's state, where the candidates
        nearer than them stand as what may hide their parts (`_in_front`)."""
        people = list(people)[:self.config.max_people]
        centres = [_centre(p, intrinsics) for p in people]
        cfg = self.config
        cost = np.full((len(self.slots), len(people)), np.nan)
        for i, slot in enumerate(self.slots):
            spread = cfg.torso_std_m + cfg.max_speed_mps * max(stamp_s - slot.seen_s, 0.0)
            for j, c in enumerate(centres):
                cost[i, j] = float(np.sum((slot.centre - c) ** 2)) / spread ** 2
        pairs = dict((j, i) for i, j in assign(cost, cfg.gate_chi2))
        out = []
        for j, (person, centre) in enumerate(zip(people, centres, strict=True)):
            if j in pairs:
                slot = self.slots[pairs[j]]
            else:
                slot = _Slot(self.template.spawn(), centre, stamp_s)
                self.slots.append(slot)
            slot.centre, slot.seen_s = centre, stamp_s
            if self._quiet(slot, person):
                slot.kept += 1
                out.append(slot.last)
                continue
            color_m, depth_mm = apply_mask(color, depth_m, person.mask)
            slot.last = slot.stage.step(color_m, depth_mm, intrinsics, mask=person.mask,
                                        stamp_s=stamp_s, blanked=True,
                                        occluder=_in_front(people, j, cfg.torso_std_m),
                                        photo=color)
            slot.depth_m, slot.mask, slot.kept = person.depth_m, person.mask, 0
            out.append(slot.last)
        keep_s = cfg.detector_keep_s or max(cfg.max_unseen_s, cfg.max_hidden_s)
        self.slots = [s for s in self.slots if stamp_s - s.seen_s <= keep_s]
        return out

    def _quiet(self, slot: _Slot, person: ForegroundResult) -> bool:
        """Whether the slot's last detection stands for this frame (`quiet_frames`)."""
        cfg = self.config
        if not (slot.kept < cfg.quiet_frames and slot.last is not None
                and slot.last.score < cfg.birth_score and slot.mask is not None
                and abs(person.depth_m - slot.depth_m) <= STILL_M
                and slot.mask.shape == person.mask.shape):
            return False
        # a person partly hidden scores as low, but moves within their region
        union = np.count_nonzero(slot.mask | person.mask)
        return np.count_nonzero(slot.mask & person.mask) >= STILL_IOU * union


def _in_front(people: Sequence[ForegroundResult], j: int, by_m: float
              ) -> NDArray[np.bool_] | None:
    """The pixels of the candidates nearer than `people[j]` by over `by_m` (their median
    depths), or None: where a nearer person may hide them (`core.dpm.infer.OcclusionFloor`)."""
    near = [p.mask for k, p in enumerate(people)
            if k != j and p.depth_m < people[j].depth_m - by_m]
    return np.logical_or.reduce(near) if near else None


def _centre(person: ForegroundResult, intrinsics: Intrinsics | None) -> NDArray[np.float64]:
    """The 3-D centre of a candidate's box at its median depth (pixels and 1 m without
    intrinsics)."""
    x0, y0, x1, y1 = person.box or (0, 0, 0, 0)
    uv = np.array([[(x0 + x1) / 2, (y0 + y1) / 2]], float)
    if intrinsics is None or not math.isfinite(person.depth_m):
        return np.array([uv[0, 0] / 100, uv[0, 1] / 100, 1.0])
    return backproject(uv, np.array([person.depth_m]), intrinsics)[0]
