"""The reduced models step exactly as the paper's equations say."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cipcore.scenario import Execution, Recording, Scenario
from cipcore.schema import plan_recording
from reduced import ArrayNoise, BalanceParams, GainNoise, ParameterError, simulate

P = BalanceParams(beta=20.0)


def one_step(model: str, params: BalanceParams, xi: np.ndarray, stepper="semi-implicit"):
    """Simulate 2 steps and return the state after the first (sample 1)."""
    noise = ArrayNoise(xi)
    return simulate(
        Scenario(model, params, 2 * params.dt, amplitude=0.1), noise=noise, stepper=stepper
    )


def test_single_first_step_matches_equation_by_hand():
    # e(0) = 0.1, history e = 0.1, at rest: x_T'' = alpha e, x_M'' = beta R e(t - tau)
    p = BalanceParams(beta=20.0, nu=0.6, dt=1e-3)
    xi = np.array([[[0.7], [0.0]]])
    tr = one_step("single", p, xi)
    r = 1 + 0.6 * 0.7 / np.sqrt(1e-3)
    a_t = 22.0 * 0.1
    a_m = 20.0 * r * 0.1
    h = 1e-3
    np.testing.assert_allclose(tr["tip_velocity"][0, 1, 0], h * a_t, rtol=1e-14)
    np.testing.assert_allclose(tr["tip_position"][0, 1, 0], 0.1 + h * h * a_t, rtol=1e-14)
    np.testing.assert_allclose(tr["base_velocity"][0, 1, 0], h * a_m, rtol=1e-14)
    np.testing.assert_allclose(tr["base_position"][0, 1, 0], h * h * a_m, rtol=1e-14)


def test_explicit_stepper_moves_positions_with_old_velocity():
    p = BalanceParams(beta=20.0, nu=0.0)
    tr = one_step("single", p, np.zeros((1, 2, 1)), stepper="explicit")
    assert tr["tip_position"][0, 1, 0] == 0.1  # v(0) = 0
    np.testing.assert_allclose(tr["tip_velocity"][0, 1, 0], 1e-3 * 22.0 * 0.1, rtol=1e-14)


def test_coupled_first_step_matches_equation_by_hand():
    p = BalanceParams(beta=20.0, nu=0.6)
    xi = np.array([[[0.3, -1.2], [0.0, 0.0]]])
    tr = one_step("coupled", p, xi)
    h = 1e-3
    # 2 q_T'' = alpha (e1 + e2) = 2 * 22 * 0.1
    np.testing.assert_allclose(tr["tip_velocity"][0, 1], h * 22.0 * 0.1, rtol=1e-14)
    for i, x in enumerate((0.3, -1.2)):
        a_m = 20.0 * (1 + 0.6 * x / np.sqrt(h)) * 0.1
        np.testing.assert_allclose(tr["base_velocity"][0, 1, i], h * a_m, rtol=1e-14)


def test_gravity_sign_error_grows_without_feedback():
    """beta = 0: the stick falls to the side it leans, e grows like exp(sqrt(alpha) t)-ish."""
    p = BalanceParams(beta=0.0, nu=0.0, gamma=0.0)
    tr = simulate(Scenario("single", p, 1.0, amplitude=1e-3))
    e = tr["balancing_error"][0, :, 0]
    assert np.all(np.diff(e) > 0)
    # undamped, no feedback: x_T'' = alpha (x_T - 0): e(1) = cosh(sqrt(alpha)) * e(0)
    np.testing.assert_allclose(e[-1], 1e-3 * np.cosh(np.sqrt(22.0) * 0.999), rtol=5e-3)


def test_feedback_pushes_base_towards_tip():
    p = BalanceParams(beta=20.0, nu=0.0)
    tr = simulate(Scenario("single", p, 0.01, amplitude=0.05))
    assert tr["base_velocity"][0, -1, 0] > 0  # e > 0: the base accelerates to +x


def test_delay_is_exactly_tau():
    """The base acceleration at step n is beta * e at step n - d, d = tau / dt.

    alpha = gamma = 0: the tip stays put, the base moves under the delayed law only.
    The history before t = 0 is constant (e = amplitude).
    """
    p = BalanceParams(beta=10.0, nu=0.0, alpha=0.0, gamma=0.0, tau=0.05, dt=1e-3)
    d = p.delay_steps
    tr = simulate(Scenario("single", p, 3 * p.tau, amplitude=0.02))
    vm = tr["base_velocity"][0, :, 0]
    acc = np.diff(vm) / p.dt
    e = tr["balancing_error"][0, :, 0]
    np.testing.assert_allclose(acc[:d], 10.0 * 0.02, rtol=1e-12)
    np.testing.assert_allclose(acc[d : 2 * d], 10.0 * e[:d], rtol=1e-9)
    assert acc[d] != pytest.approx(10.0 * e[1], rel=1e-6)  # not d - 1


def test_noise_uses_euler_maruyama_scaling():
    """One-step base velocity increments: variance (h beta nu e / sqrt(h))^2 = h (beta nu e)^2."""
    for dt in (1e-3, 2.5e-4):
        p = BalanceParams(beta=20.0, nu=0.6, alpha=0.0, gamma=0.0, dt=dt)
        tr = simulate(Scenario("single", p, 2 * dt, 4000, 3, amplitude=1.0))
        dv = tr["base_velocity"][:, 1, 0]
        expected = dt * (20.0 * 0.6) ** 2
        # sample variance of 4000 Gaussians: relative s.e. sqrt(2/3999) = 2.2 %
        assert np.var(dv) == pytest.approx(expected, rel=0.1)


def test_coupled_reduces_to_single_when_errors_equal():
    """Paper: eq. (6) coincides with eq. (2) if e1 = e2 (same noise in both)."""
    p = BalanceParams(beta=20.306)
    xi1 = GainNoise(7, 2, 1).draws(5000)
    single = simulate(Scenario("single", p, 5.0, amplitude=0.01), noise=ArrayNoise(xi1))
    coupled = simulate(
        Scenario("coupled", p, 5.0, amplitude=0.01), noise=ArrayNoise(np.repeat(xi1, 2, axis=2))
    )
    for i in range(2):
        np.testing.assert_allclose(
            coupled["balancing_error"][..., i],
            single["balancing_error"][..., 0],
            rtol=1e-12,
            atol=1e-15,
        )
    # and with independent noise they differ
    indep = simulate(Scenario("coupled", p, 5.0, 2, 7, amplitude=0.01))
    assert not np.allclose(indep["balancing_error"][..., 0], indep["balancing_error"][..., 1])


def test_rigid_rod_equal_tip_velocities_in_reduced_coupled():
    tr = simulate(Scenario("coupled", P, 1.0, 2, 1))
    np.testing.assert_array_equal(tr["tip_velocity"][..., 0], tr["tip_velocity"][..., 1])


@settings(max_examples=20, deadline=None)
@given(
    scale=st.floats(1e-6, 1e3),
    beta=st.floats(5.0, 40.0),
    seed=st.integers(0, 2**31),
)
def test_linear_in_the_initial_amplitude(scale, beta, seed):
    p = BalanceParams(beta=beta)
    a = simulate(Scenario("coupled", p, 0.5, 2, seed, amplitude=1.0))
    b = simulate(Scenario("coupled", p, 0.5, 2, seed, amplitude=scale))
    np.testing.assert_allclose(
        b["balancing_error"], scale * a["balancing_error"], rtol=1e-9, atol=1e-300
    )


def test_same_seed_same_numbers_whatever_threads_and_realisation_count():
    a = simulate(Scenario("coupled", P, 2.0, 5, 11), execution=Execution(threads=1))
    b = simulate(Scenario("coupled", P, 2.0, 5, 11), execution=Execution(threads=2))
    c = simulate(Scenario("coupled", P, 2.0, 3, 11), execution=Execution(threads=2))
    for f in a.data:
        np.testing.assert_array_equal(a[f], b[f])
        np.testing.assert_array_equal(a[f][:3], c[f])
    d = simulate(Scenario("coupled", P, 2.0, 5, 12), execution=Execution(threads=2))
    assert not np.array_equal(a["balancing_error"], d["balancing_error"])


def test_chunking_does_not_change_results(monkeypatch):
    from cipcore import driver as _driver

    a = simulate(Scenario("single", P, 3.0, 2, 5))
    monkeypatch.setattr(_driver, "CHUNK_STEPS", 777)
    b = simulate(Scenario("single", P, 3.0, 2, 5))
    np.testing.assert_array_equal(a["balancing_error"], b["balancing_error"])


def test_decimation_float32_and_schema():
    tr = simulate(
        Scenario("coupled", P, 1.0, 3),
        recording=Recording(
            decimate=10, fields=("balancing_error", "tip_velocity"), dtype=np.float32
        ),
    )
    full = simulate(Scenario("coupled", P, 1.0, 3))
    assert tr["balancing_error"].shape == (3, 100, 2)
    assert tr["balancing_error"].dtype == np.float32
    np.testing.assert_allclose(
        tr["balancing_error"], full["balancing_error"][:, ::10], rtol=1e-6, atol=1e-12
    )
    np.testing.assert_allclose(tr.time, np.arange(100) * 0.01)
    with pytest.raises(KeyError, match="not recorded"):
        tr["angle"]


def test_paper_workload_fits_in_2_gib():
    # 100 realisations x 1200 s at 1 ms, balancing errors of both controllers in float32
    small = Recording(fields=("balancing_error",), dtype=np.float32, max_bytes=2 * 1024**3)
    n, fields = plan_recording(1_200_000, 100, 2, small)
    assert n == 1_200_000 and fields == ("balancing_error",)
    big = Recording(fields=("balancing_error",) * 4, dtype=np.float64, max_bytes=2 * 1024**3)
    with pytest.raises(ParameterError, match="decimate"):
        plan_recording(1_200_000, 100, 2, big)


def test_npz_round_trip(tmp_path):
    tr = simulate(Scenario("single", P, 0.2, 2))
    path = tr.save_npz(tmp_path / "x.npz")
    back = type(tr).load_npz(path)
    np.testing.assert_array_equal(back["balancing_error"], tr["balancing_error"])
    assert back.attrs["beta"] == 20.0 and back.attrs["engine"] == "reduced"


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"beta": -1.0}, "beta"),
        ({"beta": float("nan")}, "beta"),
        ({"beta": 20.0, "gamma": -2.0}, "gamma"),
        ({"beta": 20.0, "nu": float("inf")}, "nu"),
        ({"beta": 20.0, "tau": 0.1005}, "tau"),
        ({"beta": 20.0, "dt": 0.0}, "dt"),
        ({"beta": 20.0, "tau": 0.0}, "tau"),
    ],
)
def test_bad_parameters_name_themselves(kwargs, name):
    with pytest.raises(ParameterError, match=name) as info:
        BalanceParams(**kwargs)
    assert "\n" not in str(info.value)


def test_bad_run_arguments():
    with pytest.raises(ParameterError, match="realizations"):
        simulate(Scenario("single", P, 1.0, 0))
    with pytest.raises(ParameterError, match="duration"):
        simulate(Scenario("single", P, 1.0005))
    with pytest.raises(ParameterError, match="model"):
        simulate(Scenario("triple", P, 1.0))
    with pytest.raises(ParameterError, match="amplitude"):
        simulate(Scenario("single", P, 1.0, amplitude=float("nan")))
