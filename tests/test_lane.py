"""The run's second lane: the reduced model's stages beside the engine stages.

Stage computations are replaced by cheap stand-ins (as in test_resume_state), so
these tests check the order, the crash rules and the CPU record in milliseconds.
"""

from __future__ import annotations

import json
from concurrent.futures import CancelledError

import pytest

from validation import harness
from validation.harness import BESIDE, STAGES, StageCrashed, run_validation
from validation.lane import Lane
from validation.profiles import PROFILES


def test_lane_computes_in_order_and_stops_at_a_failing_stage():
    seen = []

    def compute(name):
        seen.append(name)
        if name == "b":
            raise FloatingPointError("garbage")
        return name.upper()

    lane = Lane(["a", "b", "c"], compute)
    assert lane.result("a")[0] == "A" and "a" in lane and "z" not in lane
    with pytest.raises(FloatingPointError, match="garbage"):
        lane.result("b")
    with pytest.raises(CancelledError):
        lane.result("c")
    lane.stop(wait=True)
    assert seen == ["a", "b"]


@pytest.fixture
def stand_ins(monkeypatch):
    """Every stage a stand-in; returns the order in which they were computed."""
    order = []

    def stand_in(name):
        def compute(*args, **kwargs):
            order.append(name)
            return [] if name == "figures" else {"stage": name}

        return compute

    for mod, attr, name in (
        (harness, "conformance_and_anchors", "conformance and anchors"),
        (harness.agreement, "lyapunov_checks", "lambda1 agreement"),
        (harness.agreement, "series_checks", "time-series agreement"),
        (harness.agreement, "amplitude_scan", "amplitude scan"),
        (harness.paper, "critical_gains", "critical gains"),
        (harness.paper, "lyapunov_curve", "lambda1 curve"),
        (harness.paper, "rms_and_velocity", "RMS and velocity"),
        (harness.paper, "peaks_and_spectra", "STCC and spectra"),
        (harness.paper, "robustness", "robustness"),
        (harness.paper, "nonlinear_comparison", "nonlinear stick"),
        (harness.agreement, "rod_length_study", "rod-length study"),
        (harness, "_figures", "figures"),
    ):
        monkeypatch.setattr(mod, attr, stand_in(name))
    monkeypatch.setattr(harness, "_engine_record", lambda *a, **k: {})
    monkeypatch.setattr(harness, "_results", lambda *a, **k: {})
    return order


@pytest.mark.parametrize("workers", [1, 2])
def test_every_stage_computed_once_kept_in_stage_order(stand_ins, tmp_path, workers):
    res = run_validation(PROFILES["smoke"], tmp_path / "o", workers=workers, progress=False,
                         figures=False)  # fmt: skip
    computed = [n for n in STAGES if n != "figures"]  # no figures asked for
    assert sorted(stand_ins) == sorted(computed) and res["stages_done"] == list(STAGES)
    if workers == 1:  # one after another: the stages' own CPU seconds
        assert stand_ins == computed and set(res["cpu_s"]) == set(STAGES)
    else:  # side by side: one total
        assert list(res["cpu_s"]) == ["all stages"]


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("failing", ["robustness", "rod-length study", "amplitude scan"])
def test_a_crash_names_its_stage_and_keeps_the_stages_before_it(
    stand_ins, monkeypatch, tmp_path, workers, failing
):
    """A lane stage, a stage computed ahead while the lane works, and a main-thread
    stage: each crash names its own stage, and results.json keeps exactly the stages
    before it, as when the stages run one after another."""
    owner = harness.paper if failing == "robustness" else harness.agreement
    attr = {"robustness": "robustness", "rod-length study": "rod_length_study",
            "amplitude scan": "amplitude_scan"}[failing]  # fmt: skip

    def boom(*a, **k):
        raise FloatingPointError("engine returned garbage")

    monkeypatch.setattr(owner, attr, boom)
    out = tmp_path / "o"
    with pytest.raises(StageCrashed) as info:
        run_validation(PROFILES["smoke"], out, workers=workers, progress=False, figures=False)
    assert info.value.stage == failing
    r = json.loads((out / "results.json").read_text())
    assert r["stages_done"] == list(STAGES[: STAGES.index(failing)])
    assert r["crashed"]["stage"] == failing


def test_a_stage_computed_ahead_while_the_lane_works_crashes_in_its_turn(
    stand_ins, monkeypatch, tmp_path
):
    """While a lane stage is still running, the main thread computes the rod-length study
    ahead; its crash is raised in its own turn, after the lane's stages are kept."""
    import time

    def slow(*a, **k):
        time.sleep(0.5)
        stand_ins.append("critical gains")
        return {"stage": "critical gains"}

    def boom(*a, **k):
        stand_ins.append("rod-length study")
        raise FloatingPointError("engine returned garbage")

    monkeypatch.setattr(harness.paper, "critical_gains", slow)
    monkeypatch.setattr(harness.agreement, "rod_length_study", boom)
    out = tmp_path / "o"
    with pytest.raises(StageCrashed) as info:
        run_validation(PROFILES["smoke"], out, workers=2, progress=False, figures=False)
    assert info.value.stage == "rod-length study"
    assert stand_ins.index("rod-length study") < stand_ins.index("critical gains")  # ahead
    r = json.loads((out / "results.json").read_text())
    assert r["stages_done"] == list(STAGES[: STAGES.index("rod-length study")])


def test_the_lane_holds_the_reduced_model_stages_only():
    from validation.harness import MODEL_FILE_STAGES

    assert set(BESIDE) < set(STAGES) and not set(BESIDE) & set(MODEL_FILE_STAGES)
    assert "rod-length study" not in BESIDE and "figures" not in BESIDE
