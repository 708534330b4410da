"""Noise-free (nu = 0) stability of the reduced models.

With R = 1 the balancing errors obey linear delay equations (paper eqs.
(2) and (6)),  y'(t) = A0 y(t) + A1 y(t - tau), whose
characteristic equation is det(s I - A0 - A1 exp(-s tau)) = 0:

* single, y = (e, e'):  s^2 + gamma s - alpha + beta exp(-s tau) = 0
* coupled, y = (e1, e1', e2, e2'): the sum e1 + e2 obeys the single equation
  and the difference e1 - e2 obeys e'' + gamma e' + beta e(t - tau) = 0, so

      (s^2 + gamma s - alpha + beta e^{-s tau}) (s^2 + gamma s + beta e^{-s tau}) = 0.

Roots are found by the spectral (Chebyshev collocation) discretisation of the
infinitesimal generator of the delay equation [1], then each candidate is
polished by Newton's method on det Delta(s).  The rightmost root's real part
is the largest Lyapunov exponent of the noise-free error dynamics.

The time-stepped model (step dt) is a linear map on the state plus its delay
history; :func:`discrete_exponent` gives its exact exponent
log(spectral radius) / dt, which the simulation must reproduce to rounding.

References
----------
.. [1] D. Breda, S. Maset, R. Vermiglio, "Pseudospectral differencing methods
   for characteristic roots of delay differential equations", SIAM J. Sci.
   Comput. 27 (2005) 482-495.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from cipcore.models import get_model
from cipcore.params import BalanceParams, ParameterError


def delay_system(model: str, params: BalanceParams) -> tuple[np.ndarray, np.ndarray]:
    """Matrices (A0, A1) of y' = A0 y(t) + A1 y(t - tau) for the errors, nu = 0.

    y = (e_1, e_1', ..., e_C, e_C'); units 1/s (velocity rows: 1/s^2 entries).
    """
    nc = get_model(model).n_controllers
    a, b, g = params.alpha, params.beta, params.gamma
    n = 2 * nc
    a0 = np.zeros((n, n))
    a1 = np.zeros((n, n))
    for i in range(nc):
        a0[2 * i, 2 * i + 1] = 1.0
        a0[2 * i + 1, 2 * i + 1] = -g
        for j in range(nc):
            a0[2 * i + 1, 2 * j] += a / nc
        a1[2 * i + 1, 2 * i] = -b
    return a0, a1


def characteristic_function(model: str, params: BalanceParams, s: complex | np.ndarray):
    """The quasi-polynomial(s) whose zeros are the characteristic roots.

    Single: s^2 + gamma s - alpha + beta e^{-s tau}; coupled: the product of
    that with s^2 + gamma s + beta e^{-s tau} (module docstring).
    """
    s = np.asarray(s, dtype=complex)
    g, a, b, tau = params.gamma, params.alpha, params.beta, params.tau
    p_sum = s**2 + g * s - a + b * np.exp(-s * tau)
    if get_model(model).n_controllers == 1:
        return p_sum
    return p_sum * (s**2 + g * s + b * np.exp(-s * tau))


def _cheb(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Chebyshev points x_j = cos(pi j / n) on [-1, 1] and differentiation matrix (Trefethen)."""
    x = np.cos(np.pi * np.arange(n + 1) / n)
    c = np.hstack([2.0, np.ones(n - 1), 2.0]) * (-1.0) ** np.arange(n + 1)
    dx = x[:, None] - x[None, :]
    d = np.outer(c, 1.0 / c) / (dx + np.eye(n + 1))
    d -= np.diag(d.sum(axis=1))
    return x, d


@dataclass(frozen=True)
class Roots:
    """Characteristic roots (1/s), sorted by decreasing real part; upper half-plane only."""

    roots: np.ndarray

    @property
    def rightmost(self) -> complex:
        return complex(self.roots[0])

    @property
    def abscissa(self) -> float:
        """Spectral abscissa max Re(s) in 1/s: the noise-free Lyapunov exponent."""
        return float(self.roots[0].real)


def characteristic_roots(
    model: str, params: BalanceParams, n_nodes: int = 48, n_roots: int = 8
) -> Roots:
    """Rightmost characteristic roots of the noise-free model (1/s).

    Spectral discretisation of the generator on [-tau, 0] with ``n_nodes``
    Chebyshev intervals, then Newton polishing on det(s I - A0 - A1 e^{-s tau}).
    Complex-conjugate pairs are reported once (Im >= 0).
    """
    a0, a1 = delay_system(model, params)
    tau = params.tau
    m = a0.shape[0]
    _, dmat = _cheb(n_nodes)
    dmat = dmat * (2.0 / tau)  # theta = tau/2 (x - 1) maps [-1, 1] onto [-tau, 0]
    big = np.kron(dmat, np.eye(m))
    # row block 0 (theta = 0) carries the dynamics: y'(0) = A0 y(0) + A1 y(-tau)
    big[:m, :] = 0.0
    big[:m, :m] = a0
    big[:m, -m:] = a1
    eig = scipy.linalg.eigvals(big)
    eig = eig[np.argsort(-eig.real)]
    cands = eig[eig.imag >= -1e-9][: 4 * n_roots]
    polished = [_newton(a0, a1, tau, s) for s in cands]
    roots = np.array([s for s in polished if s is not None and np.isfinite(s)])
    if roots.size == 0:  # e.g. beta = 1e300: the generator's eigenvalues overflow float64
        raise ParameterError(
            f"no characteristic root of the {model} model converged at alpha {params.alpha:g}, "
            f"beta {params.beta:g}, gamma {params.gamma:g} (1/s^2, 1/s^2, 1/s), tau "
            f"{params.tau:g} s: the gains are beyond what float64 resolves"
        )
    roots = roots.real + 1j * np.abs(roots.imag)
    roots = _unique(roots[np.argsort(-roots.real)])
    return Roots(roots[:n_roots])


def _newton(a0: np.ndarray, a1: np.ndarray, tau: float, s: complex, iters: int = 50):
    """Newton on det Delta(s), Delta = s I - A0 - A1 e^{-s tau}, via tr(Delta^-1 Delta')."""
    eye = np.eye(a0.shape[0])
    for _ in range(iters):
        ex = np.exp(-s * tau)
        delta = s * eye - a0 - a1 * ex
        ddelta = eye + tau * a1 * ex
        try:
            step = 1.0 / np.trace(np.linalg.solve(delta, ddelta))
        except np.linalg.LinAlgError:
            return s  # exactly singular: s is a root
        s = s - step
        if abs(step) < 1e-13 * max(1.0, abs(s)):
            return s
    return None


def _unique(z: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    out: list[complex] = []
    for v in z:
        if all(abs(v - w) > tol * max(1.0, abs(v)) for w in out):
            out.append(v)
    return np.array(out)


def rightmost_root(model: str, params: BalanceParams) -> complex:
    """The rightmost characteristic root (1/s) of the noise-free model."""
    return characteristic_roots(model, params).rightmost


def discrete_exponent(model: str, params: BalanceParams, stepper: str = "semi-implicit") -> float:
    """Exact Lyapunov exponent (1/s) of the time-stepped noise-free model.

    Builds the linear one-step map of (y, delay history) used by
    :func:`reduced._kernels.advance_errors` and returns log(rho) / dt, rho its
    spectral radius.  Converges to the rightmost root's real part as dt -> 0.
    """
    a0, a1 = delay_system(model, params)
    m = a0.shape[0]
    nc = m // 2
    d = params.delay_steps
    h = params.dt
    # state z = (y_n, e_{n-1}, ..., e_{n-d}) with e_{n-k} a C-vector
    size = m + nc * d
    f = np.zeros((size, size))
    # acceleration rows: a = A0[vel rows] y + A1[vel rows] e_{n-d}
    pos = np.arange(nc) * 2
    vel = pos + 1
    acc_y = a0[vel, :]
    acc_del = a1[np.ix_(vel, pos)]
    hist_last = m + nc * (d - 1)
    semi = stepper == "semi-implicit"
    for i in range(nc):
        # v_new = v + h a
        f[vel[i], :m] = np.eye(m)[vel[i]] + h * acc_y[i]
        f[vel[i], hist_last : hist_last + nc] += h * acc_del[i]
        if semi:
            f[pos[i]] = np.eye(size)[pos[i]] + h * f[vel[i]]
        else:
            f[pos[i], pos[i]] = 1.0
            f[pos[i], vel[i]] = h
    # shift the history: new e_{n} slot <- current e (positions of y)
    for i in range(nc):
        f[m + i, pos[i]] = 1.0
    for k in range(1, d):
        for i in range(nc):
            f[m + nc * k + i, m + nc * (k - 1) + i] = 1.0
    rho = np.max(np.abs(np.linalg.eigvals(f)))
    return float(np.log(rho) / h)


def stability_region(
    model: str,
    base: BalanceParams,
    betas: np.ndarray,
    taus: np.ndarray,
) -> np.ndarray:
    """Spectral abscissa (1/s) on a (tau, beta) grid; negative means stable.

    Returns an array shaped (len(taus), len(betas)).  ``dt`` of ``base`` is
    ignored for the continuous-time roots (tau need not be a multiple of it).
    """
    out = np.empty((len(taus), len(betas)))
    for i, tau in enumerate(taus):
        for j, beta in enumerate(betas):
            p = BalanceParams(
                beta=float(beta), alpha=base.alpha, gamma=base.gamma, nu=0.0,
                tau=float(tau), dt=float(tau) / 100,
            )  # fmt: skip
            out[i, j] = characteristic_roots(model, p, n_nodes=32, n_roots=1).abscissa
    return out
