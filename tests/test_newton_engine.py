"""The Newton engine's own checks (skipped, with the reason, where newton is absent).

Newton's Featherstone solver, in float32 on warp's CPU device, steps the single model
as MuJoCo's semi-implicit Euler to float32 rounding; the coupled model's rod is held
rigid by cipval's projection; both models converge at order 1 to the exact
zero-order-hold solution under time-step refinement, to the engine's float32 floor
(the shared floor, 1e-6, is a float64 one: the engine's limit is about 1e-5); a 1e-3
error of the tip mass fails at that floor, and a control one step late is one step
late.  The first test in a process loads warp's compiled kernels (24 s of CPU once per
machine to compile them, then about 3 s from warp's kernel cache).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

pytest.importorskip("newton", reason="newton is not installed (pip install 'cipval[newton]')")

from cip.engines.drake_plant import geometry_from_mujoco
from cip.engines.newton import ENGINE, REFINEMENT_FLOOR_FLOAT32, NewtonRollout
from cip.mjcf_params import read_mapping
from cipcore.params import BalanceParams
from cipcore.registry import register_engine
from validation.checks.agreement import measured_delay, model_file
from validation.checks.refinement import (
    FLOOR,
    RefinementSetting,
    least_order,
    observable,
    open_loop_forces,
    refine,
)
from validation.faults.catalogue import make_fault
from validation.profiles import PAPER_BETA

#: warp kernels on warp's CPU device: CI's warp step runs them in one process (-n 0), so
#: that warp compiles Newton's kernels once
pytestmark = pytest.mark.warp

FULLPHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


@pytest.fixture(autouse=True, scope="module")
def registered() -> None:
    """The engine under its name for this process (its registry entry may not exist yet)."""
    register_engine(ENGINE.name, ENGINE)


def _tilted(m: mujoco.MjModel, n_realizations: int, n_steps: int) -> tuple[np.ndarray, ...]:
    """Start states tilted 0.01 rad and band-limited open-loop motor forces (seed 3)."""
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    s = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
    mujoco.mj_getState(m, d, s, FULLPHYSICS)
    state = np.tile(s, (n_realizations, 1))
    state[:, 1 + np.array(geometry_from_mujoco(m).qpos_theta)] = 0.01
    motors, _ = observable(m)
    ctrl = np.zeros((n_realizations, n_steps, m.nu))
    ctrl[..., motors] = 0.05 * open_loop_forces(
        n_realizations, n_steps, len(motors), m.opt.timestep, 3
    )
    return state, ctrl


def _two_chunks(m: mujoco.MjModel, state: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    """The engine's states over ``ctrl``, the second chunk continuing from the first."""
    n = ctrl.shape[1]
    out = np.empty((state.shape[0], n, state.shape[1]))
    backend = NewtonRollout(m, state.shape[0], 1)
    backend(state, ctrl[:, : n // 2], out[:, : n // 2])
    backend(out[:, n // 2 - 1], ctrl[:, n // 2 :], out[:, n // 2 :])
    assert backend.warnings() == 0
    return out


def test_declares_refinement_tier() -> None:
    caps = ENGINE.capabilities
    assert ENGINE.unavailable() is None
    assert caps.family == "Newton" and caps.rigid_body and caps.precision == "float32"
    assert caps.twin is None and caps.rod == "rigid" and caps.order == 1.0
    assert caps.device == "cpu" and caps.kernels == "warp" and caps.deterministic
    assert ENGINE.integrators == () and ENGINE.max_threads == 1 and not ENGINE.backend_workers


def test_single_model_is_mujoco_euler_in_float32() -> None:
    """Open-loop forces on the single model: mujoco.rollout's (Euler) states to float32
    rounding (measured 5.2e-7; |e| up to 1.2e-2 m)."""
    from mujoco import rollout

    m = model_file("single")
    state, ctrl = _tilted(m, 2, 500)
    out = _two_chunks(m, state, ctrl)
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    np.testing.assert_allclose(out[..., 0], ref[..., 0], rtol=0, atol=1e-12)
    x, y = out[..., 1:], ref[..., 1:]
    assert np.linalg.norm(x - y) / np.linalg.norm(y) < 2e-6


def test_coupled_rod_is_rigid() -> None:
    """The coupled model: the tips stay l apart to float32 rounding (measured 4.4e-10 m)
    and the positions follow MuJoCo's soft rod to its softness (measured 2e-7)."""
    from mujoco import rollout

    m = model_file("coupled")
    g = geometry_from_mujoco(m)
    state, ctrl = _tilted(m, 2, 500)
    out = _two_chunks(m, state, ctrl)
    x, theta = out[..., 1 + np.array(g.qpos_x)], out[..., 1 + np.array(g.qpos_theta)]
    L = np.array(g.pendulum_length)
    tip_x, tip_z = np.array(g.cart_x0) + x + L * np.sin(theta), L * np.cos(theta)
    dist = np.hypot(tip_x[..., 0] - tip_x[..., 1], tip_z[..., 0] - tip_z[..., 1])
    stretch = dist - g.rod_length
    assert np.abs(stretch).max() < 2e-9
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    pos = slice(1, 1 + m.nq)
    assert np.linalg.norm(out[..., pos] - ref[..., pos]) / np.linalg.norm(ref[..., pos]) < 2e-6


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_refinement_converges_to_float32_floor(model: str) -> None:
    """Order 1 towards the exact solution, the limit within the engine's float32 floor
    (measured, seed 1: E0 8.0e-6 single, 5.1e-6 coupled, intervals up to 2.8e-5 and
    1.4e-5); the shared float64 floor is out of float32's reach."""
    r = refine(model_file(model), NewtonRollout, rod="rigid", setting=RefinementSetting(1))
    assert r.passes(REFINEMENT_FLOOR_FLOAT32, least_order(ENGINE.capabilities)), r
    assert abs(r.order - 1.0) < 0.01 and r.e0 > FLOOR / 10, r


def test_tip_mass_error_fails_refinement() -> None:
    """A 1e-3 error of the tip mass moves the limit beyond the float32 floor (measured,
    seed 1: E0 1.5e-4, interval from 9.9e-5)."""
    fault = make_fault("mass_ratio", 1e-3)
    r = refine(model_file("single"), fault.backend(NewtonRollout), rod="rigid",
               setting=RefinementSetting(1))  # fmt: skip
    assert not r.passes(REFINEMENT_FLOOR_FLOAT32, least_order(ENGINE.capabilities)), r
    assert r.e0_interval[0] > REFINEMENT_FLOOR_FLOAT32, r


def test_one_step_late_control_fails_delay() -> None:
    """The delay check's count: tau/dt = 100 steps, one more with the catalogue's latency
    fault wrapped around the backend."""
    m = model_file("single")
    p = BalanceParams(beta=PAPER_BETA["single"])
    physical = read_mapping(m).physical()
    expected = round(p.tau / m.opt.timestep)
    assert measured_delay("single", p, physical, m, NewtonRollout) == expected
    late = make_fault("delay_late", 1).backend(NewtonRollout)
    assert measured_delay("single", p, physical, m, late) == expected + 1
