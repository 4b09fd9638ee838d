"""Fitting the gradient-boosted regression trees of `core.boost` with the absolute error.

Friedman's gradient boosting ("Greedy function approximation", Ann. Statist. 2001) for the
least-absolute-deviation loss (his LAD_TreeBoost): each tree is fitted by least squares to the
signs of the residuals, then each of its leaves takes the median residual of the samples it
holds (scaled by the learning rate). The absolute error makes the fit follow the typical sample
and shrug off the few that are wildly off, which squared error would chase.

Trees (`core.boost.BoostedTrees`, its layout) are grown level by level on histograms of the
features cut at their quantiles (at most `bins` bins per feature), so fitting costs a few
`np.bincount` calls per level. A node that cannot be split usefully (fewer than `min_leaf`
samples on a side, or no gain) sends everything left. Missing features (NaN) always go left.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pose4d_ros.core.boost import BoostedTrees


def _bin_edges(x: NDArray[np.float64], bins: int) -> list[NDArray[np.float64]]:
    """Per feature, the sorted unique quantile cut points of its finite values."""
    edges = []
    qs = np.linspace(0.0, 1.0, bins + 1)[1:-1]
    for col in x.T:
        v = col[np.isfinite(col)]
        edges.append(np.unique(np.quantile(v, qs)) if len(v) else np.zeros(0))
    return edges


def fit(x: NDArray[np.floating], y: NDArray[np.floating], *, trees: int = 200, depth: int = 5,
        learning_rate: float = 0.05, bins: int = 32, min_leaf: int = 20) -> BoostedTrees:
    """Fit `trees` trees of `depth` to the (N, F) samples `x` (NaN = missing) and targets
    `y` (N,), minimising the absolute error.

    Deterministic (no sampling). ValueError for mismatched shapes, non-finite targets, or fewer
    than 2 `min_leaf` samples.
    """
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if x.ndim != 2 or y.shape != (x.shape[0],):
        raise ValueError(f'x must be (N, F) and y (N,), got {x.shape} and {y.shape}')
    if not np.isfinite(y).all():
        raise ValueError('targets must be finite')
    if not (1 <= depth <= 12 and trees >= 1 and 0 < learning_rate <= 1 and 2 <= bins <= 255
            and min_leaf >= 1):
        raise ValueError(f'bad settings: trees {trees}, depth {depth}, learning_rate '
                         f'{learning_rate}, bins {bins}, min_leaf {min_leaf}')
    n, n_feat = x.shape
    if n < 2 * min_leaf:
        raise ValueError(f'{n} samples: need at least {2 * min_leaf}')
    edges = _bin_edges(x, bins)
    # bin 0 holds the missing values; bin b >= 1 holds edges[b - 2] <= x < edges[b - 1]
    codes = np.zeros((n, n_feat), np.int64)
    for f in range(n_feat):
        ok = np.isfinite(x[:, f])
        codes[ok, f] = 1 + np.searchsorted(edges[f], x[ok, f], side='right')
    n_bins = bins + 1
    flat = codes + (np.arange(n_feat) * n_bins)[None, :]       # (N, F) feature-major bins
    n_nodes = 2 ** depth - 1
    feature = np.zeros((trees, n_nodes), np.int16)
    threshold = np.full((trees, n_nodes), np.inf, np.float32)
    leaf = np.zeros((trees, n_nodes + 1), np.float32)
    base = float(np.median(y))
    pred = np.full(n, base)
    for t in range(trees):
        resid = y - pred
        grad = np.sign(resid)
        node = np.zeros(n, np.int64)             # index within the current level
        for level in range(depth):
            width = 2 ** level
            first = width - 1                     # the level's first node in the layout
            idx = (node[:, None] * (n_feat * n_bins) + flat).ravel()
            size = width * n_feat * n_bins
            g = np.bincount(idx, np.repeat(grad, n_feat), size).reshape(width, n_feat, n_bins)
            c = np.bincount(idx, None, size).reshape(width, n_feat, n_bins)
            gl, cl = np.cumsum(g, axis=2), np.cumsum(c, axis=2)    # left side: bins <= b
            gt, ct = gl[:, :, -1:], cl[:, :, -1:]
            gr, cr = gt - gl, ct - cl
            with np.errstate(divide='ignore', invalid='ignore'):
                gain = gl ** 2 / cl + gr ** 2 / cr - gt ** 2 / ct
            gain[(cl < min_leaf) | (cr < min_leaf)] = -np.inf
            gain[:, :, 0] = -np.inf               # a split after the missing bin alone
            flat_gain = gain.reshape(width, -1)
            best = flat_gain.argmax(axis=1)
            go_right = np.zeros(n, bool)
            for k in range(width):
                if not flat_gain[k, best[k]] > 1e-12:
                    continue                      # no useful split: all go left
                f, b = divmod(int(best[k]), n_bins)
                feature[t, first + k] = f
                threshold[t, first + k] = edges[f][b - 1]
                sel = node == k
                go_right[sel] = codes[sel, f] > b
            node = 2 * node + go_right
        # leaves: the median residual of their samples (the absolute error's line search)
        order = np.argsort(node, kind='stable')
        starts = np.searchsorted(node[order], np.arange(n_nodes + 2))
        for k in range(n_nodes + 1):
            members = order[starts[k]:starts[k + 1]]
            if len(members):
                leaf[t, k] = learning_rate * np.median(resid[members])
        pred += leaf[t, node]
    return BoostedTrees(base, feature, threshold, leaf)
