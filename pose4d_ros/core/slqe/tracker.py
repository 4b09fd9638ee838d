"""The per-frame front doors of the SLQE filter: `SlqeTracker` and the comparison baseline
`ConstantVelocityTracker` (with its `CvConfig`)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import PARTS_10, PartTree
from pose4d_ros.core.slqe.config import (
    REFERENCE_SCALE_PX,
    SlqeConfig,
    TrackOutput,
    TrackState,
    evolve,
    initial_state,
)
from pose4d_ros.core.slqe.kernel import config_params, slqe_step
from pose4d_ros.core.slqe.update import check_measurement


@dataclass
class SlqeTracker:
    """Per-frame front door to the SLQE filter (what the `tracker` node calls).

    >>> tracker = SlqeTracker(SlqeConfig(), PARTS_10)
    >>> out = tracker.step(uv, confidence, stamp_s)   # doctest: +SKIP

    `uv` is (P, 2) pixels in `tree.names` order with NaN rows for undetected parts, `confidence`
    (P,) in [0, 1] (or None), `stamp_s` the frame's capture time in seconds, and the optional
    `scale_px` the person's scale in this frame (pixels per half a metre of body), to which the
    pixel parameters are rescaled (see the module's notes). The tracker restarts by itself
    when the stamps jump back or leave a gap over `config.max_dt_s`.
    """

    config: SlqeConfig = field(default_factory=SlqeConfig)
    tree: PartTree = PARTS_10
    state: TrackState = field(init=False)

    def __post_init__(self) -> None:
        self.state = initial_state(len(self.tree), self.config)
        self._parents = np.array(self.tree.parents, np.int64)
        self._params_of: SlqeConfig | None = None

    def reset(self) -> None:
        """Forget every part (a lost track or a new person)."""
        self.state = initial_state(len(self.tree), self.config)

    def step(self, uv: NDArray[np.floating], confidence: NDArray[np.floating] | None,
             stamp_s: float, scale_px: float | None = None) -> TrackOutput:
        """Predict to `stamp_s`, update with the frame's detections and return the estimates
        (`scale_px`: the person's scale, pixels; None = `REFERENCE_SCALE_PX`)."""
        stamp_s = float(stamp_s)
        if not math.isfinite(stamp_s):
            raise ValueError(f'stamp must be finite seconds, got {stamp_s}')
        px_gain = 1.0
        if scale_px is not None:
            if not (math.isfinite(scale_px) and scale_px > 0):
                raise ValueError(f'scale_px must be a positive number of pixels, got {scale_px}')
            px_gain = scale_px / REFERENCE_SCALE_PX
        last = self.state.stamp
        if last is not None and not 0.0 <= stamp_s - last <= self.config.max_dt_s:
            self.reset()  # time went backwards (a looped bag) or the track was lost in a gap
            last = None
        dt = 0.0 if last is None else stamp_s - last
        s = self.state
        z, c = check_measurement(uv, confidence, s.n_parts)
        if self._params_of is not self.config:  # a new config (`TrackerStage.configure`)
            self._params_of = self.config
            self._params = config_params(self.config)
            self._limb = _limb_mask(self.tree, self.config.limb_parts)
        # predict, update and output in one compiled call (`kernel`: the Python functions'
        # work, in their order)
        (x, cov, active, counters, last_rejected, conf, shadow_x, shadow_cov, state_dt,
         motion, covariances, source, conf_out) = \
            slqe_step(s.x, s.cov, s.active, s.missed, s.rejected, s.last_rejected, s.confidence,
                      s.shadow_x, s.shadow_cov, s.shadow_left, s.dt, dt, z, c, px_gain,
                      self._params, self._parents, self._limb)
        self.state = evolve(s, x=x, cov=cov, active=active, missed=counters[0],
                            rejected=counters[1], last_rejected=last_rejected, confidence=conf,
                            shadow_x=shadow_x, shadow_cov=shadow_cov, shadow_left=counters[2],
                            stamp=stamp_s, dt=state_dt)
        return TrackOutput(positions=motion[0], covariances=covariances, velocities=motion[1],
                           source=source, confidence=conf_out, stamp=stamp_s)


@functools.lru_cache(maxsize=16)
def _limb_mask(tree: PartTree, limb_parts: tuple[str, ...]) -> NDArray[np.bool_]:
    """(P,) bool: the parts of `tree` the limb hypothesis applies to (read-only)."""
    mask = np.array([name in limb_parts for name in tree.names], bool)
    mask.setflags(write=False)
    return mask


@dataclass(frozen=True)
class CvConfig:
    """The plain constant-velocity Kalman filter used for comparison.

    The defaults of `process_noise` and `measurement_noise_px` were tuned like `SlqeConfig`'s
    (only their ratio matters without a gate).

    Attributes
    ----------
    process_noise : white-acceleration spectral density (square root), px/s^2 per sqrt(Hz).
    measurement_noise_px : detection standard deviation per axis, pixels.
    gate_chi2 : innovation gate; `inf` (the default) = a plain filter that takes every detection.
    max_missed_frames, max_dt_s, drift_frames, drift_radius_px : as in `SlqeConfig`.
    """

    process_noise: float = 10.0
    measurement_noise_px: float = 2.0
    gate_chi2: float = math.inf
    max_missed_frames: int = 30
    max_dt_s: float = 0.5
    drift_frames: int = 3
    drift_radius_px: float = 15.0

    def to_slqe(self) -> SlqeConfig:
        """The same filter as an `SlqeConfig` (order 2, no coupling, no kept tracks)."""
        return SlqeConfig(order=2, coupling=0.0, shadow_frames=0, process_noise=self.process_noise,
                          measurement_noise_px=self.measurement_noise_px,
                          gate_chi2=self.gate_chi2, max_missed_frames=self.max_missed_frames,
                          max_dt_s=self.max_dt_s, drift_frames=self.drift_frames,
                          drift_radius_px=self.drift_radius_px)


class ConstantVelocityTracker(SlqeTracker):
    """A per-part constant-velocity Kalman filter, no coupling: the comparison baseline.

    Same interface as `SlqeTracker`: ``ConstantVelocityTracker(CvConfig(), PARTS_10).step(uv,
    confidence, stamp_s)``.
    """

    def __init__(self, config: CvConfig | None = None, tree: PartTree = PARTS_10) -> None:
        self.cv_config = config if config is not None else CvConfig()
        super().__init__(self.cv_config.to_slqe(), tree)
