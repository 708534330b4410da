"""Exactness by time-step refinement (validation.checks.refinement, reduced.zoh)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate

from cipcore.scenario import EngineTarget
from reduced.zoh import zoh_matrices, zoh_response
from validation.checks import refinement
from validation.checks.refinement import FLOOR, RefinementSetting, extrapolate, refine


def test_zoh_matches_a_fine_ode_solution_under_held_input():
    """The augmented exponential is the exact hold solution: an adaptive ODE solver at
    tight tolerance over each interval agrees to its own tolerance."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((4, 4))
    b = rng.standard_normal((4, 2))
    h, u = 0.05, rng.standard_normal((1, 6, 2))
    x0 = rng.standard_normal((1, 4))
    ours = zoh_response(a, b, x0, u, h)[0]
    x = x0[0]
    for k in range(u.shape[1]):
        sol = scipy.integrate.solve_ivp(lambda t, y, k=k: a @ y + b @ u[0, k], (0, h), x,
                                        rtol=1e-12, atol=1e-14)  # fmt: skip
        x = sol.y[:, -1]
        np.testing.assert_allclose(ours[k], x, rtol=1e-9, atol=1e-12)


def test_zoh_of_a_double_integrator_is_the_kinematics():
    """x'' = u held over h: x gains v h + u h^2 / 2, v gains u h (exactly)."""
    a = np.array([[0.0, 1.0], [0.0, 0.0]])
    b = np.array([[0.0], [1.0]])
    ad, bd = zoh_matrices(a, b, 0.1)
    np.testing.assert_allclose(ad, [[1.0, 0.1], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(bd, [[0.005], [0.1]], atol=1e-15)
    with pytest.raises(ValueError, match="hold interval h"):
        zoh_matrices(a, b, 0.0)


def test_extrapolation_removes_whole_order_error_terms():
    """Levels y(h) = y0 + c1 h + c2 h^2: the observed order is 1 and the limit y0 is
    recovered to roundoff; a second-order series is recovered as well."""
    y0 = np.linspace(0.0, 1.0, 50)
    c1, c2 = np.sin(y0), np.cos(y0)
    for p in (1, 2):
        levels = [y0 + c1 * (1e-3 / 2**k) ** p + c2 * (1e-3 / 2**k) ** (p + 1) for k in range(4)]
        lim, order, order_coarse, change = extrapolate(levels)
        assert abs(order - p) < 1e-2 and abs(order_coarse - p) < 1e-2
        np.testing.assert_allclose(lim, y0, atol=1e-12)
        assert change < 1e-12


def _mujoco(integrator: str | None = None):
    from cip.engines.rigid_body import MUJOCO
    from validation.checks.agreement import model_file

    return MUJOCO, model_file("coupled", None, integrator)


@pytest.mark.parametrize(("integrator", "order"), [("Euler", 1.0), ("RK4", 4.0)])
def test_correct_steppers_converge_to_the_exact_solution(integrator, order):
    """MuJoCo's Euler and RK4 on the coupled file: the limit within a third of the floor,
    the observed order the stepper's."""
    eng, m = _mujoco(integrator)
    r = refine(m, eng.rollout(), rod="soft", setting=RefinementSetting(1, 2, 0.1))
    assert r.e0_interval[1] < FLOOR / 3, r
    assert abs(r.order - order) < 0.3, r
    assert r.passes(FLOOR, order - refinement.ORDER_SLACK)


@pytest.mark.parametrize("kind", ["mass_ratio", "gravity", "cart_damping", "pendulum_length"])
def test_a_1e4_fault_moves_the_limit_beyond_the_floor(kind):
    """A relative 1e-4 error in the engine's model converges, at the stepper's own order, to
    another limit: E0 beyond the floor by a factor of at least 5."""
    from validation.faults.catalogue import make_fault

    eng, m = _mujoco()
    backend = make_fault(kind, 1e-4).backend(eng.rollout())
    r = refine(m, backend, rod="soft", setting=RefinementSetting(1, 2, 0.1))
    assert r.e0 > 5 * FLOOR, r
    assert not r.passes(FLOOR, 0.7)


def test_a_substepping_engine_is_judged_by_refinement_and_passes(tmp_path):
    """An external engine that takes two MuJoCo steps per step (correct, finer) declares
    nothing: its twin distance moves it to the refinement tier, where it passes; its
    twin checks are n/a, not failures."""
    import sys

    from cip.engines.process import close_idle_engines, process_engine
    from cipcore.registry import register_engine
    from validation.checks.agreement import instrument_checks
    from validation.checks.stats import NOT_APPLICABLE, PASS

    cmd = f"{sys.executable} examples/chunk_engine.py --substeps 2"
    try:
        register_engine("substeps-2", process_engine(cmd, "substeps-2"))
        checks = {c.name: c for c in instrument_checks(1, 1, target=EngineTarget("substeps-2"),
                                                       models=("single",))}  # fmt: skip
    finally:
        close_idle_engines()
    assert checks["twin.trajectory.single"].status == NOT_APPLICABLE
    assert "judged against the exact solution" in checks["twin.trajectory.single"].details
    assert checks["refinement.single"].status == PASS
    assert checks["delay.single"].status == PASS


def test_version_2_declarations_are_checked():
    from cip.engines.process import declaration, declared_engine_terms

    assert declaration({"version": 1}) is None
    d = declaration({"version": 2, "integrator": "other", "order": 2, "rod": "rigid"})
    assert d == {"integrator": "other", "order": 2.0, "rod": "rigid"}
    terms = declared_engine_terms(d)
    assert terms["caps"]["twin"] is None and terms["caps"]["declared"]
    known = declared_engine_terms(declaration({"version": 2, "integrator": "RK4", "rod": "soft"}))
    assert known["caps"]["twin"] and known["integrators"] == ()
    assert refinement.tier(_caps(**known["caps"]))[0] == refinement.TWIN
    assert refinement.tier(_caps(**terms["caps"]))[0] == refinement.REFINEMENT
    for bad, field in [({"integrator": "rk4", "rod": "soft"}, "integrator"),
                       ({"integrator": "other", "rod": "soft"}, "order"),
                       ({"integrator": "other", "order": -1, "rod": "soft"}, "order"),
                       ({"integrator": "Euler", "rod": "stiff"}, "rod")]:  # fmt: skip
        with pytest.raises(ValueError, match=field):
            declaration({"version": 2, **bad})


def _caps(**kw):
    from cipcore.engine import Capabilities

    return Capabilities(precision="float64", device="cpu", rigid_body=True, linearize=False, **kw)


def test_a_level_converged_to_rounding_is_left_out_of_the_order():
    """A fourth-order series whose finest level carries rounding of its own size: without
    the cut the observed order would be about 2.7 (MuJoCo's RK4, coupled, seed 3); with it
    the order comes from the three coarser levels."""
    rng = np.random.default_rng(3)
    y0 = np.linspace(1.0, 2.0, 200)
    levels = [y0 + 1e-9 * y0 * (1 / 2**k) ** 4 for k in range(4)]
    levels[-1] = levels[-1] + 1.5e-11 * rng.standard_normal(y0.shape)
    _, blind, _, _ = extrapolate(levels)
    _, p, _, _ = extrapolate(levels, roundoff=refinement.ROUNDOFF)
    assert abs(blind - 4) > 0.5 and abs(p - 4) < 0.05


# ------------------------------------------------------------ float32 engines
def test_the_float64_setting_is_the_module_floor_and_amplitude():
    """A float64 engine is judged at 1e-5 m against 1e-6, its check carrying no float32
    keys (the exact-mode regression compares these numbers and strings)."""
    from cip.engines.rigid_body import MUJOCO
    from validation.checks.agreement import model_file

    ps = refinement.precision_setting("single", "float64")
    assert (ps.amplitude, ps.window, ps.floor) == (1e-5, 1.0, FLOOR)
    c = refinement.refinement_check("single", model_file("single"), MUJOCO, 1)
    assert c.status == "pass" and c.values["floor"] == FLOOR
    assert "setting" not in c.values and "float32" not in c.details + c.tolerance
    assert "largest |e| 1e-05 m" in c.details
    assert "<= 1e-06 (the correct engines' E0 with margin)" in c.tolerance


def test_float32_state_rounds_every_step():
    """The stand-in's states are float32 numbers, and a step of it is MuJoCo's step of the
    float32-rounded state, rounded."""
    import mujoco

    from cip.runner import MujocoRollout
    from validation.checks.agreement import model_file

    m = model_file("single")
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.tile(np.zeros(mujoco.mj_stateSize(m, spec)), (2, 1))
    state[:, 2] = [0.01, -0.02]
    ctrl = np.random.default_rng(0).standard_normal((2, 3, m.nu))
    out = np.empty((2, 3, state.shape[1]))
    refinement.float32_state(MujocoRollout)(m, 2, 1)(state, ctrl, out)
    assert np.array_equal(out, out.astype(np.float32).astype(np.float64))
    ref = np.empty((2, 1, state.shape[1]))
    MujocoRollout(m, 2, 1)(out[:, 0], ctrl[:, 1:2], ref)
    assert np.array_equal(out[:, 1], ref[:, 0].astype(np.float32).astype(np.float64))
    assert not np.array_equal(out[:, 1], ref[:, 0])  # the rounding did something


def _float32_check(model: str, fault: tuple[str, float] | None = None):
    from validation.checks.agreement import model_file
    from validation.faults.catalogue import make_fault

    eng = refinement.float32_stand_in()
    backend = make_fault(*fault).backend(eng.rollout()) if fault else None
    return refinement.refinement_check(model, model_file(model), eng, 1, backend=backend)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_the_float32_stand_in_passes_at_its_setting_and_fails_a_1e3_tip_mass(model):
    """MuJoCo's Euler rounded to float32 every step: correct, it passes the float32 setting
    (beyond the float64 floor: it is no float64 engine); a 1e-3 tip-mass error fails it."""
    clean = _float32_check(model)
    ps = refinement.FLOAT32_SETTINGS[model]
    assert clean.status == "pass", clean.values
    assert clean.values["setting"] == "float32" and clean.values["floor"] == ps.floor
    assert clean.values["amplitude_m"] == ps.amplitude and clean.values["window_s"] == ps.window
    assert "float32 setting" in clean.details and "float32 setting" in clean.tolerance
    assert clean.values["e0_interval"][1] > FLOOR  # float32 rounding: not a float64 engine
    assert clean.values["projection_bound"] == ps.projection_bound
    assert max(abs(v) for v in clean.values["projection"].values()) <= ps.projection_bound
    faulty = _float32_check(model, ("mass_ratio", 1e-3))
    assert faulty.status == "fail" and faulty.values["e0_interval"][0] > ps.floor, faulty.values


#: a 1e-4 error of each projected parameter, as CIPParams fields (value factors), the
#: model file rebuilt from them: the tip mass with its damper's coefficient gamma m held,
#: as the fault catalogue's mass error holds it (cip.edits.scale_tip_mass)
_BUILT_ERRORS = {
    "mass_ratio": {"bob_mass": 1 + 1e-4, "tip_damping": 1 / (1 + 1e-4)},
    "pendulum_length": {"pendulum_length": 1 + 1e-4},
    "gravity": {"gravity": 1 + 1e-4},
    "tip_damping": {"tip_damping": 1 + 1e-4},
    "cart_damping": {"cart_damping": 1 + 1e-4},
}


def _stepping(wrong):
    """MuJoCo stepping the compiled file ``wrong`` in place of the one it is given (whose
    time step and integrator it takes)."""
    import copy

    from cip.runner import MujocoRollout

    class Wrong(MujocoRollout):
        def __init__(self, model, *rest):
            w = copy.deepcopy(wrong)
            w.opt.timestep, w.opt.integrator = model.opt.timestep, model.opt.integrator
            super().__init__(w, *rest)

    return Wrong


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_a_parameter_error_projects_on_its_own_direction(model):
    """A model file rebuilt from parameters with one of them 1e-4 off (cip.model.build,
    not the edits the sensitivities use), integrated nonlinearly (MuJoCo's RK4, the
    reference's levels, extrapolated): its deviation from the clean file's reference
    projects on that parameter's direction as 1e-4, for every parameter and both models;
    a deviation orthogonal to a direction projects on nothing."""
    import copy
    from dataclasses import replace

    import mujoco

    from cip.model import CIPParams, build
    from validation.checks.agreement import model_file

    m = model_file(model)
    setting = RefinementSetting(1, window=1.0, amplitude=1e-3)
    ctrl, exact, x0 = refinement.excitation(m, "soft", setting)
    sens = refinement.sensitivities(m, "soft", x0, ctrl, exact)
    assert set(sens) == set(refinement.PROJECTED)
    clean = refinement.reference_limit(m, ctrl, setting)
    rk4 = copy.deepcopy(m)
    rk4.opt.integrator = int(mujoco.mjtIntegrator.mjINT_RK4)
    p = CIPParams()
    for kind, factors in _BUILT_ERRORS.items():
        wrong = build(model, replace(p, **{f: getattr(p, f) * v for f, v in factors.items()}))
        # the wrong file's dynamics, observed through the clean file's map, as an engine is
        runs = refinement.run_levels(rk4, _stepping(wrong), ctrl, setting)
        c = refinement.projections(extrapolate(runs, refinement.ROUNDOFF)[0] - clean, sens)
        assert c[kind] == pytest.approx(1e-4, rel=2e-3), (model, kind, c)
    s = sens["cart_damping"].ravel()
    noise = np.random.default_rng(0).standard_normal(s.shape)
    noise -= s * (noise @ s) / (s @ s)
    c = refinement.projections(noise.reshape(exact.shape), {"cart_damping": sens["cart_damping"]})
    assert abs(c["cart_damping"]) < 1e-12


def test_alike_directions_group_the_parameters_the_data_cannot_tell_apart():
    """Over the float32 setting's 4 s the tip mass, gravity and tip damping are one group
    (1 - |cos| below 1e-5), length and cart damping each their own; over 1 s gravity
    separates (3e-4); two orthogonal directions are never alike."""
    from validation.checks.agreement import model_file

    m = model_file("coupled")
    groups = {}
    for window in (4.0, 1.0):
        setting = RefinementSetting(1, window=window, amplitude=3e-3)
        ctrl, exact, x0 = refinement.excitation(m, "soft", setting)
        groups[window] = refinement.alike_directions(
            refinement.sensitivities(m, "soft", x0, ctrl, exact)
        )
    assert groups[4.0]["gravity"] == ("mass_ratio", "gravity", "tip_damping")
    assert groups[4.0]["pendulum_length"] == ("pendulum_length",)
    assert groups[4.0]["cart_damping"] == ("cart_damping",)
    assert groups[1.0]["gravity"] == ("gravity",)
    assert groups[1.0]["tip_damping"] == ("mass_ratio", "tip_damping")
    e = np.eye(3)
    assert refinement.alike_directions({"a": e[0], "b": e[1], "c": e[0] * -2}) == {
        "a": ("a", "c"), "b": ("b",), "c": ("a", "c")}  # fmt: skip


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_the_nonlinear_reference_leaves_float64_mujoco_no_parameter_error(model):
    """MuJoCo's own Euler in float64 at the float32 setting's amplitude (1e-3 / 3e-3 m,
    over 1 s of the setting's 4): its limit's deviation from the linear solution is the
    linearisation's error (c up to 2e-5 along the dampers, mass and gravity at 4 s); from
    the nonlinear reference it is below 1e-8 along every parameter."""
    from cip.runner import MujocoRollout
    from validation.checks.agreement import model_file

    m = model_file(model)
    ps = refinement.FLOAT32_SETTINGS[model]
    setting = RefinementSetting(2, window=1.0, amplitude=ps.amplitude)
    ctrl, _, _ = refinement.excitation(m, "soft", setting)
    runs = refinement.run_levels(m, MujocoRollout, ctrl, setting)
    c, c_linear, _ = refinement.parameter_projections(m, "soft", setting, runs)
    assert max(abs(v) for v in c.values()) < 1e-8, c
    assert max(abs(v) for v in c_linear.values()) > 5e-7, c_linear


def test_the_projection_basis_is_reused_only_for_the_same_file_and_setting():
    """The second projection of the same runs gives the same numbers (its basis reused);
    a file edited in place, or another setting, gets a basis of its own."""
    from cip.edits import scale_gravity
    from cip.runner import MujocoRollout
    from validation.checks.agreement import model_file

    m = model_file("single")
    setting = RefinementSetting(3, n_realizations=2, window=0.5, amplitude=1e-3)
    ctrl, _, _ = refinement.excitation(m, "soft", setting)
    runs = refinement.run_levels(m, MujocoRollout, ctrl, setting)
    first = refinement.parameter_projections(m, "soft", setting, runs)
    assert refinement.parameter_projections(m, "soft", setting, runs) == first
    other = RefinementSetting(4, n_realizations=2, window=0.5, amplitude=1e-3)
    assert refinement.parameter_projections(m, "soft", other, runs).c != first.c
    scale_gravity(m, 1 + 1e-3)  # in place: the same runs against a file with g 1e-3 larger
    c = refinement.parameter_projections(m, "soft", setting, runs).c
    assert c["gravity"] == pytest.approx(first.c["gravity"] - 1e-3, abs=5e-5), (c, first.c)


def test_the_float32_projection_flags_a_1e4_cart_damping_error_that_e0_cannot():
    """The float32 stand-in on the coupled model with its cart damping 1e-4 too large
    (seed 1): E0 stays inside the floor (E0 alone flagged this error at 0 of 20 seeds),
    the cart damper's projection exceeds its bound, and the check fails naming it."""
    ps = refinement.FLOAT32_SETTINGS["coupled"]
    faulty = _float32_check("coupled", ("cart_damping", 1e-4))
    assert faulty.values["e0_interval"][1] <= ps.floor, faulty.values
    assert faulty.values["projection"]["cart_damping"] > ps.projection_bound, faulty.values
    assert faulty.status == "fail" and "largest here: cart_damping +" in faulty.tolerance


def test_no_float32_setting_for_an_unknown_model():
    with pytest.raises(ValueError, match="no float32 refinement setting"):
        refinement.precision_setting("triple", "float32")


def _physx():
    pytest.importorskip("sapien", reason="sapien is not installed (pip install 'cipval[physx]')")
    from cip.engines.physx import ENGINE
    from cipcore.registry import engine_names, register_engine

    if ENGINE.name not in engine_names():
        register_engine(ENGINE.name, ENGINE)
    return ENGINE


def test_physx_coupled_fails_a_1e3_tip_mass_at_the_float32_setting():
    """At the float64 setting the rod's float32 resolution (E0 5e-3 at 1e-5 m) hid a 1e-3
    tip-mass error on the coupled model; at the float32 setting it fails (seed 1)."""
    from validation.checks.agreement import model_file
    from validation.faults.catalogue import make_fault

    eng = _physx()
    backend = make_fault("mass_ratio", 1e-3).backend(eng.rollout())
    c = refinement.refinement_check("coupled", model_file("coupled"), eng, 1, backend=backend)
    floor = refinement.FLOAT32_SETTINGS["coupled"].floor
    assert c.status == "fail" and c.values["e0_interval"][0] > floor, c.values


def test_physx_states_the_float32_floors():
    """cip.engines.physx states the floors it is held to: the float32 setting's."""
    from cip.engines.physx import REFINEMENT_FLOOR_FLOAT32

    assert REFINEMENT_FLOOR_FLOAT32 == {m: s.floor for m, s in refinement.FLOAT32_SETTINGS.items()}
