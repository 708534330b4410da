"""Compiled loop of the exact linear twin (numba, cached, GIL released).

See :mod:`reduced.twin` for the equations.  Generalised coordinates per
balancer i: the cart position x_i (m) and the balancing error e_i = L theta_i (m),
with rates v_i, w_i = e_i'.  All forces are per unit cart mass M (m/s^2).
One step is one of MuJoCo's integrators (``mjModel.opt.integrator``), as its
``mj_Euler``, ``mj_implicit`` and ``mj_RungeKutta`` define them:

* ``Euler`` (scheme 0): accelerations a = M^-1 (f + J^T lambda) from the current
  state, then v <- v + h a, q <- q + h v(new) (semi-implicit,
  :func:`reduced._steps.euler_step`);
* ``implicit`` / ``implicitfast`` (scheme 1): the constraint force lambda as for
  Euler, then a = (M - h D)^-1 (f + J^T lambda), D = d f / d v the velocity
  derivative of the smooth forces (here the affine-bias dampers; the Coriolis
  terms that ``implicit`` adds are of second order in the angles about upright),
  then the same update;
* ``RK4`` (scheme 2): the classical four-stage Runge-Kutta method on (q, v) with
  the control held over the step and the constraint force recomputed at every
  stage.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cipcore.control_kernel import delayed_control, first_sample, ring_next, sample_slot

from ._steps import euler_step, record_balancer
from ._twin_schemes import apply_rod_force, merson_step, newmark_step, tip_separation


@njit(cache=True, nogil=True)
def _accelerations(
    st: np.ndarray,
    u: np.ndarray,
    coef: np.ndarray,
    minv: np.ndarray,
    mstep: np.ndarray,
    ax: np.ndarray,
    ae: np.ndarray,
) -> None:
    """Accelerations (m/s^2) of one realisation's state ``st`` (C, 4) under controls ``u`` (C,).

    The rod's force is MuJoCo's soft-constraint solution with the explicit mass
    matrix (``minv``); the accelerations are ``mstep`` (M^-1, or (M - h D)^-1 for
    the implicit integrators) applied to the smooth forces plus the rod's.
    """
    nc = st.shape[0]
    alpha, g_tip, g_cart, mu = coef[0], coef[1], coef[2], coef[3]
    rod = coef[7] > 0.5 and nc == 2
    k_rod, b_rod, a_rod, r_rod = coef[8], coef[9], coef[10], coef[11]
    # the rod's unconstrained tip-separation acceleration a0, summed as the loop goes
    # (no scratch arrays: this runs at every step and every RK stage)
    a0 = 0.0
    for i in range(nc):
        e, v, w = st[i, 1], st[i, 2], st[i, 3]
        tip_drag = g_tip * mu * (v + w)
        qx = u[i] - g_cart * v - tip_drag
        qe = mu * alpha * e - tip_drag
        ax[i] = mstep[0, 0] * qx + mstep[0, 1] * qe
        ae[i] = mstep[1, 0] * qx + mstep[1, 1] * qe
        sgn = 1.0 if i == 0 else -1.0
        a0 += sgn * ((minv[0, 0] * qx + minv[0, 1] * qe) + (minv[1, 0] * qx + minv[1, 1] * qe))
    if rod:
        # soft equality on the tip separation: J = (+1, +1, -1, -1) in (x1, e1, x2, e2)
        sep, sep_rate = tip_separation(st)
        aref = -b_rod * sep_rate - k_rod * sep
        f = (aref - a0) / (a_rod + r_rod)
        apply_rod_force(mstep, f, ax, ae)


@njit(cache=True, nogil=True)
def _rk4_step(st: np.ndarray, u: np.ndarray, coef: np.ndarray, minv: np.ndarray, h: float) -> None:
    """One classical RK4 step of ``st`` (C, 4) in place, control held (``mj_RungeKutta``)."""
    nc = st.shape[0]
    y0 = st.copy()
    y = st.copy()
    ax = np.empty(nc)
    ae = np.empty(nc)
    dq = np.zeros((nc, 2))
    dv = np.zeros((nc, 2))
    stage = (0.5, 0.5, 1.0)
    weight = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)
    for j in range(4):
        _accelerations(y, u, coef, minv, minv, ax, ae)
        for i in range(nc):
            dq[i, 0] += weight[j] * y[i, 2]
            dq[i, 1] += weight[j] * y[i, 3]
            dv[i, 0] += weight[j] * ax[i]
            dv[i, 1] += weight[j] * ae[i]
        if j < 3:
            c = stage[j] * h
            for i in range(nc):
                y[i, 0] = y0[i, 0] + c * y[i, 2]
                y[i, 1] = y0[i, 1] + c * y[i, 3]
                y[i, 2] = y0[i, 2] + c * ax[i]
                y[i, 3] = y0[i, 3] + c * ae[i]
    for i in range(nc):
        st[i, 0] = y0[i, 0] + h * dq[i, 0]
        st[i, 1] = y0[i, 1] + h * dq[i, 1]
        st[i, 2] = y0[i, 2] + h * dv[i, 0]
        st[i, 3] = y0[i, 3] + h * dv[i, 1]


@njit(inline="always", cache=True, nogil=True)
def _advance(
    xi: np.ndarray,
    state: np.ndarray,
    hist: np.ndarray,
    pos: int,
    coef: np.ndarray,
    minv: np.ndarray,
    mstep: np.ndarray,
    scheme: int,
    n0: int,
    every: int,
    rec: np.ndarray,
) -> int:
    """Advance the twin over ``xi.shape[1]`` steps; ``xi``, ``hist``, ``pos``, ``n0``,
    ``every``, ``rec`` and the returned slot as :func:`reduced._kernels.advance_positions`'.

    Parameters
    ----------
    state : (nb, C, 4) [x, e, v, w] per balancer, updated in place.
    coef : [alpha, gamma_tip, gamma_cart, mass_ratio, beta, noise_scale, dt,
        rod (0/1), rod_stiffness k*imp (1/s^2), rod_damping b (1/s),
        rod_mobility A (per unit M), rod_regulariser R (per unit M)].
    minv : (2, 2) inverse of the per-unit-cart-mass mass matrix
        [[1 + mu, mu], [mu, mu (1 + kappa)]] in (x, e).
    mstep : (2, 2) the matrix the step applies to the forces: ``minv`` (Euler,
        RK4), (M - h D)^-1 (implicit, implicitfast) or (M - (h^2/2) K)^-1 (Newmark).
    scheme : 0 Euler, 1 implicit / implicitfast, 2 RK4 (module docstring); 3 Newmark,
        4 RK-Merson (:mod:`reduced._twin_schemes`).
    """
    nb, n, nc = xi.shape
    d = hist.shape[2]
    beta, s_noise, h = coef[4], coef[5], coef[6]
    rec_start = first_sample(n0, every)
    nrec = rec.shape[1]
    ax = np.empty(nc)
    ae = np.empty(nc)
    u = np.empty(nc)
    p_out = pos
    for r in range(nb):
        p = pos
        for k in range(n):
            j = sample_slot(n0 + k, every, rec_start, nrec)
            if j >= 0:
                for i in range(nc):
                    x, e, v, w = state[r, i, 0], state[r, i, 1], state[r, i, 2], state[r, i, 3]
                    record_balancer(rec, r, j, i, x + e, v + w, x, v)
            for i in range(nc):
                u[i] = delayed_control(hist[r, i], p, state[r, i, 1], beta, s_noise, xi[r, k, i])
            # the scheme's step (written here, not through an inlined helper: numba's
            # inlining of a helper for it made the loop 2.7 times slower)
            if scheme == 2:
                _rk4_step(state[r], u, coef, minv, h)
            elif scheme == 3:
                newmark_step(state[r], u, coef, mstep, h)
            elif scheme == 4:
                merson_step(state[r], u, coef, minv, h)
            else:
                _accelerations(state[r], u, coef, minv, mstep, ax, ae)
                for i in range(nc):
                    st = state[r, i]
                    st[0], st[2] = euler_step(st[0], st[2], ax[i], h, True)
                    st[1], st[3] = euler_step(st[1], st[3], ae[i], h, True)
            p = ring_next(p, d)
        p_out = p
    return p_out


@njit(cache=True, nogil=True)
def _renormalise(st: np.ndarray, hist: np.ndarray, rates: np.ndarray, epsilon: float) -> float:
    """Benettin's renormalisation of one realisation in place; returns the norm before it.

    The norm (m), all terms in m or m/s, of the state ``st`` (C, 4) = [x, e, v, e'] per
    balancer, the delayed errors ``hist`` and their rates ``rates`` (C, d)::

        sqrt( sum_i (x_i - mean_j x_j)^2 + e_i^2 + v_i^2 + e_i'^2
              + sum over the delay buffer of e_i^2 + e_i'^2 ),

    then the carts' common drift is dropped and everything is scaled by epsilon / norm
    (left as it is where the norm is not finite).
    """
    nc, d = hist.shape
    mean = 0.0
    for i in range(nc):
        mean += st[i, 0]
    mean /= nc
    s = 0.0
    for i in range(nc):
        s += (st[i, 0] - mean) ** 2
    for i in range(nc):
        for c in range(1, 4):
            s += st[i, c] ** 2
    for i in range(nc):
        for j in range(d):
            s += hist[i, j] ** 2 + rates[i, j] ** 2
    norm = np.sqrt(s)
    if not np.isfinite(norm):
        return norm
    c = epsilon / norm
    for i in range(nc):
        st[i, 0] -= mean
        for q in range(4):
            st[i, q] *= c
        for j in range(d):
            hist[i, j] *= c
            rates[i, j] *= c
    return norm


@njit(cache=True, nogil=True)
def renormalise_twin(state: np.ndarray, hist: np.ndarray, rates: np.ndarray,
                     epsilon: float) -> None:  # fmt: skip
    """:func:`_renormalise` of every realisation of ``state`` (R, C, 4), ``hist`` and
    ``rates`` (R, C, d)."""
    for r in range(state.shape[0]):
        _renormalise(state[r], hist[r], rates[r], epsilon)


@njit(inline="always", cache=True, nogil=True)
def _benettin(
    xi: np.ndarray,
    state: np.ndarray,
    hist: np.ndarray,
    rates: np.ndarray,
    coef: np.ndarray,
    minv: np.ndarray,
    mstep: np.ndarray,
    scheme: int,
    n0: int,
    transient_steps: int,
    epsilon: float,
    logsum: np.ndarray,
) -> int:
    """Benettin's method on the twin over ``xi.shape[1]`` steps from global step ``n0``
    (a multiple of d).

    Each realisation advances by :func:`_advance` a delay (d steps) at a time, the
    last stretch of the run maybe shorter (each stretch starts at ring slot 0, as step
    n0 + a, a multiple of d, does); ``rates`` (R, C, d) then
    holds the balancing error's rates e' (m/s) at the last d steps in time order (the
    recorded tip velocity less the cart's, as the engine's buffer holds them).  After
    each stretch the deviation is renormalised (:func:`_renormalise`: scaled back to
    ``epsilon``, the carts' common drift dropped) and log(norm / ``epsilon``) is added to
    ``logsum`` (R,) once the run is past ``transient_steps``.  Returns the global step
    after which a realisation's norm was first not finite, else -1 (the state is then
    left as it was).
    """
    nb, n, nc = xi.shape
    d = hist.shape[2]
    rec = np.empty((1, d, nc, 4))
    for r in range(nb):
        for a in range(0, n, d):
            m = min(d, n - a)
            _advance(xi[r : r + 1, a : a + m], state[r : r + 1], hist[r : r + 1],
                     0, coef, minv, mstep, scheme, 0, 1, rec)  # fmt: skip
            for i in range(nc):
                for j in range(d - m):
                    rates[r, i, j] = rates[r, i, j + m]
                for j in range(m):
                    rates[r, i, d - m + j] = rec[0, j, i, 1] - rec[0, j, i, 3]
            done = n0 + a + m
            norm = _renormalise(state[r], hist[r], rates[r], epsilon)
            if not np.isfinite(norm):
                return done
            if done > transient_steps:
                logsum[r] += np.log(norm / epsilon)
    return -1


def _kernels_for(scheme: int) -> tuple:
    """(advance_twin, benettin_twin) compiled for one scheme (:data:`KERNELS`): the
    arguments of :func:`_advance` and :func:`_benettin` less ``scheme``.  Each kernel has a
    name of its own (``advance_twin_scheme<k>``), so that numba caches every scheme in
    files of its own: closures sharing a name share one cache index, which two
    processes compiling different schemes at once could leave pointing at the wrong
    scheme's code."""
    A = np.ndarray

    def advance_twin(xi: A, state: A, hist: A, pos: int, coef: A, minv: A, mstep: A, n0: int,
                     every: int, rec: A) -> int:  # fmt: skip
        return _advance(xi, state, hist, pos, coef, minv, mstep, scheme, n0, every, rec)

    def benettin_twin(xi: A, state: A, hist: A, rates: A, coef: A, minv: A, mstep: A, n0: int,
                      transient_steps: int, epsilon: float, logsum: A) -> int:  # fmt: skip
        return _benettin(xi, state, hist, rates, coef, minv, mstep, scheme, n0, transient_steps,
                         epsilon, logsum)  # fmt: skip

    kernels = []
    for fn in (advance_twin, benettin_twin):
        fn.__qualname__ = fn.__name__ = f"{fn.__name__}_scheme{scheme}"
        kernels.append(njit(cache=True, nogil=True)(fn))
    return tuple(kernels)


#: The twin's kernels per scheme code (``reduced.twin.TWIN_SCHEMES``): ``KERNELS[scheme]``
#: is (advance_twin, benettin_twin), :func:`_advance` and :func:`_benettin` with the
#: scheme a constant of the kernel, so that numba drops the other schemes' branches and
#: compiles only the steps a run uses (a first run after install with MuJoCo's ``Euler``
#: skips RK4, Newmark and RK-Merson: 2.4 s of the 4.4 s it compiled, numba's timers;
#: the numbers are the generic loop's, bit for bit).  Each kernel is cached on its own
#: (numba keys a closure's cache entry by its constants).
KERNELS = tuple(_kernels_for(scheme) for scheme in range(5))
