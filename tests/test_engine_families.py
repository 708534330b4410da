"""The Bullet, Exudyn and Simbody engines: faults at the engine boundary reach them,
a one-step delay error fails the cross-engine trajectory check, their state maps
round-trip, and their import banners stay off stdout.

The shared contract (same noise -> reduced trajectory, delay of tau/dt steps,
rod, energy, batch split) runs on them in ``tests/test_engine_contract.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import subprocess
import sys

import numpy as np
import pytest
from helpers import engine_or_skip, without_refinement

from cip.model import CIPParams, build
from cip.runner import MujocoRollout, RigidBody
from cip.simulate import simulate_full
from cipcore import registry
from cipcore.params import BalanceParams
from cipcore.registry import get_engine
from cipcore.scenario import EngineTarget, Execution, Scenario
from validation.checks.agreement import instrument_checks
from validation.checks.stats import FAIL
from validation.faults.catalogue import Fault, make_fault

FAMILIES = ("bullet", "exudyn", "simbody")
P = BalanceParams(beta=20.306)


def faulty_backend(base: type, fault: Fault) -> type:
    """``base`` (any rollout backend) stepping a faulty copy of the model and/or controls."""
    import copy

    import mujoco

    class Faulty(base):
        def __init__(self, model, n_realizations, threads):
            m = copy.deepcopy(model)
            if fault.edit_model is not None:
                fault.edit_model(m)
                mujoco.mj_setConst(m, mujoco.MjData(m))
            self._m, self._memory = m, {}
            super().__init__(m, n_realizations, threads)

        def __call__(self, state, ctrl, out):
            if fault.edit_ctrl is not None:
                ctrl = np.ascontiguousarray(fault.edit_ctrl(self._m, ctrl, self._memory))
            super().__call__(state, ctrl, out)

    return Faulty


def _run(backend: type, model: str = "single", duration: float = 1.0) -> np.ndarray:
    return simulate_full(
        Scenario(model, P, duration, 1, 3, amplitude=1e-3),
        body=RigidBody(backend=backend),
        execution=Execution(threads=1),
    )["balancing_error"]


@functools.cache
def _clean(name: str, model: str) -> np.ndarray:
    return _run(get_engine(name).backend(), model)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("name", FAMILIES)
@pytest.mark.parametrize(
    ("kind", "size", "model"),
    [("cart_damping", 0.01, "single"), ("tip_damping", 0.01, "single"),
     ("pendulum_length", 0.005, "single"), ("mass_ratio", 1.0, "single"),
     ("gravity", 0.01, "single"), ("timestep", 0.01, "single"), ("delay_late", 1, "single"),
     ("bob_inertia", 0.01, "single"), ("rod_removed", 1, "coupled")],
)  # fmt: skip
def test_a_fault_at_the_engine_boundary_moves_the_engine_as_it_moves_mujoco(
    name: str, kind: str, size: float, model: str
) -> None:
    """The fault's effect on the trajectory (relative to the clean run of the same engine)
    matches MuJoCo's to within a factor 1.5: the engine reads the faulty model copy
    and receives the faulty controls, as the selftest's catalogue needs.  Exudyn's
    point-mass bob refuses a bob inertia with a one-line error instead."""
    from cipcore.params import ParameterError

    base = engine_or_skip(name).backend()
    fault = make_fault(kind, size)
    try:
        faulty = _run(faulty_backend(base, fault), model)
    except ParameterError as exc:  # a model the engine cannot build, refused in one line
        assert kind == "bob_inertia" and "point mass" in str(exc), str(exc)
        return
    moved = _rel(faulty, _clean(name, model))
    ref = _rel(_run(faulty_backend(MujocoRollout, fault), model), _clean("mujoco", model))
    assert ref > 1e-4, f"{kind}: MuJoCo itself barely moves ({ref:.2e})"
    assert ref / 1.5 < moved < 1.5 * ref, f"{name} {kind}: moved {moved:.3e}, MuJoCo {ref:.3e}"


@pytest.mark.parametrize("name", FAMILIES)
def test_one_step_delay_error_fails_the_run_checks(name, monkeypatch) -> None:
    """A one-step-late delay in the engine fails the direct checks that `run --engine` and
    `engines` apply (the delay measured from the response, and the twin).  The
    refinement check, which the same call runs at dt .. dt/8 (most of its time on the
    slow engines), is left out here (``helpers.without_refinement``)."""
    engine = engine_or_skip(name)
    without_refinement(monkeypatch)
    late = faulty_backend(engine.backend(), make_fault("delay_late", 1))
    faulty = dataclasses.replace(engine, name=f"{name}-late", backend=lambda: late)
    monkeypatch.setattr(sys.modules[__name__], "FAULTY", faulty, raising=False)
    monkeypatch.setitem(registry.ENGINES, faulty.name, f"{__name__}:FAULTY")
    checks = {
        c.name: c
        for c in instrument_checks(1, 2, target=EngineTarget(faulty.name), models=("single",))
    }
    delay = checks["delay.single"]
    assert delay.status == FAIL and delay.values["measured_steps"] == 101, delay
    assert checks["twin.trajectory.single"].status == FAIL


def test_exudyn_state_map_round_trips() -> None:
    pytest.importorskip("exudyn")
    from cip.engines.exudyn import ExudynRollout

    m = build("coupled", CIPParams())
    b = ExudynRollout(m, 1, 1)
    rng = np.random.default_rng(0)
    s = rng.normal(size=1 + m.nq + m.nv) * 0.1
    back = s.copy()
    b.from_exudyn(*b.to_exudyn(s), back)
    np.testing.assert_allclose(back, s, rtol=0, atol=1e-15)


def test_exudyn_refuses_a_bob_of_finite_radius() -> None:
    pytest.importorskip("exudyn")
    from cip.engines.exudyn import ExudynRollout
    from cipcore.params import ParameterError

    with pytest.raises(ParameterError, match="point mass"):
        ExudynRollout(build("single", CIPParams(bob_radius=0.02)), 1, 1)


def test_bullet_single_model_is_mujoco_to_rounding() -> None:
    """Same scheme (semi-implicit Euler, explicit forces), no constraint: the same numbers."""
    base = engine_or_skip("bullet").backend()
    assert _rel(_run(base), _clean("mujoco", "single")) < 1e-12


@pytest.mark.parametrize("name", FAMILIES)
def test_import_banners_stay_off_stdout_and_stderr(name: str, tmp_path) -> None:
    """Nothing on stdout or stderr, and no log file left in the working directory."""
    engine_or_skip(name)
    import os

    code = (
        "from cipcore.registry import get_engine; from cipcore.params import BalanceParams; "
        f"get_engine({name!r}).simulate('coupled', BalanceParams(beta=20.306), 0.01, 1)"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp_path, env=env)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and done.stderr == "", (done.stdout, done.stderr)
    assert os.listdir(tmp_path) == []


def test_engines_json_stays_parseable_when_an_engine_prints_a_banner(tmp_path, capfd) -> None:
    """warp announces its devices on stdout when first imported; ``--json`` keeps it out."""
    import json

    from validation.cli.main import main

    rc = main(["engines", "--engines", "reduced,mujoco-warp", "--profile", "smoke", "--json",
               "--out", str(tmp_path), "--no-figures"])  # fmt: skip
    cap = capfd.readouterr()
    assert cap.out.strip(), f"nothing on stdout; stderr: {cap.err[-500:]}"
    res = json.loads(cap.out)
    assert rc == 0 and [r["engine"] for r in res["engines"]] == ["reduced", "mujoco-warp"]


def test_the_engines_run_records_each_engines_package_versions():
    """``cip-validate engines`` records the versions of what each engine imports (its
    ``requires``: DART's dartpy) beside the core stack's; MuJoCo (the core, nothing
    required) and a name not in the registry add nothing."""
    dartpy = pytest.importorskip("dartpy")
    from validation.cli.commands.engines import engine_versions

    got = engine_versions(["dart", "mujoco", "no-such-engine"])
    assert got["dartpy"] == dartpy.__version__, got
    assert set(got) - {"commit"} == {"dartpy"}, got


class _ThirdCallFails:
    """Counts the engine's steps; the third raises, as a failed engine step does."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self) -> None:
        self.calls += 1
        if self.calls == 3:
            raise RuntimeError("the engine's step failed")


def _simbody_fails(monkeypatch, fail: _ThirdCallFails) -> None:
    """Each ``Manager.integrate`` counted by ``fail`` (it raises as Simbody's projection does)."""
    from cip.engines import simbody

    make = simbody._Model.manager

    class Failing:
        def __init__(self, mgr):
            self.mgr = mgr

        def getState(self):  # OpenSim's name
            return self.mgr.getState()

        def integrate(self, t):
            fail()
            return self.mgr.integrate(t)

    monkeypatch.setattr(simbody._Model, "manager", lambda *a: Failing(make(*a)))


def _exudyn_fails(monkeypatch, fail: _ThirdCallFails) -> None:
    """Each Exudyn step counted by ``fail`` (it raises as a failed Newton iteration does)."""
    from cip.engines import exudyn

    step = exudyn._Realization.step

    def failing(self, f_cart, f_bob):
        fail()
        return step(self, f_cart, f_bob)

    monkeypatch.setattr(exudyn._Realization, "step", failing)


@pytest.mark.parametrize(("name", "inject"), [("simbody", _simbody_fails),
                                              ("exudyn", _exudyn_fails)])  # fmt: skip
def test_a_step_failing_mid_chunk_keeps_the_steps_before_it(name, inject, monkeypatch) -> None:
    """The engine's step fails at step 3 of realisation 0: that realisation's first two
    steps are those of a clean run, NaN from step 3 on, one warning; the other realisation
    is untouched."""
    from cip.runner import CIPRunner

    backend = engine_or_skip(name).backend()

    def chunk() -> tuple[np.ndarray, int]:
        r = CIPRunner("coupled", P, CIPParams.from_reduced(P), 2, 1e-3, threads=1,
                      backend=backend)  # fmt: skip
        out = np.empty((2, 6, r.state.shape[1]))
        r.backend(r.state.copy(), np.zeros((2, 6, r.m.nu)), out)
        return out, r.backend.warnings()

    clean, w0 = chunk()
    inject(monkeypatch, _ThirdCallFails())
    failed, w1 = chunk()
    assert (w0, w1) == (0, 1)
    np.testing.assert_array_equal(failed[0, :2], clean[0, :2])
    assert np.isnan(failed[0, 2:, 1:]).all() and np.isfinite(failed[0, :2]).all()
    np.testing.assert_array_equal(failed[1], clean[1])
