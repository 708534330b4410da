"""Compiled loop of the paper's nonlinear stick, eq. (1) (numba, cached, GIL released).

    theta'' + gamma theta' - alpha sin(theta) + beta R(t) theta(t - tau) = sigma eta(t)

with R_n = 1 + noise_scale * xi[r, n, 0] held over step n, and an optional
additive noise floor sigma eta(t), held over the step as floor_scale *
xi[r, n, 1] (floor_scale = sigma / sqrt(dt), Euler–Maruyama).  The delay is a
ring buffer of the last d = tau/dt angles, read then overwritten at each step,
exactly as in the linear kernel (both use :mod:`cipcore.control_kernel`), so
for |theta| << 1 and sigma = 0 the map is the linear single model's map for its
balancing error (eq. (2)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cipcore.control_kernel import (
    delayed_random_gain,
    first_sample,
    ring_exchange,
    ring_next,
    sample_slot,
)


@njit(cache=True, nogil=True)
def advance_angle(
    xi: np.ndarray,
    state: np.ndarray,
    hist: np.ndarray,
    pos: int,
    alpha: float,
    beta: float,
    gamma: float,
    noise_scale: float,
    floor_scale: float,
    dt: float,
    semi_implicit: bool,
    n0: int,
    every: int,
    rec: np.ndarray,
) -> int:
    """Advance (theta, theta') of each realisation over ``xi.shape[1]`` steps.

    xi : (nb, n, 2) draws [gain, floor]; state : (nb, 2) updated in place;
    hist : (nb, d) ring buffer; rec : (nb, S, 2) samples [theta, theta'] recorded
    before every step whose global index is a multiple of ``every``.
    Returns the ring-buffer slot for the next call.
    """
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
            th_delayed = ring_exchange(hist[r], p, th)
            a = (
                -gamma * om
                + alpha * math.sin(th)
                - delayed_random_gain(beta, noise_scale, xi[r, k, 0], th_delayed)
                + floor_scale * xi[r, k, 1]
            )
            if semi_implicit:
                om = om + dt * a
                th = th + dt * om
            else:
                th = th + dt * om
                om = om + dt * a
            p = ring_next(p, d)
        state[r, 0] = th
        state[r, 1] = om
        p_out = p
    return p_out
