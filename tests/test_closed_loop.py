"""The closed loop by refinement (validation.checks.closed_loop, reduced.zoh's feedback loop)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cipcore.params import BalanceParams
from reduced.zoh import DelayedFeedback, zoh_delayed_feedback
from validation.checks.closed_loop import closed_loop_check, substepped
from validation.checks.refinement import FLOOR
from validation.profiles import PAPER_BETA


def _refinement_mujoco():
    """MuJoCo's Euler declared as an engine without a twin: judged by refinement."""
    from cip.engines.rigid_body import MUJOCO

    return replace(MUJOCO, capabilities=replace(MUJOCO.capabilities, twin=None))


def _check(model: str, fault=None, seed: int = 1, engine=None):
    from validation.checks.agreement import model_file
    from validation.faults.catalogue import make_fault

    eng = engine or _refinement_mujoco()
    f = make_fault(*fault) if fault else None
    return closed_loop_check(model, model_file(model), eng, seed,
                             params=BalanceParams(beta=PAPER_BETA[model]), fault=f)  # fmt: skip


def test_the_sampled_loop_is_the_scalar_recursion():
    """One state, x_{k+1} = a x_k + b u_k, u_k = g (1 + s xi_k) x_{k-d}: the loop written
    out by hand for three steps with d = 2 (x before the start held at e_before)."""
    a, b, g, s, d = np.array([[1.1]]), np.array([[0.5]]), -2.0, 0.3, 2
    xi = np.array([[[0.4], [-1.0], [2.0]]])
    x0 = np.array([[1.0]])
    loop = DelayedFeedback(np.eye(1), np.eye(1), gain=g, noise_scale=s, delay_steps=d)
    got = zoh_delayed_feedback(a, b, x0, loop, xi=xi, e_before=np.array([[0.7]]))[0, :, 0]
    x, hist, want = 1.0, [0.7, 0.7], []
    for k in range(3):
        hist.append(x)
        x = 1.1 * x + 0.5 * g * (1 + s * xi[0, k, 0]) * hist[k]
        want.append(x)
    np.testing.assert_allclose(got, want, rtol=1e-15)
    with pytest.raises(ValueError, match="delay_steps"):
        DelayedFeedback(np.eye(1), np.eye(1), gain=g, noise_scale=s, delay_steps=0)


def test_substepped_steps_the_interval_in_halves():
    """MuJoCo's Euler sub-stepped 2x per step of h is one MuJoCo run at h/2 sampled at h."""
    import copy

    import mujoco

    from cip.runner import MujocoRollout
    from validation.checks.agreement import model_file

    m = model_file("single")
    data = mujoco.MjData(m)
    data.qpos[1] = 0.01
    mujoco.mj_forward(m, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    s0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, data, s0, spec)
    ctrl = np.random.default_rng(0).standard_normal((1, 5, m.nu))
    got = np.empty((1, 5, s0.size))
    substepped(MujocoRollout, 2)(m, 1, 1)(s0[None], ctrl, got)
    fine = copy.deepcopy(m)
    fine.opt.timestep /= 2
    want = np.empty((1, 10, s0.size))
    MujocoRollout(fine, 1, 1)(s0[None], np.repeat(ctrl, 2, axis=1), want)
    np.testing.assert_array_equal(got, want[:, 1::2])
    assert substepped(MujocoRollout, 1) is MujocoRollout


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_a_correct_engine_converges_to_the_exact_loop(model):
    """MuJoCo's Euler judged by refinement: E0 far inside the floor, first order."""
    c = _check(model)
    assert c.status == "pass", c.values
    assert c.values["e0_interval"][1] < FLOOR / 10, c.values
    assert abs(c.values["order"] - 1.0) < 0.05


@pytest.mark.parametrize(
    ("model", "fault"),
    [
        ("single", ("noise_scale", 1e-4)),
        ("coupled", ("noise_scale", 1e-4)),
        ("single", ("noise_without_sqrt_dt", 1)),
        ("coupled", ("shared_noise", 1)),
        ("coupled", ("gain_one_controller", -1e-3)),
        ("single", ("delay_short", 1)),
    ],
)
def test_controller_faults_move_the_limit(model, fault):
    """The faults no open-loop check can see (the noise's strength, scaling and draws, one
    controller's gain) move the closed loop's limit beyond the floor."""
    c = _check(model, fault)
    assert c.status == "fail" and c.values["e0_interval"][0] > FLOOR, c.values


def test_only_refinement_tier_engines_get_the_check():
    """The check is part of an engine's run where no twin checks its controller: MuJoCo
    (twin tier) has none; the same engine declared without a twin has it, and passes."""
    from cipcore.registry import register_engine
    from cipcore.scenario import EngineTarget
    from validation.checks.agreement import instrument_checks

    names = {c.name for c in instrument_checks(1, 1, models=("single",))}
    assert "closed_loop.single" not in names
    register_engine("mujoco-refinement-tier", _refinement_mujoco())
    checks = {c.name: c for c in instrument_checks(
        1, 1, target=EngineTarget("mujoco-refinement-tier"), models=("single",))}  # fmt: skip
    assert checks["closed_loop.single"].status == "pass", checks["closed_loop.single"].values


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_the_float32_stand_in_passes_at_its_setting_and_fails_a_noise_fault(model):
    """MuJoCo's Euler rounded to float32 every step (a correct float32 engine without a
    twin) passes at the float32 setting's floor; nu x1.01 fails it."""
    from validation.checks import refinement

    eng = refinement.float32_stand_in()
    ps = refinement.FLOAT32_SETTINGS[model]
    clean = _check(model, engine=eng)
    assert clean.status == "pass" and clean.values["floor"] == ps.floor, clean.values
    assert clean.values["e0_interval"][1] > FLOOR  # float32 rounding: not a float64 engine
    faulty = _check(model, ("noise_scale", 0.01), engine=eng)
    assert faulty.status == "fail" and faulty.values["e0_interval"][0] > ps.floor


def test_the_order_asked_follows_the_files_integrator():
    """An engine that follows the file's integrator is asked the file's order: RK4's
    (4 less 0.3), as the open-loop check asks it."""
    from validation.checks.agreement import model_file

    eng = _refinement_mujoco()
    c = closed_loop_check("single", model_file("single", None, "RK4"), eng, 1,
                          params=BalanceParams(beta=PAPER_BETA["single"]))  # fmt: skip
    assert c.values["least_order"] == pytest.approx(3.7)
    assert c.status == "pass" and c.values["order"] > 3.7, c.values
