"""The Drake engine's own contract (skipped, with the reason, where pydrake is absent).

Beyond the suite every engine passes (tests/test_engine_contract.py): the plant
is the MJCF's CIP (parameters, signs), the single model is MuJoCo's scheme to
round-off, the coupled model's rod is held by the distance constraint, a step
in the balancing error reaches the cart force exactly d = tau/dt steps later,
energy is conserved without control or damping, and a realisation's numbers do
not depend on the batch it is stepped in.
"""

from __future__ import annotations

import importlib.util

import mujoco
import numpy as np
import pytest

from cip.model import CIPParams, build
from cipcore.noise import GainNoise
from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import availability, get_engine

if importlib.util.find_spec("pydrake") is None:
    pytest.skip("pydrake is not installed (pip install 'cipval[drake]')", allow_module_level=True)

from cip.engines.drake import DrakeRollout
from cip.engines.drake_plant import build_plant, geometry_from_mujoco

P = BalanceParams(beta=20.306)
FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


def _state(m: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray | None = None) -> np.ndarray:
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    if qvel is not None:
        d.qvel[:] = qvel
    s = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
    mujoco.mj_getState(m, d, s, FULLPHYSICS)
    return s


def _rollout(m, states: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    out = np.empty((*ctrl.shape[:2], states.shape[1]))
    DrakeRollout(m, len(states), 1)(states, ctrl, out)
    return out


def test_registered_and_available() -> None:
    assert availability("drake") is None
    caps = get_engine("drake").capabilities
    assert caps.family == "Drake" and caps.rigid_body and caps.precision == "float64"


def test_plant_is_built_from_the_cip_parameters() -> None:
    phys = CIPParams(bob_mass=2e-3, cart_mass=1.5, rod_length=0.7, tip_damping=40.0)
    g = geometry_from_mujoco(build("coupled", phys))
    assert g.n_controllers == 2 and g.timestep == phys.timestep
    assert g.gravity == (0.0, 0.0, -phys.gravity)
    assert g.cart_mass == (1.5, 1.5) and g.bob_mass == (2e-3, 2e-3)
    assert g.pendulum_length == (phys.pendulum_length,) * 2
    assert g.cart_x0 == (0.35, -0.35) and g.rod_length == pytest.approx(0.7, abs=1e-15)
    assert g.tip_damping == pytest.approx((40.0 * 2e-3,) * 2, rel=1e-15)
    assert g.cart_damping == pytest.approx((50.0 * 1.5,) * 2, rel=1e-15)
    assert geometry_from_mujoco(build("single")).rod_length is None


def test_positive_theta_tilts_the_tip_to_plus_x_as_in_mujoco() -> None:
    m = build("single")
    cip = build_plant(geometry_from_mujoco(m))
    plant = cip.plant
    ctx = plant.CreateDefaultContext()
    q = np.zeros(plant.num_positions())
    q[cip.q_x], q[cip.q_theta] = 0.2, 0.3
    plant.SetPositions(ctx, q)
    pend = plant.GetBodyByName("pendulum_1")
    L = m.site_pos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip_1")][2]
    tip = plant.CalcPointsPositions(ctx, pend.body_frame(), [0, 0, L], plant.world_frame())
    d = mujoco.MjData(m)
    d.qpos[:] = [0.2, 0.3]
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(tip.ravel(), d.site_xpos[2], rtol=0, atol=1e-15)
    assert tip[0, 0] == pytest.approx(0.2 + L * np.sin(0.3), abs=1e-15)


def test_a_model_that_is_not_the_cip_is_refused() -> None:
    def model(hinge: str) -> mujoco.MjModel:
        return mujoco.MjModel.from_xml_string(
            '<mujoco><worldbody><body><joint name="x_M1" type="slide" axis="0 0 1"/>'
            f'<geom size=".1"/>{hinge}</body></worldbody></mujoco>'
        )

    with pytest.raises(ParameterError, match="no joint named 'theta_1'"):
        geometry_from_mujoco(model(""))
    hinge = '<body><joint name="theta_1" axis="0 1 0"/><geom size=".1"/></body>'
    with pytest.raises(ParameterError, match="slide along \\+x"):
        geometry_from_mujoco(model(hinge))


def test_single_model_is_mujocos_semi_implicit_euler_to_round_off() -> None:
    """No constraint: SAP's step is MuJoCo's Euler (explicit forces, v then q)."""
    m = build("single")
    s0 = _state(m, [0.0, 0.02], [0.01, -0.05])
    ctrl = np.random.default_rng(0).normal(0, 0.05, (1, 500, m.nu))
    out = _rollout(m, s0[None], ctrl)
    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, s0, FULLPHYSICS)
    ref = np.empty_like(out[0])
    for k in range(ctrl.shape[1]):
        d.ctrl[:] = ctrl[0, k]
        mujoco.mj_step(m, d)
        mujoco.mj_getState(m, d, ref[k], FULLPHYSICS)
    np.testing.assert_allclose(out[0], ref, rtol=1e-11, atol=1e-14)


def test_same_noise_gives_the_reduced_and_the_mujoco_trajectory() -> None:
    """Coupled, 1e-6 m: within the declared tolerance of the reduced model, and within
    1e-5 of MuJoCo (the two rod constraints differ only in their softness)."""
    engine = get_engine("drake")
    ref = get_engine("reduced").simulate("coupled", P, 1.0, 2, seed=3, amplitude=1e-6)
    muj = get_engine("mujoco").simulate("coupled", P, 1.0, 2, seed=3, amplitude=1e-6)
    tr = engine.simulate("coupled", P, 1.0, 2, seed=3, amplitude=1e-6)
    e, e_ref, e_muj = (t["balancing_error"] for t in (tr, ref, muj))
    assert np.linalg.norm(e - e_ref) / np.linalg.norm(e_ref) < (
        engine.capabilities.trajectory_tolerance
    )
    assert np.linalg.norm(e - e_muj) / np.linalg.norm(e_muj) < 1e-5


def test_a_step_in_the_balancing_error_reaches_the_force_exactly_d_steps_later() -> None:
    """Tilt the pendulum abruptly at step n0: the cart force M beta e(n - d) jumps at
    n0 + d, d = round(tau/dt), and not a step earlier or later.

    The force per unit mass is recovered from the cart velocity as the MJCF's
    explicit damping implies, F_n / M = (v_{n+1} - v_n) / dt + gamma v_n; m/M =
    1e-7 makes the pendulum's reaction on the cart negligible.
    """
    p = BalanceParams(beta=20.306, nu=0.0)
    d = round(p.tau / p.dt)
    runner = get_engine("drake").runner(
        "single", p, 1, 1e-5, physical=CIPParams.from_reduced(p, mass_ratio=1e-7)
    )
    n0, jump = 2 * d, 1e-4  # m, at a chunk boundary (chunks of d steps)
    assert runner.max_chunk == d
    chunks = []
    while runner.step < 5 * d:
        if runner.step == n0:
            cip = runner.runner
            cip.state[:, cip.i_th] += jump / cip.L
        chunks.append(runner.advance(np.zeros((1, d, 1))))
    v = np.concatenate([c["base_velocity"] for c in chunks], axis=1)[0, :, 0]
    force = (v[1:] - v[:-1]) / p.dt + p.gamma * v[:-1]  # F_n / M, 1/s^2 * m
    change = np.abs(np.diff(force))  # |F_n - F_{n-1}| at index n - 1
    lag = int(np.argmax(change)) + 1 - n0
    assert lag == d, f"the force jumped {lag} steps after the error, expected {d}"
    assert change[n0 + d - 1] == pytest.approx(p.beta * jump, rel=1e-3)
    others = np.delete(change, n0 + d - 1)
    assert others.max() < 0.05 * change[n0 + d - 1]


def test_rod_length_is_held() -> None:
    """Coupled, controlled, 1e-3 m: the tips stay the rod length apart to 1e-9 of it."""
    m = build("coupled")
    g = geometry_from_mujoco(m)
    tr = get_engine("drake").simulate("coupled", P, 1.0, 2, seed=5, amplitude=1e-3)
    th = tr["angle"]
    x = tr["base_position"] + np.array(g.cart_x0)
    L = g.pendulum_length[0]
    tip_x, tip_z = x + L * np.sin(th), L * np.cos(th)
    length = np.hypot(tip_x[..., 0] - tip_x[..., 1], tip_z[..., 0] - tip_z[..., 1])
    assert np.abs(th).max() > 1e-3  # the pendula moved
    assert np.abs(length - g.rod_length).max() < 1e-9 * g.rod_length


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_energy_is_conserved_without_control_or_damping(model: str) -> None:
    """gamma = beta = 0: the pendula fall from 0.05 rad and swing through the bottom for
    3 s; Drake's own kinetic plus potential energy stays within 1 % of the largest
    kinetic energy (semi-implicit Euler: a bounded O(dt) oscillation, no drift)."""
    phys = CIPParams(bob_mass=0.5, tip_damping=0.0, cart_damping=0.0)
    m = build(model, phys)
    qpos = np.zeros(m.nq)
    qpos[1::2] = 0.05
    out = _rollout(m, _state(m, qpos)[None], np.zeros((1, 3000, m.nu)))[0]
    backend = DrakeRollout(m, 1, 1)
    plant, ctx = backend.plant, backend.contexts[0]
    energy, kinetic = [], []
    for s in out[::10]:
        x = np.zeros(backend.nx)
        x[backend.drake_index] = s[backend.mj_index]
        plant.SetPositionsAndVelocities(ctx, x)
        kinetic.append(plant.CalcKineticEnergy(ctx))
        energy.append(kinetic[-1] + plant.CalcPotentialEnergy(ctx))
    energy = np.array(energy)
    assert np.abs(out[:, 1 + m.nq + 1 :: 2]).max() > 5.0, "the pendula should swing"
    drift = np.abs(energy - energy[0]).max() / max(kinetic)
    assert drift < 1e-2, f"energy changed by {drift:.2e} of the largest kinetic energy"


def test_a_realisation_gives_the_same_numbers_in_any_batch() -> None:
    m = build("coupled")
    rng = np.random.default_rng(4)
    states = np.stack(
        [_state(m, rng.normal(0, 0.02, m.nq), rng.normal(0, 0.02, m.nv)) for _ in range(3)]
    )
    ctrl = rng.normal(0, 0.05, (3, 200, m.nu))
    whole = _rollout(m, states, ctrl)
    parts = np.concatenate([_rollout(m, states[[r]], ctrl[[r]]) for r in (0, 1, 2)])
    assert np.array_equal(whole, parts)
    tr = get_engine("drake").simulate("coupled", P, 0.3, 3, seed=9, amplitude=1e-3)
    one = get_engine("drake").simulate(
        "coupled", P, 0.3, noise=GainNoise(9, 1, 2, first_realization=2), amplitude=1e-3
    )
    assert np.array_equal(tr["balancing_error"][2:], one["balancing_error"])
