"""The exact solution of a linear system under piecewise-constant (zero-order-hold) input.

For x' = A x + B u with u held constant over each interval [t_k, t_k + h),
the state at the interval boundaries is exactly

    x_{k+1} = A_d x_k + B_d u_k,   A_d = exp(A h),   B_d = int_0^h exp(A s) ds B,

both read off one matrix exponential of the augmented matrix (Van Loan 1978)::

    exp([[A, B], [0, 0]] h) = [[A_d, B_d], [0, I]].

No time step of any integrator enters: this is the limit every consistent
stepper converges to as its step shrinks with the input held over the same
intervals, which is what :mod:`validation.checks.refinement` measures an engine
against.  Pure functions over numpy arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["DelayedFeedback", "zoh_delayed_feedback", "zoh_matrices", "zoh_response"]


def zoh_matrices(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_d, B_d) of x' = A x + B u over one interval of length ``h`` (s), u held.

    Parameters
    ----------
    a : (n, n) continuous state matrix (1/s).
    b : (n, m) continuous input matrix.
    h : the hold interval (s), > 0.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n, m = b.shape
    if a.shape != (n, n):
        raise ValueError(f"A must be ({n}, {n}) for B of shape {b.shape}, got {a.shape}")
    if not h > 0:
        raise ValueError(f"the hold interval h must be > 0 s, got {h!r}")
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a
    aug[:n, n:] = b
    e = scipy.linalg.expm(aug * h)
    return e[:n, :n], e[:n, n:]


def zoh_response(
    a: np.ndarray, b: np.ndarray, x0: np.ndarray, u: np.ndarray, h: float
) -> np.ndarray:
    """States after each hold interval: x_{k+1} = A_d x_k + B_d u_k (the exact solution).

    Parameters
    ----------
    a, b : continuous system matrices, (n, n) and (n, m).
    x0 : (R, n) initial states of R realisations.
    u : (R, K, m) inputs, ``u[:, k]`` held over interval k.
    h : the hold interval (s).

    Returns
    -------
    (R, K, n): the state at t = (k + 1) h for k = 0 .. K-1.
    """
    ad, bd = zoh_matrices(a, b, h)
    x = np.array(x0, dtype=float)
    u = np.asarray(u, dtype=float)
    out = np.empty((x.shape[0], u.shape[1], x.shape[1]))
    forced = u @ bd.T  # (R, K, n)
    for k in range(u.shape[1]):
        x = x @ ad.T + forced[:, k]
        out[:, k] = x
    return out


@dataclass(frozen=True)
class DelayedFeedback:
    """The paper's delayed random-gain controllers (eq. (5)) as one value.

    Parameters
    ----------
    errors : (C, n) the balancing errors' rows (m per state unit): e = errors @ x.
    inputs : (m, C) which input each controller's force drives.
    gain : M beta (N/m).
    noise_scale : nu / sqrt(h), the random gain's spread per unit draw.
    delay_steps : d = tau / h, >= 1.
    """

    errors: np.ndarray
    inputs: np.ndarray
    gain: float
    noise_scale: float
    delay_steps: int

    def __post_init__(self) -> None:
        if self.delay_steps < 1:
            raise ValueError(f"delay_steps must be >= 1, got {self.delay_steps!r}")


def zoh_delayed_feedback(
    ad: np.ndarray,
    bd: np.ndarray,
    x0: np.ndarray,
    loop: DelayedFeedback,
    *,
    xi: np.ndarray,
    e_before: np.ndarray,
) -> np.ndarray:
    """The exact sampled-data closed loop of the paper's eq. (5), forces held per interval.

    x_{k+1} = A_d x_k + B_d u_k with u_k = inputs @ f_k and, per controller i,
    f_{k,i} = gain (1 + noise_scale xi_{k,i}) e_{k-d,i}, e_j = errors @ x_j (m), the
    error before the start (j < 0) held at ``e_before``: the delayed random-gain
    feedback as :class:`cip.runner.CIPRunner` applies it, with the plant solved exactly
    over each hold interval (A_d, B_d from :func:`zoh_matrices`).

    Parameters
    ----------
    ad, bd : (n, n), (n, m) the discrete plant over one hold interval h.
    x0 : (R, n) initial states.
    loop : the controllers (errors, inputs, gain, noise scale, delay d).
    xi : (R, K, C) standard-normal draws, one per interval and controller.
    e_before : (R, C) the balancing errors held before t = 0 (m).

    Returns
    -------
    (R, K, n): the state at t = (k + 1) h for k = 0 .. K-1.
    """
    d, errors = loop.delay_steps, loop.errors
    x = np.array(x0, dtype=float)
    r, k_total, _ = xi.shape
    hist = np.empty((r, d + k_total, errors.shape[0]))
    hist[:, :d] = e_before[:, None]  # steps -d .. -1
    out = np.empty((r, k_total, x.shape[1]))
    for k in range(k_total):
        hist[:, d + k] = x @ errors.T  # step k
        f = loop.gain * (1.0 + loop.noise_scale * xi[:, k]) * hist[:, k]  # e at step k - d
        x = x @ ad.T + (f @ loop.inputs.T) @ bd.T
        out[:, k] = x
    return out
