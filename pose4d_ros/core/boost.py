"""Gradient-boosted regression trees with the absolute error: the fitted trees and a fast
predictor (`training.boost` fits them).

Trees are complete binary trees of a fixed depth. Missing features (NaN) always go left.
Prediction is one numba loop over samples and trees.

Layout (`BoostedTrees`): node k of a tree has children 2k + 1 (left) and 2k + 2 (right); a
sample goes right when ``x[feature[k]] >= threshold[k]``. The 2^depth leaves follow the
2^depth - 1 internal nodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class BoostedTrees:
    """A fitted ensemble (see the module docstring for the layout).

    Attributes
    ----------
    base : the starting value (the median of the targets).
    feature : (T, 2^D - 1) int16 feature index per internal node.
    threshold : (T, 2^D - 1) float32; inf = every sample goes left.
    leaf : (T, 2^D) float32 leaf values, the learning rate included.
    """

    base: float
    feature: NDArray[np.int16]
    threshold: NDArray[np.float32]
    leaf: NDArray[np.float32]

    def __post_init__(self) -> None:
        t, n = self.feature.shape
        if self.threshold.shape != (t, n) or self.leaf.shape != (t, n + 1) or \
                (n + 1) & n:
            raise ValueError(f'bad tree arrays: feature {self.feature.shape}, threshold '
                             f'{self.threshold.shape}, leaf {self.leaf.shape}')
        if not (np.isfinite(self.base) and np.isfinite(self.leaf).all()):
            raise ValueError('tree values must be finite')

    @property
    def depth(self) -> int:
        return int(self.leaf.shape[1]).bit_length() - 1

    def predict(self, x: NDArray[np.floating]) -> NDArray[np.float64]:
        """(N,) predictions for the (N, F) samples `x` (NaN = missing)."""
        x = np.asarray(x, np.float32)
        return predict_stacked(x, np.zeros(len(x), np.int64), np.array([self.base]),
                               self.feature[None], self.threshold[None], self.leaf[None])


def predict_stacked(x: NDArray[np.float32], ensemble: NDArray[np.int64],
                    base: NDArray[np.floating], feature: NDArray[np.int16],
                    threshold: NDArray[np.float32], leaf: NDArray[np.float32]
                    ) -> NDArray[np.float64]:
    """Predictions of E ensembles of one shape stacked along a first axis (`base` (E,),
    `feature` and `threshold` (E, T, N), `leaf` (E, T, N + 1)): sample i of `x` (N, F) by
    ensemble `ensemble[i]`, or 0 where that is -1. One numba call for all samples."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    ensemble = np.asarray(ensemble, np.int64)
    if x.ndim != 2 or ensemble.shape != (len(x),) or (
            feature.size and int(feature.max()) >= x.shape[1]) or (
            len(x) and int(ensemble.max(initial=-1)) >= len(base)):
        raise ValueError(f'samples {x.shape} and ensembles {ensemble.shape} do not fit '
                         f'{len(base)} ensembles of trees {feature.shape}')
    return predict_kernel(x, ensemble, np.asarray(base, np.float64), feature, threshold, leaf)


@nb.njit(cache=True)
def predict_kernel(x: NDArray[np.float32], ensemble: NDArray[np.int64],
                   base: NDArray[np.float64], feature: NDArray[np.int16],
                   threshold: NDArray[np.float32], leaf: NDArray[np.float32]
                   ) -> NDArray[np.float64]:
    """`predict_stacked` without its checks, for arrays already known to fit (C-contiguous
    `x`; a caller that checked the trees once, such as `core.refine`)."""
    _, n_trees, n_nodes = feature.shape
    out = np.zeros(x.shape[0])
    for i in range(x.shape[0]):
        e = ensemble[i]
        if e < 0:
            continue
        s = base[e]
        for t in range(n_trees):
            k = 0
            while k < n_nodes:
                # right when x >= threshold, as a number, not a branch (the trees' branches,
                # half of them mispredicted, took half the time); NaN >= threshold is False:
                # missing values go left
                k = 2 * k + 1 + (x[i, feature[e, t, k]] >= threshold[e, t, k])
            s += leaf[e, t, k - n_nodes]
        out[i] = s
    return out
