"""Independent anchors for the code the engines and the reference share.

The full model and the reduced model are driven by the same parameter object
(:class:`cipcore.params.BalanceParams`) and the same noise
(:mod:`cipcore.noise`); a mistake there moves both alike and no full-vs-reduced
comparison can see it.  Each anchor here compares shared code with something
outside it:

* ``anchor.paper_constants``: the shared defaults alpha, gamma, nu, tau equal
  the paper's literal values (section 2.2: alpha = 22, gamma = 50, nu = 0.6,
  tau = 0.1), written here as literals, exactly;
* ``anchor.gain_variance``: the held random gain R_k = 1 + noise_scale xi_k the
  engines apply (``BalanceParams.noise_scale`` times :class:`GainNoise` draws)
  has mean 1 and variance nu^2 / dt (R(t) = 1 + nu xi(t) of section 2.1, Euler–Maruyama) with the
  literal nu and dt: sample mean and variance of ``GAIN_STEPS`` draws per
  controller, judged by their exact 99.9 % intervals (Student t for the mean,
  chi-square for the variance; false-failure rate 0.1 % per statistic);
* ``anchor.stability_boundary.<model>``: the noise-free stability boundary
  beta_c (lower end of the stable gains) of the reduced model, from its
  characteristic roots (:func:`reduced.stability.characteristic_roots`, a
  zero of the spectral abscissa), against the boundary of the linearised full
  model read from the model file (the gain at which the closed loop x' = A x
  + beta B K x(t - tau), K the delayed error feedback, has a root s = 0: a
  generalised eigenvalue of the pencil at s = 0, translation removed).  The
  full model's boundary is alpha (1 + m/M) (1 + O(kappa)): the tolerance is the
  specification's largest known terms, alpha (m/M_max + kappa_max), plus 1e-6
  alpha for the finite-difference linearisation.  Deterministic.

The delay (``delay.<model>``, the engine's response) is the fourth anchor, in
:mod:`validation.checks.agreement`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.optimize
from scipy import stats as sstats

from cipcore.models import MODEL_NAMES, get_model
from cipcore.noise import GainNoise
from cipcore.params import BalanceParams
from validation.checks.conformance import KAPPA_MAX, MASS_RATIO_MAX
from validation.checks.stats import FAIL, PASS, Check

#: The paper's literal parameters (section 2.2), independent of cipcore.params.PAPER.
PAPER_LITERAL = {"alpha": 22.0, "gamma": 50.0, "nu": 0.6, "tau": 0.1}
#: The time step of the reduced models' integration and of the experiment (1 ms).
DT_LITERAL = 1e-3
GAIN_STEPS = 200_000
ANCHOR_LEVEL = 0.999
LINEARISATION_RTOL = 1e-6


def paper_constants_check() -> Check:
    """The shared defaults against the paper's literal values."""
    p = BalanceParams(beta=1.0)
    values = {k: {"shared": getattr(p, k), "paper": v} for k, v in PAPER_LITERAL.items()}
    bad = [k for k, v in values.items() if v["shared"] != v["paper"]]
    return Check(
        name="anchor.paper_constants",
        status=FAIL if bad else PASS,
        values=values,
        tolerance="equal to the paper's literal values (section 2.2), exactly",
        details=("differs: " + ", ".join(bad)) if bad else "alpha, gamma, nu, tau as printed",
    )


def gain_stream(seed: int, n_steps: int = GAIN_STEPS, n_controllers: int = 2) -> np.ndarray:
    """The gain R (n_steps, controllers) the engines apply, from the shared code."""
    p = BalanceParams(beta=1.0)
    xi = GainNoise(seed, 1, n_controllers).next_chunk(n_steps)[0]
    return 1.0 + p.noise_scale * xi


def gain_variance_check(seed: int, n_steps: int = GAIN_STEPS) -> Check:
    """Sample mean and variance of the shared gain stream against 1 and nu^2 / dt."""
    r = gain_stream(seed, n_steps)
    n = r.shape[0]
    target = PAPER_LITERAL["nu"] ** 2 / DT_LITERAL
    a = 1.0 - ANCHOR_LEVEL
    lo_q, hi_q = sstats.chi2.ppf([1 - a / 2, a / 2], n - 1)
    tq = sstats.t.ppf(1 - a / 2, n - 1)
    values, ok = {}, True
    for i in range(r.shape[1]):
        var = float(r[:, i].var(ddof=1))
        ci_var = [float(var * (n - 1) / lo_q), float(var * (n - 1) / hi_q)]
        mean = float(r[:, i].mean())
        hw = float(tq * np.sqrt(var / n))
        ok_i = ci_var[0] <= target <= ci_var[1] and abs(mean - 1.0) <= hw
        ok = ok and ok_i
        values[f"controller_{i + 1}"] = {
            "variance": var, "variance_ci": ci_var, "expected_variance": target,
            "variance_ratio": var / target, "mean": mean, "mean_ci": [mean - hw, mean + hw],
        }  # fmt: skip
    return Check(
        name="anchor.gain_variance",
        status=PASS if ok else FAIL,
        values=values,
        tolerance=f"nu^2/dt = {target:g} (paper's nu = 0.6, dt = 1 ms) inside the chi-square "
        f"{100 * ANCHOR_LEVEL:g}% interval of the sample variance, and 1 inside the t interval "
        "of the mean (false-failure rate 0.1% per statistic)",
        details=f"{n} steps per controller, seed {seed}",
    )


def reduced_boundary(model: str) -> float:
    """Lower end beta_c of the reduced model's noise-free stable gains (1/s^2).

    The zero of the spectral abscissa of the characteristic roots between
    alpha / 2 and 1.05 alpha (the abscissa is positive below, negative above).
    """
    from reduced.stability import characteristic_roots

    base = BalanceParams(beta=1.0, nu=0.0)

    def abscissa(beta: float) -> float:
        return characteristic_roots(model, base.with_(beta=beta)).abscissa

    return float(scipy.optimize.brentq(abscissa, 0.5 * base.alpha, 1.05 * base.alpha,
                                       xtol=1e-10))  # fmt: skip


def full_boundary(model: str, mj_model, pendulum_length: float, cart_mass: float) -> float:
    """Lower end of the linearised full model's noise-free stable gains (1/s^2).

    x = (q, v) of the model file, x' = A x + B u with A, B from
    :func:`cip.linearize.qacc_jacobians`; the controller's force on cart i is
    M beta L theta_i(t - tau).  A root s = 0 of det(s I - A - beta B K e^{-s
    tau}) means det(A + beta B K) = 0 (the delay drops out): the finite real
    generalised eigenvalues of the pencil (A, -B K), with the free translation
    of the whole system removed from the positions.  Returns the smallest
    one in the bracket of :func:`reduced_boundary` (the coupled model's other
    mode, the tips' difference, has its boundary near 0 in both models).
    """
    import mujoco

    from cip.linearize import qacc_jacobians
    from cip.names import cart_joint, hinge_joint, motor

    a, b = qacc_jacobians(mj_model)
    nv = mj_model.nv
    nc = get_model(model).n_controllers
    k = np.zeros((mj_model.nu, 2 * nv))
    trans = np.zeros(nv)
    for i in range(1, nc + 1):
        jt = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_JOINT, hinge_joint(i))
        jx = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_JOINT, cart_joint(i))
        act = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_ACTUATOR, motor(i))
        k[act, mj_model.jnt_dofadr[jt]] = cart_mass * pendulum_length
        trans[mj_model.jnt_dofadr[jx]] = 1.0
    # positions orthogonal to the common translation, all velocities
    q = scipy.linalg.null_space(trans[None, :])
    t = scipy.linalg.block_diag(q, np.eye(nv))  # x = t z
    a0 = np.linalg.pinv(t) @ a @ t
    a1 = np.linalg.pinv(t) @ (b @ k) @ t
    w = scipy.linalg.eigvals(a0, -a1)
    w = w[np.isfinite(w)]
    alpha = BalanceParams(beta=1.0).alpha
    w = w[np.abs(w.imag) < 1e-9 * np.abs(w.real).max(initial=1.0)].real
    w = w[(w >= 0.5 * alpha) & (w <= 1.05 * alpha)]
    return float(w.min()) if w.size else float("nan")


def stability_boundary_checks(files: dict[str, str] | None = None) -> list[Check]:
    """``anchor.stability_boundary.<model>``: reduced characteristic roots vs full eigenvalues."""
    from cip.mjcf_params import load_model_file, read_mapping, shipped_model_path

    checks = []
    for model in MODEL_NAMES:
        path = (files or {}).get(model) or shipped_model_path(model)
        m = load_model_file(path)
        mp = read_mapping(m)
        red = reduced_boundary(model)
        full = full_boundary(model, m, mp.pendulum_length, mp.cart_mass)
        alpha = PAPER_LITERAL["alpha"]
        tol = alpha * (MASS_RATIO_MAX + KAPPA_MAX + LINEARISATION_RTOL)
        ok = bool(np.isfinite(full) and abs(full - red) <= tol)
        checks.append(Check(
            name=f"anchor.stability_boundary.{model}",
            status=PASS if ok else FAIL,
            values={"reduced_characteristic_roots": red, "full_linearised": full,
                    "difference": full - red, "tolerance": tol},
            tolerance="|full - reduced| <= alpha (m/M_max + kappa_max + 1e-6): the known "
            "terms a conforming model may add, and the linearisation's finite differences",
            details=f"noise-free lower stability boundary (root s = 0), file {path}",
        ))  # fmt: skip
    return checks


def anchor_checks(seed: int, files: dict[str, str] | None = None) -> list[Check]:
    """Every anchor of the shared code (module docstring)."""
    return [
        paper_constants_check(),
        gain_variance_check(seed),
        *stability_boundary_checks(files),
    ]
