"""The SLQE motion model: A(dt) from the part tree (eqs. 10-12), Q(dt) (eq. 8) and the
prediction (eqs. 7-9); see `core.slqe` for the model."""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.skeleton import PartTree
from pose4d_ros.core.slqe.config import NOMINAL_DT_S, SlqeConfig, TrackState, evolve

# `ndarray.any` without its Python wrapper (the per-frame path)
_any = np.logical_or.reduce


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
    if dt == 0.0 or not _any(state.active):
        return state
    a, q = _prediction_matrices(dt, config, tree, tuple(state.active.tolist()))
    x = a @ state.x
    cov = a @ state.cov @ a.T + (px_gain * px_gain) * q
    inactive = (~state.active).repeat(config.block)
    # Inactive parts carry no information: keep their blocks zero rather than growing noise.
    x[inactive] = 0.0
    cov[inactive, :] = 0.0
    cov[:, inactive] = 0.0
    shadow_x, shadow_cov = state.shadow_x, state.shadow_cov
    kept = (state.shadow_left > 0).nonzero()[0]
    if len(kept):
        # a kept track moves on by its own kinematics (its parent's pull was in the old state)
        b = config.block
        f = _kron_i2(axis_transition(dt, config.order, config.accel_time_s))
        q_own = (px_gain * px_gain) * q[:b, :b]
        shadow_x, shadow_cov = shadow_x.copy(), shadow_cov.copy()
        shadow_x[kept] = shadow_x[kept] @ f.T
        shadow_cov[kept] = f @ shadow_cov[kept] @ f.T + q_own
    return evolve(state, x=x, cov=0.5 * (cov + cov.T), shadow_x=shadow_x,
                  shadow_cov=shadow_cov, dt=dt)
