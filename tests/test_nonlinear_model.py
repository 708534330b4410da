"""The nonlinear stick, eq. (1): linear limit, saturation, seeds and threads."""

from __future__ import annotations

import numpy as np
import pytest

from cipcore.scenario import Execution, Recording, Scenario
from reduced import BalanceParams, ParameterError, simulate
from reduced.nonlinear import simulate_nonlinear

P = BalanceParams(beta=20.306)


def test_small_angle_limit_is_the_linear_single_model_under_the_same_seed():
    lin = simulate(
        Scenario("single", P, 20.0, 3, 9, amplitude=1e-7),
        recording=Recording(fields=("balancing_error",)),
    )
    non = simulate_nonlinear(
        Scenario("single", P, 20.0, 3, 9, amplitude=1e-7),
        recording=Recording(fields=("balancing_error",)),
    )
    e, th = lin["balancing_error"], non["balancing_error"]
    assert np.max(np.abs(e)) < 1e-3  # still small: sin(theta) = theta to 1e-7 relative
    np.testing.assert_allclose(th, e, rtol=1e-6, atol=1e-9 * np.max(np.abs(e)))


def test_same_seed_same_draws_for_any_thread_count_and_split():
    kw = {"noise_floor": 1e-3, "recording": Recording(fields=("angle",))}
    four = Scenario("single", P, 5.0, 4, 3, amplitude=0.01)
    a = simulate_nonlinear(four, execution=Execution(threads=1), **kw)["angle"]
    b = simulate_nonlinear(four, execution=Execution(threads=2), **kw)["angle"]
    two = Scenario("single", P, 5.0, 2, 3, amplitude=0.01)
    c = simulate_nonlinear(two, first_realization=2, execution=Execution(threads=1), **kw)["angle"]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[2:], c)
    # the floor changes the path; without it the path differs
    d = simulate_nonlinear(
        Scenario("single", P, 5.0, 4, 3, amplitude=0.01), recording=Recording(fields=("angle",))
    )["angle"]
    assert not np.array_equal(a, d)


def test_sine_saturates_where_the_linear_model_runs_away():
    # far above the stability boundary in gain: the linear error grows without bound,
    # the stick falls over and stays bounded near theta = pi (mod 2 pi)
    p = BalanceParams(beta=5.0)
    scn = Scenario("single", p, 40.0, 2, 1, amplitude=0.1)
    th = simulate_nonlinear(scn, recording=Recording(decimate=10, fields=("angle",)))["angle"]
    assert np.all(np.isfinite(th)) and np.max(np.abs(th)) < 4 * np.pi
    lin = simulate(scn, recording=Recording(decimate=10, fields=("balancing_error",)))
    assert np.max(np.abs(lin["balancing_error"])) > 1e3


def test_bad_input_names_the_parameter():
    with pytest.raises(ParameterError, match="noise_floor"):
        simulate_nonlinear(Scenario("single", P, 1.0), noise_floor=-1.0)
    with pytest.raises(ParameterError, match="fields"):
        simulate_nonlinear(
            Scenario("single", P, 1.0), recording=Recording(fields=("tip_position",))
        )
