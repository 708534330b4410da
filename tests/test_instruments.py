"""Instruments over twenty decades: STCC precision, density ratio, peaks, heavy-tailed RMS."""

from __future__ import annotations

import numpy as np
import pytest

from validation.metrics import stcc

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
    assert worst < 1e-9
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
            assert r[0, k, j] == pytest.approx(ref, abs=1e-9)
            assert r[1, k, j] == pytest.approx(-ref, abs=1e-9)
