"""SLQE: a skeleton-constrained Kalman filter for the parts of a tracked person.

After Martinez Berti, Sanchez Salmeron and Ricolfe Viala, "4-Dimensional deformation part model
for pose estimation using Kalman filter constraints", eqs. (6)-(16). Everything is in the colour
image, pixels (u, v), as in the paper.

Model
-----
Each part i has the state ``s_i = (x, y, vx, vy, ax, ay)`` (pixels, px/s, px/s^2; eq. 6) and the
whole pose is ``s = (s_0, ..., s_{P-1})``. With ``dt`` the time between two frames (taken from
the stamps, so irregular frame rates are handled), the prediction is (eqs. 7-9)::

    s' = A(dt) s,    Sigma' = A Sigma A^T + Q(dt)

``A`` couples connected parts (eqs. 10-12). The paper writes it for 8 joints as blocks ``A1`` (a
part's own constant-acceleration kinematics) and ``A2`` (the pull of the connected part); here it
is built from any part tree (`core.skeleton.PARTS_10` by default): a child's velocity and
acceleration are blended with its parent's before they are integrated,

    d_c <- (1 - k) d_c + k d_p          (d = velocity and acceleration)
    A_cc = F(dt) diag(1, 1 - k, 1 - k) (x) I2,      A_cp = F(dt) diag(0, k, k) (x) I2,

with ``F(dt)`` the kinematic transition of one axis (``A1`` of the paper) and ``k``
the coupling (`SlqeConfig.coupling` per 1/30 s, rescaled for other ``dt`` so that the pull per
second does not depend on the frame rate). ``k = 0`` gives independent parts. The root (neck)
has ``A_rr = F``. An occluded wrist thus keeps moving with its shoulder rather than flying off
along its last velocity.

One change to ``A1``: the acceleration decays with a time constant (`accel_time_s`, Singer's
manoeuvre model, integrated exactly into velocity and position) instead of persisting, because
a waving hand's acceleration turns within a fifth of a second: kept, it carries a part whose
detections are rejected far past the point where it turned.

``Q(dt)`` is the discretised white noise of the highest derivative (jerk for constant
acceleration, acceleration for constant velocity) with spectral density
``process_noise**2``. The measurement (eq. 13) is ``z_i = H s_i + r_i``, ``H`` picking the
positions, ``R_i = measurement_noise_px**2 / confidence_i * I2``. The update is the Kalman update
(eqs. 14-15), Joseph form.

The choice of eq. (16) between the filter's estimate and the detection is made per part from the
innovation ``y_i = z_i - H s'_i`` and its covariance ``S_i``:

- ``y_i^T S_i^-1 y_i <= gate_chi2``: the detection agrees with the prediction; it is used for the
  update and the part is DETECTED (its output is the filtered estimate, or the detection itself
  with ``output='detection'``, the literal reading of eq. 16).
- beyond the gate: an outlier; the detection is rejected and the prediction is used (TRACKED),
  unless it is within the gate of where the part was at the previous frame: a hand that stops or
  turns back, which the prediction overshoots, is restarted on its detection
  (`stop_hypothesis`).
- a limb that turns fast about its joint (a hand whipped round the elbow) outruns the
  prediction for frames on end, while the detections of it stay where the limb is: so an arm's
  detection beyond the gate, its previous one rejected too, is restarted on (DETECTED) when its
  parent's detection is accepted and the limb between them keeps its length, within
  `limb_tolerance` of the tracked one.
- when ``drift_frames`` consecutive detections are rejected but agree with each other (each within
  ``drift_radius_px`` per 1/30 s of the previous one), the filter is the one that drifted: the
  part is re-initialised on the detection (DETECTED).
- a restart may follow a detector stuck on a wrong place for a few frames; so the track from
  before it is kept, predicted, for `shadow_frames`, and a detection beyond the gate but within
  that track's brings it back (DETECTED).

Pixels depend on the person's distance and the camera's resolution: a hand moves twice as many
pixels per second at 1.5 m as at 3 m, or at 640x480 as at 320x240. So the parameters in pixels
(`process_noise`, `measurement_noise_px`, `drift_radius_px`, `init_velocity_std`,
`init_accel_std`) are stated for a person of `REFERENCE_SCALE_PX` pixels per half a metre of
body (a 320x240 Kinect 2.85 m away), and each step may be given the person's scale in its frame
(``step(..., scale_px=...)``), which multiplies them all by ``scale_px / REFERENCE_SCALE_PX``
(Q by its square): the same filter, in units of the person.

Parts without a detection (NaN) are predicted only (TRACKED). A part that has had no accepted
detection for more than ``max_missed_frames`` is dropped (MISSING, NaN) and re-initialised when
detected again; a time gap over ``max_dt_s``, a stamp going backwards or `reset` restart the
whole track.

Design: `SlqeConfig` (frozen) + `TrackState` (frozen arrays) + the pure functions `predict`,
`update` and `output`; `SlqeTracker` wraps them behind one per-frame call,
``tracker.step(uv, confidence, stamp_s)``. `ConstantVelocityTracker` is the plain per-part
constant-velocity Kalman filter used for comparison, with the same interface.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import PARTS_10, PartTree

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
    "Results").

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
    shadow_frames : after a part is restarted on a detection (drift, stop or limb hypothesis), its
        previous track is kept, predicted, for this many frames: a later detection beyond the
        gate but within that track's brings the track back (the restart followed a wrong
        detection). 0 disables.
    """

    order: int = 3
    coupling: float = 0.1
    process_noise: float = 300.0
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
        if min(self.drift_frames, self.max_missed_frames, self.shadow_frames) < 0:
            raise ValueError(f'drift_frames ({self.drift_frames}), max_missed_frames '
                             f'({self.max_missed_frames}) and shadow_frames '
                             f'({self.shadow_frames}) must be >= 0')
        if not 0.0 <= self.limb_tolerance < 1.0:
            raise ValueError(f'limb_tolerance must be in [0, 1), got {self.limb_tolerance}')
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f'min_confidence must be in [0, 1], got {self.min_confidence}')
        if not 0.0 < self.confidence_decay <= 1.0:
            raise ValueError(f'confidence_decay must be in (0, 1], got {self.confidence_decay}')

    @property
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

    @property
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


def _kron_i2(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """``m (x) I2`` (per-axis block -> interleaved (x, y) block), without np.kron's overhead."""
    n = m.shape[0]
    out = np.zeros((2 * n, 2 * n))
    out[0::2, 0::2] = m
    out[1::2, 1::2] = m
    return out


def axis_transition(dt: float, order: int, accel_time_s: float = math.inf
                    ) -> NDArray[np.float64]:
    """F(dt): one axis's (order x order) kinematic transition, ``F_ij = dt^(j-i) / (j-i)!``;
    with a finite `accel_time_s` (order 3) the acceleration decays as ``exp(-dt / tau)``
    (Singer's model, integrated exactly into velocity and position)."""
    f = np.zeros((order, order))
    for i in range(order):
        for j in range(i, order):
            f[i, j] = dt ** (j - i) / math.factorial(j - i)
    if order == 3 and math.isfinite(accel_time_s):
        tau = accel_time_s
        lost = -math.expm1(-dt / tau)  # 1 - exp(-dt / tau), exact for small steps too
        f[0, 2] = tau * tau * (dt / tau - lost)
        f[1, 2] = tau * lost
        f[2, 2] = 1.0 - lost
    return f


def axis_process_noise(dt: float, order: int, q: float) -> NDArray[np.float64]:
    """One axis's discretised white noise on the highest derivative (spectral density ``q**2``).

    ``Q_ij = q^2 dt^(2n-1-i-j) / ((n-1-i)! (n-1-j)! (2n-1-i-j))`` with n = order, e.g. the
    familiar ``[[dt^3/3, dt^2/2], [dt^2/2, dt]]`` for constant velocity.
    """
    n = order
    out = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            p = 2 * n - 1 - i - j
            out[i, j] = dt ** p / (math.factorial(n - 1 - i) * math.factorial(n - 1 - j) * p)
    return q * q * out


def coupling_at(dt: float, coupling: float) -> float:
    """The per-step coupling for a step of `dt` seconds (`coupling` is stated per 1/30 s)."""
    return 1.0 - (1.0 - coupling) ** (max(dt, 0.0) / NOMINAL_DT_S)


def transition_matrix(dt: float, config: SlqeConfig, tree: PartTree,
                      active: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """A(dt) of eqs. (10)-(12) for the whole pose, built from the part tree.

    Parameters
    ----------
    dt : seconds.
    config : the filter's parameters (order, coupling).
    tree : parts and parents; state blocks follow `tree.names`.
    active : (P,) bool, optional; a child is coupled only to an active parent.

    Returns
    -------
    (P * B, P * B) float64, B = `config.block`, blocks ``A1`` on the diagonal and ``A2`` at
    (child, parent).
    """
    n_parts = len(tree)
    order, b = config.order, config.block
    f = axis_transition(dt, order, config.accel_time_s)
    k = coupling_at(dt, config.coupling)
    own = _kron_i2(f)
    d_own = np.ones(order)
    d_own[1:] = 1.0 - k
    d_par = np.zeros(order)
    d_par[1:] = k
    own_coupled = _kron_i2(f * d_own[None, :])
    from_parent = _kron_i2(f * d_par[None, :])
    a = np.zeros((n_parts * b, n_parts * b))
    for i, p in enumerate(tree.parents):
        rows = slice(i * b, (i + 1) * b)
        coupled = p >= 0 and k > 0.0 and (active is None or (active[i] and active[p]))
        if coupled:
            a[rows, rows] = own_coupled
            a[rows, p * b:(p + 1) * b] = from_parent
        else:
            a[rows, rows] = own
    return a


def process_noise_matrix(dt: float, config: SlqeConfig, n_parts: int) -> NDArray[np.float64]:
    """Q(dt) of eq. (8): block diagonal, one ``axis_process_noise (x) I2`` per part."""
    q = _kron_i2(axis_process_noise(dt, config.order, config.process_noise))
    b = config.block
    out = np.zeros((n_parts * b, n_parts * b))
    for i in range(n_parts):
        out[i * b:(i + 1) * b, i * b:(i + 1) * b] = q
    return out


# Smallest confidence that scales a detection's R (R / confidence): at most 1000 R.
MIN_WEIGHT = 1e-3


@functools.lru_cache(maxsize=32)
def _prediction_matrices(dt: float, config: SlqeConfig, tree: PartTree,
                         active: tuple[bool, ...]
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A(dt) and Q(dt) (read-only), built once per step, model and set of active parts: a
    camera's frames come at one rate, and the parts seen change rarely."""
    a = transition_matrix(dt, config, tree, np.array(active, bool))
    q = process_noise_matrix(dt, config, len(tree))
    a.setflags(write=False)
    q.setflags(write=False)
    return a, q


def predict(state: TrackState, dt: float, config: SlqeConfig, tree: PartTree,
            px_gain: float = 1.0) -> TrackState:
    """The prediction of eqs. (7)-(9) over `dt` seconds (0 = no motion).

    Parameters
    ----------
    state : the state at the previous frame (not modified).
    dt : seconds, >= 0.
    config, tree : the model.
    px_gain : the person's scale over `REFERENCE_SCALE_PX`; the process noise is `config`'s times
        it (Q times its square).

    Returns
    -------
    The predicted state (same stamp; `update` or the caller sets the new one).
    """
    if not dt >= 0.0:
        raise ValueError(f'dt must be >= 0 seconds, got {dt}')
    if state.n_parts != len(tree):
        raise ValueError(f'state has {state.n_parts} parts, tree {len(tree)}')
    if dt == 0.0 or not state.active.any():
        return state
    a, q = _prediction_matrices(dt, config, tree, tuple(state.active.tolist()))
    x = a @ state.x
    cov = a @ state.cov @ a.T + (px_gain * px_gain) * q
    inactive = np.repeat(~state.active, config.block)
    # Inactive parts carry no information: keep their blocks zero rather than growing noise.
    x[inactive] = 0.0
    cov[inactive, :] = 0.0
    cov[:, inactive] = 0.0
    shadow_x, shadow_cov = state.shadow_x, state.shadow_cov
    kept = np.flatnonzero(state.shadow_left > 0)
    if len(kept):
        # a kept track moves on by its own kinematics (its parent's pull was in the old state)
        b = config.block
        f = _kron_i2(axis_transition(dt, config.order, config.accel_time_s))
        q_own = (px_gain * px_gain) * q[:b, :b]
        shadow_x, shadow_cov = shadow_x.copy(), shadow_cov.copy()
        shadow_x[kept] = shadow_x[kept] @ f.T
        shadow_cov[kept] = f @ shadow_cov[kept] @ f.T + q_own
    return replace(state, x=x, cov=0.5 * (cov + cov.T), shadow_x=shadow_x,
                   shadow_cov=shadow_cov, dt=dt)


def _check_measurement(uv: NDArray, confidence: NDArray | None, n_parts: int
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    z = np.asarray(uv, dtype=np.float64)
    if z.shape != (n_parts, 2):
        raise ValueError(f'uv must have shape ({n_parts}, 2), got {z.shape}')
    if confidence is None:
        c = np.ones(n_parts)
    else:
        c = np.asarray(confidence, dtype=np.float64)
        if c.shape != (n_parts,):
            raise ValueError(f'confidence must have shape ({n_parts},), got {c.shape}')
        if np.any(c[np.isfinite(c)] < 0) or np.any(c[np.isfinite(c)] > 1):
            raise ValueError(f'confidence must be in [0, 1], got {c}')
    return z, c


def _init_part(x: NDArray, cov: NDArray, i: int, z: NDArray, parent: int,
               active: NDArray, config: SlqeConfig, r: float, px_gain: float) -> None:
    """(Re-)start part i at detection z; its velocity/acceleration start as its parent's."""
    b = config.block
    sl = slice(i * b, (i + 1) * b)
    x[sl] = 0.0
    x[i * b:i * b + 2] = z
    if parent >= 0 and active[parent]:
        x[i * b + 2:(i + 1) * b] = x[parent * b + 2:(parent + 1) * b]
    cov[sl, :] = 0.0
    cov[:, sl] = 0.0
    stds = [math.sqrt(r)] * 2 + [px_gain * config.init_velocity_std] * 2
    if config.order == 3:
        stds += [px_gain * config.init_accel_std] * 2
    cov[sl, sl] = np.diag(np.square(stds))


def _mahalanobis2(y: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    """y_n^T S_n^-1 y_n for innovations `y` (N, 2) and covariances `s` (N, 2, 2), in closed
    form; inf where S_n is not positive definite."""
    det = s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0]
    with np.errstate(divide='ignore', invalid='ignore'):
        d2 = (s[:, 1, 1] * y[:, 0] ** 2 + s[:, 0, 0] * y[:, 1] ** 2
              - (s[:, 0, 1] + s[:, 1, 0]) * y[:, 0] * y[:, 1]) / det
    return np.where(det > 0, d2, math.inf)


def _keeps_length(z: NDArray[np.float64], before: TrackState, i: int, parent: int, b: int,
                  tolerance: float) -> bool:
    """Whether detections `z` of part i and its parent are as far apart as the two parts
    were at the previous frame (`before`), within `tolerance` of that distance."""
    if not (before.active[i] and before.active[parent]):
        return False
    was = math.dist(before.x[i * b:i * b + 2], before.x[parent * b:parent * b + 2])
    return abs(math.dist(z[i], z[parent]) - was) <= tolerance * was


def update(state: TrackState, uv: NDArray[np.floating], confidence: NDArray[np.floating] | None,
           config: SlqeConfig, tree: PartTree, px_gain: float = 1.0,
           before: TrackState | None = None) -> tuple[TrackState, UpdateInfo]:
    """The measurement update of eqs. (13)-(15) with eq. (16)'s choice per part.

    Parameters
    ----------
    state : the predicted state (not modified).
    uv : (P, 2) float detections, pixel (u, v); NaN rows = not detected.
    confidence : (P,) float in [0, 1] or None (all 1); NaN or below `config.min_confidence` =
        not detected. Scales R as ``R / confidence``.
    config, tree : the model.
    px_gain : the person's scale over `REFERENCE_SCALE_PX`; the pixel parameters are `config`'s
        times it.

    Returns
    -------
    The updated state and what happened to each detection.
    """
    n_parts = state.n_parts
    if n_parts != len(tree):
        raise ValueError(f'state has {n_parts} parts, tree {len(tree)}')
    z, conf = _check_measurement(uv, confidence, n_parts)
    b = config.block
    valid = np.isfinite(z).all(axis=1) & np.isfinite(conf) & (conf > 0) & \
        (conf >= config.min_confidence)
    # R / confidence, the confidence floored: a detection of confidence 1e-6 would otherwise
    # start a part with a variance of millions of pixels (metres squared beyond any camera's
    # range once lifted to 3-D, which the next stage rightly refuses)
    safe_conf = np.where(valid, np.maximum(conf, MIN_WEIGHT), 1.0)
    r_var = (px_gain * config.measurement_noise_px) ** 2 / safe_conf
    x, cov = state.x.copy(), state.cov.copy()
    active = state.active.copy()
    missed, rejected = state.missed.copy(), state.rejected.copy()
    last_rejected, out_conf = state.last_rejected.copy(), state.confidence.copy()
    shadow_x, shadow_cov = state.shadow_x.copy(), state.shadow_cov.copy()
    shadow_left = np.maximum(state.shadow_left - 1, 0)
    source = np.full(n_parts, Source.MISSING, np.uint8)
    source[active] = Source.TRACKED
    nis = np.full(n_parts, np.nan)

    # Gate each active part's detection on its own innovation (eq. 16's choice).
    accepted: list[int] = []
    restart: list[int] = []
    drift_radius = px_gain * config.drift_radius_px * max(1.0, state.dt / NOMINAL_DT_S)
    gated = np.flatnonzero(valid & active)
    if len(gated):
        pos = gated[:, None] * b + np.arange(2)[None, :]
        y_all = z[gated] - x[pos]
        s_all = cov[pos[:, :, None], pos[:, None, :]] + r_var[gated, None, None] * np.eye(2)
        d2_all = _mahalanobis2(y_all, s_all)
        nis[gated] = d2_all
    limb = ({i for i, name in enumerate(tree.names) if name in config.limb_parts}
            if config.limb_tolerance > 0 and before is not None else set())
    for i, d2 in zip(gated, d2_all if len(gated) else [], strict=True):
        if d2 <= config.gate_chi2:
            accepted.append(int(i))
            rejected[i] = 0
            last_rejected[i] = np.nan
            continue
        if config.stop_hypothesis and before is not None and before.active[i]:
            p0 = np.arange(i * b, i * b + 2)
            s0 = before.cov[np.ix_(p0, p0)] + r_var[i] * np.eye(2)
            if _mahalanobis2((z[i] - before.x[p0])[None], s0[None])[0] <= config.gate_chi2:
                restart.append(int(i))
                continue
        if i in limb and state.rejected[i] > 0 and tree.parents[i] in accepted and \
                _keeps_length(z, before, i, tree.parents[i], b, config.limb_tolerance):
            restart.append(int(i))
            continue
        if state.shadow_left[i] > 0:
            s1 = shadow_cov[i, :2, :2] + r_var[i] * np.eye(2)
            if _mahalanobis2((z[i] - shadow_x[i, :2])[None], s1[None])[0] <= config.gate_chi2:
                # the last restart followed a wrong detection: back to the track kept
                sl = slice(i * b, (i + 1) * b)
                x[sl] = shadow_x[i]
                cov[sl, :] = 0.0
                cov[:, sl] = 0.0
                cov[sl, sl] = shadow_cov[i]
                shadow_left[i] = 0
                accepted.append(int(i))
                rejected[i] = 0
                last_rejected[i] = np.nan
                continue
        consistent = np.all(np.isfinite(last_rejected[i])) and \
            float(np.hypot(*(z[i] - last_rejected[i]))) <= drift_radius
        rejected[i] = rejected[i] + 1 if consistent else 1
        last_rejected[i] = z[i]
        if config.drift_frames > 0 and rejected[i] >= config.drift_frames:
            restart.append(int(i))

    if accepted:
        idx = np.concatenate([np.arange(i * b, i * b + 2) for i in accepted])
        y = (z[accepted] - x[idx].reshape(-1, 2)).reshape(-1)
        r = np.diag(np.repeat(r_var[accepted], 2))
        ph = cov[:, idx]
        s = cov[np.ix_(idx, idx)] + r
        gain = np.linalg.solve(s, ph.T).T
        x = x + gain @ y
        # Joseph form (I - K H) P (I - K H)^T + K R K^T, with H picking the rows `idx`: the
        # same products restricted to the columns H touches (K H P = K P[idx])
        m = cov - gain @ cov[idx, :]
        cov = m - m[:, idx] @ gain.T + (gain * np.diag(r)) @ gain.T
        cov = 0.5 * (cov + cov.T)
        source[accepted] = Source.DETECTED
        missed[accepted] = 0
        out_conf[accepted] = conf[accepted]

    # New parts and drifted parts start on their detection, parents first; a restarted part's
    # track is kept a while in case the detection followed was the wrong one
    if config.shadow_frames and restart:
        for i in restart:
            sl = slice(i * b, (i + 1) * b)
            shadow_x[i], shadow_cov[i] = x[sl], cov[sl, sl]
            shadow_left[i] = config.shadow_frames
    for i in sorted(set(np.flatnonzero(valid & ~state.active)) | set(restart)):
        _init_part(x, cov, i, z[i], tree.parents[i], active, config, r_var[i], px_gain)
        active[i] = True
        source[i] = Source.DETECTED
        missed[i] = 0
        rejected[i] = 0
        last_rejected[i] = np.nan
        out_conf[i] = conf[i]

    coasting = active & (source == Source.TRACKED)
    missed[coasting] += 1
    out_conf[coasting] *= config.confidence_decay
    lost = coasting & (missed > config.max_missed_frames)
    if lost.any():
        drop = np.repeat(lost, b)
        x[drop] = 0.0
        cov[drop, :] = 0.0
        cov[:, drop] = 0.0
        active[lost] = False
        source[lost] = Source.MISSING
        missed[lost] = 0
        rejected[lost] = 0
        last_rejected[lost] = np.nan
        out_conf[lost] = 0.0
        shadow_left[lost] = 0
    new = replace(state, x=x, cov=cov, active=active, missed=missed, rejected=rejected,
                  last_rejected=last_rejected, confidence=out_conf, shadow_x=shadow_x,
                  shadow_cov=shadow_cov, shadow_left=shadow_left)
    return new, UpdateInfo(source=source, nis=nis)


def output(state: TrackState, info: UpdateInfo, uv: NDArray[np.floating],
           confidence: NDArray[np.floating] | None, config: SlqeConfig, px_gain: float = 1.0
           ) -> TrackOutput:
    """Positions, per-part covariance, source and confidence of an updated state.

    `uv` and `confidence` are the frame's detections (used when ``config.output ==
    'detection'``); `px_gain` as in `update`.
    """
    n_parts, b = state.n_parts, config.block
    xs = state.x.reshape(n_parts, b)
    pos = xs[:, 0:2].copy()
    vel = xs[:, 2:4].copy()
    covs = np.stack([state.cov[i * b:i * b + 2, i * b:i * b + 2] for i in range(n_parts)])
    if config.output == 'detection':
        z, conf = _check_measurement(uv, confidence, n_parts)
        det = info.source == Source.DETECTED
        pos[det] = z[det]
        safe = np.where(det, np.maximum(np.nan_to_num(conf, nan=1.0), 1e-6), 1.0)
        r_var = (px_gain * config.measurement_noise_px) ** 2 / safe
        covs[det] = r_var[det, None, None] * np.eye(2)
    missing = info.source == Source.MISSING
    pos[missing] = np.nan
    vel[missing] = np.nan
    covs[missing] = np.nan
    conf_out = np.where(missing, 0.0, np.clip(state.confidence, 0.0, 1.0)).astype(np.float32)
    return TrackOutput(positions=pos, covariances=covs, velocities=vel,
                       source=info.source.astype(np.uint8), confidence=conf_out,
                       stamp=float(state.stamp) if state.stamp is not None else math.nan)


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
        state = predict(self.state, dt, self.config, self.tree, px_gain)
        state, info = update(state, uv, confidence, self.config, self.tree, px_gain,
                             before=self.state)
        self.state = replace(state, stamp=stamp_s)
        return output(self.state, info, uv, confidence, self.config, px_gain)


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
