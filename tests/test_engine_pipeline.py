"""One pipeline for every rigid-body engine: its own twin, direct checks, faults at its boundary."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import engine_or_skip, without_refinement

from cip.mjcf_params import read_mapping
from cipcore.params import BalanceParams
from cipcore.registry import get_engine
from cipcore.scenario import EngineTarget, Recording, Scenario
from reduced.twin import TwinParams, simulate_twin
from validation.checks.agreement import instrument_checks, model_file
from validation.checks.metrics import relative_l2
from validation.faults.catalogue import make_fault

BETA = {"single": 20.306, "coupled": 21.032}


def _twin_distance(name: str, model: str, integrator: str | None, duration: float = 2.0):
    eng = engine_or_skip(name)
    m = model_file(model, None, integrator)
    mp = read_mapping(m)
    p = BalanceParams(beta=BETA[model])
    tw = TwinParams(**eng.twin_terms(mp))
    kw = {"amplitude": 1e-6, "fields": ("balancing_error",)}
    full = eng.simulate(model, p, duration, 2, 3, physical=mp.physical(), mj_model=m, **kw)
    scn = Scenario(model, p, duration, 2, 3, amplitude=1e-6)
    twin = simulate_twin(scn, tw, recording=Recording(fields=("balancing_error",)))
    return relative_l2(full["balancing_error"], twin["balancing_error"]), eng, tw


@pytest.mark.parametrize("integrator", ["implicitfast", "RK4"])
@pytest.mark.parametrize("model", ["single", "coupled"])
def test_twin_steps_as_mujoco_for_each_integrator(model: str, integrator: str) -> None:
    """MuJoCo stepping RK4 or implicitfast meets its own twin at the floor, not the Euler twin."""
    d, eng, tw = _twin_distance("mujoco", model, integrator)
    assert tw.integrator == integrator
    assert d < eng.twin_tolerance_for(model)
    euler = TwinParams(**{**tw.as_dict(), "integrator": "Euler"})
    m = model_file(model, None, integrator)
    p = BalanceParams(beta=BETA[model])
    kw = {"amplitude": 1e-6, "fields": ("balancing_error",)}
    full = eng.simulate(model, p, 2.0, 2, 3, physical=read_mapping(m).physical(), mj_model=m, **kw)
    scn = Scenario(model, p, 2.0, 2, 3, amplitude=1e-6)
    e_euler = simulate_twin(scn, euler, recording=Recording(fields=("balancing_error",)))[
        "balancing_error"
    ]
    assert relative_l2(full["balancing_error"], e_euler) > 1e3 * eng.twin_tolerance_for(model)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_drake_meets_its_rigid_rod_twin(model: str) -> None:
    """Drake's SAP step with its near-rigid rod is matched to the twin's floor."""
    d, eng, _ = _twin_distance("drake", model, None, duration=1.0)
    assert eng.capabilities.rod == "rigid" and eng.capabilities.twin
    assert d < eng.twin_tolerance_for(model)


@pytest.mark.parametrize(
    "name", ["mujoco", "mjx", "drake", pytest.param("mujoco-warp", marks=pytest.mark.warp)]
)
@pytest.mark.parametrize(
    ("kind", "size"), [("delay_late", 1), ("cart_damping", 0.01), ("pendulum_length", 0.005)]
)
def test_faults_at_the_engine_boundary_fail_the_direct_checks(name, kind, size, monkeypatch):
    """A one-step-late delay, +1 % cart damping and +0.5 % pole length in the single model,
    injected into the engine, fail the checks `run --engine` and `engines` both run
    (:func:`validation.checks.agreement.series_checks` runs them for both).  MJX reuses its
    compiled step for the model edits; MuJoCo Warp runs on warp's CPU device only with
    CIPVAL_WARP_DEVICE=cpu (else skipped with the reason).  Refinement is left out
    (``helpers.without_refinement``)."""
    engine_or_skip(name)
    without_refinement(monkeypatch)
    fault = make_fault(kind, size)
    checks = instrument_checks(
        1, 1, threads=1, fault=fault, models=("single",), target=EngineTarget(name)
    )
    failed = [c.name for c in checks if c.status == "fail"]
    assert failed, f"{kind} {size} in {name} was not flagged"
    assert "twin.trajectory.single" in failed
    if kind == "delay_late":
        assert "delay.single" in failed


def test_unmodified_drake_passes_every_direct_check() -> None:
    engine_or_skip("drake")
    checks = instrument_checks(1, 1, threads=1, target=EngineTarget("drake"))
    assert [c.name for c in checks if c.status != "pass"] == []


def test_a_fault_an_engine_cannot_have_is_not_applicable() -> None:
    eng = engine_or_skip("drake")
    assert "rigid" in make_fault("rod_softness", 25.0).not_applicable(eng)
    assert "own integrator" in make_fault("integrator", 1).not_applicable(eng)
    assert make_fault("rod_softness", 25.0).not_applicable(get_engine("mujoco")) is None


def test_run_refuses_what_the_engine_cannot_do(capsys) -> None:
    from validation.cli.main import main

    for argv, text in (
        (["run", "--engine", "reduced"], "not a rigid-body engine"),
        (["run", "--engine", "mujoco", "--integrator", "Verlet"], "--integrator must be one of"),
        (["selftest", "--engine", "nosuch"], "engine must be one of"),
    ):
        assert main([*argv, "--profile", "smoke"] if argv[0] == "run" else argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and text in err[0], err


def test_integrator_is_set_in_the_model_file_and_refused_where_fixed(capsys) -> None:
    from validation.cli.main import main

    m = model_file("single", None, "RK4")
    assert read_mapping(m).integrator == "RK4"
    assert np.array_equal(m.opt.gravity, model_file("single").opt.gravity)
    engine_or_skip("drake")
    assert main(["selftest", "--engine", "drake", "--integrator", "RK4"]) == 2
    assert "it steps with SAP" in capsys.readouterr().err


def test_a_baseline_of_another_engine_is_refused(tmp_path, capsys) -> None:
    """A regression run compares an engine with a baseline of the same engine and integrator."""
    from validation.cli.main import main

    argv = ["run", "--baseline", "validation/data/baseline_quick.json", "--out", str(tmp_path)]
    assert main([*argv, "--integrator", "RK4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "was made with engine 'mujoco'" in err[0]


@pytest.mark.parametrize(
    ("name", "method", "option", "why"),
    [
        ("reduced", "simulate", "physical", "does not apply to it"),
        ("reduced", "lyapunov", "mj_model", "does not apply to it"),
        ("reduced", "simulate", "amplitde", "is not an engine option"),
        ("mujoco", "simulate", "stepper", "does not apply to it"),
        ("mujoco", "lyapunov", "renorm_interval", "is not an engine option"),
    ],
)
def test_an_option_the_engine_does_not_take_is_one_line_naming_it(name, method, option, why):
    """The engine contract is typed: nothing a caller passes is silently dropped."""
    from cipcore.params import ParameterError

    eng = get_engine(name)
    p = BalanceParams(beta=BETA["single"])
    with pytest.raises(ParameterError) as exc:
        getattr(eng, method)("single", p, 1.0, 1, 0, **{option: None})
    text = str(exc.value)
    assert "\n" not in text and f"option {option!r} {why}" in text and name in text


def test_the_reference_runner_refuses_rigid_body_parameters() -> None:
    from cip.model import CIPParams
    from cipcore.params import ParameterError

    p = BalanceParams(beta=BETA["single"])
    with pytest.raises(ParameterError, match="option 'physical' does not apply"):
        get_engine("reduced").runner("single", p, 1, 1e-4, physical=CIPParams.from_reduced(p))
    assert get_engine("reduced").runner("single", p, 1, 1e-4).n_realizations == 1


def test_mjx_declares_its_constraint_solve_and_meets_mujoco_at_small_amplitude() -> None:
    """MJX runs one Newton iteration per step (declared in its capabilities), as MuJoCo on
    the CPU takes; with the file's tolerance it took none at 1e-8 m (4e-4 off the twin)."""
    eng = engine_or_skip("mjx")
    from cip.engines.mjx import SOLVER_ITERATIONS, solver_model

    m = model_file("coupled")
    s = solver_model(m)
    assert s.opt.iterations == SOLVER_ITERATIONS == 1 and m.opt.iterations != 1
    assert eng.capabilities.solver and "one iteration" in eng.capabilities.solver
    p = BalanceParams(beta=BETA["coupled"])
    kw = {"amplitude": 1e-8, "fields": ("balancing_error",), "mj_model": m}
    a = eng.simulate("coupled", p, 0.3, 2, 1, **kw)["balancing_error"]
    b = get_engine("mujoco").simulate("coupled", p, 0.3, 2, 1, **kw)["balancing_error"]
    assert relative_l2(a, b) < 1e-9
