"""Compiled loop of the exact linear twin (numba, cached, GIL released).

See :mod:`reduced.twin` for the equations.  Generalised coordinates per
balancer i: the cart position x_i (m) and the balancing error e_i = L theta_i (m),
with rates v_i, w_i = e_i'.  All forces are per unit cart mass M (m/s^2).
One step is MuJoCo's ``Euler`` step: accelerations from the current state, then
v <- v + h a, q <- q + h v(new).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def advance_twin(
    xi: np.ndarray,
    state: np.ndarray,
    hist: np.ndarray,
    pos: int,
    coef: np.ndarray,
    minv: np.ndarray,
    n0: int,
    every: int,
    rec: np.ndarray,
) -> int:
    """Advance the twin over ``xi.shape[1]`` steps.

    Parameters
    ----------
    xi : (nb, n, C) standard normal draws for steps n0 .. n0+n-1.
    state : (nb, C, 4) [x, e, v, w] per balancer, updated in place.
    hist : (nb, C, d) ring buffer of past balancing errors, updated in place.
    pos : ring-buffer slot holding e at step n0 - d.
    coef : [alpha, gamma_tip, gamma_cart, mass_ratio, beta, noise_scale, dt,
        rod (0/1), rod_stiffness k*imp (1/s^2), rod_damping b (1/s),
        rod_mobility A (per unit M), rod_regulariser R (per unit M)].
    minv : (2, 2) inverse of the per-unit-cart-mass mass matrix
        [[1 + mu, mu], [mu, mu (1 + kappa)]] in (x, e).
    rec : (nb, S, C, 4) samples [tip pos, tip vel, base pos, base vel] recorded
        *before* every step whose global index is a multiple of ``every``.

    Returns
    -------
    The ring-buffer slot for the next call.
    """
    nb, n, nc = xi.shape
    d = hist.shape[2]
    alpha, g_tip, g_cart, mu = coef[0], coef[1], coef[2], coef[3]
    beta, s_noise, h = coef[4], coef[5], coef[6]
    rod = coef[7] > 0.5 and nc == 2
    k_rod, b_rod, a_rod, r_rod = coef[8], coef[9], coef[10], coef[11]
    rec_start = (n0 + every - 1) // every
    nrec = rec.shape[1]
    ax = np.empty(nc)
    ae = np.empty(nc)
    p_out = pos
    for r in range(nb):
        p = pos
        for k in range(n):
            nk = n0 + k
            if nk % every == 0:
                j = nk // every - rec_start
                if j < nrec:
                    for i in range(nc):
                        rec[r, j, i, 0] = state[r, i, 0] + state[r, i, 1]
                        rec[r, j, i, 1] = state[r, i, 2] + state[r, i, 3]
                        rec[r, j, i, 2] = state[r, i, 0]
                        rec[r, j, i, 3] = state[r, i, 2]
            for i in range(nc):
                e, v, w = state[r, i, 1], state[r, i, 2], state[r, i, 3]
                e_delayed = hist[r, i, p]
                hist[r, i, p] = e
                u = beta * (1.0 + s_noise * xi[r, k, i]) * e_delayed
                tip_drag = g_tip * mu * (v + w)
                qx = u - g_cart * v - tip_drag
                qe = mu * alpha * e - tip_drag
                ax[i] = minv[0, 0] * qx + minv[0, 1] * qe
                ae[i] = minv[1, 0] * qx + minv[1, 1] * qe
            if rod:
                # soft equality on the tip separation: J = (+1, +1, -1, -1) in (x1, e1, x2, e2)
                sep = (state[r, 0, 0] + state[r, 0, 1]) - (state[r, 1, 0] + state[r, 1, 1])
                sep_rate = (state[r, 0, 2] + state[r, 0, 3]) - (state[r, 1, 2] + state[r, 1, 3])
                a0 = (ax[0] + ae[0]) - (ax[1] + ae[1])
                aref = -b_rod * sep_rate - k_rod * sep
                f = (aref - a0) / (a_rod + r_rod)
                cx = (minv[0, 0] + minv[0, 1]) * f
                ce = (minv[1, 0] + minv[1, 1]) * f
                ax[0] += cx
                ae[0] += ce
                ax[1] -= cx
                ae[1] -= ce
            for i in range(nc):
                v = state[r, i, 2] + h * ax[i]
                w = state[r, i, 3] + h * ae[i]
                state[r, i, 2] = v
                state[r, i, 3] = w
                state[r, i, 0] = state[r, i, 0] + h * v
                state[r, i, 1] = state[r, i, 1] + h * w
            p += 1
            if p == d:
                p = 0
        p_out = p
    return p_out
