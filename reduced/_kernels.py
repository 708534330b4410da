"""Compiled hot loops of the reduced models (numba, cached, GIL released).

One kernel covers the single model (C = 1, eq. (3)) and the coupled
model (C = 2, eq. (5)): C controllers whose bases q_Mi are joined through a
common tip q_T,

    q_T''  + gamma q_T'  = (alpha / C) * sum_i e_i(t),       e_i = q_T - q_Mi
    q_Mi'' + gamma q_Mi' = beta * R_i(t) * e_i(t - tau),

and for C = 2 the first line is the paper's 2 q_T'' + 2 gamma q_T' = alpha (e_1 + e_2).

The delay is a ring buffer ``hist[r, i, :]`` of the last d = tau/dt values of
e_i.  At step n the slot ``p`` holds e_i at step n - d; it is read, then
overwritten with e_i at step n.  The random gain over step n is
R_{i,n} = 1 + noise_scale * xi[r, n, i], noise_scale = nu / sqrt(dt).  The law,
the ring and the recording rule are :mod:`cipcore.control_kernel`'s, the step
and the error coordinates' step :mod:`reduced._steps`', all inlined.

Steppers (``semi_implicit``, :func:`reduced._steps.euler_step`):
  * True: semi-implicit Euler as in MuJoCo's ``Euler`` integrator,
    v <- v + dt*a(x, v);  x <- x + dt*v(new).
  * False: explicit Euler–Maruyama, x <- x + dt*v;  v <- v + dt*a(x, v).

Loop order: both kernels loop over the realisations inside the loop over steps.  The
realisations' recurrences are independent, so the processor overlaps them, where one
realisation's steps form one chain of dependent operations (each balancing error needs
the last step's).  Each realisation's operations, and so its numbers, are those of the
loop the other way round, bit for bit.  Measured (8 realisations x 20 000 steps,
d = 100, one thread, idle): advance_positions 6.5 -> 2.9 ns per controller-step
(coupled) and 8.9 -> 4.4 (single), advance_errors 6.2 -> 3.8 and 11.2 -> 5.1.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cipcore.control_kernel import delayed_control, first_sample, ring_next, sample_slot

from ._steps import error_step, euler_step, record_balancer, renormalise


@njit(cache=True, nogil=True)
def advance_positions(
    xi: np.ndarray,
    state: np.ndarray,
    hist: np.ndarray,
    pos: int,
    law: tuple,
    semi_implicit: bool,
    n0: int,
    every: int,
    rec: np.ndarray,
) -> int:
    """Advance absolute positions over ``xi.shape[1]`` steps.

    Parameters
    ----------
    xi : (nb, n, C) standard normal draws for steps n0 .. n0+n-1.
    state : (nb, 2 + 2C) [q_T, v_T, q_M1, v_M1, ...], updated in place.
    hist : (nb, C, d) ring buffer of past balancing errors, updated in place.
    pos : ring-buffer slot holding e at step n0 - d (same for every realisation).
    law : (alpha (1/s^2), beta (1/s^2), gamma (1/s), noise_scale (nu / sqrt(dt)),
        dt (s)): :attr:`cipcore.params.BalanceParams.law`.
    n0, every : global index of the first step; a sample is recorded *before*
        every step whose global index is a multiple of ``every``.
    rec : (nb, S, C, 4) output samples [tip pos, tip vel, base pos, base vel];
        sample j holds global step ``(ceil(n0/every) + j) * every``.

    Returns
    -------
    The ring-buffer slot for the next call.
    """
    alpha, beta, gamma, noise_scale, dt = law
    nb, n, nc = xi.shape
    d = hist.shape[2]
    rec_start = first_sample(n0, every)
    nrec = rec.shape[1]
    p = pos
    # the realisations inside the steps (module docstring, Loop order)
    for k in range(n):
        j = sample_slot(n0 + k, every, rec_start, nrec)
        for r in range(nb):
            q_t = state[r, 0]
            v_t = state[r, 1]
            if j >= 0:
                for i in range(nc):
                    q_m, v_m = state[r, 2 + 2 * i], state[r, 3 + 2 * i]
                    record_balancer(rec, r, j, i, q_t, v_t, q_m, v_m)
            esum = 0.0
            for i in range(nc):
                q_m = state[r, 2 + 2 * i]
                v_m = state[r, 3 + 2 * i]
                e = q_t - q_m
                esum += e
                u = delayed_control(hist[r, i], p, e, beta, noise_scale, xi[r, k, i])
                q_m, v_m = euler_step(q_m, v_m, -gamma * v_m + u, dt, semi_implicit)
                state[r, 2 + 2 * i] = q_m
                state[r, 3 + 2 * i] = v_m
            a_t = -gamma * v_t + alpha * esum / nc
            q_t, v_t = euler_step(q_t, v_t, a_t, dt, semi_implicit)
            state[r, 0] = q_t
            state[r, 1] = v_t
        p = ring_next(p, d)
    return p


@njit(cache=True, nogil=True)
def advance_errors(
    xi: np.ndarray,
    y: np.ndarray,
    hist: np.ndarray,
    pos: int,
    law: tuple,
    semi_implicit: bool,
    n0: int,
    renorm_every: int,
    transient_steps: int,
    logsum: np.ndarray,
) -> int:
    """Advance the balancing errors (Lyapunov mode) with Benettin renormalisation.

    Integrates the error coordinates only (eq. (2) / (6)),

        e_i'' + gamma e_i' - (alpha / C) sum_j e_j + beta R_i(t) e_i(t - tau) = 0,

    which removes the neutral common drift of tip and bases (a direction in which
    the absolute positions grow freely and would swamp e with rounding noise),
    one :func:`reduced._steps.error_step` per step.  Every ``renorm_every`` steps
    the whole state, (e_i, e_i') and the delay history, is divided by its Euclidean
    norm (:func:`reduced._steps.renormalise`); after ``transient_steps`` the log of
    each norm is added to ``logsum[r]``.  The same discrete map as
    :func:`advance_positions` applied to e = q_T - q_M (the model is linear).

    y : (nb, 2C) [e_1, e_1', e_2, e_2', ...], updated in place;  logsum : (nb,) the
    running sum of the log norms after ``transient_steps``;  renormalisation after
    every global step count that is a multiple of ``renorm_every``; ``xi``,
    ``hist``, ``pos``, ``n0``, the other parameters and the returned slot as
    :func:`advance_positions`'.
    """
    nb, n, _ = xi.shape
    d = hist.shape[2]
    p = pos
    for k in range(n):  # the realisations inside the steps (module docstring)
        for r in range(nb):
            error_step(y[r], hist[r], p, xi[r, k], law, semi_implicit)
        p = ring_next(p, d)
        nk = n0 + k + 1
        if nk % renorm_every == 0:
            for r in range(nb):
                norm = renormalise(y[r], hist[r])
                if nk > transient_steps:
                    logsum[r] += math.log(norm)
    return p
