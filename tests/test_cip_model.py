"""The MuJoCo CIP: files, physics, delay, and agreement with the reduced model."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cip.linearize import linearize, transition_check
from cip.lyapunov import lyapunov_full
from cip.mjcf_params import read_mapping
from cip.model import MODEL_DIR, CIPParams, bob_rotational_inertia, build, mjcf
from cip.runner import CIPRunner, RigidBody
from cip.simulate import DivergenceWarning, simulate_full
from cipcore.scenario import Execution, Recording, Scenario
from reduced import (
    BalanceParams,
    GainNoise,
    ParameterError,
    characteristic_roots,
    lyapunov,
    simulate,
)

P = BalanceParams(beta=20.306)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_model_files_hold_the_default_parameters(model):
    """The shipped file compiles to build()'s model at CIPParams() defaults, array for array."""
    path = MODEL_DIR / f"cip_{model}.xml"
    assert path.read_text() == mjcf(model)
    m = mujoco.MjModel.from_xml_path(str(path))
    assert model_arrays_differ(m, build(model)) == []
    nc = 1 if model == "single" else 2
    assert m.nq == m.nv == 2 * nc
    for i in range(1, nc + 1):
        for obj, name in [
            (mujoco.mjtObj.mjOBJ_JOINT, f"x_M{i}"),
            (mujoco.mjtObj.mjOBJ_JOINT, f"theta_{i}"),
            (mujoco.mjtObj.mjOBJ_SITE, f"tip_{i}"),
            (mujoco.mjtObj.mjOBJ_ACTUATOR, f"u_{i}"),
            (mujoco.mjtObj.mjOBJ_SENSOR, f"angle_{i}"),
        ]:
            assert mujoco.mj_name2id(m, obj, name) >= 0, name
    if nc == 2:
        assert m.neq == 1 and m.ntendon == 1


def model_arrays_differ(a: mujoco.MjModel, b: mujoco.MjModel) -> list[str]:
    """Names of the MjModel arrays and options in which two compiled models differ."""
    out = []
    for obj, prefix in ((a, ""), (a.opt, "opt.")):
        other = b if obj is a else b.opt
        for name in (n for n in dir(obj) if not n.startswith("_")):
            x = getattr(obj, name)
            if isinstance(x, np.ndarray | int | float) and not callable(x):
                y = getattr(other, name)
                if np.shape(x) != np.shape(y) or not np.array_equal(x, y, equal_nan=True):
                    out.append(prefix + name)
    return out


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_edited_parameters_read_back(model):
    """build() edits every physical parameter of the shipped file (read back by the mapping)."""
    p = CIPParams(pendulum_length=0.37, bob_mass=3.3e-3, cart_mass=1.7, tip_damping=13.1,
                  cart_damping=7.7, rod_length=2.345, rod_mass=0.1, bob_radius=0.0213,
                  solref=(0.0031, 0.77), solimp=(0.95, 0.97, 0.0021), timestep=7e-4,
                  integrator="RK4", gravity=9.7)  # fmt: skip
    mp = read_mapping(build(model, p))
    names = ("gravity", "pendulum_length", "tip_mass", "cart_mass", "tip_damping",
             "cart_damping", "timestep")  # fmt: skip
    got = {n: getattr(mp, n) for n in names} | {"bob_inertia": mp.bob_inertia}
    want = {n: getattr(p, n) for n in names} | {"bob_inertia": bob_rotational_inertia(p)}
    for name, value in want.items():
        assert got[name] == pytest.approx(value, rel=1e-12), name
    assert mp.integrator == p.integrator
    if model == "coupled":
        assert mp.solref == p.solref and mp.solimp == p.solimp
        m = build(model, p)
        assert m.body("cart_1").pos[0] - m.body("cart_2").pos[0] == pytest.approx(p.rod_length)


def test_masses_and_lengths_as_specified():
    p = CIPParams(bob_mass=2e-3, cart_mass=3.0, pendulum_length=0.5)
    m = build("single", p)
    cart = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "cart_1")
    pend = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "pendulum_1")
    assert m.body_mass[cart] == 3.0 and m.body_mass[pend] == 2e-3
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(d.site("tip_1").xpos, [0, 0, 0.5], atol=1e-15)


def test_gravity_sign_and_fall_direction():
    """Uncontrolled, undamped: a pendulum tilted to +x falls to +x, the free cart recoils to -x."""
    m = build("single", CIPParams(tip_damping=0.0, cart_damping=0.0))
    d = mujoco.MjData(m)
    d.qpos[1] = 0.05
    for _ in range(300):
        mujoco.mj_step(m, d)
    assert d.qpos[1] > 0.1 and d.site("tip_1").xpos[0] > 0.04 and d.qpos[0] < 0
    assert m.opt.gravity[2] == -9.81


def test_energy_conserved_without_control_and_damping():
    p = CIPParams(tip_damping=0.0, cart_damping=0.0, bob_mass=0.3, integrator="RK4", timestep=1e-4)
    m = build("coupled", p)
    m.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    d = mujoco.MjData(m)
    d.qpos[:] = [0.0, 0.2, 0.0, 0.2]
    d.qvel[:] = [0.1, 0.0, 0.1, 0.0]
    mujoco.mj_forward(m, d)
    e0 = d.energy.sum()
    for _ in range(3000):
        mujoco.mj_step(m, d)
    assert abs(d.energy.sum() - e0) < 1e-4 * abs(d.energy[1] + 1e-3)
    assert abs(d.qpos[1]) > 0.3  # it really moved


def _tip_velocity_mismatch(amplitude: float) -> tuple[float, object]:
    tr = simulate_full(
        Scenario("coupled", BalanceParams(beta=20.306), 5.0, 3, 2, amplitude=amplitude)
    )
    vt = tr["tip_velocity"]
    diff = vt[..., 0] - vt[..., 1]
    return float(np.sqrt((diff**2).mean() / (vt**2).mean())), tr


def test_rod_holds_its_length():
    """Random forcing of the carts: the rod length stays l to the constraint's accuracy."""
    _, tr = _tip_velocity_mismatch(0.05)
    assert np.max(tr.attrs["max_abs_angle"]) > 0.05  # the test exercised real motion
    m = build("coupled")
    d = mujoco.MjData(m)
    lengths = []
    for k in range(0, tr.time.size, 50):
        d.qpos[:] = [tr["base_position"][0, k, 0], tr["angle"][0, k, 0],
                     tr["base_position"][0, k, 1], tr["angle"][0, k, 1]]  # fmt: skip
        mujoco.mj_kinematics(m, d)
        mujoco.mj_tendon(m, d)
        lengths.append(d.ten_length[0])
    assert np.max(np.abs(np.array(lengths) - 1.0)) < 1e-6


def test_tip_velocities_equal_in_the_small_angle_regime():
    """Paper eq. (4): q_T1' = q_T2'.  In the rigid body it holds to second order in
    the angles (tips at unequal heights tilt the rod) plus the soft constraint's lag, a
    linear, amplitude-independent floor (measured 1.2e-5 relative RMS)."""
    tiny, _ = _tip_velocity_mismatch(1e-4)
    small, _ = _tip_velocity_mismatch(1e-3)
    large, _ = _tip_velocity_mismatch(3e-2)
    assert small < 3e-5
    assert small == pytest.approx(tiny, rel=0.1)  # linear regime: a floor, not geometry
    assert large > 30 * small  # second order in the angles


def test_delay_is_exactly_tau_and_noise_at_time_t():
    """The force applied over step n is M beta R_n e(n - d), R_n the noise *of step n*."""
    p = BalanceParams(beta=20.306, tau=0.02)
    runner = CIPRunner("single", p, CIPParams.from_reduced(p), 2, 0.01)
    noise = GainNoise(5, 2, 1)
    e_all = [runner.errors(runner.state)[0]]
    forces = []
    xis = []
    for _ in range(5):
        xi = noise.next_chunk(runner.d)
        out = runner.advance(xi)
        forces.append(runner.controls[:, : runner.d, runner.i_u[0]].copy())
        xis.append(xi[..., 0])
        e_all.append(runner.errors(out)[0][..., 0].T)
    e = np.concatenate([np.atleast_2d(e_all[0].T)] + [x for x in e_all[1:]], axis=0).T
    f = np.concatenate(forces, axis=1)
    xi = np.concatenate(xis, axis=1)
    d = runner.d
    n = np.arange(d, 5 * d)
    expected = 1.0 * 20.306 * (1 + p.noise_scale * xi[:, n]) * e[:, n - d]
    np.testing.assert_allclose(f[:, n], expected, rtol=1e-12)
    wrong = 1.0 * 20.306 * (1 + p.noise_scale * xi[:, n]) * e[:, n - d + 1]
    assert not np.allclose(f[:, n], wrong, rtol=1e-6)


def _rel_l2(model, amplitude, mass_ratio, duration=10.0):
    phys = CIPParams.from_reduced(P, mass_ratio=mass_ratio)
    full = simulate_full(
        Scenario(model, P, duration, 2, 1, amplitude=amplitude),
        body=RigidBody(physical=phys),
        recording=Recording(fields=("balancing_error",)),
    )
    red = simulate(
        Scenario(model, P, duration, 2, 1, amplitude=amplitude),
        recording=Recording(fields=("balancing_error",)),
    )
    ef, er = full["balancing_error"], red["balancing_error"]
    return np.linalg.norm(ef - er) / np.linalg.norm(er)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_same_noise_same_trajectory_as_reduced_model(model):
    """Issue 3: amplitude 1e-6, paper parameters, 10 s: < 1 % relative L2, and the
    difference shrinks with m/M (the cart reaction) and, at large amplitude, grows."""
    base = _rel_l2(model, 1e-6, 1e-3)
    assert base < 0.01
    assert _rel_l2(model, 1e-6, 1e-4) < 0.2 * base
    assert _rel_l2(model, 3e-2, 1e-4) > 3 * _rel_l2(model, 1e-6, 1e-4)


def test_same_seed_same_numbers_whatever_threads():
    a = simulate_full(Scenario("coupled", P, 1.05, 3, 9), execution=Execution(threads=1))
    b = simulate_full(Scenario("coupled", P, 1.05, 3, 9), execution=Execution(threads=2))
    for f in a.data:
        np.testing.assert_array_equal(a[f], b[f])
    assert a.time.size == 1050  # the last, partial chunk of tau is included


def test_linearisation_matches_reduced_up_to_documented_terms():
    for model in ("single", "coupled"):
        lin = linearize(model)
        assert np.abs(lin.A_diff).max() > 0.02  # the extra terms are really there (m/M alpha)
        assert lin.residual < 1e-4
        # a bob of finite radius adds kappa = 2/5 (r/L)^2, predicted to first order
        sphere = linearize(model, CIPParams(bob_radius=0.02))
        assert np.abs(sphere.A_extra).max() > np.abs(lin.A_extra).max() + 0.01
        assert sphere.residual < 1e-4
        small = linearize(model, CIPParams(bob_mass=1e-5))
        assert small.residual < 1e-6
        assert transition_check(model) < 1e-9
    k = linearize("coupled").rod_stiffness
    assert k == pytest.approx(CIPParams().implied_reduced()["rod_stiffness"], rel=0.02)


def test_noise_free_full_exponent_is_root_with_cart_reaction():
    p = BalanceParams(beta=23.0, nu=0.0)
    lam = lyapunov_full(Scenario("single", p, 100.0, 1)).lambda1
    eff = characteristic_roots("single", p.with_(alpha=22.0 * 1.001)).abscissa
    assert lam == pytest.approx(eff, abs=2e-4)


@pytest.mark.parametrize("beta", [19.5, 20.3, 23.0])
def test_full_lyapunov_agrees_with_reduced_within_ci(beta):
    p = BalanceParams(beta=beta)
    scn = Scenario("single", p, 100.0, 6, 3)
    full = lyapunov_full(scn)
    red = lyapunov(scn)
    assert full.ci95[0] <= red.lambda1 <= full.ci95[1]
    assert red.ci95[0] <= full.lambda1 <= red.ci95[1]


def test_divergence_stops_and_keeps_what_was_computed():
    p = BalanceParams(beta=1e9, nu=0.0)
    with pytest.warns(DivergenceWarning, match="realisation"):
        tr = simulate_full(Scenario("single", p, 5.0, 2, amplitude=0.01))
    assert tr.attrs["diverged"] is not None
    assert 0 < tr.time.size < 5000
    assert np.isfinite(tr["balancing_error"][:, :10]).all()
    # every realisation keeps its samples up to the stop, whatever the thread timing
    for threads in (1, 2):
        with pytest.warns(DivergenceWarning):
            again = simulate_full(
                Scenario("single", p, 5.0, 2, amplitude=0.01), execution=Execution(threads=threads)
            )
        assert again.time.size == tr.time.size
        np.testing.assert_array_equal(again["balancing_error"], tr["balancing_error"])


def test_a_non_finite_state_mid_chunk_returns_only_the_finite_samples_before_it(
    mujoco_nan_after,
):
    """An engine whose state goes non-finite inside a chunk (Exudyn at the quick profile's
    largest scan amplitude, seed 7) stops there: the trajectory ends with the last sample
    before the first non-finite state, not at the chunk's end with NaNs in it, and the
    warning names the engine."""
    at = 1234  # the state after this global step is non-finite in realisation 1
    mujoco_nan_after(at, row=1)
    scn = Scenario("single", BalanceParams(beta=21.0), 3.0, 2, amplitude=0.01)
    body = RigidBody(name="nan-engine")
    with pytest.warns(DivergenceWarning, match="nan-engine run stopped: non-finite state"):
        tr = simulate_full(scn, body=body, recording=Recording(decimate=5),
                           execution=Execution(threads=1))  # fmt: skip
    assert tr.time.size == -(-(at + 1) // 5)  # samples at steps 0, 5, ..., 1230: 247
    assert np.isfinite(tr["balancing_error"]).all()
    assert tr.attrs["diverged"]["reason"] == "non-finite state"


@pytest.mark.parametrize("threads", [1, 2])
def test_a_non_finite_benettin_run_is_an_infinite_exponent_and_the_others_run_on(
    threads, mujoco_nan_after
):
    """An engine whose Benettin run goes non-finite in one realisation: that realisation's
    exponent is +inf and the time is recorded (the end of the renormalisation interval),
    the run goes on (it used to raise FloatingPointError and crash the lambda1 stage), and
    every other realisation's exponent is the clean run's bit for bit, whatever the
    threads (each block's first realisation goes non-finite: with 2 threads, 0 and 2)."""
    p = BalanceParams(beta=21.0)
    scn = Scenario("single", p, 3.0, 4, seed=5)
    clean = lyapunov_full(scn, execution=Execution(threads=1))
    assert clean.diverged_at is None and "diverged_at" not in clean.as_dict()
    mujoco_nan_after(1234)
    body = RigidBody(name="nan-engine")
    with pytest.warns(DivergenceWarning, match="nan-engine lambda1 run: non-finite state"):
        got = lyapunov_full(scn, body=body, execution=Execution(threads=threads))
    bad = [0] if threads == 1 else [0, 2]
    end = -(-1235 // p.delay_steps) * p.delay_steps * p.dt  # the interval holding step 1234
    assert np.isinf(got.per_realization[bad]).all() and got.lambda1 == np.inf
    np.testing.assert_allclose(got.diverged_at[bad], end, rtol=1e-12)
    good = [k for k in range(4) if k not in bad]
    np.testing.assert_array_equal(got.per_realization[good], clean.per_realization[good])
    assert np.isnan(got.diverged_at[good]).all()
    assert "non-finite in" in got.divergence() and got.as_dict()["diverged_at"][bad[0]] > 0
    from validation.checks.divergence import lyapunov_events

    ev = lyapunov_events(got.per_realization, diverged_at=got.diverged_at)  # `lyapunov`'s
    assert [(e.realization, e.time) for e in ev] == [(k, pytest.approx(end)) for k in bad]
    assert ev[0].reason == "non-finite state (Benettin run)"
    part = got.part(slice(1, 2), 21.0, 5)  # a batch's part keeps its realisations' times
    assert part.diverged_at is None and got.part(slice(2, 4), 21.0, 5).divergence() == (
        None
        if threads == 1
        else f"the engine's state went non-finite in 1 of 2 realisations (0 by t = {end:.4g} s)"
    )


def test_bad_input():
    with pytest.raises(ParameterError, match="amplitude"):
        simulate_full(Scenario("single", P, 1.0, amplitude=0.5))
    with pytest.raises(ParameterError, match="bob_mass"):
        CIPParams(bob_mass=-1.0)
    with pytest.raises(ParameterError, match="integrator"):
        CIPParams(integrator="Verlet")
    with pytest.raises(ParameterError, match="fields"):
        simulate_full(Scenario("single", P, 1.0), recording=Recording(fields=("torque",)))


def test_full_lyapunov_same_seed_same_numbers_whatever_threads():
    p = BalanceParams(beta=21.0)
    a = lyapunov_full(Scenario("coupled", p, 5.0, 3, 4), execution=Execution(threads=1))
    b = lyapunov_full(Scenario("coupled", p, 5.0, 3, 4), execution=Execution(threads=2))
    np.testing.assert_array_equal(a.per_realization, b.per_realization)


def test_pd_controller_balances_the_cip():
    """The authors' earlier PD-controlled CIP: F = M (kp e + kd e'), delayed one step.

    Linear error dynamics e'' + (gamma + kd) e' + (kp - alpha_eff) e = 0 with
    alpha_eff = alpha (1 + m/M): kp > alpha_eff decays at the slow root, kp < alpha falls."""
    from cip.runner import Controller

    p = BalanceParams(beta=0.0, nu=0.0, tau=0.001)
    kp, kd = 60.0, 10.0
    good = simulate_full(
        Scenario("coupled", p, 3.0, 1, amplitude=1e-4), controller=Controller("pd", kp=kp, kd=kd)
    )
    e = good["balancing_error"][0, :, 0]
    rate = np.log(e[-1] / e[2000]) / (good.time[-1] - good.time[2000])
    slow = max(np.roots([1.0, 50.0 + kd, kp - 22.0 * 1.001]).real)
    assert rate == pytest.approx(slow, rel=0.01)
    assert good.attrs["controller"] == "pd"
    weak = simulate_full(
        Scenario("single", p, 3.0, 1, amplitude=0.02), controller=Controller("pd", kp=10.0, kd=10.0)
    )
    assert np.abs(weak["balancing_error"][0, -1, 0]) > 0.02


@pytest.mark.parametrize("ratio", [0.0, 1e-13, 1.5, float("nan"), float("inf")])
def test_from_reduced_refuses_a_mass_ratio_outside_its_declared_range(ratio):
    """The bob/cart ratio's range is declared once (cipcore.params.MASS_RATIO_RANGE): the
    Python API refuses what the command line refuses, in one line naming it."""
    from cip.model import CIPParams
    from cipcore.params import MASS_RATIO_RANGE, BalanceParams, ParameterError
    from validation.cli.domains import DOMAINS

    assert (DOMAINS["mass ratio"].low, DOMAINS["mass ratio"].high) == MASS_RATIO_RANGE
    with pytest.raises(ParameterError, match=r"mass_ratio must be in \[1e-12, 1\]"):
        CIPParams.from_reduced(BalanceParams(beta=20.0), mass_ratio=ratio)
    CIPParams.from_reduced(BalanceParams(beta=20.0), mass_ratio=MASS_RATIO_RANGE[1])
