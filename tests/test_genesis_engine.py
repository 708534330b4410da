"""The Genesis engine's own checks (skipped, with the reason, where genesis-world is absent).

Genesis takes every parameter of the model as the geometry states it (read back after
the build); the single model is MuJoCo's semi-implicit Euler step with explicit dampers
to round-off; both models converge to the exact zero-order-hold solution under
time-step refinement (the engine has no exact twin: cipval judges it so), a 1e-3 error
of the tip mass fails that check, a control one step late fails the delay check, and a
realisation's numbers do not depend on the batch it is stepped in.  Genesis compiles
its kernels on the first scene of the process (22 s on a cold kernel cache, 10 s from
a warm one, at load 4-5 on 2 cores), after 15-20 s of importing it (``.ci/genesis`` runs
these tests: 11 in 104 s from a cold cache).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

pytest.importorskip("genesis", reason="genesis-world is not installed (see .ci/genesis)")

from cip.engines.drake_plant import geometry_from_mujoco
from cip.engines.genesis import (
    ENGINE,
    PROBE_TOLERANCE,
    GenesisModelError,
    GenesisRollout,
    build_scene,
    verify_scene,
)
from cip.mjcf_params import shipped_model_path
from cipcore.registry import register_engine
from cipcore.scenario import EngineTarget
from validation.checks.agreement import instrument_checks, model_file
from validation.checks.refinement import (
    observable,
    open_loop_forces,
    refinement_check,
)
from validation.checks.stats import FAIL, PASS
from validation.faults.catalogue import make_fault

FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


@pytest.fixture(autouse=True, scope="module")
def registered() -> None:
    """The engine under its name for this process (its registry entry may not exist yet)."""
    register_engine(ENGINE.name, ENGINE)


def _upright(m: mujoco.MjModel, n_realizations: int) -> np.ndarray:
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    s = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
    mujoco.mj_getState(m, d, s, FULLPHYSICS)
    return np.tile(s, (n_realizations, 1))


def _forced(model: str, n_realizations: int, n: int, seed: int = 3):
    """The compiled ``model``, a tilted upright state (R, S) and open-loop controls (R, n, nu)."""
    m = model_file(model)
    motors, _ = observable(m)
    ctrl = np.zeros((n_realizations, n, m.nu))
    ctrl[..., motors] = 0.05 * open_loop_forces(
        n_realizations, n, len(motors), m.opt.timestep, seed
    )
    state = _upright(m, n_realizations)
    g = geometry_from_mujoco(m)
    for j in g.qpos_theta:  # tilted alike (the rod's length kept): nonlinear terms take part
        state[:, 1 + j] = 0.01
    return m, state, ctrl


def _run(m: mujoco.MjModel, state: np.ndarray, ctrl: np.ndarray, n_envs: int) -> np.ndarray:
    """The states after each step, in two chunks (the second from the first's last state)."""
    out = np.empty((*ctrl.shape[:2], state.shape[1]))
    backend = GenesisRollout(m, n_envs, 1)
    half = ctrl.shape[1] // 2
    try:
        backend(state, ctrl[:, :half], out[:, :half])
        backend(out[:, half - 1], ctrl[:, half:], out[:, half:])
        assert backend.warnings() == 0
    finally:
        backend.close()
    return out


def test_declares_refinement_tier() -> None:
    caps = ENGINE.capabilities
    assert ENGINE.unavailable() is None
    assert caps.family == "Genesis" and caps.rigid_body and caps.precision == "float64"
    assert caps.twin is None and caps.rod == "rigid" and caps.order == 1.0
    assert ENGINE.integrators == () and ENGINE.max_threads == 1 and not ENGINE.backend_workers


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_genesis_takes_the_model_as_stated(model: str) -> None:
    """Masses, inertias, zero damping/armature, gravity, dt: read back after the build;
    the unconstrained acceleration at a tilted, moving state is MuJoCo's to round-off."""
    m = model_file(model)
    c = build_scene(geometry_from_mujoco(m), 2)
    try:
        assert verify_scene(c, m) <= PROBE_TOLERANCE
    finally:
        c.scene.destroy()


def test_a_wrong_tip_mass_fails_the_probe() -> None:
    """A scene built with a 1e-3 error of the tip mass differs from the model file's
    MuJoCo acceleration at the probe state (the check has power)."""
    m = model_file("single")
    g = geometry_from_mujoco(m)
    c = build_scene(dataclasses.replace(g, bob_mass=(g.bob_mass[0] * 1.001,)), 1)
    try:
        with pytest.raises(GenesisModelError, match="probe state"):
            verify_scene(c, m)
    finally:
        c.scene.destroy()


def test_genesis_parses_the_shipped_single_file_alike_and_refuses_the_rod() -> None:
    """Genesis's own MJCF parse of the shipped single file takes the masses and centres of
    mass of the document the engine writes (its dampers and motor it leaves out: zero
    actuator gains and biases); the coupled file's rod (a tendon equality) it refuses."""
    import genesis as gs

    from cip.engines.genesis import _genesis, _numpy

    _genesis()
    g = geometry_from_mujoco(model_file("single"))
    options = gs.options.RigidOptions(enable_collision=False, disable_constraint=True)
    scene = gs.Scene(rigid_options=options, show_viewer=False)
    entity = scene.add_entity(
        gs.morphs.MJCF(file=str(shipped_model_path("single")), default_armature=None)
    )
    scene.build(n_envs=1)
    try:
        links = [entity.get_link(n).idx_local for n in ("cart_1", "pendulum_1")]
        np.testing.assert_array_equal(
            _numpy(entity.get_links_mass(links)).ravel(), [g.cart_mass[0], g.bob_mass[0]]
        )
        com = _numpy(entity.get_links_COM(links)).reshape(2, 3)
        np.testing.assert_array_equal(com[1], [0.0, 0.0, g.pendulum_length[0]])
        assert not _numpy(entity.get_dofs_act_gain()).any()
        assert not any(_numpy(b).any() for b in entity.get_dofs_act_bias())
    finally:
        scene.destroy()
    coupled = gs.Scene(rigid_options=options, show_viewer=False)
    with pytest.raises(gs.GenesisException, match="equality"):
        coupled.add_entity(gs.morphs.MJCF(file=str(shipped_model_path("coupled"))))
    coupled.destroy()


def test_single_model_is_mujoco_euler() -> None:
    """Open-loop forces on the single model: the same states as mujoco.rollout (Euler)
    (measured 5.6e-17 relative, seed 3)."""
    from mujoco import rollout

    m, state, ctrl = _forced("single", 2, 500)
    out = _run(m, state, ctrl, 2)
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    np.testing.assert_allclose(out[..., 0], ref[..., 0], rtol=0, atol=1e-12)
    x, y = out[..., 1 : 1 + m.nq + m.nv], ref[..., 1 : 1 + m.nq + m.nv]
    assert np.linalg.norm(x - y) / np.linalg.norm(y) < 1e-12


def test_rod_holds_and_a_realisation_ignores_its_batch() -> None:
    """Coupled model: the rod's stretch stays at the projection's curvature term, and
    realisation 0 is bit-identical stepped alone or with two others, in blocks of 3 or 2."""
    m, state, ctrl = _forced("coupled", 3, 400)
    ctrl[1:] *= 2.0  # the batch neighbours move differently
    together = _run(m, state, ctrl, 3)
    alone = _run(m, state[:1], ctrl[:1], 1)
    blocks = _run(m, state, ctrl, 2)  # 3 realisations in blocks of 2 environments
    np.testing.assert_array_equal(together[0], alone[0])
    np.testing.assert_array_equal(together, blocks)
    g = geometry_from_mujoco(m)
    q = together[..., 1 : 1 + m.nq]
    x = [q[..., g.qpos_x[i]] + g.cart_x0[i] + g.pendulum_length[i] * np.sin(q[..., g.qpos_theta[i]])
         for i in range(2)]  # fmt: skip
    z = [g.pendulum_length[i] * np.cos(q[..., g.qpos_theta[i]]) for i in range(2)]
    stretch = np.hypot(x[0] - x[1], z[0] - z[1]) - g.rod_length
    assert np.abs(stretch).max() < 1e-9


def test_an_overflow_stops_its_realisation_only() -> None:
    """A force beyond MAXVAL (1e12 N) and a NaN start state end those realisations as NaN
    from the step they enter; the batch's other realisation steps as it does alone."""
    m, state, ctrl = _forced("single", 3, 50)
    ctrl[1, 20:] = 1e12
    state[2, 2] = np.nan
    out = np.empty((*ctrl.shape[:2], state.shape[1]))
    backend = GenesisRollout(m, 3, 1)
    try:
        backend(state, ctrl, out)
        assert backend.warnings() == 1
    finally:
        backend.close()
    # (the time column of _run's two chunks rounds otherwise)
    np.testing.assert_array_equal(out[0, :, 1:], _run(m, state[:1], ctrl[:1], 1)[0, :, 1:])
    assert np.isfinite(out[1, :20]).all() and np.isnan(out[1, 20:, 1:]).all()
    assert np.isnan(out[2, :, 1:]).all()


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_refinement_passes(model: str) -> None:
    c = refinement_check(model, model_file(model), ENGINE, 1)
    assert c.status == PASS, c.values
    assert c.values["e0_interval"][1] <= 1e-6 and c.values["order"] >= 0.7


def test_tip_mass_error_fails_refinement() -> None:
    fault = make_fault("mass_ratio", 1e-3)
    c = refinement_check(
        "single", model_file("single"), ENGINE, 1, backend=fault.backend(ENGINE.rollout())
    )
    assert c.status == FAIL, c.values
    assert c.values["e0_interval"][0] > 1e-6


def test_one_step_late_control_fails_delay() -> None:
    """A control one step late (the backend wrapped by the catalogue's latency fault)."""
    checks = instrument_checks(
        1,
        1,
        target=EngineTarget(ENGINE.name),
        models=("single",),
        fault=make_fault("delay_late", 1),
    )
    by_name = {c.name: c for c in checks}
    delay = by_name["delay.single"]
    assert delay.status == FAIL, delay.values
    assert delay.values["measured_steps"] == delay.values["expected_steps"] + 1
