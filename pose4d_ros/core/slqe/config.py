"""The SLQE filter's parameters (`SlqeConfig`), its state (`TrackState`) and what a step returns
(`TrackOutput`, `UpdateInfo`); see `core.slqe` for the model."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

# The frame period at which `SlqeConfig.coupling` is stated (the paper's 30 fps Kinect).
NOMINAL_DT_S = 1.0 / 30.0

# The person scale (pixels per half a metre of body) at which the pixel parameters of
# `SlqeConfig` hold: a 320x240 Kinect (fx 285 px) seeing a person about 3 m away, the median of
# the synthetic sets the defaults were tuned and measured on. `SlqeTracker.step`
# rescales them to the person's scale in each frame.
REFERENCE_SCALE_PX = 50.0


class Source(IntEnum):
    """Where a joint estimate came from; the values of pose4d_msgs/Joint's constants."""

    DETECTED = 0
    TRACKED = 1
    INFERRED = 2
    MISSING = 3


@dataclass(frozen=True)
class SlqeConfig:
    """Parameters of the SLQE filter (units: pixels and seconds).

    The defaults of `coupling`, `process_noise`, `measurement_noise_px`, `gate_chi2` and
    `output` were tuned on real motion (UTKinect subjects s01-s06 at 30 fps, 320x240, detector-
    like corruption: 3 px noise, 10 % outliers 20-60 px away, 5 % dropouts; see
    `evaluation.tracking.tune_tracking`); `accel_time_s`, `shadow_frames` and `limb_tolerance` on
    the detector's own output on the validation renders (val30, tune30_wide, tune30_arms; README,
    "Results"). `process_noise` was then raised from that tuning's 300 to 1000 for real
    cameras: a real detector's parts jump further than that corruption model's (3 px noise),
    and at 300 the filter held people's parts back on a real recording. On the real
    development recording lab_walk (`pose4d eval ../shared/data/real/lab_walk --fps 10 --labels
    labels/real/lab_walk.json --peer mediapipe [--colour-net lspet_convnet] --config
    slqe.process_noise=Q`; agreement with MediaPipe within 0.1 x height): 300 19.2 % (with the
    photograph network 35.9 %), 1000 23.5 % (43.5 %), 3000 22.0 % (45.7 %); the detections
    themselves 25.4 % (49.0 %). Validation renders, PCK@0.1 average7 of `rgbd_kf_ik`, 300 ->
    1000: valid30 98.6 -> 98.5, valid60_people2 89.2 -> 88.9, valid60_people3b 89.8 -> 89.6,
    valid60_people3d 87.2 -> 87.0, valid30_people2b 87.1 -> 87.0 (MOTA and IDF1 unchanged).

    Attributes
    ----------
    order : 3 = constant acceleration (the paper's state), 2 = constant velocity.
    coupling : pull of a part's velocity/acceleration towards its parent's per 1/30 s, 0..1
        (eqs. 10-12's A2); 0 = independent parts.
    process_noise : spectral density (square root) of the white noise on the highest derivative,
        px/s^order per sqrt(Hz) (jerk for order 3, acceleration for order 2); Q(dt) of eq. 8.
    measurement_noise_px : standard deviation of a detection per axis at confidence 1, pixels
        (R of eq. 13).
    gate_chi2 : eq. (16)'s gate on the squared Mahalanobis innovation (2 degrees of freedom;
        9.21 = 99 %); `inf` accepts every detection.
    output : 'filtered' (posterior estimate for accepted detections) or 'detection' (the
        detection itself, the literal eq. 16).
    drift_frames : consecutive rejected but mutually consistent detections after which the part
        is re-initialised on the detection; 0 disables.
    drift_radius_px : two rejected detections in a row are consistent when this close, pixels
        per 1/30 s (scaled up for longer frame intervals: a part moves farther between them).
    max_missed_frames : frames without an accepted detection before a part is dropped.
    max_dt_s : a longer gap between stamps restarts the track, seconds.
    init_velocity_std : prior standard deviation of a new part's velocity, px/s.
    init_accel_std : prior standard deviation of a new part's acceleration, px/s^2.
    min_confidence : detections with a lower confidence are ignored (treated as missing).
    confidence_decay : factor applied to a part's confidence per frame it is only predicted.
    stop_hypothesis : a detection beyond the gate that is within it of where the part was at
        the previous frame (a part that stopped or turned back, which a constant-acceleration
        prediction overshoots) restarts the part there, DETECTED, instead of being rejected.
    accel_time_s : time constant of the acceleration, seconds: it decays as
        ``exp(-dt / accel_time_s)`` (Singer's manoeuvre model: a hand's acceleration turns
        within a wave); `inf` = the paper's constant acceleration. Order 3 only.
    limb_tolerance : a detection of a part in `limb_parts` beyond the gate, its previous one
        rejected too, whose parent's detection is accepted, restarts the part on it when its
        distance from that detection is within this fraction of the parts' distance at the
        previous frame (the limb kept its length: the part turned fast about its parent, which
        the prediction lost); 0 disables.
    limb_parts : the parts `limb_tolerance` applies to: the arms, whose hands make the fastest
        turns (on the legs too, it cost the held-out renders' knees).
    limb_rejected_frames : detections of the part rejected just before, at least, for the limb
        rule to apply: 1 = at the second rejected frame (as shipped), 0 = at the first.
    shadow_frames : after a part is restarted on a detection (drift, stop or limb hypothesis), its
        previous track is kept, predicted, for this many frames: a later detection beyond the
        gate but within that track's brings the track back (the restart followed a wrong
        detection). 0 disables.
    """

    order: int = 3
    coupling: float = 0.1
    process_noise: float = 1000.0
    measurement_noise_px: float = 4.5
    gate_chi2: float = 9.21
    output: str = 'filtered'
    drift_frames: int = 3
    drift_radius_px: float = 15.0
    max_missed_frames: int = 30
    max_dt_s: float = 0.5
    init_velocity_std: float = 100.0
    init_accel_std: float = 1000.0
    min_confidence: float = 0.0
    confidence_decay: float = 0.9
    stop_hypothesis: bool = True
    accel_time_s: float = 0.2
    shadow_frames: int = 5
    limb_tolerance: float = 0.35
    limb_parts: tuple[str, ...] = ('left_elbow', 'left_wrist', 'right_elbow', 'right_wrist')
    limb_rejected_frames: int = 1

    def __post_init__(self) -> None:
        if self.order not in (2, 3):
            raise ValueError(f'order must be 2 (constant velocity) or 3 (constant acceleration), '
                             f'got {self.order}')
        if not 0.0 <= self.coupling < 1.0:
            raise ValueError(f'coupling must be in [0, 1), got {self.coupling}')
        for name in ('process_noise', 'measurement_noise_px', 'gate_chi2', 'drift_radius_px',
                     'max_dt_s', 'init_velocity_std', 'init_accel_std', 'accel_time_s'):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f'{name} must be positive, got {value}')
        if self.output not in ('filtered', 'detection'):
            raise ValueError(f"output must be 'filtered' or 'detection', got {self.output!r}")
        if min(self.drift_frames, self.max_missed_frames, self.shadow_frames,
               self.limb_rejected_frames) < 0:
            raise ValueError(f'drift_frames ({self.drift_frames}), max_missed_frames '
                             f'({self.max_missed_frames}), shadow_frames '
                             f'({self.shadow_frames}) and limb_rejected_frames '
                             f'({self.limb_rejected_frames}) must be >= 0')
        if not 0.0 <= self.limb_tolerance < 1.0:
            raise ValueError(f'limb_tolerance must be in [0, 1), got {self.limb_tolerance}')
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f'min_confidence must be in [0, 1], got {self.min_confidence}')
        if not 0.0 < self.confidence_decay <= 1.0:
            raise ValueError(f'confidence_decay must be in (0, 1], got {self.confidence_decay}')

    @functools.cached_property  # a frozen dataclass's too: read each frame, computed once
    def block(self) -> int:
        """State size per part: 2 axes x `order` derivatives."""
        return 2 * self.order


@dataclass(frozen=True)
class TrackState:
    """The filter's state for P parts (treat as immutable; functions return new states).

    Attributes
    ----------
    x : (P * B,) float64 state, per part (x, y, vx, vy[, ax, ay]), px, px/s, px/s^2; B =
        `SlqeConfig.block`. Zero for inactive parts.
    cov : (P * B, P * B) float64 covariance of `x`.
    active : (P,) bool, the part is being tracked.
    missed : (P,) int64, consecutive frames without an accepted detection.
    rejected : (P,) int64, consecutive rejected detections that agree with each other.
    last_rejected : (P, 2) float64, the last rejected detection (NaN if none), pixels.
    confidence : (P,) float64, 0..1, confidence of the current estimate.
    shadow_x, shadow_cov : (P, B) and (P, B, B) float64, each part's track from before its last
        restart, predicted on (`SlqeConfig.shadow_frames`).
    shadow_left : (P,) int64, frames that track is still kept (0 = none).
    stamp : time of the last frame, seconds; None before the first frame.
    dt : the time step of the last prediction, seconds.
    """

    x: NDArray[np.float64]
    cov: NDArray[np.float64]
    active: NDArray[np.bool_]
    missed: NDArray[np.int64]
    rejected: NDArray[np.int64]
    last_rejected: NDArray[np.float64]
    confidence: NDArray[np.float64]
    shadow_x: NDArray[np.float64]
    shadow_cov: NDArray[np.float64]
    shadow_left: NDArray[np.int64]
    stamp: float | None = None
    dt: float = NOMINAL_DT_S

    @functools.cached_property  # `evolve` copies it with the arrays, which keep their size
    def n_parts(self) -> int:
        return len(self.active)


@dataclass(frozen=True)
class TrackOutput:
    """One frame of tracked parts.

    Attributes
    ----------
    positions : (P, 2) float64 pixel (u, v); NaN where MISSING.
    covariances : (P, 2, 2) float64 position covariance, px^2; NaN where MISSING.
    velocities : (P, 2) float64 px/s; NaN where MISSING.
    source : (P,) uint8 `Source` values (DETECTED, TRACKED, MISSING).
    confidence : (P,) float32, 0..1; 0 where MISSING.
    stamp : seconds.
    """

    positions: NDArray[np.float64]
    covariances: NDArray[np.float64]
    velocities: NDArray[np.float64]
    source: NDArray[np.uint8]
    confidence: NDArray[np.float32]
    stamp: float


@dataclass(frozen=True)
class UpdateInfo:
    """What `update` did with each part's detection.

    Attributes
    ----------
    source : (P,) uint8 `Source` values for this frame.
    nis : (P,) float64 squared Mahalanobis innovation of the gated detections (NaN otherwise).
    """

    source: NDArray[np.uint8]
    nis: NDArray[np.float64]


def evolve(obj: TrackState | TrackOutput, **changes: object) -> TrackState | TrackOutput:
    """`dataclasses.replace` for the per-frame path: a copy of a `TrackState` or `TrackOutput`
    (frozen, no checks to rerun) with `changes`, without replace's per-field work."""
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    new.__dict__.update(changes)
    return new


def initial_state(n_parts: int, config: SlqeConfig) -> TrackState:
    """A state with no part tracked yet."""
    if n_parts <= 0:
        raise ValueError(f'n_parts must be positive, got {n_parts}')
    b = config.block
    n = n_parts * b
    return TrackState(
        x=np.zeros(n), cov=np.zeros((n, n)), active=np.zeros(n_parts, bool),
        missed=np.zeros(n_parts, np.int64), rejected=np.zeros(n_parts, np.int64),
        last_rejected=np.full((n_parts, 2), np.nan), confidence=np.zeros(n_parts),
        shadow_x=np.zeros((n_parts, b)), shadow_cov=np.zeros((n_parts, b, b)),
        shadow_left=np.zeros(n_parts, np.int64), stamp=None)
