"""Compiled loop of the short-time cross-correlation coefficient (numba, cached, GIL released).

:func:`validation.checks.metrics.stcc` (paper eq. (8)) calls :func:`stcc_lags` once per
series and range of lags.  The arithmetic is the decomposition that function's
docstring states, and nothing else: the series is cut into blocks of g samples (g =
gcd(window, stride) in samples), each block's mean and centred sums are formed directly,
and a window's comoment is combined from its k = window / g blocks by the exact
within/between decomposition (Chan, Golub & LeVeque 1983, equal blocks)::

    C_W = sum_b C_b + g sum_b (m_x,b - M_x)(m_y,b - M_y),   M = mean_b m_b,

every sum taken directly over its window or block (no differences of running sums), so
R keeps full relative precision whatever the dynamic range of the series.  The blocks of
the lagged series y(s + tau) are formed for each lag, as the windows of x(s) and
y(s + tau) start at the same block boundaries only after the shift.

What the loop changes against the numpy expression it replaced (7 December): the order
of the additions inside a block (sequential here, numpy's pairwise there), so R moves
at rounding level (at most 1.0e-15 over 16 x 600 s of correlated series sampled every
5 ms, windows of 2.5, 5 and 10 s; every first dominant peak the same; the quick run's
1286 baseline numbers reproduced exactly), and its cost: the lags share the blocks of x
and each window's centred block means of x, which numpy formed again for every lag
(``benchmarks/bench_stcc.py``, 16 x 600 s, 5 s windows, 61 lags, 2 threads, idle:
0.040-0.049 -> 0.007 s per realisation).  Each lag is computed alone,
so the result of a lag does not depend on the range of lags a call covers (the caller
splits lags across threads when a batch has fewer series than cores).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def stcc_lags(
    x: np.ndarray,
    y: np.ndarray,
    first: np.ndarray,
    g: int,
    k: int,
    lag0: int,
    lag1: int,
    out: np.ndarray,
) -> None:
    """R(x, y; tau) of one series pair at lags ``lag0`` .. ``lag1 - 1`` (samples).

    The function is long because it is one function without helpers on purpose: numba
    compiles it in 0.54 s against 0.83 s for the same loops split into three jitted
    functions (a first run after install pays it).

    Parameters
    ----------
    x, y : (samples,) float64, e.g. tip and cart velocity.
    first : (windows,) int64, the first block of each window (window start / g).
    g, k : block length (samples) and blocks per window.
    out : (windows, lags) float64; columns ``lag0`` .. ``lag1 - 1`` are written:
        R = C_xy / sqrt(C_xx C_yy), C_yy of y's unlagged window (paper eq. (8)); NaN where
        a window has zero deviation and zero comoment, +-inf where only the deviation is 0.
    """
    nw = first.size
    nblocks = first[nw - 1] + k
    mx = np.empty(nblocks)  # block means of x, then of the lagged y
    my = np.empty(nblocks)
    cxx = np.empty(nblocks)  # within-block sums: of (x - m)^2, then of the lagged products
    cyy = np.empty(nblocks)
    for b in range(nblocks):
        a = b * g
        sx = 0.0
        sy = 0.0
        for i in range(g):
            sx += x[a + i]
            sy += y[a + i]
        mx[b] = sx / g
        my[b] = sy / g
        sx = 0.0
        sy = 0.0
        for i in range(g):
            u = x[a + i] - mx[b]
            v = y[a + i] - my[b]
            sx += u * u
            sy += v * v
        cxx[b] = sx
        cyy[b] = sy
    # each window's block means of x about their window mean (shared by every lag), and
    # the norm: the windows' variances of x and of unlagged y
    dx = np.empty((nw, k))
    norm = np.empty(nw)
    for w in range(nw):
        f = first[w]
        sx = 0.0
        sy = 0.0
        for j in range(k):
            sx += mx[f + j]
            sy += my[f + j]
        sx /= k
        sy /= k
        wx = 0.0
        bx = 0.0
        wy = 0.0
        by = 0.0
        for j in range(k):
            dx[w, j] = mx[f + j] - sx
            dyj = my[f + j] - sy
            wx += cxx[f + j]
            bx += dx[w, j] * dx[w, j]
            wy += cyy[f + j]
            by += dyj * dyj
        norm[w] = np.sqrt((wx + g * bx) * (wy + g * by))
    for lag in range(lag0, lag1):
        for b in range(nblocks):  # the blocks of y(s + lag)
            a = b * g + lag
            s = 0.0
            for i in range(g):
                s += y[a + i]
            my[b] = s / g
        for b in range(nblocks):
            a = b * g
            s = 0.0
            for i in range(g):
                s += (x[a + i] - mx[b]) * (y[a + lag + i] - my[b])
            cxx[b] = s
        for w in range(nw):
            f = first[w]
            s = 0.0
            for j in range(k):
                s += my[f + j]
            s /= k
            within = 0.0
            between = 0.0
            for j in range(k):
                within += cxx[f + j]
                between += dx[w, j] * (my[f + j] - s)
            out[w, lag] = (within + g * between) / norm[w]
