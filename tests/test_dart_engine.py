"""The DART engine's own checks (skipped, with the reason, where dartpy is absent).

The single model is MuJoCo's semi-implicit Euler step with explicit dampers to
round-off; both models converge to the exact zero-order-hold solution under time-step
refinement (the engine has no exact twin: cipval judges it so), a 1e-3 error of the
tip mass fails that check, a control one step late fails the delay check, and a state
that overflows is NaN from that step (DART itself would zero it and go on).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

pytest.importorskip("dartpy", reason="dartpy is not installed (pip install 'cipval[dart]')")

from cip.engines.dart import ENGINE, MAXVAL, DartRollout
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


def test_declares_refinement_tier() -> None:
    caps = ENGINE.capabilities
    assert ENGINE.unavailable() is None
    assert caps.family == "DART" and caps.rigid_body and caps.precision == "float64"
    assert caps.twin is None and caps.rod == "rigid" and caps.order == 1.0
    assert caps.integrator == "semi-implicit Euler (DART)" and caps.deterministic
    assert ENGINE.integrators == () and ENGINE.backend_workers


def test_single_model_is_mujoco_euler() -> None:
    """Open-loop forces on the single model: the same states as mujoco.rollout (Euler)."""
    from mujoco import rollout

    m = model_file("single")
    motors, _ = observable(m)
    R, n = 2, 500
    ctrl = np.zeros((R, n, m.nu))
    ctrl[..., motors] = 0.05 * open_loop_forces(R, n, len(motors), m.opt.timestep, 3)
    state = _upright(m, R)
    state[:, 2] = 0.01  # tilted: the nonlinear terms take part
    out = np.empty((R, n, state.shape[1]))
    backend = DartRollout(m, R, 1)
    half = n // 2  # two chunks: the second continues from the first's last state
    backend(state, ctrl[:, :half], out[:, :half])
    backend(out[:, half - 1], ctrl[:, half:], out[:, half:])
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    assert backend.warnings() == 0
    np.testing.assert_allclose(out[..., 0], ref[..., 0], rtol=0, atol=1e-12)
    x, y = out[..., 1:], ref[..., 1:]
    assert np.linalg.norm(x - y) / np.linalg.norm(y) < 1e-12


def test_rigid_rod_holds_the_tips_apart() -> None:
    """Coupled model, tilted and forced: the tips stay the rod's length apart."""
    m = model_file("coupled")
    motors, _ = observable(m)
    R, n = 2, 500
    ctrl = np.zeros((R, n, m.nu))
    ctrl[..., motors] = 0.05 * open_loop_forces(R, n, len(motors), m.opt.timestep, 4)
    state = _upright(m, R)
    state[:, [2, 4]] = 0.01  # both pendulums tilted alike: the rod closed
    out = np.empty((R, n, state.shape[1]))
    backend = DartRollout(m, R, 1)
    backend(state, ctrl, out)
    g = backend.geometry
    x = out[..., 1 + np.array(g.qpos_x)] + np.array(g.cart_x0)
    th = out[..., 1 + np.array(g.qpos_theta)]
    L = np.array(g.pendulum_length)
    tx, tz = x + L * np.sin(th), L * np.cos(th)
    stretch = np.hypot(tx[..., 0] - tx[..., 1], tz[..., 0] - tz[..., 1]) - g.rod_length
    assert backend.warnings() == 0 and np.abs(th).max() > 0.01
    assert np.abs(stretch).max() < 1e-10


def test_overflow_is_nan_from_its_step() -> None:
    """A force beyond MAXVAL, or a state driven beyond it: NaN from that step on, counted
    in ``warnings()``; the other realisations of the batch are untouched."""
    m = model_file("single")
    state = _upright(m, 3)
    ctrl = np.zeros((3, 40, m.nu))
    ctrl[1, 10:] = np.inf
    ctrl[2, 5:] = 1e9  # the cart's velocity passes MAXVAL within the chunk
    out = np.empty((3, 40, state.shape[1]))
    backend = DartRollout(m, 3, 1)
    backend(state, ctrl, out)
    assert backend.warnings() == 2
    assert np.isfinite(out[0]).all()
    assert np.isfinite(out[1, :10]).all() and np.isnan(out[1, 10:, 1:]).all()
    first = int(np.argmax(np.isnan(out[2, :, 1])))
    assert 5 < first < 40 and np.isnan(out[2, first:, 1:]).all()
    assert np.abs(out[2, :first, 1:]).max() < MAXVAL


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
