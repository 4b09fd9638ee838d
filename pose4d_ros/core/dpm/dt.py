"""Generalized distance transforms (Felzenszwalb & Huttenlocher, "Distance transforms of sampled
functions", Theory of Computing 2012) for the spring terms of the part model.

A child part's score map S is turned into the best score its parent can get from it at each
parent position, under the spring of Yang & Ramanan (PAMI 2013, eq. 1 and section 5):

    M(y, x) = max_{y', x'} S(y', x') - (wx d_x + wx2 d_x^2 + wy d_y + wy2 d_y^2),
    d_x = x' - (x + ax),  d_y = y' - (y + ay),

with (ax, ay) the child type's anchor (rest offset from the parent, cells) and wx2, wy2 > 0.
The quadratic cost is separable, so the 2-D transform is two 1-D lower-envelope passes (along x
for every child row, then along y for every parent column), O(n) each, keeping the argmax for
backtracking.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numpy.typing import NDArray

# A finite "minus infinity": keeps the envelope arithmetic free of inf - inf.
NEG = -1.0e10


@nb.njit(cache=True, inline='always')
def dt1d(src: NDArray[np.float32], a: float, b: float, shift: int, n_out: int,
         out: NDArray[np.float32], arg: NDArray[np.int32], v: NDArray[np.int32],
         z: NDArray[np.float64]) -> None:
    """out[p] = max_q src[q] - a (q - p - shift)^2 - b (q - p - shift), arg[p] = the best q.

    `v` (n int32) and `z` (n + 1 float64) are scratch buffers; `a` must be > 0.
    Felzenszwalb & Huttenlocher's lower envelope of parabolas, minimising f = -src.
    Inlined into `dt2d` by numba (called for every row and column of every map).
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
    ny, nx = score.shape
    n = max(ny, nx)
    v = np.empty(n, np.int32)
    z = np.empty(n + 1, np.float64)
    col_in = np.empty(ny, np.float32)
    col_out = np.empty(ny, np.float32)
    col_arg = np.empty(ny, np.int32)
    for y in range(ny):
        dt1d(score[y], wx2, wx, ax, nx, tmp[y], ix[y], v, z)
    for x in range(nx):
        for y in range(ny):
            col_in[y] = tmp[y, x]
        dt1d(col_in, wy2, wy, ay, ny, col_out, col_arg, v, z)
        for y in range(ny):
            out[y, x] = col_out[y]
            iy[y, x] = col_arg[y]
