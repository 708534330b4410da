"""Compiled loop of the beta* study: lambda1 of the reduced models under variants.

The same error-coordinate equations as :func:`reduced._kernels.advance_errors`
(paper eqs. (2) and (6), one kernel for C = 1 and C = 2 controllers),

    e_i'' + gamma e_i' - (alpha / C) sum_j e_j + beta R_i(t) e_i(t - tau) = 0,

with three things that kernel fixes made variable, for :mod:`reduced.beta_star`:

* the noise: one standardised draw per *hold* of ``hold`` steps, held over the
  hold (``hold = 1``: one draw per step, today's discretisation);
* the deterministic part: semi-implicit Euler (0, today's), explicit
  Euler-Maruyama (1) or Heun's predictor-corrector (2, second order for the
  deterministic part, the random gain held over the step in both stages);
* what is recorded: the running sum of the log renormalisation factors after
  the transient (today's Benettin estimate), their sum up to the transient, and
  at given steps the log norms of the renormalised state: the whole delay state,
  the state (e_i, e_i') of the paper's lambda1, the positions e_i, and the first
  balancer's (e_1, e_1').

With ``hold = 1`` and scheme 0 or 1 every operation is the one
:func:`reduced._kernels.advance_errors` performs, in the same order (both step
with :func:`reduced._steps.error_step` and renormalise with
:func:`reduced._steps.renormalise`), so the Benettin sums are equal to the bit
(``tests/test_beta_star_study.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cipcore.control_kernel import delayed_control, delayed_random_gain, ring_next

from ._steps import error_acceleration, error_step, error_sum, renormalise

#: the deterministic steppers, by the code the kernel takes
SCHEME_CODES = {"semi-implicit": 0, "explicit": 1, "heun": 2}
#: the columns of a record: the Benettin sum, then the log norms of the four norms
RECORD_COLUMNS = ("logsum", "delay-state", "state", "positions", "balancer-1")


@njit(inline="always", cache=True, nogil=True)
def _heun_step(y, hist, p, draws, model, work):
    """One Heun step: an explicit Euler predictor, then the trapezoid of the two slopes.

    The corrector reads the delayed error one step later, e_i(n + 1 - d), which the
    ring holds in the slot after ``p`` once e_i(n) is stored; the random gain is the
    same in both stages (held over the step).  Arguments as
    :func:`reduced._steps.error_step`'s; ``work`` is (4, C) scratch.
    """
    alpha, beta, gamma, scale, dt = model
    nc = hist.shape[0]
    d = hist.shape[1]
    pn = ring_next(p, d)
    esum = error_sum(y, nc)
    esum_p = 0.0
    for i in range(nc):
        e = y[2 * i]
        v = y[2 * i + 1]
        u = delayed_control(hist[i], p, e, beta, scale, draws[i])
        a = error_acceleration(v, esum, nc, alpha, gamma, u)
        work[0, i] = a
        work[1, i] = e + dt * v
        work[2, i] = v + dt * a
        esum_p += work[1, i]
    for i in range(nc):
        vp = work[2, i]
        u = delayed_random_gain(beta, scale, draws[i], hist[i, pn])
        a2 = error_acceleration(vp, esum_p, nc, alpha, gamma, u)
        y[2 * i] = y[2 * i] + 0.5 * dt * (y[2 * i + 1] + vp)
        y[2 * i + 1] = y[2 * i + 1] + 0.5 * dt * (work[0, i] + a2)


@njit(cache=True, nogil=True)
def log_norms(y: np.ndarray, hist: np.ndarray, out: np.ndarray) -> None:
    """The log Euclidean norms of one realisation's state into ``out`` (4,).

    ``out`` = [whole delay state (e_i, e_i', history), state (e_i, e_i'), positions
    e_i, first balancer (e_1, e_1')]; -inf for a norm that is exactly 0.
    """
    nc = hist.shape[0]
    pos = 0.0
    vel = 0.0
    for i in range(nc):
        pos += y[2 * i] * y[2 * i]
        vel += y[2 * i + 1] * y[2 * i + 1]
    past = 0.0
    for i in range(nc):
        for m in range(hist.shape[1]):
            past += hist[i, m] * hist[i, m]
    first = y[0] * y[0] + y[1] * y[1]
    sums = (pos + vel + past, pos + vel, pos, first)
    for j in range(4):
        out[j] = 0.5 * math.log(sums[j]) if sums[j] > 0.0 else -np.inf


@njit(cache=True, nogil=True)
def advance_variant(
    xi: np.ndarray,
    hold: int,
    y: np.ndarray,
    hist: np.ndarray,
    pos: int,
    coef: np.ndarray,
    scheme: int,
    steps: np.ndarray,
    marks: np.ndarray,
    rec: np.ndarray,
    sums: np.ndarray,
) -> int:
    """Advance the error coordinates ``xi.shape[1] * hold`` steps with renormalisation.

    Parameters
    ----------
    xi : (nb, H, C) standardised draws, one per hold of ``hold`` steps.
    hold : steps each draw is held.
    y : (nb, 2C) [e_1, e_1', e_2, e_2', ...];  hist : (nb, C, d) delay rings.
    pos : ring slot of the first step (global step n0 mod d).
    coef : [alpha (1/s^2), beta (1/s^2), gamma (1/s), noise scale nu/sqrt(hold time)
        (s^-1/2 per unit draw), dt (s)].
    scheme : :data:`SCHEME_CODES`.
    steps : [n0 (global index of the first step), renormalisation interval in steps,
        transient in steps].
    marks : sorted global step counts (multiples of the interval) where ``rec`` is written.
    rec : (nb, len(marks), 5): at each mark the Benettin sum so far and :func:`log_norms`.
    sums : (nb, 2): [sum of log norms after the transient, sum up to the transient].

    Returns
    -------
    The ring slot for the next call.
    """
    nb, nh, nc = xi.shape
    d = hist.shape[2]
    model = (coef[0], coef[1], coef[2], coef[3], coef[4])
    n0, every, transient = steps[0], steps[1], steps[2]
    first = np.searchsorted(marks, n0, side="right")
    work = np.empty((4, nc))
    p = pos
    for r in range(nb):
        p = pos
        jm = first
        for k in range(nh * hold):
            if scheme == 2:
                _heun_step(y[r], hist[r], p, xi[r, k // hold], model, work)
            else:
                error_step(y[r], hist[r], p, xi[r, k // hold], model, scheme != 1)
            p = ring_next(p, d)
            nk = n0 + k + 1
            if nk % every == 0:
                norm = renormalise(y[r], hist[r])
                if nk > transient:
                    sums[r, 0] += math.log(norm)
                else:
                    sums[r, 1] += math.log(norm)
                if jm < marks.size and marks[jm] == nk:
                    rec[r, jm, 0] = sums[r, 0]
                    log_norms(y[r], hist[r], rec[r, jm, 1:])
                    jm += 1
    return p
