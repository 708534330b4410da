"""The steps the reduced models' kernels share (numba, inlined; cached with their callers).

* :func:`euler_step`: one step of x'' = a with a held over the step, the
  semi-implicit Euler of MuJoCo's ``Euler`` integrator (v <- v + dt a, then
  x <- x + dt v(new)) or explicit Euler–Maruyama (x <- x + dt v, then
  v <- v + dt a); :mod:`reduced._kernels`, :mod:`reduced._nonlinear_kernel`,
  :mod:`reduced._twin_kernel` and the warp kernel of :mod:`reduced.gpu` (which
  compiles the same function with ``wp.func``) step with it;
* :func:`record_balancer`: one balancer's sample [tip pos, tip vel, base pos,
  base vel] (m, m/s), the layout :func:`reduced.simulate.record_fields` reads;
* the error coordinates of paper eqs. (2) and (6), one realisation,

      e_i'' + gamma e_i' - (alpha / C) sum_j e_j + beta R_i(t) e_i(t - tau) = 0:

  :func:`error_sum`, :func:`error_acceleration`, :func:`error_step` (one
  Euler step of every balancer) and :func:`renormalise` (Benettin's division by
  the norm of the whole delay state), shared by
  :func:`reduced._kernels.advance_errors` and
  :func:`reduced._beta_star_kernel.advance_variant`, so that their Benettin sums
  are equal to the bit.

numba caches a kernel by its own file only: after editing this module, clear
``reduced/__pycache__`` to recompile the kernels that inline it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from cipcore.control_kernel import delayed_control


@njit(inline="always", cache=True, nogil=True)
def euler_step(x: Any, v: Any, a: Any, dt: Any, semi_implicit: Any):
    """One Euler step of (x, v) under the acceleration ``a`` (held over the step).

    Parameters
    ----------
    x, v : position (m or rad) and its rate at the start of the step.
    a : acceleration at the start of the step (m/s^2 or rad/s^2).
    dt : the step (s).
    semi_implicit : true for v <- v + dt a, x <- x + dt v(new) (MuJoCo's
        ``Euler``); false for x <- x + dt v, v <- v + dt a (Euler–Maruyama).

    Returns
    -------
    (x, v) at the end of the step.  Annotated ``Any`` so that warp instantiates
    it in the kernel's precision.
    """
    if semi_implicit:
        v = v + dt * a
        x = x + dt * v
    else:
        x = x + dt * v
        v = v + dt * a
    return x, v


@njit(inline="always", cache=True, nogil=True)
def record_balancer(
    rec: Any, r: Any, j: Any, i: Any, tip_pos: Any, tip_vel: Any, base_pos: Any, base_vel: Any
):
    """Write balancer ``i``'s sample into ``rec[r, j, i]`` (4,): [tip pos, tip vel, base pos,
    base vel] (m, m/s), realisation ``r``, sample row ``j``."""
    rec[r, j, i, 0] = tip_pos
    rec[r, j, i, 1] = tip_vel
    rec[r, j, i, 2] = base_pos
    rec[r, j, i, 3] = base_vel


@njit(inline="always", cache=True, nogil=True)
def error_sum(y: np.ndarray, nc: int) -> float:
    """sum_j e_j (m) of one realisation's error state y (2C,) [e_1, e_1', e_2, e_2', ...]."""
    esum = 0.0
    for i in range(nc):
        esum += y[2 * i]
    return esum


@njit(inline="always", cache=True, nogil=True)
def error_acceleration(
    v: float, esum: float, nc: int, alpha: float, gamma: float, u: float
) -> float:
    """e_i'' = -gamma e_i' + (alpha / C) sum_j e_j - u_i (m/s^2), u_i the delayed control."""
    return -gamma * v + alpha * esum / nc - u


@njit(inline="always", cache=True, nogil=True)
def error_step(
    y: np.ndarray, hist: np.ndarray, p: int, xi: np.ndarray, model: tuple, semi_implicit: bool
) -> None:
    """One Euler step (:func:`euler_step`) of every balancer's (e_i, e_i') in place.

    y : (2C,) [e_1, e_1', e_2, e_2', ...];  hist : (C, d) delay rings, slot ``p``
    holding e_i at step n - d (:func:`cipcore.control_kernel.delayed_control`);
    xi : (C,) the draws of step n;  model : (alpha, beta (1/s^2), gamma (1/s),
    noise_scale (nu / sqrt(dt)), dt (s)).  The coupling sum is taken before any
    balancer moves.
    """
    alpha, beta, gamma, noise_scale, dt = model
    nc = hist.shape[0]
    esum = error_sum(y, nc)
    for i in range(nc):
        e = y[2 * i]
        v = y[2 * i + 1]
        u = delayed_control(hist[i], p, e, beta, noise_scale, xi[i])
        a = error_acceleration(v, esum, nc, alpha, gamma, u)
        e, v = euler_step(e, v, a, dt, semi_implicit)
        y[2 * i] = e
        y[2 * i + 1] = v


@njit(inline="always", cache=True, nogil=True)
def renormalise(y: np.ndarray, hist: np.ndarray) -> float:
    """Divide one realisation's whole delay state, y (2C,) and hist (C, d), by its
    Euclidean norm (the squares summed over y, then the rings in order) and return
    the norm; a norm that is not finite and positive (the state overflowed float64 within
    one interval) is returned with the state left as it is."""
    nc = hist.shape[0]
    d = hist.shape[1]
    s = 0.0
    for m in range(2 * nc):
        s += y[m] * y[m]
    for i in range(nc):
        for m in range(d):
            s += hist[i, m] * hist[i, m]
    norm = math.sqrt(s)
    if not (norm > 0.0 and norm < math.inf):  # overflowed (or nan): left for the caller
        return norm
    inv = 1.0 / norm
    for m in range(2 * nc):
        y[m] *= inv
    for i in range(nc):
        for m in range(d):
            hist[i, m] *= inv
    return norm
