"""The PhysX engine's own checks (skipped, with the reason, where sapien is absent).

PhysX (through SAPIEN, CPU) steps in float32.  The single model is MuJoCo's
semi-implicit Euler step with explicit dampers to float32's floor; the rod holds the
tips at its length to float32's resolution of their world positions; both models
converge under time-step refinement to the exact zero-order-hold solution to within
the engine's float32 floors (the engine has no exact twin: cipval judges it so; the
shared floor of 1e-6 is for float64 engines, see ``cip.engines.physx``), a 1e-3 error
of the tip mass fails that check above the float32 floor, and a control one step late
fails the delay check.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

pytest.importorskip("sapien", reason="sapien is not installed (pip install 'cipval[physx]')")

from cip.engines.drake_plant import geometry_from_mujoco
from cip.engines.physx import ENGINE, REFINEMENT_FLOOR_FLOAT32, PhysxRollout
from cipcore.registry import register_engine
from cipcore.scenario import EngineTarget
from validation.checks.agreement import instrument_checks, model_file
from validation.checks.refinement import (
    REFINEMENT,
    observable,
    open_loop_forces,
    refinement_check,
    tier,
)
from validation.checks.stats import FAIL
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


def _forced(model: str, n: int) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """The model file, 2 states tilted 0.01 rad and 0.05 x the band-limited forces (seed 3)."""
    m = model_file(model)
    motors, _ = observable(m)
    ctrl = np.zeros((2, n, m.nu))
    ctrl[..., motors] = 0.05 * open_loop_forces(2, n, len(motors), m.opt.timestep, 3)
    state = _upright(m, 2)
    state[:, 2] = 0.01  # first pendulum tilted: the nonlinear terms take part
    if model == "coupled":
        state[:, 4] = 0.01  # and the second, so that the rod closes
    return m, state, ctrl


def test_declares_refinement_tier() -> None:
    caps = ENGINE.capabilities
    assert ENGINE.unavailable() is None
    assert caps.family == "PhysX" and caps.rigid_body and caps.precision == "float32"
    assert caps.twin is None and caps.rod == "rigid" and caps.order == 1.0
    assert tier(caps)[0] == REFINEMENT
    assert ENGINE.integrators == () and ENGINE.backend_workers


def test_single_model_is_mujoco_euler_to_float32() -> None:
    """Open-loop forces on the single model: mujoco.rollout's (Euler) states to float32's
    floor (measured 6.1e-7 over 1 s; MuJoCo's Euler rounded to float32 every step: 5.7e-7)."""
    from mujoco import rollout

    n = 1000
    m, state, ctrl = _forced("single", n)
    out = np.empty((2, n, state.shape[1]))
    backend = PhysxRollout(m, 2, 1)
    half = n // 2  # two chunks: the second continues from the first's last state
    backend(state, ctrl[:, :half], out[:, :half])
    backend(out[:, half - 1], ctrl[:, half:], out[:, half:])
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    assert backend.warnings() == 0
    np.testing.assert_allclose(out[..., 0], ref[..., 0], rtol=0, atol=1e-12)
    x, y = out[..., 1 : 1 + m.nq + m.nv], ref[..., 1 : 1 + m.nq + m.nv]
    assert np.array_equal(x.astype(np.float32), x)  # the state is PhysX's float32
    assert np.linalg.norm(x - y) / np.linalg.norm(y) < 2e-6
    # one chunk gives the same numbers as two, bit for bit
    whole = np.empty_like(out)
    PhysxRollout(m, 2, 1)(state, ctrl, whole)
    assert np.array_equal(whole[..., 1:], out[..., 1:])


def test_rod_holds_the_tips_at_its_length() -> None:
    """Coupled, forced to 0.015 rad: the tips' distance (from the float32 joint coordinates,
    in float64) stays within 2e-7 m of the rod (measured 9.0e-8 m; the float32 resolution
    of the tips' world positions near x = +-0.5 m is 6e-8 m)."""
    m, state, ctrl = _forced("coupled", 1000)
    out = np.empty((2, 1000, state.shape[1]))
    PhysxRollout(m, 2, 1)(state, ctrl, out)
    g = geometry_from_mujoco(m)
    (a, b), (la, lb) = g.cart_x0, g.pendulum_length
    x1, t1, x2, t2 = (out[..., 1 + j] for j in (g.qpos_x[0], g.qpos_theta[0], g.qpos_x[1],
                                                 g.qpos_theta[1]))  # fmt: skip
    dx = (a + x1 + la * np.sin(t1)) - (b + x2 + lb * np.sin(t2))
    dz = la * np.cos(t1) - lb * np.cos(t2)
    stretch = np.hypot(dx, dz) - g.rod_length
    assert np.abs(t1).max() > 0.01 and np.abs(t2).max() > 0.01  # the rod was at work
    assert np.abs(stretch).max() < 2e-7


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_refinement_within_float32_floor(model: str) -> None:
    """Refinement converges, order 1, to within the float32 setting's floor
    (validation.checks.refinement.FLOAT32_SETTINGS: 1.2e-4 single, 1.6e-4 coupled; the
    largest upper end over seeds 1-20 8.2e-5 and 1.1e-4): the check passes."""
    c = refinement_check(model, model_file(model), ENGINE, 1)
    assert c.values["e0_interval"][1] <= REFINEMENT_FLOOR_FLOAT32[model], c.values
    if model == "single":  # the coupled model's order is the rod's float32 noise (0.6-0.7)
        assert abs(c.values["order"] - 1.0) < 0.05, c.values


def test_tip_mass_error_fails_refinement() -> None:
    """A 1e-3 error of the tip mass lifts E0 above the float32 setting's floor (E0 6.8e-4
    or more)."""
    fault = make_fault("mass_ratio", 1e-3)
    c = refinement_check(
        "single", model_file("single"), ENGINE, 1, backend=fault.backend(ENGINE.rollout())
    )
    assert c.status == FAIL, c.values
    assert c.values["e0_interval"][0] > REFINEMENT_FLOOR_FLOAT32["single"], c.values


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
