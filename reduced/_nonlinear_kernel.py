"""Compiled loop of the paper's nonlinear stick, eq. (1) (numba, cached, GIL released).

    theta'' + gamma theta' - alpha sin(theta) + beta R(t) theta(t - tau) = sigma eta(t)

with R_n = 1 + noise_scale * xi[r, n, 0] held over step n, and an optional
additive noise floor sigma eta(t), held over the step as floor_scale *
xi[r, n, 1] (floor_scale = sigma / sqrt(dt), Euler–Maruyama).  The delay is a
ring buffer of the last d = tau/dt angles, read then overwritten at each step,
exactly as in the linear kernel (both use :mod:`cipcore.control_kernel`, and
:func:`reduced._steps.euler_step` for the step), so for |theta| << 1 and
sigma = 0 the map is the linear single model's map for its balancing error
(eq. (2)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cipcore.control_kernel import delayed_control, first_sample, ring_next, sample_slot

from ._steps import euler_step


@njit(cache=True, nogil=True)
def advance_angle(
    xi: np.ndarray,
    state: np.ndarray,
    hist: np.ndarray,
    pos: int,
    law: tuple,
    floor_scale: float,
    semi_implicit: bool,
    n0: int,
    every: int,
    rec: np.ndarray,
) -> int:
    """Advance (theta, theta') of each realisation over ``xi.shape[1]`` steps.

    law : :attr:`cipcore.params.BalanceParams.law`; floor_scale : the floor noise's
    sigma / sqrt(dt); xi : (nb, n, 2) draws [gain, floor]; state : (nb, 2) updated in place;
    hist : (nb, d) ring buffer; rec : (nb, S, 2) samples [theta, theta'] recorded
    before every step whose global index is a multiple of ``every``.
    Returns the ring-buffer slot for the next call.
    """
    alpha, beta, gamma, noise_scale, dt = law
    nb, n, _ = xi.shape
    d = hist.shape[1]
    rec_start = first_sample(n0, every)
    nrec = rec.shape[1]
    p_out = pos
    for r in range(nb):
        th = state[r, 0]
        om = state[r, 1]
        p = pos
        for k in range(n):
            j = sample_slot(n0 + k, every, rec_start, nrec)
            if j >= 0:
                rec[r, j, 0] = th
                rec[r, j, 1] = om
            u = delayed_control(hist[r], p, th, beta, noise_scale, xi[r, k, 0])
            a = -gamma * om + alpha * math.sin(th) - u + floor_scale * xi[r, k, 1]
            th, om = euler_step(th, om, a, dt, semi_implicit)
            p = ring_next(p, d)
        state[r, 0] = th
        state[r, 1] = om
        p_out = p
    return p_out
