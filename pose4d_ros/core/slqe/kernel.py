"""One SLQE step compiled: `motion.predict`, `update.update` and `update.output` of a frame in
one kernel, the per-frame path of `SlqeTracker.step`.

The Python functions stay the readable statement of the paper's equations (and what the tests
check the filter's behaviour on); this kernel does exactly their work, in their order, with the
same arithmetic (`test_slqe.py` runs both on the same detections and compares every array). It
exists because the Python path costs some 130 interpreter-level calls per person and frame
(numpy's wrappers, index arrays, the gate's per-part loop), which is what slows down most on a
slow robot computer; compiled, a step is one call.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.slqe.config import NOMINAL_DT_S, SlqeConfig, Source

_DETECTED, _TRACKED, _MISSING = Source.DETECTED.value, Source.TRACKED.value, Source.MISSING.value
# the smallest confidence that scales a detection's R (update.MIN_WEIGHT)
_MIN_WEIGHT = 1e-3
# factorials of 0..5 (a block's derivative orders)
_FACTORIAL = np.array([1.0, 1.0, 2.0, 6.0, 24.0, 120.0])
_FACTORIAL.setflags(write=False)

# `params`: an SlqeConfig as numbers, in this order (`config_params`)
(_ORDER, _COUPLING, _PROCESS_NOISE, _MEASUREMENT_NOISE, _GATE, _DETECTION_OUTPUT, _DRIFT_FRAMES,
 _DRIFT_RADIUS, _MAX_MISSED, _INIT_VELOCITY, _INIT_ACCEL, _MIN_CONFIDENCE, _DECAY, _STOP,
 _ACCEL_TIME, _SHADOW_FRAMES, _LIMB_TOLERANCE, _LIMB_REJECTED) = range(18)


def config_params(config: SlqeConfig) -> NDArray[np.float64]:
    """`config`'s numbers as the kernel reads them (read-only)."""
    p = np.array([config.order, config.coupling, config.process_noise,
                  config.measurement_noise_px, config.gate_chi2, config.output == 'detection',
                  config.drift_frames, config.drift_radius_px, config.max_missed_frames,
                  config.init_velocity_std, config.init_accel_std, config.min_confidence,
                  config.confidence_decay, config.stop_hypothesis, config.accel_time_s,
                  config.shadow_frames, config.limb_tolerance, config.limb_rejected_frames],
                 np.float64)
    p.setflags(write=False)
    return p


@nb.njit(cache=True)
def _axis_transition(dt: float, order: int, tau: float) -> NDArray[np.float64]:
    """`motion.axis_transition`."""
    f = np.zeros((order, order))
    for i in range(order):
        for j in range(i, order):
            f[i, j] = dt ** float(j - i) / _FACTORIAL[j - i]
    if order == 3 and math.isfinite(tau):
        lost = -math.expm1(-dt / tau)
        f[0, 2] = tau * tau * (dt / tau - lost)
        f[1, 2] = tau * lost
        f[2, 2] = 1.0 - lost
    return f


@nb.njit(cache=True)
def _kron_i2(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """`motion._kron_i2`: ``m (x) I2``."""
    n = m.shape[0]
    out = np.zeros((2 * n, 2 * n))
    for i in range(n):
        for j in range(n):
            out[2 * i, 2 * j] = m[i, j]
            out[2 * i + 1, 2 * j + 1] = m[i, j]
    return out


@nb.njit(cache=True)
def _process_noise(dt: float, order: int, q: float) -> NDArray[np.float64]:
    """`motion.axis_process_noise` (x) I2: one part's Q(dt) block."""
    out = np.empty((order, order))
    for i in range(order):
        for j in range(order):
            p = 2 * order - 1 - i - j
            out[i, j] = dt ** float(p) / (_FACTORIAL[order - 1 - i] * _FACTORIAL[order - 1 - j]
                                          * p)
    return _kron_i2(q * q * out)


@nb.njit(cache=True)
def _transition(dt: float, params: NDArray[np.float64], parents: NDArray[np.int64],
                active: NDArray[np.bool_]) -> NDArray[np.float64]:
    """`motion.transition_matrix` for the parts `active`."""
    order = int(params[_ORDER])
    b = 2 * order
    f = _axis_transition(dt, order, params[_ACCEL_TIME])
    k = 1.0 - (1.0 - params[_COUPLING]) ** (max(dt, 0.0) / NOMINAL_DT_S)
    own = _kron_i2(f)
    scaled_own = f.copy()
    scaled_parent = np.zeros_like(f)
    for j in range(1, order):
        scaled_own[:, j] = f[:, j] * (1.0 - k)
        scaled_parent[:, j] = f[:, j] * k
    own_coupled = _kron_i2(scaled_own)
    from_parent = _kron_i2(scaled_parent)
    n = len(parents)
    a = np.zeros((n * b, n * b))
    for i in range(n):
        p = parents[i]
        r = i * b
        if p >= 0 and k > 0.0 and active[i] and active[p]:
            a[r:r + b, r:r + b] = own_coupled
            a[r:r + b, p * b:(p + 1) * b] = from_parent
        else:
            a[r:r + b, r:r + b] = own
    return a


@nb.njit(cache=True)
def _mahalanobis2(y0: float, y1: float, s00: float, s01: float, s10: float,
                  s11: float) -> float:
    """`update._mahalanobis2` of one innovation."""
    det = s00 * s11 - s01 * s10
    if not det > 0:
        return math.inf
    return (s11 * (y0 * y0) + s00 * (y1 * y1) - (s01 + s10) * y0 * y1) / det


@nb.njit(cache=True)
def _zero_block(x: NDArray[np.float64], cov: NDArray[np.float64], i: int, b: int) -> None:
    x[i * b:(i + 1) * b] = 0.0
    cov[i * b:(i + 1) * b, :] = 0.0
    cov[:, i * b:(i + 1) * b] = 0.0


@nb.njit(cache=True)
def _kalman_update(x: NDArray[np.float64], cov: NDArray[np.float64], z: NDArray[np.float64],
                   r_var: NDArray[np.float64], accepted: NDArray[np.int64], b: int
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], bool]:
    """`update._kalman_update` (Joseph form): the new x and cov, and whether the gain is
    finite (False: a singular innovation covariance)."""
    m = 2 * len(accepted)
    n = len(x)
    idx = np.empty(m, np.int64)
    y = np.empty(m)
    r_diag = np.empty(m)
    for k in range(len(accepted)):
        for axis in range(2):
            idx[2 * k + axis] = accepted[k] * b + axis
            y[2 * k + axis] = z[accepted[k], axis] - x[accepted[k] * b + axis]
            r_diag[2 * k + axis] = r_var[accepted[k]]
    ph_t = np.empty((m, n))  # (P H^T)^T = H P (P symmetric in its use: numpy's cov[:, idx].T)
    s = np.empty((m, m))
    for a in range(m):
        for c in range(n):
            ph_t[a, c] = cov[c, idx[a]]
        for c in range(m):
            s[a, c] = cov[idx[a], idx[c]] + (r_diag[a] if a == c else 0.0)
    gain = np.linalg.solve(s, ph_t).T.copy()
    if not np.all(np.isfinite(gain)):
        return x, cov, False
    x = x + gain @ y
    rows = np.empty((m, n))
    for a in range(m):
        rows[a] = cov[idx[a]]
    mm = cov - gain @ rows
    cols = np.empty((n, m))
    for a in range(m):
        cols[:, a] = mm[:, idx[a]]
    weighted = gain * r_diag
    new = mm - cols @ gain.T + weighted @ gain.T
    return x, 0.5 * (new + new.T), True


@nb.njit(cache=True)
def slqe_step(x0, cov0, active0, missed0, rejected0, last_rejected0, confidence0, shadow_x0,
              shadow_cov0, shadow_left0, dt0, dt, z, conf, px_gain, params, parents, limb):
    """One frame: predict over `dt` (> 0 or 0 = no motion) from the state at the previous
    frame (the arrays ending in 0 and `dt0`, not modified), update with detections `z` (P, 2)
    and confidences `conf` (P,), and output. `params` from `config_params`, `parents` the
    tree's, `limb` (P,) bool the parts of `limb_parts`. (One numba kernel of more than 100
    lines: it is `motion.predict`, `update.update` and `update.output` in their order, phases
    handing each other a dozen state arrays, which pieces would pass back and forth and no
    longer read beside the Python path `test_slqe.py` compares it with; what stands alone,
    the transition, the Kalman update, the restart and kept-track tests, is its helpers.)

    Returns the new state's arrays (x, cov, active, counters: (3, P) missed, rejected and
    shadow_left, last_rejected, confidence, shadow_x, shadow_cov, its dt) and the output's
    (motion: (2, P, 2) positions and velocities, covariances, source, confidence).
    LinAlgError for a singular innovation covariance.
    """
    n_parts = len(active0)
    order = int(params[_ORDER])
    b = 2 * order
    gate = params[_GATE]
    g2 = px_gain * px_gain
    # --- predict (motion.predict)
    x = x0.copy()
    cov = cov0.copy()
    shadow_x = shadow_x0.copy()
    shadow_cov = shadow_cov0.copy()
    state_dt = dt0
    if dt != 0.0 and np.any(active0):
        a = _transition(dt, params, parents, active0)
        q = _process_noise(dt, order, params[_PROCESS_NOISE])
        x = a @ x0
        cov = a @ cov0 @ a.T
        for i in range(n_parts):
            cov[i * b:(i + 1) * b, i * b:(i + 1) * b] += g2 * q
        for i in range(n_parts):
            if not active0[i]:
                _zero_block(x, cov, i, b)
        f = _kron_i2(_axis_transition(dt, order, params[_ACCEL_TIME]))
        for i in range(n_parts):
            if shadow_left0[i] > 0:
                shadow_x[i] = shadow_x0[i] @ f.T
                shadow_cov[i] = f @ shadow_cov0[i] @ f.T + g2 * q
        cov = 0.5 * (cov + cov.T)
        state_dt = dt
    # --- update (update.update_arrays): the gate and the hypotheses
    active = active0.copy()
    # the counters in one array (each returned array is a Python-level call to box it)
    counters = np.empty((3, n_parts), np.int64)
    missed, rejected, shadow_left = counters[0], counters[1], counters[2]
    missed[:] = missed0
    rejected[:] = rejected0
    shadow_left[:] = np.maximum(shadow_left0 - 1, 0)
    last_rejected = last_rejected0.copy()
    confidence = confidence0.copy()
    valid = np.empty(n_parts, np.bool_)
    r_var = np.empty(n_parts)
    noise = px_gain * params[_MEASUREMENT_NOISE]
    for i in range(n_parts):
        c = conf[i]
        valid[i] = (math.isfinite(z[i, 0]) and math.isfinite(z[i, 1]) and math.isfinite(c)
                    and c > 0 and c >= params[_MIN_CONFIDENCE])
        r_var[i] = noise * noise / (max(c, _MIN_WEIGHT) if valid[i] else 1.0)
    source = np.empty(n_parts, np.uint8)
    for i in range(n_parts):
        source[i] = _TRACKED if active[i] else _MISSING
    is_accepted = np.zeros(n_parts, np.bool_)
    is_restart = np.zeros(n_parts, np.bool_)
    d2 = np.full(n_parts, math.nan)
    all_inside = True
    for i in range(n_parts):
        if valid[i] and active[i]:
            p = i * b
            d2[i] = _mahalanobis2(z[i, 0] - x[p], z[i, 1] - x[p + 1], cov[p, p] + r_var[i],
                                  cov[p, p + 1], cov[p + 1, p], cov[p + 1, p + 1] + r_var[i])
            if d2[i] <= gate:
                is_accepted[i] = True
                rejected[i] = 0
                last_rejected[i] = math.nan
            else:
                all_inside = False
    if not all_inside:
        drift_radius = px_gain * params[_DRIFT_RADIUS] * max(1.0, state_dt / NOMINAL_DT_S)
        use_limb = params[_LIMB_TOLERANCE] > 0
        for i in range(n_parts):
            if not (valid[i] and active[i]) or d2[i] <= gate:
                continue
            if _restarts(i, z, r_var[i], rejected0, active0, x0, cov0, is_accepted,
                         use_limb and limb[i], params, parents, b):
                is_restart[i] = True
                continue
            if shadow_left0[i] > 0 and _back_to_kept_track(x, cov, shadow_x, shadow_cov,
                                                           shadow_left, i, z, r_var[i], gate,
                                                           b):
                is_accepted[i] = True
                rejected[i] = 0
                last_rejected[i] = math.nan
                continue
            consistent = (math.isfinite(last_rejected[i, 0])
                          and math.isfinite(last_rejected[i, 1])
                          and math.hypot(z[i, 0] - last_rejected[i, 0],
                                         z[i, 1] - last_rejected[i, 1]) <= drift_radius)
            rejected[i] = rejected[i] + 1 if consistent else 1
            last_rejected[i] = z[i]
            if params[_DRIFT_FRAMES] > 0 and rejected[i] >= params[_DRIFT_FRAMES]:
                is_restart[i] = True
    accepted = is_accepted.nonzero()[0]
    if len(accepted):
        x, cov, finite = _kalman_update(x, cov, z, r_var, accepted, b)
        if not finite:  # what np.linalg.solve's checks would refuse
            raise np.linalg.LinAlgError('singular innovation covariance S')
        for i in accepted:
            source[i] = _DETECTED
            missed[i] = 0
            confidence[i] = conf[i]
    # new and restarted parts (update._start_parts), parents first
    if params[_SHADOW_FRAMES] > 0:
        for i in range(n_parts):
            if is_restart[i]:
                shadow_x[i] = x[i * b:(i + 1) * b]
                shadow_cov[i] = cov[i * b:(i + 1) * b, i * b:(i + 1) * b]
                shadow_left[i] = int(params[_SHADOW_FRAMES])
    for i in range(n_parts):
        if not (is_restart[i] or (valid[i] and not active0[i])):
            continue
        _zero_block(x, cov, i, b)
        x[i * b] = z[i, 0]
        x[i * b + 1] = z[i, 1]
        p = parents[i]
        if p >= 0 and active[p]:
            x[i * b + 2:(i + 1) * b] = x[p * b + 2:(p + 1) * b]
        std = math.sqrt(r_var[i])
        velocity = px_gain * params[_INIT_VELOCITY]
        accel = px_gain * params[_INIT_ACCEL]
        for axis in range(2):
            cov[i * b + axis, i * b + axis] = std * std
            cov[i * b + 2 + axis, i * b + 2 + axis] = velocity * velocity
            if order == 3:
                cov[i * b + 4 + axis, i * b + 4 + axis] = accel * accel
        active[i] = True
        source[i] = _DETECTED
        missed[i] = 0
        rejected[i] = 0
        last_rejected[i] = math.nan
        confidence[i] = conf[i]
    # parts only predicted (update._coast)
    for i in range(n_parts):
        if not (active[i] and source[i] == _TRACKED):
            continue
        missed[i] += 1
        confidence[i] *= params[_DECAY]
        if missed[i] > params[_MAX_MISSED]:
            _zero_block(x, cov, i, b)
            active[i] = False
            source[i] = _MISSING
            missed[i] = 0
            rejected[i] = 0
            last_rejected[i] = math.nan
            confidence[i] = 0.0
            shadow_left[i] = 0
    # --- output (update.output)
    motion = np.empty((2, n_parts, 2))  # positions and velocities, one array
    positions, velocities = motion[0], motion[1]
    covariances = np.empty((n_parts, 2, 2))
    conf_out = np.empty(n_parts, np.float32)
    for i in range(n_parts):
        p = i * b
        if source[i] == _MISSING:
            positions[i] = math.nan
            velocities[i] = math.nan
            covariances[i] = math.nan
            conf_out[i] = 0.0
            continue
        positions[i, 0], positions[i, 1] = x[p], x[p + 1]
        velocities[i, 0], velocities[i, 1] = x[p + 2], x[p + 3]
        covariances[i] = cov[p:p + 2, p:p + 2]
        if params[_DETECTION_OUTPUT] > 0 and source[i] == _DETECTED:
            c = conf[i] if math.isfinite(conf[i]) else 1.0
            r = noise * noise / max(c, 1e-6)
            positions[i] = z[i]
            covariances[i] = 0.0
            covariances[i, 0, 0] = r
            covariances[i, 1, 1] = r
        conf_out[i] = min(max(confidence[i], 0.0), 1.0)
    return (x, cov, active, counters, last_rejected, confidence, shadow_x, shadow_cov,
            state_dt, motion, covariances, source, conf_out)


@nb.njit(cache=True)
def _restarts(i, z, r, rejected0, active0, x0, cov0, is_accepted, limb, params, parents, b):
    """`update._restarts` (the state at the previous frame is the arrays ending in 0)."""
    gate = params[_GATE]
    if params[_STOP] > 0 and active0[i]:
        p = i * b
        if _mahalanobis2(z[i, 0] - x0[p], z[i, 1] - x0[p + 1], cov0[p, p] + r, cov0[p, p + 1],
                         cov0[p + 1, p], cov0[p + 1, p + 1] + r) <= gate:
            return True
    parent = parents[i]
    if not (limb and rejected0[i] >= params[_LIMB_REJECTED] and parent >= 0
            and is_accepted[parent] and active0[i] and active0[parent]):
        return False
    was = math.hypot(x0[i * b] - x0[parent * b], x0[i * b + 1] - x0[parent * b + 1])
    now = math.hypot(z[i, 0] - z[parent, 0], z[i, 1] - z[parent, 1])
    return abs(now - was) <= params[_LIMB_TOLERANCE] * was


@nb.njit(cache=True)
def _back_to_kept_track(x, cov, shadow_x, shadow_cov, shadow_left, i, z, r, gate, b):
    """`update._back_to_kept_track`: in place, True when part i went back to its kept track."""
    s = shadow_cov[i]
    if _mahalanobis2(z[i, 0] - shadow_x[i, 0], z[i, 1] - shadow_x[i, 1], s[0, 0] + r, s[0, 1],
                     s[1, 0], s[1, 1] + r) > gate:
        return False
    _zero_block(x, cov, i, b)
    x[i * b:(i + 1) * b] = shadow_x[i]
    cov[i * b:(i + 1) * b, i * b:(i + 1) * b] = shadow_cov[i]
    shadow_left[i] = 0
    return True
