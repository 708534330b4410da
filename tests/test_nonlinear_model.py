"""The nonlinear stick, eq. (1): linear limit, saturation, seeds and threads."""

from __future__ import annotations

import numpy as np
import pytest

from reduced import BalanceParams, ParameterError, simulate
from reduced.nonlinear import simulate_nonlinear

P = BalanceParams(beta=20.306)


def test_small_angle_limit_is_the_linear_single_model_under_the_same_seed():
    lin = simulate("single", P, 20.0, 3, seed=9, amplitude=1e-7, fields=("balancing_error",))
    non = simulate_nonlinear(P, 20.0, 3, seed=9, amplitude=1e-7, fields=("balancing_error",))
    e, th = lin["balancing_error"], non["balancing_error"]
    assert np.max(np.abs(e)) < 1e-3  # still small: sin(theta) = theta to 1e-7 relative
    np.testing.assert_allclose(th, e, rtol=1e-6, atol=1e-9 * np.max(np.abs(e)))


def test_same_seed_same_draws_for_any_thread_count_and_split():
    kw = {"amplitude": 0.01, "noise_floor": 1e-3, "fields": ("angle",)}
    a = simulate_nonlinear(P, 5.0, 4, seed=3, threads=1, **kw)["angle"]
    b = simulate_nonlinear(P, 5.0, 4, seed=3, threads=2, **kw)["angle"]
    c = simulate_nonlinear(P, 5.0, 2, seed=3, first_realization=2, threads=1, **kw)["angle"]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[2:], c)
    # the floor changes the path; without it the path differs
    d = simulate_nonlinear(P, 5.0, 4, seed=3, amplitude=0.01, fields=("angle",))["angle"]
    assert not np.array_equal(a, d)


def test_sine_saturates_where_the_linear_model_runs_away():
    # far above the stability boundary in gain: the linear error grows without bound,
    # the stick falls over and stays bounded near theta = pi (mod 2 pi)
    p = BalanceParams(beta=5.0)
    kw = {"amplitude": 0.1, "decimate": 10}
    th = simulate_nonlinear(p, 40.0, 2, seed=1, fields=("angle",), **kw)["angle"]
    assert np.all(np.isfinite(th)) and np.max(np.abs(th)) < 4 * np.pi
    lin = simulate("single", p, 40.0, 2, seed=1, fields=("balancing_error",), **kw)
    assert np.max(np.abs(lin["balancing_error"])) > 1e3


def test_bad_input_names_the_parameter():
    with pytest.raises(ParameterError, match="noise_floor"):
        simulate_nonlinear(P, 1.0, noise_floor=-1.0)
    with pytest.raises(ParameterError, match="fields"):
        simulate_nonlinear(P, 1.0, fields=("tip_position",))
