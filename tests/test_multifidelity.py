"""The two-model MFMC / control-variate estimator on synthetic data with a known mean."""

from __future__ import annotations

import json

import numpy as np
import pytest

from validation.checks import multifidelity as mf

MU_Y, MU_X = 0.3, -0.2


def draw(rng: np.random.Generator, n: int, m: int, rho: float, sy: float = 2.0,
         sx: float = 0.5, draws: int = 1) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(draws, n) y and (draws, m) x, corr(y, x) = rho, x[:, :n] paired with y."""
    z1 = rng.standard_normal((draws, m))
    z2 = rng.standard_normal((draws, n))
    x = MU_X + sx * z1
    y = MU_Y + sy * (rho * z1[:, :n] + np.sqrt(1 - rho**2) * z2)
    return y, x


def estimates(rho: float, n: int, m: int, draws: int, seed: int) -> list[mf.MFEstimate]:
    y, x = draw(np.random.default_rng(seed), n, m, rho, draws=draws)
    return [mf.mfmc_estimate(y[k], x[k]) for k in range(draws)]


def test_alpha_one_is_engine_minus_twin_plus_twin_minus_reduced():
    rng = np.random.default_rng(1)
    y, x = draw(rng, 4, 30, 0.9)
    est = mf.mfmc_estimate(y[0], x[0], alpha=1.0)
    assert est.mean == pytest.approx((y[0] - x[0, :4]).mean() + x[0].mean(), abs=1e-14)


def test_unbiased_over_many_draws():
    est = estimates(0.95, 5, 60, 1500, seed=2)
    means = np.array([e.mean for e in est])
    se = means.std(ddof=1) / np.sqrt(means.size)
    assert abs(means.mean() - MU_Y) < 4 * se


@pytest.mark.parametrize("rho", [0.5, 0.9, 0.99])
def test_variance_reduction_matches_theory(rho):
    n, m, sy = 20, 200, 2.0
    means = np.array([e.mean for e in estimates(rho, n, m, 1500, seed=3)])
    theory = mf.mfmc_variance(sy, 0.5, rho, n, m)
    assert theory == pytest.approx(sy**2 / n * (1 - (1 - n / m) * rho**2))
    # alpha estimated from n = 20 pairs inflates the variance by O(1/n)
    assert means.var(ddof=1) / theory == pytest.approx(1.0, abs=0.15)
    assert means.var(ddof=1) < sy**2 / n  # better than plain sampling of y over n


def test_estimated_variance_and_coverage():
    est = estimates(0.9, 8, 80, 1200, seed=4)
    inside = np.mean([e.ci95[0] <= MU_Y <= e.ci95[1] for e in est])
    assert 0.92 <= inside <= 0.98
    means = np.array([e.mean for e in est])
    assert np.mean([e.se**2 for e in est]) / means.var(ddof=1) == pytest.approx(1.0, abs=0.2)


def test_general_variance_formula_at_optimal_alpha():
    sy, sx, rho, n, m = 1.3, 0.7, 0.8, 5, 40
    a = rho * sy / sx
    assert mf.mfmc_variance(sy, sx, rho, n, m, alpha=a) == pytest.approx(
        mf.mfmc_variance(sy, sx, rho, n, m)
    )
    # any other alpha is worse
    assert mf.mfmc_variance(sy, sx, rho, n, m, alpha=1.1 * a) > mf.mfmc_variance(sy, sx, rho, n, m)


def test_control_variate_coefficient():
    rng = np.random.default_rng(5)
    y, x = draw(rng, 20000, 20000, 0.8)
    a, rho = mf.control_variate(y[0], x[0])
    assert rho == pytest.approx(0.8, abs=0.01)
    assert a == pytest.approx(0.8 * 2.0 / 0.5, rel=0.02)
    assert mf.control_variate(np.arange(5.0), np.ones(5)) == (0.0, 0.0)


def test_optimal_ratio_minimises_the_budget_variance():
    rho, w = 0.97, 50.0
    r = mf.optimal_ratio(rho, w)
    assert r == pytest.approx(np.sqrt(w * rho**2 / (1 - rho**2)))
    grid = np.linspace(1.0, 10 * r, 20001)
    best = grid[np.argmin([mf.budget_variance_ratio(rho, w, g) for g in grid])]
    assert best == pytest.approx(r, rel=1e-2)
    assert mf.optimal_ratio(1.0, w) == np.inf
    assert mf.optimal_ratio(0.0, w) == 0.0


def test_fallback_to_plain_sampling_when_rho_is_low():
    # rho ~ 0: the control variate cannot help, sample the costly model plainly
    alloc = mf.allocate(rho=0.02, w=30.0, budget=30.0 * 8)
    assert not alloc.multifidelity and alloc.n == 8 and alloc.m == 8
    assert not mf.beats_plain(0.02, 3, 64, 8)
    # the estimator itself stays unbiased, and near ybar_n's variance (alpha estimated
    # from n = 10 pairs adds O(1 / n))
    est = estimates(0.0, 10, 100, 1000, seed=6)
    means = np.array([e.mean for e in est])
    assert abs(means.mean() - MU_Y) < 4 * means.std(ddof=1) / np.sqrt(means.size)
    assert means.var(ddof=1) <= 1.3 * 2.0**2 / 10


def test_allocation_with_an_exact_twin():
    alloc = mf.allocate(rho=1.0 - 1e-12, w=30.0, budget=30.0 * 8, m_max=64)
    assert alloc.multifidelity and alloc.n == mf.MIN_PAIRED and alloc.m == 64
    assert mf.beats_plain(1.0 - 1e-12, 3, 64, 8)
    assert mf.predicted_half_width_ratio(1.0, 3, 64, 8) == pytest.approx(
        (2.0 / np.sqrt(64)) / (2.365 / np.sqrt(8)), rel=0.02
    )


def test_bootstrap_interval_close_to_the_t_interval():
    rng = np.random.default_rng(7)
    y, x = draw(rng, 40, 400, 0.9)
    est = mf.mfmc_estimate(y[0], x[0])
    lo, hi = mf.bootstrap_interval(y[0], x[0], np.random.default_rng(8), 2000)
    assert lo < est.mean < hi
    assert (hi - lo) / (2 * est.half_width) == pytest.approx(1.0, abs=0.2)


def test_finite_nested_drops_pairs_and_extras():
    y = np.array([1.0, np.nan, 3.0, 4.0])
    x = np.array([1.0, 2.0, np.inf, 4.0, 5.0, np.nan, 7.0])
    yy, xx = mf.finite_nested(y, x)
    assert yy.tolist() == [1.0, 4.0]
    assert xx.tolist() == [1.0, 4.0, 5.0, 7.0]


@pytest.mark.parametrize(
    ("y", "x", "match"),
    [(np.ones(2), np.ones(5), "y must hold at least 3"),
     (np.ones(4), np.ones(3), "x must hold at least"),
     (np.array([1.0, np.nan, 2.0]), np.ones(3), "finite")],
)  # fmt: skip
def test_bad_input_names_the_parameter(y, x, match):
    with pytest.raises(ValueError, match=match):
        mf.mfmc_estimate(y, x)
    with pytest.raises(ValueError, match="w must be > 0"):
        mf.optimal_ratio(0.5, 0.0)


def test_variance_ratio_with_an_exact_control():
    rng = np.random.default_rng(9)
    y, x = draw(rng, 4, 40, 1.0)
    est = mf.mfmc_estimate(y[0], x[0])
    assert est.variance_ratio == pytest.approx(4 / 40, rel=1e-9)
    assert est.half_width / est.plain_half_width(8) == pytest.approx(
        mf.predicted_half_width_ratio(1.0, 4, 40, 8), rel=1e-6
    )


# ------------------------------------------------------------------ wired into the agreement
def _tiny_profile():
    from dataclasses import replace

    from validation.profiles import PROFILES

    return replace(PROFILES["smoke"], series_realizations=4,
                   mf_engine_realizations=3, mf_twin_realizations=8)  # fmt: skip


def _series_args(profile, model="coupled"):
    """series_model_checks' scenario and target, then its keywords."""
    from cipcore.params import BalanceParams
    from cipcore.scenario import EngineTarget, Scenario
    from validation.profiles import PAPER_BETA

    scn = Scenario(model, BalanceParams(beta=PAPER_BETA[model]), profile.series_duration,
                   profile.series_realizations, profile.seed_for("series", model),
                   profile.amplitude)  # fmt: skip
    return (scn, EngineTarget()), {"threads": 1, "nearest": None, "precision": "float64"}


def test_mujoco_series_by_its_exact_twin():
    from validation.checks import agreement

    profile = _tiny_profile()
    checks, data = agreement.multifidelity_series(
        *_series_args(profile)[0], profile, **_series_args(profile)[1]
    )
    names = [c.name for c in checks]
    metrics = ("log10_rms", "spectrum_bands", "spectral_slopes", "stcc_peak_median",
               "stcc_fast_fraction", "log10_velocity_sd")  # fmt: skip
    own = ["twin.metrics.coupled", "agreement.trajectory.coupled"]
    assert names == [f"agreement.{m}.coupled" for m in metrics] + own
    assert all(c.status == "pass" for c in checks), [(c.name, c.status) for c in checks]
    rms = checks[0].values
    assert (rms["n"], rms["n_twin"]) == (3, 8)
    assert rms["multifidelity"]["rho"] > 0.999999
    assert rms["multifidelity"]["half_width_vs_plain"] < 1
    assert data["full"].shape[0] == 3 and data["reduced"].shape[0] == 8
    assert "multifidelity: engine 3 x 45 s, twin and reduced 8 x 45 s" in checks[0].details


def test_uncorrelated_twin_falls_back_to_plain_sampling(monkeypatch):
    """A control that shares no noise with the engine (rho ~ 0) is refused."""
    from dataclasses import replace

    from validation.checks import agreement

    real = agreement.run_twin

    def other_noise(scenario, target, **kw):
        return real(replace(scenario, seed=scenario.seed + 1), target, **kw)

    monkeypatch.setattr(agreement, "run_twin", other_noise)
    profile = _tiny_profile()
    checks, data = agreement.series_model_checks(
        *_series_args(profile)[0], profile, **_series_args(profile)[1]
    )
    assert data["full"].shape[0] == profile.series_realizations  # the engine ran them all
    rms = next(c for c in checks if c.name == "agreement.log10_rms.coupled")
    assert "multifidelity" not in rms.values and rms.values["n"] == profile.series_realizations
    assert "multifidelity not used: " in rms.details


def test_engine_realisations_out_of_range_is_one_line():
    from dataclasses import replace

    from cipcore.params import ParameterError
    from validation.checks import agreement

    profile = replace(_tiny_profile(), mf_engine_realizations=4)
    with pytest.raises(ParameterError, match=r"mf_engine_realizations must be 0 or in \[3, "):
        agreement.multifidelity_series(
            *_series_args(profile)[0], profile, **_series_args(profile)[1]
        )


def test_a_control_fitted_to_three_pairs_is_not_trusted():
    """Three pairs on a line of slope -0.5 (rho = -1): an alpha fitted to them would leave
    no residual and an interval of the twin's alone, narrower than plain sampling's (PhysX's
    coupled 15 Hz band failed so, 7 December). With alpha = 1 the engine - twin spread
    counts, the interval is wider than plain sampling's and the series falls back."""
    from validation.checks.agreement import mf_equivalence

    rng = np.random.default_rng(5)
    twin = rng.standard_normal(16)
    full = -0.5 * twin[:3]
    _, v, ratio = mf_equivalence(full, np.zeros(16), twin, twin, 8, rng)
    assert v["multifidelity"]["alpha"] == 1.0 and v["multifidelity"]["rho"] < -0.999
    assert ratio > 1
    fitted = mf.mfmc_estimate(full, twin)  # what the fitted alpha would claim
    assert (
        fitted.v_paired < 1e-20
        and fitted.half_width < v["difference_ci95"][1] - v["difference_mean"]
    )


@pytest.mark.parametrize("k", [0.0, 0.3])
def test_pairs_over_another_duration_keep_their_coverage(k):
    """x_paired: the engine's pairs ran shorter (the lambda1 check's engine duration). The
    control over the whole duration x_i, its pairs' own values x_i + b_i, the engine's
    y_i = x_i + b_i + c + e_i with e_i correlated with x_i by ``k``: mean_n(y - x_paired) +
    xbar_m is unbiased for mu_x + c and the interval (the covariance bounded) covers it."""
    rng = np.random.default_rng(11)
    n, m, c, mu_x = 3, 16, 0.01, -0.002
    hits, means = [], []
    for _ in range(3000):
        x = mu_x + 0.014 * rng.standard_normal(m)
        xp = x[:n] + 0.02 * rng.standard_normal(n)
        y = xp + c + k * (x[:n] - mu_x) + 0.002 * rng.standard_normal(n)
        est = mf.mfmc_estimate(y, x, alpha=1.0, x_paired=xp)
        assert est.mean == pytest.approx((y - xp).mean() + x.mean(), abs=1e-15)
        hits.append(est.ci95[0] <= mu_x + c <= est.ci95[1])
        means.append(est.mean)
    assert abs(np.mean(means) - (mu_x + c)) < 4 * np.std(means) / np.sqrt(len(means))
    assert np.mean(hits) >= 0.93  # 0.90 at k = 0.3 without the covariance bound


@pytest.mark.parametrize("x_paired, match", [
    (np.ones(4), r"x_paired must hold one value per y \(3\), got 4"),
    (np.ones(2), r"x_paired must hold one value per y \(3\), got 2"),
    (np.array([1.0, np.nan, 1.0]), "x_paired must be finite"),
])  # fmt: skip
def test_pairs_that_do_not_fit_name_the_parameter(x_paired, match):
    with pytest.raises(ValueError, match=match):
        mf.mfmc_estimate(np.zeros(3), np.arange(16.0), alpha=1.0, x_paired=x_paired)


def _as_batch(monkeypatch, batch: bool, real) -> list[int]:
    """MuJoCo's engine declared ``batch`` (or not); returns the realisations of each of
    its series calls (``real``, the unpatched ``run_full``), appended as they happen."""
    from dataclasses import replace

    from validation.checks import agreement

    eng = agreement.rigid_engine("mujoco")
    monkeypatch.setattr(eng, "capabilities", replace(eng.capabilities, batch=batch))
    calls: list[int] = []

    def counted(scenario, target, **kw):
        calls.append(scenario.realizations)
        return real(scenario, target, **kw)

    monkeypatch.setattr(agreement, "run_full", counted)
    return calls


def test_a_batch_engine_pairs_its_whole_plain_allocation_from_one_call(monkeypatch):
    """A ``batch`` engine (a call costs about the same for 3 worlds as for 8) runs the
    plain allocation once and pairs all of it; the estimate passes as with n = 3."""
    from validation.checks import agreement

    profile = _tiny_profile()
    calls = _as_batch(monkeypatch, True, agreement.run_full)
    checks, data = agreement.series_model_checks(
        *_series_args(profile)[0], profile, **_series_args(profile)[1]
    )
    n_plain = profile.series_realizations
    assert calls == [n_plain]
    rms = checks[0]
    assert rms.name == "agreement.log10_rms.coupled" and rms.values["n"] == n_plain
    assert rms.values["multifidelity"]["half_width_vs_plain"] < 1
    assert "a batch engine: every realisation of its one call paired" in rms.details
    assert all(c.status in ("pass", "n/a") for c in checks), [(c.name, c.status) for c in checks]
    assert data["full"].shape[0] == n_plain


def test_a_batch_engine_falls_back_to_plain_sampling_without_a_second_call(monkeypatch):
    """Where the estimate would be wider than plain sampling's, a batch engine's plain
    checks reuse its one call: the same checks, to the bit, as another engine's two calls."""
    from validation.checks import agreement

    real_compare = agreement.compare_series_mf
    monkeypatch.setattr(agreement, "compare_series_mf",
                        lambda *a, **k: (real_compare(*a, **k)[0], 2.0))  # fmt: skip
    profile = _tiny_profile()
    got, real = {}, agreement.run_full
    for batch in (False, True):
        calls = _as_batch(monkeypatch, batch, real)
        checks, data = agreement.series_model_checks(
            *_series_args(profile)[0], profile, **_series_args(profile)[1]
        )
        got[batch] = (checks, data, calls)
    n, n_plain = profile.mf_engine_realizations, profile.series_realizations
    assert got[False][2] == [n, n_plain] and got[True][2] == [n_plain]
    for a, b in zip(got[False][0], got[True][0], strict=True):  # NaN equal to NaN
        assert (a.name, a.status) == (b.name, b.status)
        assert json.dumps(a.values, sort_keys=True, default=str) == json.dumps(
            b.values, sort_keys=True, default=str
        )
    assert "multifidelity not used: " in got[True][0][0].details
    np.testing.assert_array_equal(got[False][1]["full"]["balancing_error"],
                                  got[True][1]["full"]["balancing_error"])  # fmt: skip


def test_head_cuts_the_per_realisation_attributes():
    from cipcore.schema import Trajectory
    from validation.checks.agreement import head

    tr = Trajectory(time=np.arange(3.0), data={"balancing_error": np.zeros((4, 3, 1))},
                    attrs={"max_abs_angle": [0.1, 0.2, 0.3, 0.4], "seed": 7,
                           "left_small_angle": [False, False, True, True]})  # fmt: skip
    h = head(tr, 2)
    assert h.data["balancing_error"].shape == (2, 3, 1)
    assert h.attrs["max_abs_angle"] == [0.1, 0.2] and h.attrs["left_small_angle"] == [False] * 2
    assert h.attrs["seed"] == 7 and tr.attrs["max_abs_angle"] == [0.1, 0.2, 0.3, 0.4]


def test_an_engine_run_that_stopped_has_no_estimate_and_is_not_run_again(
    monkeypatch, mujoco_nan_after
):
    """An engine whose series run stops at a non-finite state (0.5 s into 45 s): its
    metrics are NaN with a whole run's shapes, so every comparison is inconclusive and
    says why, the trajectory check fails, and the plain allocation is not run after it
    (it would only stop again: one engine call, not two)."""
    from validation.checks import agreement

    mujoco_nan_after(500)  # MuJoCo's state NaN in each block's first realisation
    profile = _tiny_profile()
    calls = _as_batch(monkeypatch, False, agreement.run_full)
    with pytest.warns(RuntimeWarning, match="run stopped"):
        checks, data = agreement.series_model_checks(
            *_series_args(profile)[0], profile, **_series_args(profile)[1]
        )
    assert calls == [profile.mf_engine_realizations]
    status = {c.name: c.status for c in checks}
    assert status["agreement.trajectory.coupled"] == "fail"
    for m in ("log10_rms", "spectrum_bands", "stcc_peak_median", "log10_velocity_sd"):
        assert status[f"agreement.{m}.coupled"] == "inconclusive"
    assert "the engine's run stopped between t = 0.5 and 0.6 s" in checks[0].details
    mf = data["metrics_full"]
    assert np.isnan(mf.log_rms).all() and mf.band_log_power.shape == (3, 8)
    assert data["full"].time.size < data["reduced"].time.size
