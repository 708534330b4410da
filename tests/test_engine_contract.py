"""One contract for every registered engine (skipped, with the reason, where unavailable).

The checks live in the installed package (:mod:`validation.checks.contract`, also
``cip-validate contract --engine NAME`` for an engine's own CI); this file runs
them for every registered engine.  Against the reduced reference under the same
noise draws each engine must: reproduce the reduced trajectory within its
declared precision at small amplitude; apply the control exactly d = tau/dt
steps after the balancing error it uses; hold the rod length (coupled rigid
body); conserve energy without control or damping (rigid body); give the same
numbers for any batch split.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import engine_or_skip

from cipcore.noise import ArrayNoise, GainNoise
from cipcore.params import BalanceParams
from cipcore.registry import REFERENCE, declared_engines, engine_names, get_engine
from validation.checks import contract

P = BalanceParams(beta=20.306)


#: engines stepping warp kernels (CPU device only by opt-in): marked ``warp``, run by CI's
#: warp step
ON_WARP = declared_engines(kernels="warp")


def _marked(names) -> list:
    return [pytest.param(n, marks=pytest.mark.warp) if n in ON_WARP else n for n in names]


ENGINES = _marked(engine_names())
RIGID = _marked(n for n in engine_names() if n != REFERENCE)


def _check(fn, name: str, *args) -> None:
    try:
        fn(engine_or_skip(name), *args)
    except contract.ContractSkip as exc:
        pytest.skip(str(exc))


@pytest.mark.parametrize("name", ENGINES)
@pytest.mark.parametrize("model", ["single", "coupled"])
def test_same_noise_gives_the_reduced_trajectory(name: str, model: str) -> None:
    _check(contract.same_noise_gives_the_reduced_trajectory, name, model)


@pytest.mark.parametrize("name", ENGINES)
def test_delay_is_tau_over_dt_steps(name: str) -> None:
    _check(contract.delay_is_tau_over_dt_steps, name)


@pytest.mark.parametrize("integrator", ["RK4", "implicitfast"])
def test_delay_is_tau_over_dt_steps_for_any_integrator(integrator: str) -> None:
    """MuJoCo stepping RK4 or implicitfast applies the same delay (the estimator assumes
    no stepper)."""
    d, resid = contract.lag_residuals(engine_or_skip("mujoco"), integrator)
    assert min(resid, key=resid.get) == d, resid
    assert resid[d] < 1e-3 and min(resid[d - 1], resid[d + 1]) > 10 * resid[d]


@pytest.mark.parametrize("name", RIGID)
def test_rod_holds_the_tips_together(name: str) -> None:
    _check(contract.rod_holds_the_tips_together, name)


@pytest.mark.parametrize("name", RIGID)
def test_energy_is_conserved_without_control_or_damping(name: str) -> None:
    _check(contract.energy_is_conserved_without_control_or_damping, name)


@pytest.mark.parametrize("name", ENGINES)
def test_same_seed_same_numbers_for_any_batch_split(name: str) -> None:
    _check(contract.same_seed_same_numbers_for_any_batch_split, name)


def test_array_noise_and_gain_noise_agree_across_engines() -> None:
    """Handing the draws as an array changes nothing (the noise is the same value)."""
    xi = GainNoise(2, 2, 1).draws(500)
    a = get_engine(REFERENCE).simulate("single", P, 0.5, noise=ArrayNoise(xi, seed=2))
    b = get_engine(REFERENCE).simulate("single", P, 0.5, 2, seed=2)
    assert np.array_equal(a["balancing_error"], b["balancing_error"])


def test_engines_command_lists_every_engine_with_verdicts(tmp_path, capsys) -> None:
    """`cip-validate engines --json`, smoke size: verdicts, throughputs, skips with reasons."""
    import json

    from validation.cli.main import main

    rc = main(["engines", "--engines", "reduced,mujoco", "--profile", "smoke", "--json",
               "--out", str(tmp_path), "--no-figures"])  # fmt: skip
    res = json.loads(capsys.readouterr().out)
    rows = {r["engine"]: r for r in res["engines"]}
    assert set(rows) == {"reduced", "mujoco"}
    assert rc == (1 if res["status"] == "fail" else 0)
    m = rows["mujoco"]
    # the same direct checks as `run --engine mujoco`: its twin, rod, delay, declared model
    names = {c["name"] for c in m["checks"]}
    assert {"twin.trajectory.coupled", "twin.rod.coupled", "delay.single"} <= names
    assert not [f for f in m["failed"] if f.startswith(("twin.", "delay.", "model."))]
    assert m["twin_distance"]["coupled"] < m["twin_tolerance"]["coupled"]
    assert m["delay_steps"] == {"single": 100, "coupled": 100}
    assert m["throughput"]["ratio_to_mujoco"] == 1.0
    assert 0 < m["trajectory_distance"]["coupled"] < 1e-2
    assert rows["reduced"]["trajectory_distance"]["coupled"] == 0.0
    # each stage's wall time, summing to no more than the engine's
    stages = m["stage_seconds"]
    assert list(stages) == ["throughput", "lambda1", "time series", "amplitude scan"]
    assert sum(stages.values()) <= m["seconds"] + 0.2
    cross, reproduced = (tmp_path / "report.md").read_text().split("## What each engine reproduced")
    assert "Wall time by stage: throughput " in reproduced
    assert cross.count("| mujoco |") == 1 and reproduced.count("| mujoco |") == 1
    assert_tables_well_formed((tmp_path / "report.md").read_text())


def assert_tables_well_formed(md: str) -> None:
    """Every row of every Markdown table has the header's cell count, no cell empty."""
    from validation.report.document import markdown_tables

    tables = markdown_tables(md)
    assert tables
    for table in tables:
        head = table[0]
        for row in table[1:]:
            assert len(row) == len(head), (head, row)
            assert all(c.strip() for c in row), row


def test_engines_command_rejects_an_unknown_engine(capsys) -> None:
    from validation.cli.main import main

    assert main(["engines", "--engines", "reduced,nosuchengine"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "engine must be one of" in err[0] and "nosuchengine" in err[0]


def test_an_absent_engine_is_listed_as_skipped_with_the_reason(monkeypatch) -> None:
    from cipcore import registry
    from validation.engines import EnginesSetting, compare_engines

    monkeypatch.setitem(registry.ENGINES, "absent", "cipval_no_such_module:ENGINE")
    res = compare_engines(["absent"], EnginesSetting("smoke"))
    (row,) = res["engines"]
    assert row["status"] == "skipped" and "cipval_no_such_module" in row["reason"]
    from validation.engines import markdown

    md = markdown(res)
    assert_tables_well_formed(md)
    assert "cipval_no_such_module" in md.split("| absent | skipped |")[1].splitlines()[0]


class _SteppedBy:
    """MuJoCo with every model it builds stepped by ``integrator`` (the physical setting
    ``--integrator`` sets), so the whole contract runs for it."""

    def __init__(self, integrator: str) -> None:
        from dataclasses import replace

        base = engine_or_skip("mujoco")
        self.base, self.integrator = base, integrator
        self.name = base.name
        self.capabilities = replace(base.capabilities, integrator=integrator)

    def _physical(self, params, physical):
        from dataclasses import replace

        from cip.model import CIPParams

        return replace(physical or CIPParams.from_reduced(params), integrator=self.integrator)

    def simulate(self, model, params, *args, physical=None, **kw):
        tr = self.base.simulate(model, params, *args, physical=self._physical(params, physical),
                                **kw)  # fmt: skip
        assert tr.attrs["stepper"] == self.integrator
        return tr

    def runner(self, model, params, n, amplitude, *, physical=None):
        return self.base.runner(model, params, n, amplitude,
                                physical=self._physical(params, physical))  # fmt: skip


@pytest.mark.parametrize("check", list(contract.CHECKS))
@pytest.mark.parametrize("integrator", ["RK4", "implicitfast"])
def test_mujoco_passes_the_whole_contract_with_another_integrator(integrator, check) -> None:
    """--integrator RK4 / implicitfast is a physical setting, not a fault: MuJoCo stepping
    with it passes every contract check (trajectory, delay, rod, energy, batch split)."""
    contract.CHECKS[check](_SteppedBy(integrator))
