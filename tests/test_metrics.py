"""Metrics against signals whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from validation.checks.metrics import (
    first_dominant_peak,
    fit_two_power_laws,
    laminar_phases,
    power_law_exponent,
    power_spectrum,
    rms,
    stcc,
    stcc_significance,
    velocity_density_ratio,
)

RNG = np.random.default_rng(12345)


def test_stcc_equals_the_definition_by_brute_force():
    dt, n = 0.01, 900
    x = RNG.standard_normal((2, n)).cumsum(axis=-1)
    y = np.roll(x, 3, axis=-1) + RNG.standard_normal((2, n))
    t, lags, r = stcc(x, y, dt, window=2.0, max_lag=0.1, stride=0.5)
    w = 200
    for k, t0 in enumerate(t):
        i = round(t0 / dt)
        for j in range(len(lags)):
            xs, ys_ = x[1, i : i + w], y[1, i + j : i + j + w]
            yw = y[1, i : i + w]
            c = np.mean((xs - xs.mean()) * (ys_ - yw.mean()))
            expect = c / (xs.std() * yw.std())
            assert r[1, k, j] == pytest.approx(expect, rel=1e-9, abs=1e-12)


def test_stcc_of_delayed_copy_peaks_at_the_delay():
    dt, delay = 0.005, 0.035
    n = 40_000
    x = RNG.standard_normal((3, n))
    y = np.roll(x, round(delay / dt), axis=-1) + 0.5 * RNG.standard_normal((3, n))
    _, lags, r = stcc(x, y, dt, window=5.0, max_lag=0.2, stride=1.0)
    tau_hat = first_dominant_peak(r, lags, significance=stcc_significance(1000))
    assert np.all(tau_hat == pytest.approx(delay))


def test_white_noise_has_no_dominant_peak():
    dt = 0.005
    x = RNG.standard_normal((3, 40_000))
    y = RNG.standard_normal((3, 40_000))
    _, lags, r = stcc(x, y, dt, window=5.0, max_lag=0.2, stride=1.0)
    tau_hat = first_dominant_peak(r, lags, significance=stcc_significance(1000))
    # max over 41 lags of |R| exceeds 3 sigma in a few windows by chance
    assert np.mean(np.isnan(tau_hat)) > 0.9
    # without a significance level nearly every window would report a spurious peak
    assert np.mean(np.isnan(first_dominant_peak(r, lags))) < 0.1


def test_first_dominant_peak_rule():
    lags = np.arange(6) * 0.01
    assert first_dominant_peak(np.array([0.1, 0.5, 0.2, 0.55, 0.3, 0.2]), lags) == 0.01
    assert first_dominant_peak(np.array([0.1, 0.2, 0.1, 0.9, 0.3, 0.2]), lags) == 0.03
    assert np.isnan(first_dominant_peak(np.array([0.9, 0.5, 0.4, 0.3, 0.2, 0.1]), lags))
    # R still rising at the end of the lag range: a boundary, never a peak
    assert np.isnan(first_dominant_peak(np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6]), lags))


def _process_with_spectrum(slopes, fc, n, dt, reals):
    """Gaussian noise whose PSD is f^s1 below fc and f^s2 above (continuous)."""
    f = np.fft.rfftfreq(n, dt)
    f = np.maximum(f, f[1])
    amp = np.where(f < fc, (f / fc) ** (slopes[0] / 2), (f / fc) ** (slopes[1] / 2))
    amp[0] = 0
    z = RNG.standard_normal((reals, f.size)) + 1j * RNG.standard_normal((reals, f.size))
    return np.fft.irfft(z * amp, n=n, axis=-1)


@pytest.mark.parametrize(("slopes", "fc"), [((-0.5, -2.0), 1.0), ((0.0, -3.0), 2.0)])
def test_power_law_fit_recovers_known_slopes(slopes, fc):
    dt = 0.01
    x = _process_with_spectrum(slopes, fc, 2**17, dt, reals=8)
    f, s = power_spectrum(x, dt, segment=100.0)
    fit = fit_two_power_laws(f, s, fmin=0.05, fmax=20.0, n_bootstrap=50)
    assert fit.slope_low == pytest.approx(slopes[0], abs=0.08)
    assert fit.slope_high == pytest.approx(slopes[1], abs=0.1)
    assert fit.crossover == pytest.approx(fc, rel=0.3)
    assert 0 < fit.slope_low_se < 0.1


def test_welch_spectrum_of_white_noise_is_flat_at_2_sigma2_dt():
    dt = 0.001
    x = RNG.normal(0, 2.0, (4, 200_000))
    _f, s = power_spectrum(x, dt, segment=2.0)
    assert np.mean(s) == pytest.approx(2 * 4.0 * dt, rel=0.02)  # one-sided PSD


def test_rms_and_velocity_density_ratio():
    assert rms(np.array([[3.0, -3.0, 3.0, -3.0]]))[0] == 3.0
    edges = np.linspace(-3, 3, 61)
    narrow = RNG.normal(0, 0.5, 200_000)
    wide = RNG.normal(0, 1.0, 200_000)
    centres, ratio = velocity_density_ratio(narrow, wide, edges)
    mid = np.argmin(np.abs(centres))
    assert ratio[mid] == pytest.approx(2.0, rel=0.1)  # Gaussian densities at 0: 1/0.5 vs 1/1


def test_laminar_phase_durations_and_exponent():
    e = np.array([5, 0, 0, 0, 5, 0, 5, 5, 0, 0, 5], dtype=float)
    np.testing.assert_allclose(laminar_phases(e, 0.1, 1.0), [0.3, 0.1, 0.2])
    # runs touching the ends are dropped
    np.testing.assert_allclose(laminar_phases(np.array([0, 0, 5, 0, 5, 0.0]), 1.0, 1.0), [1.0])
    # durations drawn from a density ~ T^-3/2 on [1, 1000]
    u = RNG.random(200_000)
    t = (1 - u * (1 - 1000**-0.5)) ** -2.0
    slope, se = power_law_exponent(t, 1.0, 1000.0)
    assert slope == pytest.approx(-1.5, abs=max(3 * se, 0.05))


def test_bootstrap_broken_lines_fitted_at_once_equal_one_at_a_time():
    """The bootstrap's broken lines, fitted in one pass, are the one-by-one fits to rounding."""
    from validation.checks.metrics import _broken_line, broken_lines, log_bins

    rng = np.random.default_rng(3)
    f = np.linspace(0.02, 30.0, 2000)
    s = (f**-0.5 / (1 + (f / 2) ** 2)) * np.exp(rng.standard_normal((12, f.size)))
    lf, ls = log_bins(f, s, 0.05, 20.0, 24)
    rows = np.stack([ls[rng.integers(0, 12, 12)].mean(axis=0) for _ in range(60)])
    together = broken_lines(lf, rows)
    alone = np.array([_broken_line(lf, r) for r in rows])
    np.testing.assert_array_equal(together[:, 2], alone[:, 2])  # the same breakpoints
    np.testing.assert_allclose(together, alone, rtol=1e-12, atol=0)


def test_stcc_and_its_bartlett_level_do_not_depend_on_the_number_of_threads(monkeypatch):
    """Series and lag ranges (STCC) and realisations (Bartlett) are spread over threads: the
    same numbers on 1, 2 or 7 threads, whether a thread takes whole series or part of one
    series' lags (3 series on 7 threads: each series' lags in 3 ranges)."""
    import validation.checks.metrics as m

    rng = np.random.default_rng(8)
    x, y = rng.standard_normal((2, 3, 4000)).cumsum(-1)
    monkeypatch.setattr(m, "_STCC_THREADED", 100)  # a thread per 100 samples, up to the cores
    got = []
    for n in (1, 2, 7):
        monkeypatch.setattr(m.os, "cpu_count", lambda n=n: n)
        t, _, r = m.stcc(x, y, 0.005, 2.0, 0.1, 0.25)
        got.append((r, m.effective_samples(x, y, 0.005, t, 2.0)))
    for other in got[1:]:
        np.testing.assert_array_equal(got[0][0], other[0])
        np.testing.assert_array_equal(got[0][1], other[1])
    # 1-D series: one series' lags split across the threads
    r1 = m.stcc(x[0], y[0], 0.005, 2.0, 0.1, 0.25)[2]
    np.testing.assert_array_equal(r1, got[0][0][0])


@pytest.mark.parametrize("starts", ["even", "uneven"])
def test_bartlett_effective_samples_equal_the_formula_by_brute_force(starts):
    """n_eff of each window from the autocorrelations summed directly (Bartlett's formula,
    in the form of Pyper & Peterman 1998, eq. 1), for window starts evenly spaced (read
    from a strided view) and not (gathered), over more windows than one FFT block."""
    import validation.checks.metrics as m

    dt, window = 0.01, 1.0
    rng = np.random.default_rng(5)
    x = rng.standard_normal((2, 3000)).cumsum(-1) * 1e-3
    y = rng.standard_normal((2, 3000)) + 5.0  # an offset the window means remove
    t = np.arange(0.0, 28.0, 0.2) if starts == "even" else np.sort(rng.uniform(0, 28, 70))
    t = np.round(t / dt) * dt
    got = m.effective_samples(x, y, dt, t, window)
    w, lag = 100, 20

    def acf(z, s):
        z = z[s : s + w] - z[s : s + w].mean()
        return np.array([z[: w - j] @ z[j:] for j in range(lag + 1)]) / (z @ z)

    for i in range(2):
        for k, t0 in enumerate(t):
            s = round(t0 / dt)
            rx, ry = acf(x[i], s), acf(y[i], s)
            j = np.arange(1, lag + 1)
            inv = 1 / w + 2 / w * np.sum((w - j) / w * rx[1:] * ry[1:])
            assert got[i, k] == pytest.approx(np.clip(1 / inv, 2, w), rel=1e-10)


def test_dominant_peaks_each_equals_dominant_peaks_at_each_dominance():
    from validation.checks.metrics import dominant_peaks, dominant_peaks_each

    rng = np.random.default_rng(6)
    r = rng.standard_normal((3, 40, 31))
    r[0, 3, 5], r[1, :2] = np.nan, np.nan  # a NaN lag, windows of NaN
    lags = np.arange(31) * 0.01
    for sig in (0.3, rng.random((3, 40))):
        each = dominant_peaks_each(r, lags, (0.5, 0.8, 0.95), sig)
        for dom, got in zip((0.5, 0.8, 0.95), each, strict=True):
            want = dominant_peaks(r, lags, dom, sig)
            for f in ("tau_hat", "no_peak", "boundary_max"):
                np.testing.assert_array_equal(getattr(got, f), getattr(want, f))
        assert not np.array_equal(each[0].tau_hat, each[2].tau_hat, equal_nan=True)
