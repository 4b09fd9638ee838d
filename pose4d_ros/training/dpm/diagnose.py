"""Checks of a trained part model against its labels (`tools/lspet_diagnose.py`,
`tools/dpm_selfcheck.py`): the labelled pose's own score under the model."""

from __future__ import annotations

import numpy as np

from pose4d_ros.core.dpm.model import PartModel


def labelled_score(resp: np.ndarray, cells: np.ndarray, model: PartModel) -> float:
    """The best score over part types of the pose with part c at window `cells[c]` = (row,
    col) on a level whose filter responses are `resp` (P, K, ny, nx)."""
    parents = np.asarray(model.parents)
    sp, an, bias = (model.springs.astype(np.float64), model.anchors, model.bias.astype(np.float64))
    n_parts, n_types = resp.shape[:2]
    below = np.zeros((n_parts, n_types))  # best score of each part's subtree, per its type
    for c in range(n_parts - 1, -1, -1):
        r, q = cells[c]
        below[c] += resp[c, :, r, q]
        if c == 0:
            break
        p = parents[c]
        dx = q - cells[p, 1] - an[c, :, 0]
        dy = r - cells[p, 0] - an[c, :, 1]
        spring = (sp[c, :, 0] * dx + sp[c, :, 1] * dx * dx
                  + sp[c, :, 2] * dy + sp[c, :, 3] * dy * dy)
        # message to the parent: for each parent type, the best child type
        below[p] += np.max(below[c][None, :] - spring[None, :] + bias[c], axis=1)
    return float(np.max(below[0] + bias[0, 0]))
