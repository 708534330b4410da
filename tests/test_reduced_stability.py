"""Characteristic roots, Lyapunov exponents and the paper's critical gains."""

from __future__ import annotations

import numpy as np
import pytest

from cipcore.scenario import Execution, Scenario
from cipcore.stats import mean_ci95
from reduced import (
    BalanceParams,
    ParameterError,
    characteristic_function,
    characteristic_roots,
    critical_gain,
    discrete_exponent,
    lyapunov,
    lyapunov_gains,
)


@pytest.mark.parametrize("model", ["single", "coupled"])
@pytest.mark.parametrize("beta", [5.0, 15.0, 23.0, 30.0, 60.0])
def test_roots_are_zeros_of_the_characteristic_equation(model, beta):
    p = BalanceParams(beta=beta, nu=0.0)
    roots = characteristic_roots(model, p).roots
    assert len(roots) >= 3
    vals = np.abs(characteristic_function(model, p, roots))
    assert np.all(vals < 1e-8 * np.maximum(1, np.abs(roots)) ** 4)
    assert np.all(np.diff(roots.real) <= 1e-12)


def test_zero_root_at_beta_equal_alpha():
    # s = 0 solves s^2 + gamma s - alpha + beta e^{-s tau} = 0 iff beta = alpha
    p = BalanceParams(beta=22.0, nu=0.0)
    roots = characteristic_roots("single", p).roots
    assert np.min(np.abs(roots)) < 1e-10


def test_coupled_roots_are_union_of_sum_and_difference_modes():
    p = BalanceParams(beta=40.0, nu=0.0)
    single = characteristic_roots("single", p, n_roots=4).roots
    coupled = characteristic_roots("coupled", p, n_roots=8).roots
    for z in single[:2]:
        assert np.min(np.abs(coupled - z)) < 1e-8
    # the difference mode s^2 + gamma s + beta e^{-s tau} = 0 has a root the single lacks
    diff = [z for z in coupled if np.min(np.abs(single - z)) > 1e-6]
    g, b, tau = 50.0, 40.0, 0.1
    assert diff and abs(diff[0] ** 2 + g * diff[0] + b * np.exp(-diff[0] * tau)) < 1e-8


@pytest.mark.parametrize("model", ["single", "coupled"])
@pytest.mark.parametrize("beta", [12.0, 20.3, 23.0, 35.0])
def test_noise_free_lyapunov_equals_rightmost_root(model, beta):
    """nu = 0: Benettin over the whole delay history gives the spectral abscissa."""
    p = BalanceParams(beta=beta, nu=0.0)
    res = lyapunov(Scenario(model, p, 300.0, 2, 1))
    exact_discrete = discrete_exponent(model, p)
    root = characteristic_roots(model, p).abscissa
    # the time-stepped map: equal up to the initial alignment of the tangent vector
    assert res.lambda1 == pytest.approx(exact_discrete, abs=2e-4)
    # the continuous-time root: within the O(dt) error of the stepper
    assert res.lambda1 == pytest.approx(root, abs=2e-4 + 2e-3 * abs(root))
    # and the sign is right on both sides of the threshold beta = alpha
    assert np.sign(res.lambda1) == np.sign(root)


def test_discrete_exponent_converges_to_root_as_dt_shrinks():
    errs = []
    for dt in (2e-3, 1e-3, 5e-4):
        p = BalanceParams(beta=30.0, nu=0.0, dt=dt)
        errs.append(
            abs(discrete_exponent("single", p) - characteristic_roots("single", p).abscissa)
        )
    assert errs[0] > errs[1] > errs[2]
    assert errs[1] / errs[2] == pytest.approx(2.0, rel=0.2)  # first order in dt


def test_common_drift_does_not_bias_the_exponent():
    """Strongly stable errors give a clearly negative exponent (no creep towards 0)."""
    p = BalanceParams(beta=30.0, nu=0.0)
    short = lyapunov(Scenario("single", p, 50.0, 1)).lambda1
    long = lyapunov(Scenario("single", p, 400.0, 1)).lambda1
    assert long == pytest.approx(short, rel=0.02)
    assert long < -0.1


def test_mean_ci95_covers_at_nominal_rate():
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(400):
        _m, (lo, hi) = mean_ci95(rng.normal(1.0, 2.0, size=10))
        hits += lo <= 1.0 <= hi
    assert 0.92 <= hits / 400 <= 0.98


def test_noise_stabilises_and_coupling_shifts_threshold_fast():
    """Fast version of the paper check: at beta = 20.306 the single balancer sits on
    its threshold (lambda1 ~ 5e-4) while the coupled one is still unstable; at 19.3 both
    are unstable and at 21.8 both stable.  Noise-free, beta < alpha = 22 is unstable."""

    def lam(model: str, beta: float):
        return lyapunov(Scenario(model, BalanceParams(beta=beta), 400.0, 12, 2))

    on = lam("single", 20.306)
    assert on.ci95[0] - 0.004 < 5e-4 < on.ci95[1] + 0.004
    coupled = lam("coupled", 20.306)
    assert coupled.ci95[0] > on.ci95[1]
    assert lam("single", 19.3).ci95[0] > 0
    assert lam("coupled", 21.8).ci95[1] < 0
    assert characteristic_roots("single", BalanceParams(beta=20.306, nu=0.0)).abscissa > 0


def test_lyapunov_independent_of_dt_with_euler_maruyama_scaling():
    """With R = 1 + nu xi / sqrt(dt) the exponent converges as dt shrinks; without the
    1/sqrt(dt) the noise would vanish and lambda1 would climb to the noise-free 0.1."""
    a = lyapunov(Scenario("single", BalanceParams(beta=19.0, dt=1e-3), 200.0, 12, 4))
    b = lyapunov(Scenario("single", BalanceParams(beta=19.0, dt=5e-4), 200.0, 12, 4))
    free = characteristic_roots("single", BalanceParams(beta=19.0, nu=0.0)).abscissa
    half = (a.ci95[1] - a.ci95[0] + b.ci95[1] - b.ci95[0]) / 2
    assert abs(a.lambda1 - b.lambda1) < half + 0.003
    assert b.ci95[1] < free - 0.02


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_lyapunov_at_several_gains_equals_one_call_per_gain(model):
    """The draws made once for every gain give each gain's exponents bit for bit."""
    gains = [BalanceParams(beta=b) for b in (19.5, 20.3, 23.0)]
    scn = Scenario(model, gains[0], 30.0, 5, 7)
    kw = {"execution": Execution(threads=2)}
    for one, many in zip([lyapunov(scn.with_params(p), **kw) for p in gains],
                         lyapunov_gains(scn, gains, **kw), strict=True):  # fmt: skip
        assert np.array_equal(one.per_realization, many.per_realization)
        assert one.ci95 == many.ci95 and one.params == many.params
    with pytest.raises(ParameterError, match="share dt and tau"):
        lyapunov_gains(scn, [gains[0], BalanceParams(beta=20.0, tau=0.2)], **kw)


def test_bootstrap_fits_at_once_equal_one_fit_each():
    """critical_gain's bootstrap solves every resample's fit at once: the same roots (or
    none) as one fit each."""
    from reduced.lyapunov import _solve_fit, _solve_fits

    rng = np.random.default_rng(3)
    betas = np.linspace(19.8, 20.8, 5)
    for deg in (1, 2):
        lams = 5e-4 + 0.01 * (betas[:, None] - 20.3) + 0.004 * (betas[:, None] - 20.3) ** 2
        lams = lams + 0.006 * rng.standard_normal((5, 400))
        one = [_solve_fit(betas, lams[:, j], 5e-4, deg) for j in range(lams.shape[1])]
        one = np.array([np.nan if b is None else b for b in one])
        assert np.isnan(one).any() and np.isfinite(one).any()  # both cases exercised
        np.testing.assert_array_equal(_solve_fits(betas, lams, 5e-4, deg), one)


def test_lyapunov_bad_input():
    with pytest.raises(ParameterError, match="transient"):
        lyapunov(Scenario("single", BalanceParams(beta=20.0), 10.0), transient=20.0)
    with pytest.raises(ParameterError, match="realizations"):
        lyapunov(Scenario("single", BalanceParams(beta=20.0), 200.0, realizations=0))
    with pytest.raises(ParameterError, match="beta_range"):
        critical_gain(Scenario("single", BalanceParams(beta=20.0), 500.0, 16), (21.0, 20.0))


def test_paper_critical_gains_at_low_power():
    """The fast version of :func:`test_paper_critical_gains`: 16 realisations x 500 s, each
    beta* and the coupling's shift within 4 of their bootstrap standard deviations (about
    0.11 each) of the paper's.  Seeds 1-7 and 2011: at most 2.0 standard deviations off."""
    base = BalanceParams(beta=20.0)
    single = critical_gain(Scenario("single", base, 500.0, 16, 2011), (19.8, 20.8), n_gains=7)
    coupled = critical_gain(Scenario("coupled", base, 500.0, 16, 2011), (20.5, 21.5), n_gains=7)
    assert single.beta_star == pytest.approx(20.306, abs=4 * single.std)
    assert coupled.beta_star == pytest.approx(21.032, abs=4 * coupled.std)
    shift_std = float(np.hypot(single.std, coupled.std))
    assert coupled.beta_star - single.beta_star == pytest.approx(0.726, abs=4 * shift_std)


@pytest.mark.slow
def test_paper_critical_gains():
    """Paper Figs. 3, 4: beta* = 20.306 (single), 21.032 (coupled) for lambda1 = 5e-4.

    Measured (this test's settings): 20.358 +- 0.033 and 21.068 +- 0.032 (about 20 s)."""
    base = BalanceParams(beta=20.0)
    single = critical_gain(Scenario("single", base, 2000.0, 32, 2011), (19.8, 20.8), n_gains=7)
    coupled = critical_gain(Scenario("coupled", base, 2000.0, 32, 2011), (20.5, 21.5), n_gains=7)
    assert single.beta_star == pytest.approx(20.306, abs=0.25)
    assert coupled.beta_star == pytest.approx(21.032, abs=0.25)
    assert coupled.beta_star - single.beta_star == pytest.approx(0.726, abs=0.15)
