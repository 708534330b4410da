"""Instruments over twenty decades: STCC precision, density ratio, peaks, heavy-tailed RMS."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from validation.checks.metrics import (
    density,
    density_ratio_near_zero,
    dominant_peaks,
    stcc,
    stcc_significance_bartlett,
)
from validation.checks.stats import bootstrap_ratio_ci, heavy_tailed_summary

DT = 0.005


def _spanning_pair(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Correlated velocities whose envelope climbs from 1e-12 to 1e9 and falls back again."""
    rng = np.random.default_rng(seed)
    log_env = 9.0 - 21.0 * np.abs(np.linspace(-1.0, 1.0, n)) + 0.3 * np.sin(np.linspace(0, 40, n))
    base = np.convolve(rng.standard_normal(n + 20), np.ones(20) / 20, mode="valid")[:n]
    x = 10.0**log_env * base
    y = 10.0**log_env * (np.roll(base, 7) + 0.5 * rng.standard_normal(n)) + 3.0 * 10.0**log_env
    return x, y


def _brute_force(x, y, i, w, lag):
    xs, ys, yw = x[i : i + w], y[i + lag : i + lag + w], y[i : i + w]
    return np.mean((xs - xs.mean()) * (ys - yw.mean())) / (xs.std() * yw.std())


def test_stcc_over_twenty_one_decades_equals_direct_per_window_computation():
    n, w = 24_000, 500
    x, y = _spanning_pair(n, 7)
    assert np.abs(x).max() > 1e8 and np.abs(x[np.abs(x) > 0]).min() < 1e-11
    t, lags, r = stcc(x, y, DT, window=w * DT, max_lag=0.1, stride=0.25)
    worst = 0.0
    for k, t0 in enumerate(t):
        i = round(t0 / DT)
        for j in range(len(lags)):
            worst = max(worst, abs(r[k, j] - _brute_force(x, y, i, w, j)))
    assert worst < 1e-13  # rounding: 7e-16 measured
    # the same windows from differences of whole-series running sums lose the small windows
    c1 = np.concatenate([[0.0], np.cumsum(x)])
    c2 = np.concatenate([[0.0], np.cumsum(x * x)])
    starts = np.round(t / DT).astype(int)
    mean = (c1[starts + w] - c1[starts]) / w
    var_cumsum = (c2[starts + w] - c2[starts]) / w - mean**2
    var_direct = np.array([x[i : i + w].var() for i in starts])
    assert np.nanmax(np.abs(var_cumsum / var_direct - 1)) > 1e-3


def test_stcc_windows_not_multiple_of_stride_and_leading_axes():
    x, y = _spanning_pair(6_000, 3)
    xx, yy = np.stack([x, 2 * x]), np.stack([y, -y])
    t, lags, r = stcc(xx, yy, DT, window=1.5, max_lag=0.05, stride=0.2)  # g = gcd(300, 40) = 20
    for k in (0, len(t) // 2, len(t) - 1):
        i = round(t[k] / DT)
        for j in range(len(lags)):
            ref = _brute_force(x, y, i, 300, j)
            assert r[0, k, j] == pytest.approx(ref, abs=1e-13)
            assert r[1, k, j] == pytest.approx(-ref, abs=1e-13)


# ------------------------------------------------------------ dominant peaks
def test_rising_r_at_end_of_lag_range_gives_no_peak_and_is_counted_as_boundary():
    lags = np.arange(8) * 0.01
    r = np.array(
        [
            [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8],  # rising to the end
            [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2],  # falling from lag 0
            [0.1, 0.5, 0.2, 0.3, 0.4, 0.5, 0.55, 0.6],  # a peak, then rising above it
            [0.1, 0.3, 0.6, 0.4, 0.2, 0.1, 0.0, -0.1],  # an ordinary peak
        ]
    )
    p = dominant_peaks(r, lags, dominance=0.8)
    np.testing.assert_array_equal(p.no_peak, [True, True, False, False])
    np.testing.assert_array_equal(p.boundary_max, [True, True, True, False])
    np.testing.assert_allclose(p.tau_hat, [np.nan, np.nan, 0.01, 0.02])
    assert p.fractions() == {"with_peak": 0.5, "no_peak": 0.5, "boundary_max": 0.75}
    # a dominance above 0.5 / 0.6 removes the early peak of row 2
    assert np.isnan(dominant_peaks(r[2], lags, dominance=0.9).tau_hat)


def test_non_finite_lags_are_never_the_largest_and_never_a_boundary():
    """A NaN lag (a window with zero deviation at that lag) is never the largest R nor a
    neighbour that makes a peak; a window all NaN has no peak and no boundary; an infinite
    R is the largest and can be the peak; the significance level is per window."""
    lags = np.arange(6) * 0.01
    nan, inf = np.nan, np.inf
    r = np.array([
        [0.1, 0.3, nan, 0.4, 0.2, 0.1],  # the NaN lag spoils both neighbours' peaks
        [nan] * 6,
        [0.1, 0.5, 0.2, inf, 0.1, 0.0],  # the infinite lag is the largest and the peak
        [0.2, 0.6, 0.1, 0.5, 0.3, 0.1],
        [0.2, 0.6, 0.1, 0.5, 0.3, 0.1],
    ])  # fmt: skip
    sig = np.array([0.0, 0.0, 0.0, 0.55, 0.65])
    p = dominant_peaks(r, lags, dominance=0.8, significance=sig)
    np.testing.assert_array_equal(p.tau_hat, [nan, nan, 0.03, 0.01, nan])
    np.testing.assert_array_equal(p.no_peak, [True, True, False, False, True])
    np.testing.assert_array_equal(p.boundary_max, [False] * 5)
    # one window alone gives what it gives in the batch
    for k in range(len(r)):
        one = dominant_peaks(r[k], lags, dominance=0.8, significance=sig[k])
        np.testing.assert_array_equal(one.tau_hat, p.tau_hat[k])


def _ar1(rng, phi, shape):
    e = rng.standard_normal(shape)
    out = np.empty(shape)
    out[..., 0] = e[..., 0] / np.sqrt(1 - phi**2)
    for k in range(1, shape[-1]):
        out[..., k] = phi * out[..., k - 1] + e[..., k]
    return out


@pytest.mark.parametrize("corr_time", [0.0, 0.05])
def test_bartlett_level_gives_the_nominal_false_exceedance_rate(corr_time):
    """Independent x, y (white, or AR(1) with correlation time 50 ms): the fraction of
    (window, lag) with R above z / sqrt(n_eff) is the one-sided normal tail at z."""
    rng = np.random.default_rng(2024)
    phi = np.exp(-DT / corr_time) if corr_time else 0.0
    x, y = _ar1(rng, phi, (4, 30_000)), _ar1(rng, phi, (4, 30_000))
    t, _lags, r = stcc(x, y, DT, window=5.0, max_lag=0.3, stride=1.0)
    z = 2.0
    level = stcc_significance_bartlett(x, y, DT, t, 5.0, z=z)
    n_eff_true = 1000 * (1 - phi**2) / (1 + phi**2)  # Bartlett for two AR(1) of the same phi
    assert np.median((z / level) ** 2) == pytest.approx(n_eff_true, rel=0.25)
    rate = np.mean(r > level[..., None])
    nominal = scipy.stats.norm.sf(z)  # 0.0228
    # windows x lags are correlated: generous but discriminating bounds
    assert 0.4 * nominal < rate < 2.0 * nominal
    naive = np.mean(r > z / np.sqrt(1000))
    if corr_time:
        assert naive > 4 * nominal  # the white-noise level over-counts correlated series


def test_white_and_correlated_noise_false_peak_rate_at_documented_level():
    """At the default z = 3 a window of 61 lags reports a false dominant peak with at most
    the probability 1 - (1 - 0.00135)^59 (independent interior lags: white noise)."""
    rng = np.random.default_rng(7)
    xw, yw = rng.standard_normal((8, 30_000)), rng.standard_normal((8, 30_000))
    t, lags, r = stcc(xw, yw, DT, window=5.0, max_lag=0.3, stride=0.5)
    p = dominant_peaks(r, lags, significance=stcc_significance_bartlett(xw, yw, DT, t, 5.0))
    expected = 1 - (1 - scipy.stats.norm.sf(3.0)) ** (len(lags) - 2)  # 0.077
    assert 0.5 * expected < p.fractions()["with_peak"] < 1.5 * expected
    phi = np.exp(-DT / 0.05)
    x, y = _ar1(rng, phi, (6, 30_000)), _ar1(rng, phi, (6, 30_000))
    t, lags, r = stcc(x, y, DT, window=5.0, max_lag=0.3, stride=0.5)
    p = dominant_peaks(r, lags, significance=stcc_significance_bartlett(x, y, DT, t, 5.0))
    # at most about lags x 0.13 % per window; far below with the white-noise level's 40 %+
    assert p.fractions()["with_peak"] < 0.08
    naive = dominant_peaks(r, lags, significance=3 / np.sqrt(1000))
    assert naive.fractions()["with_peak"] > 3 * p.fractions()["with_peak"]


# ------------------------------------------------------------ density ratio
def test_velocity_density_ratio_two_recovered_within_ci_despite_a_runaway_realisation():
    rng = np.random.default_rng(11)
    n_real, n = 40, 5_000
    single = rng.uniform(-1.0, 1.0, (n_real, n))  # density 1/2 near 0
    coupled = rng.uniform(-0.5, 0.5, (n_real, n))  # density 1 near 0: ratio exactly 2
    single[0] *= 1e7  # one runaway realisation in each model (its density near 0: ~1e-7)
    coupled[0] *= 1e7
    true = 2.0  # (n_real - 1) / n_real of the samples in each model, same factor
    res = density_ratio_near_zero(coupled, single, half_width=0.2, n_bootstrap=500, seed=3)
    assert res.ci95[0] <= true <= res.ci95[1]
    assert res.ci95[1] - res.ci95[0] < 0.5
    assert res.ci95[0] > 1.5  # excludes the degenerate 1
    # the old construction: pooled-std bins (set by the runaway) and density=True -> about 1
    h = np.std(coupled) / 20
    old = np.histogram(coupled, np.linspace(-5 * h, 5 * h, 11), density=True)[0]
    old_s = np.histogram(single, np.linspace(-5 * h, 5 * h, 11), density=True)[0]
    assert abs(old[4:6].mean() / old_s[4:6].mean() - 1) < 0.1
    # normalised per realisation both are the same uniform shape: ratio 1
    norm = density_ratio_near_zero(coupled, single, 0.2, normalise=True, n_bootstrap=500, seed=3)
    assert norm.ci95[0] <= 1.0 <= norm.ci95[1]
    # same seed, same interval
    again = density_ratio_near_zero(coupled, single, half_width=0.2, n_bootstrap=500, seed=3)
    assert again.ci95 == res.ci95


def test_density_is_normalised_by_all_samples():
    v = np.array([0.1, 0.2, 5.0, 7.0])
    np.testing.assert_allclose(density(v, np.array([0.0, 0.5])), [2 / 4 / 0.5])


# ------------------------------------------------------------ heavy-tailed RMS
def test_heavy_tailed_summary_median_geomean_stable_mean_flagged():
    rng = np.random.default_rng(5)
    x = 10.0 ** rng.normal(0.0, 2.0, 400)  # log-normal over about ten decades
    s = heavy_tailed_summary(x, thresholds=(1.0, 1e3), n_bootstrap=800, seed=1)
    assert s["median"]["ci95"][0] < 1.0 < s["median"]["ci95"][1]  # true median 1
    assert s["geometric_mean"]["ci95"][0] < 1.0 < s["geometric_mean"]["ci95"][1]
    assert s["fraction_above"]["1"] == pytest.approx(0.5, abs=0.08)
    assert s["fraction_above"]["1000"] == pytest.approx(scipy.stats.norm.sf(1.5), abs=0.04)
    # the mean is carried by a few draws: its interval spans more than a decade
    assert s["mean"]["largest_share"] > 0.2
    lo, hi = s["mean"]["ci95"]
    assert hi / lo > 10
    r, rlo, rhi = bootstrap_ratio_ci(x / 100, x, "median", 500, seed=2)
    assert r == pytest.approx(0.01) and rlo < 0.01 < rhi
