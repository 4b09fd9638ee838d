"""The SLQE measurement update (eqs. 13-15) with eq. (16)'s choice per part, and the output of a
step; see `core.slqe` for the gate and the restart hypotheses."""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
from numpy.linalg import _umath_linalg
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import PartTree
from pose4d_ros.core.slqe.config import (
    NOMINAL_DT_S,
    SlqeConfig,
    Source,
    TrackOutput,
    TrackState,
    UpdateInfo,
    evolve,
)

# Smallest confidence that scales a detection's R (R / confidence): at most 1000 R.
MIN_WEIGHT = 1e-3


def check_measurement(uv: NDArray, confidence: NDArray | None, n_parts: int
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
        if _any(np.isfinite(c) & ((c < 0) | (c > 1))):
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
    d2 = np.empty(len(det))
    d2.fill(math.inf)
    # divided only where det > 0 (no warning to silence: np.errstate is three calls a frame)
    np.divide(s[:, 1, 1] * y[:, 0] ** 2 + s[:, 0, 0] * y[:, 1] ** 2
              - (s[:, 0, 1] + s[:, 1, 0]) * y[:, 0] * y[:, 1], det, out=d2, where=det > 0)
    return d2


def _keeps_length(z: NDArray[np.float64], before: TrackState, i: int, parent: int, b: int,
                  tolerance: float) -> bool:
    """Whether detections `z` of part i and its parent are as far apart as the two parts
    were at the previous frame (`before`), within `tolerance` of that distance."""
    if not (before.active[i] and before.active[parent]):
        return False
    was = math.dist(before.x[i * b:i * b + 2], before.x[parent * b:parent * b + 2])
    return abs(math.dist(z[i], z[parent]) - was) <= tolerance * was


# `ndarray.any` and `ndarray.all` without their Python wrappers (the per-frame path)
_any = np.logical_or.reduce
_all = np.logical_and.reduce
# np.linalg.solve's LAPACK call (gesv) without its wrapper: NaN where it would raise
_solve = _umath_linalg.solve
# the sources as uint8 scalars (an enum member's look-up is a Python call)
_DETECTED, _TRACKED, _MISSING = (np.uint8(Source.DETECTED), np.uint8(Source.TRACKED),
                                 np.uint8(Source.MISSING))
# the (x, y) offsets of a part's position in its state block, and the 2 x 2 identity
_XY = np.arange(2)
_EYE2 = np.eye(2)
for _a in (_XY, _EYE2):
    _a.setflags(write=False)


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
    before : the state at the previous frame (for the stop and limb hypotheses).

    Returns
    -------
    The updated state and what happened to each detection.
    """
    w, info = update_arrays(state, uv, confidence, config, tree, px_gain, before)
    return evolve(state, **vars(w)), info


def update_arrays(state: TrackState, uv: NDArray[np.floating],
            confidence: NDArray[np.floating] | None, config: SlqeConfig, tree: PartTree,
            px_gain: float, before: TrackState | None) -> tuple[SimpleNamespace, UpdateInfo]:
    """`update`'s work: the new state's arrays (a namespace) and the `UpdateInfo`."""
    n_parts = state.n_parts
    if n_parts != len(tree):
        raise ValueError(f'state has {n_parts} parts, tree {len(tree)}')
    z, conf = check_measurement(uv, confidence, n_parts)
    valid = _all(np.isfinite(z), axis=1) & np.isfinite(conf) & (conf > 0) & \
        (conf >= config.min_confidence)
    # R / confidence, the confidence floored: a detection of confidence 1e-6 would otherwise
    # start a part with a variance of millions of pixels (metres squared beyond any camera's
    # range once lifted to 3-D, which the next stage rightly refuses)
    safe_conf = np.where(valid, np.maximum(conf, MIN_WEIGHT), 1.0)
    r_var = (px_gain * config.measurement_noise_px) ** 2 / safe_conf
    # the state's arrays, which the steps below change in place (copies: `state` stays)
    w = SimpleNamespace(x=state.x.copy(), cov=state.cov.copy(), active=state.active.copy(),
                        missed=state.missed.copy(), rejected=state.rejected.copy(),
                        last_rejected=state.last_rejected.copy(),
                        confidence=state.confidence.copy(), shadow_x=state.shadow_x.copy(),
                        shadow_cov=state.shadow_cov.copy(),
                        shadow_left=np.maximum(state.shadow_left - 1, 0))
    source = np.where(w.active, _TRACKED, _MISSING)
    nis = np.empty(n_parts)
    nis.fill(np.nan)
    accepted, restart = _gate(w, nis, state, before, z, valid, r_var, config, tree, px_gain)
    if accepted:
        _kalman_update(w, z[accepted], r_var[accepted], accepted, config.block)
        source[accepted] = _DETECTED
        w.missed[accepted] = 0
        w.confidence[accepted] = conf[accepted]
    new = (valid & ~state.active).nonzero()[0].tolist()
    starts = sorted(set(new) | set(restart)) if restart else new
    if starts:
        _start_parts(w, starts, restart, z, conf, r_var, source, config, tree, px_gain)
    _coast(w, source, config)
    return w, UpdateInfo(source=source, nis=nis)


def _gate(w: SimpleNamespace, nis: NDArray[np.float64], state: TrackState,
          before: TrackState | None, z: NDArray[np.float64], valid: NDArray[np.bool_],
          r_var: NDArray[np.float64], config: SlqeConfig, tree: PartTree,
          px_gain: float) -> tuple[list[int], list[int]]:
    """Eq. (16)'s choice for each active part's detection, on its own innovation: accepted
    within the gate; beyond it, restarted on (`_restarts`), back on its kept track
    (`_back_to_kept_track`, accepted) or rejected, counting towards the drift hypothesis.
    Writes each gated part's squared innovation into `nis`; returns (accepted, restarted)."""
    b = config.block
    gated = (valid & w.active).nonzero()[0]
    if not len(gated):
        return [], []
    pos = gated[:, None] * b + _XY
    y_all = z[gated] - w.x[pos]
    s_all = w.cov[pos[:, :, None], pos[:, None, :]] + r_var[gated, None, None] * _EYE2
    d2_all = _mahalanobis2(y_all, s_all)
    nis[gated] = d2_all
    # within the gate: accepted (all at once); the others one by one, in the parts' order
    # (parents before children: a child's limb hypothesis sees its parent's decision)
    inside = d2_all <= config.gate_chi2
    within = gated[inside]
    w.rejected[within] = 0
    w.last_rejected[within] = np.nan
    accepted: list[int] = within.tolist()
    restart: list[int] = []
    if _all(inside):
        return accepted, restart
    drift_radius = px_gain * config.drift_radius_px * max(1.0, state.dt / NOMINAL_DT_S)
    limb = ({i for i, name in enumerate(tree.names) if name in config.limb_parts}
            if config.limb_tolerance > 0 and before is not None else set())
    for i, d2 in zip(gated[~inside], d2_all[~inside], strict=True):
        if d2 > config.gate_chi2 and _restarts(i, z, r_var[i], state, before, accepted,
                                               i in limb, config, tree):
            restart.append(int(i))
            continue
        if state.shadow_left[i] > 0 and _back_to_kept_track(w, i, z[i], r_var[i], config):
            accepted.append(int(i))
            w.rejected[i] = 0
            w.last_rejected[i] = np.nan
            continue
        consistent = np.all(np.isfinite(w.last_rejected[i])) and \
            float(np.hypot(*(z[i] - w.last_rejected[i]))) <= drift_radius
        w.rejected[i] = w.rejected[i] + 1 if consistent else 1
        w.last_rejected[i] = z[i]
        if config.drift_frames > 0 and w.rejected[i] >= config.drift_frames:
            restart.append(int(i))
    return sorted(accepted), restart


def _restarts(i: int, z: NDArray[np.float64], r: float, state: TrackState,
              before: TrackState | None, accepted: list[int], limb: bool, config: SlqeConfig,
              tree: PartTree) -> bool:
    """Whether part i, its detection beyond the gate, is restarted on it: the stop hypothesis
    (the detection is within the gate of where the part was at the previous frame) or the limb
    hypothesis (an arm part rejected the frame before, its parent's detection accepted, the
    limb between the two detections keeping its length)."""
    b = config.block
    if config.stop_hypothesis and before is not None and before.active[i]:
        p0 = slice(i * b, i * b + 2)
        s0 = before.cov[p0, p0] + r * _EYE2
        if _mahalanobis2((z[i] - before.x[p0])[None], s0[None])[0] <= config.gate_chi2:
            return True
    return limb and state.rejected[i] >= config.limb_rejected_frames and \
        tree.parents[i] in accepted and \
        _keeps_length(z, before, i, tree.parents[i], b, config.limb_tolerance)


def _back_to_kept_track(w: SimpleNamespace, i: int, z: NDArray[np.float64], r: float,
                        config: SlqeConfig) -> bool:
    """The last restart of part i followed a wrong detection when detection `z` is within the
    gate of the track kept from before it: back to that track (True)."""
    s1 = w.shadow_cov[i, :2, :2] + r * _EYE2
    if _mahalanobis2((z - w.shadow_x[i, :2])[None], s1[None])[0] > config.gate_chi2:
        return False
    b = config.block
    sl = slice(i * b, (i + 1) * b)
    w.x[sl] = w.shadow_x[i]
    w.cov[sl, :] = 0.0
    w.cov[:, sl] = 0.0
    w.cov[sl, sl] = w.shadow_cov[i]
    w.shadow_left[i] = 0
    return True


def _kalman_update(w: SimpleNamespace, z: NDArray[np.float64], r_var: NDArray[np.float64],
                   accepted: list[int], b: int) -> None:
    """Eqs. (14)-(15) with the accepted parts' detections `z` (N, 2), variances `r_var` (N,)."""
    idx = (np.array(accepted)[:, None] * b + _XY).reshape(-1)
    y = (z - w.x[idx].reshape(-1, 2)).reshape(-1)
    r_diag = r_var.repeat(2)
    r = np.zeros((len(idx), len(idx)))
    r.flat[::len(idx) + 1] = r_diag
    ph = w.cov[:, idx]
    s = w.cov[idx[:, None], idx] + r
    gain = _solve(s, ph.T, signature='dd->d').T
    if not _all(np.isfinite(gain), axis=None):  # what np.linalg.solve's checks would refuse
        raise np.linalg.LinAlgError(f'singular innovation covariance S = {s.tolist()}')
    w.x = w.x + gain @ y
    # Joseph form (I - K H) P (I - K H)^T + K R K^T, with H picking the rows `idx`: the
    # same products restricted to the columns H touches (K H P = K P[idx])
    m = w.cov - gain @ w.cov[idx, :]
    cov = m - m[:, idx] @ gain.T + (gain * r_diag) @ gain.T
    w.cov = 0.5 * (cov + cov.T)


def _start_parts(w: SimpleNamespace, starts: list[int], restart: list[int], z: NDArray[np.float64],
                 conf: NDArray[np.float64], r_var: NDArray[np.float64],
                 source: NDArray[np.uint8], config: SlqeConfig, tree: PartTree,
                 px_gain: float) -> None:
    """New and restarted parts start on their detection, parents first; a restarted part's
    track is kept a while in case the detection followed was the wrong one."""
    b = config.block
    if config.shadow_frames and restart:
        for i in restart:
            sl = slice(i * b, (i + 1) * b)
            w.shadow_x[i], w.shadow_cov[i] = w.x[sl], w.cov[sl, sl]
            w.shadow_left[i] = config.shadow_frames
    for i in starts:
        _init_part(w.x, w.cov, i, z[i], tree.parents[i], w.active, config, r_var[i], px_gain)
        w.active[i] = True
        source[i] = _DETECTED
        w.missed[i] = 0
        w.rejected[i] = 0
        w.last_rejected[i] = np.nan
        w.confidence[i] = conf[i]


def _coast(w: SimpleNamespace, source: NDArray[np.uint8], config: SlqeConfig) -> None:
    """Parts only predicted this frame: one more frame missed, their confidence decayed; past
    `max_missed_frames` they are dropped (MISSING)."""
    coasting = w.active & (source == _TRACKED)
    w.missed[coasting] += 1
    w.confidence[coasting] *= config.confidence_decay
    lost = coasting & (w.missed > config.max_missed_frames)
    if _any(lost):
        drop = np.repeat(lost, config.block)
        w.x[drop] = 0.0
        w.cov[drop, :] = 0.0
        w.cov[:, drop] = 0.0
        w.active[lost] = False
        source[lost] = _MISSING
        w.missed[lost] = 0
        w.rejected[lost] = 0
        w.last_rejected[lost] = np.nan
        w.confidence[lost] = 0.0
        w.shadow_left[lost] = 0


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
    at = _block_xy(n_parts, b)
    covs = state.cov[at[:, :, None], at[:, None, :]]
    if config.output == 'detection':
        z, conf = check_measurement(uv, confidence, n_parts)
        det = info.source == _DETECTED
        pos[det] = z[det]
        safe = np.where(det, np.maximum(np.nan_to_num(conf, nan=1.0), 1e-6), 1.0)
        r_var = (px_gain * config.measurement_noise_px) ** 2 / safe
        covs[det] = r_var[det, None, None] * _EYE2
    missing = info.source == _MISSING
    pos[missing] = np.nan
    vel[missing] = np.nan
    covs[missing] = np.nan
    # np.clip's values, without its Python wrapper
    clipped = np.minimum(np.maximum(state.confidence, 0.0), 1.0)
    conf_out = np.where(missing, 0.0, clipped).astype(np.float32)
    return TrackOutput(positions=pos, covariances=covs, velocities=vel,
                       source=info.source.astype(np.uint8), confidence=conf_out,
                       stamp=float(state.stamp) if state.stamp is not None else math.nan)


@functools.lru_cache(maxsize=8)
def _block_xy(n_parts: int, b: int) -> NDArray[np.intp]:
    """(P, 2) the state indices of each part's position (read-only)."""
    at = np.arange(n_parts)[:, None] * b + _XY
    at.setflags(write=False)
    return at
