"""Generalized distance transforms (Felzenszwalb & Huttenlocher, "Distance transforms of sampled
functions", Theory of Computing 2012) for the spring terms of the part model.

A child part's score map S is turned into the best score its parent can get from it at each
parent position, under the spring of Yang & Ramanan (PAMI 2013, eq. 1 and section 5):

    M(y, x) = max_{y', x'} S(y', x') - (wx d_x + wx2 d_x^2 + wy d_y + wy2 d_y^2),
    d_x = x' - (x + ax),  d_y = y' - (y + ay),

with (ax, ay) the child type's anchor (rest offset from the parent, cells) and wx2, wy2 > 0.
The quadratic cost is separable, so the 2-D transform is two 1-D passes (along x for every
child row, then along y for every parent column), keeping the argmax for backtracking.

Each 1-D output is the maximum over its candidates only: a cell whose spring cost exceeds the
cheapest cell's by more than the map's range of scores cannot win (its score is at most the
map's maximum, the cheapest cell's at least its minimum). The part model's springs are stiff
and its maps small, so that is a few cells; each pass runs over whole rows of the map at once
(one candidate, every row or column), in the same float64 arithmetic as Felzenszwalb and
Huttenlocher's lower envelope of parabolas, which it replaced: the same values and argmaxes
(the stage digests of the demo bag, valid30_near, valid60_people2 and rgb_10's depth-free
search are unchanged), the tree DP 2.09 -> 1.51 ms a level on the demo bag. Ties go to the
first candidate. A pass whose windows are wide (`WIDE`: training's latent positives, maps of
`NEG` but near the labels) runs the envelope column by column instead: alone it made those
maps' tree DP 3.2x slower, with the envelope 1.2x.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numpy.typing import NDArray

# A finite "minus infinity" for score maps (`training.dpm.mining`): keeps the arithmetic free of
# inf - inf.
NEG = -1.0e10
# A pass whose candidate windows average more cells than this runs the lower envelope instead
# (training's latent positives: maps of NEG but near the labels, whose range spans them all)
WIDE = 12


@nb.njit(cache=True, inline='always')
def _envelope(src: NDArray, a: float, b: float, shift: int, n_out: int,
              out: NDArray[np.float32], arg: NDArray[np.int32], v: NDArray[np.int32],
              z: NDArray[np.float64]) -> None:
    """out[p] = max_q src[q] - a (q - p - shift)^2 - b (q - p - shift), arg[p] = the best q.

    `v` (n int32) and `z` (n + 1 float64) are scratch buffers; `a` must be > 0.
    Felzenszwalb & Huttenlocher's lower envelope of parabolas, minimising f = -src: O(n),
    for the maps whose candidate windows are wide (`_pass`). Inlined by numba.
    """
    n = src.shape[0]
    # in the envelope's form: min_q f(q) + a (t - q)^2 + bb (t - q), t = p + shift, bb = -b
    bb = -b
    k = 0
    v[0] = 0
    z[0] = -np.inf
    z[1] = np.inf
    for q in range(1, n):
        fq = -np.float64(src[q])
        r = v[k]
        s = ((fq + np.float64(src[r])) - bb * (q - r) + a * (q * q - r * r)) / (2.0 * a * (q - r))
        while s <= z[k]:  # z[0] = -inf ends the loop
            k -= 1
            r = v[k]
            s = ((fq + np.float64(src[r])) - bb * (q - r) + a * (q * q - r * r)) / (
                2.0 * a * (q - r))
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = np.inf
    k = 0
    for p in range(n_out):
        t = p + shift
        while z[k + 1] < t:
            k += 1
        q = v[k]
        d = t - q
        out[p] = np.float32(np.float64(src[q]) - (a * d * d + bb * d))
        arg[p] = q


@nb.njit(cache=True)
def _candidates(n: int, a: float, bb: float, shift: int, span: float,
                lo: NDArray[np.int64], hi: NDArray[np.int64]) -> None:
    """For each output p of a 1-D pass over n cells, the cells q in lo[p]..hi[p] whose cost
    a d^2 + bb d (d = p + shift - q) is within `span` of the cheapest cell's (a > 0: they are
    contiguous)."""
    for p in range(n):
        t = p + shift
        cheapest = np.inf
        for q in range(n):
            d = t - q
            cheapest = min(cheapest, a * d * d + bb * d)
        limit = cheapest + span
        first = 0
        while first < n - 1:
            d = t - first
            if a * d * d + bb * d <= limit:
                break
            first += 1
        last = n - 1
        while last > first:
            d = t - last
            if a * d * d + bb * d <= limit:
                break
            last -= 1
        lo[p] = first
        hi[p] = last


@nb.njit(cache=True)
def _span(src: NDArray) -> float:
    """The range of the map's scores, widened a little for the rounding of one subtraction."""
    top = -np.inf
    bottom = np.inf
    for v in src.ravel():
        top = max(top, np.float64(v))
        bottom = min(bottom, np.float64(v))
    return (top - bottom) * (1.0 + 1e-9) + 1e-9


@nb.njit(cache=True)
def _pass(src: NDArray, a: float, b: float, shift: int, out: NDArray[np.float32],
          arg: NDArray[np.int32]) -> None:
    """out[p, j] = max_q src[q, j] - a (q - p - shift)^2 - b (q - p - shift), arg[p, j] = the
    first best q: the transform along the first axis, for every j at once."""
    n, m = src.shape
    bb = -b  # the cost of d = p + shift - q: a d^2 + bb d
    lo = np.empty(n, np.int64)
    hi = np.empty(n, np.int64)
    _candidates(n, a, bb, shift, _span(src), lo, hi)
    if (hi - lo + 1).sum() > WIDE * n:
        column = np.empty(n)
        col_out = np.empty(n, np.float32)
        col_arg = np.empty(n, np.int32)
        v = np.empty(n, np.int32)
        z = np.empty(n + 1)
        for j in range(m):
            column[:] = src[:, j]
            _envelope(column, a, b, shift, n, col_out, col_arg, v, z)
            out[:, j] = col_out
            arg[:, j] = col_arg
        return
    best = np.empty(m, np.float64)
    which = np.empty(m, np.int32)
    for p in range(n):
        t = p + shift
        q = lo[p]
        d = t - q
        cost = a * d * d + bb * d
        for j in range(m):
            best[j] = np.float64(src[q, j]) - cost
            which[j] = q
        for q in range(lo[p] + 1, hi[p] + 1):
            d = t - q
            cost = a * d * d + bb * d
            for j in range(m):  # selects, not branches: the loop vectorises
                v = np.float64(src[q, j]) - cost
                better = v > best[j]
                best[j] = v if better else best[j]
                which[j] = np.int32(q) if better else which[j]
        for j in range(m):
            out[p, j] = np.float32(best[j])
            arg[p, j] = which[j]


@nb.njit(cache=True)
def dt2d(score: NDArray[np.float32], wx: float, wx2: float, wy: float, wy2: float, ax: int,
         ay: int, out: NDArray[np.float32], ix: NDArray[np.int32], iy: NDArray[np.int32],
         tmp: NDArray[np.float32]) -> None:
    """2-D transform of a child score map (see the module docstring).

    Parameters
    ----------
    score : (Ny, Nx) float32 child scores.
    wx, wx2, wy, wy2 : spring weights (wx2, wy2 > 0), per cell and per cell^2.
    ax, ay : anchor, cells.
    out : (Ny, Nx) float32, written: best child score + spring for each parent cell.
    ix : (Ny, Nx) int32, written: best child column for (child row, parent column).
    iy : (Ny, Nx) int32, written: best child row for (parent row, parent column).
    tmp : (Ny, Nx) float32 scratch.
    """
    # along x: the transposed map's rows are the columns, each pass over all rows at once
    ny, nx = score.shape
    along_x = np.empty((nx, ny))
    along_x[:] = score.T
    _pass(along_x, np.float64(wx2), np.float64(wx), ax, tmp.T, ix.T)
    # along y, over all columns at once
    _pass(tmp, np.float64(wy2), np.float64(wy), ay, out, iy)
