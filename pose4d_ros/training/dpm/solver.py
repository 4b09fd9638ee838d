"""The structural SVM's quadratic programme (`train`, step 4): its weight layout, its
constraints stored by blocks, the whitening of the filter windows, and dual coordinate descent
(numba).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.dpm.model import PartModel
from pose4d_ros.core.skeleton import PartTree
from pose4d_ros.training.dpm.samples import TrainConfig


@dataclass(frozen=True)
class Layout:
    """Where each parameter sits in the QP's weight vector."""

    n_parts: int
    n_types: int
    dim: int

    @property
    def n_filter(self) -> int:
        return self.n_parts * self.n_types * self.dim

    @property
    def n_spring(self) -> int:
        return self.n_parts * self.n_types * 4

    @property
    def size(self) -> int:
        return self.n_filter + self.n_spring + self.n_parts * self.n_types * self.n_types

    def filter_off(self, part: int, typ: int) -> int:
        return (part * self.n_types + typ) * self.dim

    def spring_off(self, part: int, typ: int) -> int:
        return self.n_filter + (part * self.n_types + typ) * 4

    def bias_off(self, part: int, ptype: int, typ: int) -> int:
        return (self.n_filter + self.n_spring
                + (part * self.n_types + ptype) * self.n_types + typ)


class Examples:
    """The QP's constraints y_i w . x_i >= m_i - xi_i, stored by blocks.

    Each example owns, per part, a filter block (D floats at offset `of`), a spring block (4
    floats at `od`, -1 for the root) and a type indicator (1 float at `ob`). A structural
    constraint Phi(z_n) - Phi(z) stores -Phi(z) as its own blocks and refers (`ref`) to the
    positive example holding Phi(z_n); other examples have ref = -1. Positives come first and
    are never dropped, so references stay valid when the cache is compacted.
    """

    def __init__(self, capacity: int, n_parts: int, dim: int) -> None:
        self.n = 0
        self.xf = np.zeros((capacity, n_parts, dim), np.float32)
        self.of = np.zeros((capacity, n_parts), np.int64)
        self.xd = np.zeros((capacity, n_parts, 4), np.float32)
        self.od = np.full((capacity, n_parts), -1, np.int64)
        self.xb = np.zeros((capacity, n_parts), np.float32)
        self.ob = np.zeros((capacity, n_parts), np.int64)
        self.y = np.zeros(capacity)
        self.m = np.zeros(capacity)
        self.ref = np.full(capacity, -1, np.int64)
        self.alpha = np.zeros(capacity)
        self.keys: list[tuple] = []

    @property
    def capacity(self) -> int:
        return len(self.y)

    def add(self, blocks: tuple, label: float, margin: float, ref: int, key: tuple) -> bool:
        if self.n >= self.capacity:
            return False
        i = self.n
        self.xf[i], self.of[i], self.xd[i], self.od[i], self.xb[i], self.ob[i] = blocks
        self.y[i], self.m[i], self.ref[i], self.alpha[i] = label, margin, ref, 0.0
        self.keys.append(key)
        self.n += 1
        return True

    def keep(self, idx: NDArray[np.int64]) -> None:
        """Keep only examples `idx` (sorted, all positives included), compacting the arrays."""
        k = len(idx)
        for a in (self.xf, self.of, self.xd, self.od, self.xb, self.ob, self.y, self.m,
                  self.ref, self.alpha):
            a[:k] = a[idx]
        self.keys = [self.keys[i] for i in idx]
        self.n = k

    def arrays(self) -> tuple:
        n = self.n
        return (self.xf[:n], self.of[:n], self.xd[:n], self.od[:n], self.xb[:n], self.ob[:n],
                self.y[:n], self.m[:n], self.ref[:n])


def pose_blocks(feat: NDArray[np.float32], parts: NDArray[np.int64], parents: NDArray,
                 anchors: NDArray, lay: Layout, fs: int, bias_feature: float,
                 patches: NDArray[np.float32] | None = None) -> tuple:
    """The block feature vector Phi of a pose ((type, row, col) per part) on a padded level
    (or from windows already cut, `patches`); filter blocks raw (not whitened)."""
    p_n = lay.n_parts
    xf = np.empty((p_n, lay.dim), np.float32)
    of = np.empty(p_n, np.int64)
    xd = np.zeros((p_n, 4), np.float32)
    od = np.full(p_n, -1, np.int64)
    xb = np.full(p_n, bias_feature, np.float32)
    ob = np.empty(p_n, np.int64)
    for c in range(p_n):
        t, r, q = (int(v) for v in parts[c])
        xf[c] = feat[r:r + fs, q:q + fs].reshape(-1) if patches is None else patches[c]
        of[c] = lay.filter_off(c, t)
        if c == 0:
            ob[c] = lay.bias_off(0, 0, t)
            continue
        pt, pr, pq = (int(v) for v in parts[parents[c]])
        dx = q - pq - int(anchors[c, t, 0])
        dy = r - pr - int(anchors[c, t, 1])
        xd[c] = (-dx, -dx * dx, -dy, -dy * dy)
        od[c] = lay.spring_off(c, t)
        ob[c] = lay.bias_off(c, pt, t)
    return xf, of, xd, od, xb, ob


@nb.njit(cache=True)
def _own_dot(w, xf, of, xd, od, xb, ob, i):
    s = 0.0
    p_n, dim = xf.shape[1], xf.shape[2]
    for c in range(p_n):
        o = of[i, c]
        for d in range(dim):
            s += xf[i, c, d] * w[o + d]
        o = od[i, c]
        if o >= 0:
            for d in range(4):
                s += xd[i, c, d] * w[o + d]
        s += xb[i, c] * w[ob[i, c]]
    return s


@nb.njit(cache=True)
def _own_axpy(w, a, xf, of, xd, od, xb, ob, i):
    p_n, dim = xf.shape[1], xf.shape[2]
    for c in range(p_n):
        o = of[i, c]
        for d in range(dim):
            w[o + d] += a * xf[i, c, d]
        o = od[i, c]
        if o >= 0:
            for d in range(4):
                w[o + d] += a * xd[i, c, d]
        w[ob[i, c]] += a * xb[i, c]


@nb.njit(cache=True)
def _cross(xf, of, xd, od, xb, ob, i, j):
    """x_i . x_j of two examples' own blocks (part c's blocks can only meet part c's)."""
    s = 0.0
    p_n, dim = xf.shape[1], xf.shape[2]
    for c in range(p_n):
        if of[i, c] == of[j, c]:
            for d in range(dim):
                s += xf[i, c, d] * xf[j, c, d]
        if od[i, c] >= 0 and od[i, c] == od[j, c]:
            for d in range(4):
                s += xd[i, c, d] * xd[j, c, d]
        if ob[i, c] == ob[j, c]:
            s += xb[i, c] * xb[j, c]
    return s


@nb.njit(cache=True)
def dot(w, xf, of, xd, od, xb, ob, ref, i):
    s = _own_dot(w, xf, of, xd, od, xb, ob, i)
    if ref[i] >= 0:
        s += _own_dot(w, xf, of, xd, od, xb, ob, ref[i])
    return s


@nb.njit(cache=True)
def dcd(w, xf, of, xd, od, xb, ob, y, m, ref, alpha, cost, lb_idx, lb_val, beta, epochs,
         seed):
    """Dual coordinate descent for the constraints y_i w.x_i >= m_i - xi_i (0 <= a_i <= C_i) and
    the hard lower bounds w_k >= lb (b_k >= 0). `w` must equal w0 + sum_i a_i y_i x_i +
    sum_k b_k e_k on entry (warm start); it is kept so. Returns the largest projected gradient
    of the last epoch."""
    n = y.shape[0]
    np.random.seed(seed)  # noqa: NPY002  (numba's generator: seeded, deterministic)
    q = np.empty(n)
    for i in range(n):
        v = _cross(xf, of, xd, od, xb, ob, i, i)
        r = ref[i]
        if r >= 0:
            v += _cross(xf, of, xd, od, xb, ob, r, r) + 2.0 * _cross(xf, of, xd, od, xb, ob, i, r)
        q[i] = max(v, 1e-12)
    order = np.arange(n)
    maxpg = 0.0
    for _ in range(epochs):
        np.random.shuffle(order)  # noqa: NPY002
        maxpg = 0.0
        for i in order:
            g = y[i] * dot(w, xf, of, xd, od, xb, ob, ref, i) - m[i]
            a = alpha[i]
            pg = g
            if a <= 0.0:
                pg = min(g, 0.0)
            elif a >= cost[i]:
                pg = max(g, 0.0)
            if abs(pg) > maxpg:
                maxpg = abs(pg)
            if abs(pg) > 1e-12:
                na = min(max(a - g / q[i], 0.0), cost[i])
                if na != a:
                    step = (na - a) * y[i]
                    _own_axpy(w, step, xf, of, xd, od, xb, ob, i)
                    if ref[i] >= 0:
                        _own_axpy(w, step, xf, of, xd, od, xb, ob, ref[i])
                    alpha[i] = na
        for j in range(lb_idx.shape[0]):
            k = lb_idx[j]
            g = w[k] - lb_val[j]
            nb_ = max(beta[j] - g, 0.0)
            w[k] += nb_ - beta[j]
            beta[j] = nb_
    return maxpg


@nb.njit(cache=True)
def rebuild_w(w0, xf, of, xd, od, xb, ob, y, ref, alpha, lb_idx, beta):
    """w = w0 + sum_i a_i y_i x_i + sum_k b_k e_k: the dual's weights again after examples'
    blocks changed (latent positives), so that `dcd` can warm-start from the same duals."""
    w = w0.copy()
    for i in range(y.shape[0]):
        a = alpha[i] * y[i]
        if a != 0.0:
            _own_axpy(w, a, xf, of, xd, od, xb, ob, i)
            if ref[i] >= 0:
                _own_axpy(w, a, xf, of, xd, od, xb, ob, ref[i])
    for j in range(lb_idx.shape[0]):
        w[lb_idx[j]] += beta[j]
    return w


@nb.njit(cache=True)
def margins(w, xf, of, xd, od, xb, ob, y, ref):
    """y_i w . x_i for every example."""
    n = y.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = y[i] * dot(w, xf, of, xd, od, xb, ob, ref, i)
    return out


@dataclass(frozen=True)
class Whitening:
    """x' = W (x - mu0) with W = L^-1, L L^T = the covariance of random windows (+ ridge):
    the QP works on whitened HOG windows (Hariharan, Malik & Ramanan 2012), whose dimensions are
    decorrelated and of unit variance. That makes dual coordinate descent converge (raw HOG
    windows are strongly correlated) and puts the LDA templates' prior into the regulariser."""

    mean: NDArray[np.float64]        # (D,)
    transform: NDArray[np.float64]   # (D, D) W = L^-1
    chol: NDArray[np.float64]        # (D, D) L

    def __call__(self, x: NDArray) -> NDArray[np.float32]:
        return ((np.asarray(x, np.float64) - self.mean) @ self.transform.T).astype(np.float32)


def whitened(blocks: tuple, white: Whitening, sign: float = 1.0) -> tuple:
    xf, of, xd, od, xb, ob = blocks
    return (sign * white(xf), of, sign * xd, od, sign * xb, ob)


def model_from_w(w: NDArray[np.float64], lay: Layout, tree: PartTree, cfg: TrainConfig,
                  anchors: NDArray[np.int32], scale_range: tuple[float, float],
                  white: Whitening) -> PartModel:
    """The model of a QP solution: filters on raw windows are w_raw = W^T w', and
    w_raw . mu0 moves into the type biases."""
    fs = cfg.filter_cells
    c = lay.dim // (fs * fs)
    wf = w[:lay.n_filter].reshape(lay.n_parts, lay.n_types, lay.dim) @ white.transform
    shift = wf @ white.mean                              # (P, K)
    filters = wf.reshape(lay.n_parts, lay.n_types, fs, fs, c)
    springs = w[lay.n_filter:lay.n_filter + lay.n_spring].reshape(lay.n_parts, lay.n_types, 4)
    springs = springs.copy()
    springs[0] = 0.0
    springs[1:, :, 1] = np.maximum(springs[1:, :, 1], cfg.spring_lb)
    springs[1:, :, 3] = np.maximum(springs[1:, :, 3], cfg.spring_lb)
    bias = w[lay.n_filter + lay.n_spring:].reshape(lay.n_parts, lay.n_types, lay.n_types)
    bias = bias * cfg.bias_feature - shift[:, None, :]
    bias[0, 1:] = 0.0
    return PartModel(
        part_names=tree.names, parents=tree.parents, channels=cfg.channels, sbin=cfg.sbin,
        filters=filters.astype(np.float32), springs=springs.astype(np.float32),
        anchors=anchors.astype(np.int32), bias=bias.astype(np.float32),
        canonical_scale_px=cfg.canonical_scale_px, scale_length_m=cfg.scale_length_m,
        scale_range_px=scale_range,
        depth_encoding=cfg.depth_encoding if cfg.channels == 'rgbd' else '',
        depth_range_m=cfg.depth_range_m, calibration=None, masked_input=cfg.masked_input)


def w_from_model(model: PartModel, lay: Layout, white: Whitening, cfg: TrainConfig
                  ) -> NDArray[np.float64]:
    """The inverse of `model_from_w`: a model's parameters in the QP's (whitened) layout."""
    w = np.zeros(lay.size)
    wraw = model.filters.reshape(lay.n_parts, lay.n_types, lay.dim).astype(np.float64)
    w[:lay.n_filter] = (wraw @ white.chol).ravel()     # w' = L^T w_raw, row-wise
    w[lay.n_filter:lay.n_filter + lay.n_spring] = model.springs.astype(np.float64).ravel()
    shift = wraw @ white.mean
    bias = (model.bias.astype(np.float64) + shift[:, None, :]) / cfg.bias_feature
    bias[0, 1:] = 0.0
    w[lay.n_filter + lay.n_spring:] = bias.ravel()
    return w
