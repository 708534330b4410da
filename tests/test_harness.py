"""cip-validate run: exit codes, outputs, regression baseline, verdict rules."""

from __future__ import annotations

import json

import numpy as np
import pytest

from validation.checks.stats import FAIL, INCONCLUSIVE, PASS, ci_overlap, paired_equivalence
from validation.cli.main import main
from validation.report.document import compare_with_baseline


@pytest.fixture(scope="module")
def smoke_run(smoke_run_once):
    return smoke_run_once


def test_smoke_profile_runs_every_stage_and_passes(smoke_run):
    code, out = smoke_run
    results = json.loads((out / "results.json").read_text())
    assert code == 0, [c["name"] for c in results["checks"] if c["status"] != "pass"]
    names = {c["name"] for c in results["checks"]}
    for expected in (
        "agreement.lambda1.single.beta=19.5", "agreement.log10_rms.coupled",
        "agreement.spectrum_bands.single", "agreement.stcc_peak_median.coupled",
        "agreement.trajectory.single", "agreement.breakdown_detected.coupled",
        "paper.beta_star.shift",
    ):  # fmt: skip
        assert expected in names
    assert {r["quantity"] for r in results["paper"]} >= {"beta* single (lambda1 = 5e-4)"}
    assert len(results["figures"]) == 11
    for f in results["figures"]:
        assert (out / f).stat().st_size > 5000
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64") == 11
    assert "Paper reproduction" in (out / "report.md").read_text()
    assert results["versions"]["mujoco"]
    # run in validation.run.STAGES' order (the conformance stage last, before the
    # figures), listed in RESULT_ORDER's: the model files' conformance and anchors first
    from validation.run import RESULT_ORDER, STAGES

    assert results["stages_done"] == list(STAGES)
    assert STAGES[-2:] == ("conformance and anchors", "figures")
    assert sorted(RESULT_ORDER) == sorted(STAGES)
    first = [c["name"].split(".")[0] for c in results["checks"][:6]]
    assert first == ["model", "model", "anchor", "anchor", "anchor", "anchor"]


def test_baseline_regression_passes_on_itself_and_fails_on_a_moved_number(smoke_run, tmp_path):
    _, out = smoke_run
    results = json.loads((out / "results.json").read_text())
    same = compare_with_baseline(results, results)
    assert same and all(c.status == PASS for c in same)
    moved = json.loads(json.dumps(results))
    for c in moved["checks"]:
        if c["name"] == "paper.beta_star.single":
            c["values"]["value"] += 10 * c["values"]["se"]
    bad = [c for c in compare_with_baseline(results, moved) if c.status == FAIL]
    assert [c.name for c in bad] == ["regression.paper.beta_star.single.value"]  # exact mode
    bad = [c for c in compare_with_baseline(results, moved, "statistical") if c.status == FAIL]
    assert [c.name for c in bad] == ["regression.paper.beta_star.single"]
    # a round-off move: named in exact mode (old and new value), within statistical tolerances
    tiny = json.loads(json.dumps(results))
    for c in tiny["checks"]:
        if c["name"] == "twin.trajectory.single":
            c["values"]["relative_l2"] *= 1 + 1e-9
            moved_to = c["values"]["relative_l2"]
    bad = [c for c in compare_with_baseline(results, tiny, "exact") if c.status == FAIL]
    assert [c.name for c in bad] == ["regression.twin.trajectory.single.relative_l2"]
    assert bad[0].values["baseline"] == moved_to
    assert all(c.status == PASS for c in compare_with_baseline(results, tiny, "statistical"))
    # the trajectory distance is in the baseline in both modes (issue 9: 0.28% -> 0.9%)
    far = json.loads(json.dumps(results))
    for c in far["checks"]:
        if c["name"] == "agreement.trajectory.single":
            c["values"]["relative_l2"] *= 3
    for mode in ("exact", "statistical"):
        bad = [c.name for c in compare_with_baseline(results, far, mode) if c.status == FAIL]
        assert bad == ["regression.agreement.trajectory.single.relative_l2"]


def test_results_follow_the_run_schema_with_numeric_tolerances(smoke_run):
    from validation.schemas import validate

    _, out = smoke_run
    results = json.loads((out / "results.json").read_text())
    validate(results, "run")
    limits = {c["name"]: c["tolerance_limit"] for c in results["checks"]}
    assert limits["twin.trajectory.single"] == {"on": "relative_l2", "limit": 1e-9}
    # rules with no single number: every item of the specification within its bound, a
    # chi-square interval per controller, every far amplitude disagreeing
    rule_only = {n for n in limits if n.startswith(("model.conforms.", "anchor.gain_variance",
                                                   "agreement.breakdown_detected."))}  # fmt: skip
    assert {n for n, v in limits.items() if v is None} == rule_only
    assert limits["paper.beta_star.shift"]["on"] == "value - paper"


def test_baseline_command_and_wrong_baseline_is_usage_error(smoke_run, tmp_path, capsys):
    _, out = smoke_run
    base = tmp_path / "base.json"
    assert main(["baseline", "--from", str(out / "results.json"), "--out", str(base)]) == 0
    assert json.loads(base.read_text())["profile"] == "smoke"
    # a baseline of another profile is refused before anything runs
    assert main(["run", "--profile", "quick", "--baseline", str(base), "--out", str(tmp_path)]) == 2
    assert "profile" in capsys.readouterr().err
    assert main(["run", "--baseline", str(tmp_path / "missing.json")]) == 2


def test_ci_overlap_rule():
    assert ci_overlap(1.0, (0.9, 1.1), 1.05, (0.95, 1.15))[0] == PASS
    assert ci_overlap(1.0, (0.9, 1.1), 1.3, (1.25, 1.35))[0] == FAIL
    assert ci_overlap(1.0, (0.9, 1.1), 1.15, (1.1, 1.2))[0] == INCONCLUSIVE


def test_paired_equivalence_rule():
    rng = np.random.default_rng(0)
    base = rng.normal(0, 1, 40)
    assert paired_equivalence(base + 1e-3 * rng.normal(size=40), base)[0] == PASS
    assert paired_equivalence(base + 2.0, base)[0] == FAIL


def _start_run(out, *extra):
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "validation.cli.main", "run", "--profile", "smoke",
           "--out", str(out), *extra]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _stages_done(out) -> list[str]:
    path = out / "results.json"
    return json.loads(path.read_text())["stages_done"] if path.is_file() else []


def _interrupt_after(proc, out, n_stages: int, sig, then=None) -> tuple[int, str, list[str]]:
    """Send ``sig`` once ``n_stages`` stages are on disk, and ``then`` (a second signal)
    20 ms later, while the run stops or exits; (exit status, stderr, stages)."""
    import time

    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and len(_stages_done(out)) < n_stages:
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be interrupted"
    proc.send_signal(sig)
    if then is not None:
        time.sleep(0.02)
        if proc.poll() is None:
            proc.send_signal(then)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, err, _stages_done(out)


def test_sigterm_keeps_every_finished_stage_and_resume_reuses_them(smoke_run, tmp_path):
    """The fast version of the test below: SIGTERM after the first stage, then a resume
    stopped one stage later; it reuses the kept stage, and every check so far has the
    numbers of the uninterrupted run.  The resume gets a SIGINT 20 ms after its SIGTERM:
    the first signal decides the exit status, and the second breaks off nothing.  (The
    slow version keeps two stages, the figures' process, SIGINT, and resumes to the
    end.)"""
    import signal

    from validation.run import STAGES

    out = tmp_path / "interrupted"
    # without the figures' process (the slow version keeps it): the stages alone
    code, err, kept = _interrupt_after(_start_run(out, "--no-figures"), out, 1, signal.SIGTERM)
    assert code == 143, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("cip-validate: interrupted by SIGTERM: kept ") and "--resume" in last
    assert len(kept) >= 1 and kept == list(STAGES[: len(kept)])
    code, err, kept2 = _interrupt_after(
        _start_run(out, "--no-figures", "--resume"),
        out,
        len(kept) + 1,
        signal.SIGTERM,
        then=signal.SIGINT,
    )
    assert code == 143, err
    assert err.strip().splitlines()[-1].startswith("cip-validate: interrupted by SIGTERM: ")
    assert len(kept2) > len(kept) and kept2[: len(kept)] == kept
    partial = json.loads((out / "results.json").read_text())
    assert partial["partial"] is True and partial["stages_reused"] == kept
    _, clean_out = smoke_run
    clean = {c["name"]: c for c in json.loads((clean_out / "results.json").read_text())["checks"]}
    assert partial["checks"] and all(c == clean[c["name"]] for c in partial["checks"])


@pytest.mark.slow
def test_sigint_and_sigterm_keep_every_finished_stage_and_resume_completes(smoke_run, tmp_path):
    import signal

    from validation.run import STAGES

    out = tmp_path / "interrupted"
    code, err, kept = _interrupt_after(_start_run(out), out, 2, signal.SIGINT)
    assert code == 130, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("cip-validate: interrupted by SIGINT: kept ") and "--resume" in last
    assert len(kept) >= 2 and kept == list(STAGES[: len(kept)])
    assert f"kept {len(kept)} of {len(STAGES)} stages" in last
    partial = json.loads((out / "results.json").read_text())
    assert partial["partial"] is True and partial["checks"]

    code, err, kept2 = _interrupt_after(
        _start_run(out, "--resume"), out, len(kept) + 1, signal.SIGTERM
    )
    assert code == 143, err
    assert "cip-validate: interrupted by SIGTERM: kept " in err.strip().splitlines()[-1]
    assert len(kept2) > len(kept) and kept2[: len(kept)] == kept

    proc = _start_run(out, "--resume")
    _, err = proc.communicate(timeout=600)
    results = json.loads((out / "results.json").read_text())
    assert results["partial"] is False and results["stages_done"] == list(STAGES)
    assert results["stages_reused"] == kept2
    assert "reused from the last run" in err
    # the same numbers as the uninterrupted run
    _, clean_out = smoke_run
    clean = json.loads((clean_out / "results.json").read_text())
    assert results["checks"] == clean["checks"]
    assert results["paper"] == clean["paper"]
    assert proc.returncode == smoke_run[0]


def test_divergence_of_the_stages_is_listed_per_run_and_point():
    import xarray as xr

    from validation.run import _divergence

    t = np.full((2, 2, 3), np.nan)
    t[1, 0, 2] = 4.5  # l/L = 2, amplitude 1e-3, realisation 2 diverged at 4.5 s
    ds = xr.Dataset(
        {"divergence_time": (("rod_length_ratio", "amplitude", "realization"), t)},
        coords={"rod_length_ratio": [0.5, 2.0], "amplitude": [1e-3, 0.1], "realization": [0, 1, 2]},
    )
    scan = [
        {"model": "single", "amplitude": 1e-5, "small_angle": True, "fell": False,
         "max_abs_angle": 1e-4},
        {"model": "single", "amplitude": 0.3, "small_angle": False, "fell": True,
         "max_abs_angle": 3.0},
    ]  # fmt: skip
    out = _divergence({"amplitude scan": ([], scan), "rod-length study": ([], [], ds)})
    assert [d["stage"] for d in out] == ["amplitude scan", "rod-length study"]
    assert "fell" in out[0]["summary"] and "0.3 m" in out[0]["run"]
    assert out[1]["run"] == "rod_length_ratio=2.0, amplitude=0.001"
    assert "realisations [2] of 3 diverged (first at t = 4.5 s)" == out[1]["summary"]


def test_divergence_searches_each_stage_once_per_run(monkeypatch):
    """The partial results written after every stage reuse the rows of the stages already
    searched (``seen``), and search a stage again when its value is another object."""
    import validation.run as run

    calls = []
    real = run._stage_divergence
    monkeypatch.setattr(run, "_stage_divergence",
                        lambda name, value: calls.append(name) or real(name, value))  # fmt: skip
    scan = ([], [{"model": "single", "amplitude": 0.3, "small_angle": False, "fell": True,
                  "max_abs_angle": 3.0}])  # fmt: skip
    seen: dict = {}
    first = run._divergence({"amplitude scan": scan}, seen)
    again = run._divergence({"amplitude scan": scan, "robustness": {}}, seen)
    assert first == again and len(first) == 1 and calls == ["amplitude scan"]
    other = ([], [{**scan[1][0], "amplitude": 0.2}])
    assert "0.2 m" in run._divergence({"amplitude scan": other}, seen)[0]["run"]
    assert calls == ["amplitude scan"] * 2
    run._divergence({"amplitude scan": scan})  # no memo: searched every time
    assert calls == ["amplitude scan"] * 3


def test_an_engine_gone_non_finite_fails_its_checks_and_every_stage_runs(
    mujoco_nan_after, tmp_path
):
    """An engine whose state turns NaN 0.5 s into every run (in the first realisation of
    each call's block): every stage finishes and the run fails (exit 1), not crashes
    (exit 4). Before, the rod-length study (shapes of a stopped run against the
    reference's), the time series (an STCC window longer than the stopped run) and lambda1
    (FloatingPointError) each crashed the run."""
    mujoco_nan_after(500)  # MuJoCo's state NaN in each block's first realisation
    with pytest.warns(RuntimeWarning):
        code = main(["run", "--profile", "smoke", "--no-figures", "--out", str(tmp_path)])
    res = json.loads((tmp_path / "results.json").read_text())
    assert code == 1 and not res.get("partial") and "crashed" not in res
    status = {c["name"]: c["status"] for c in res["checks"]}
    assert status["agreement.lambda1.single.beta=19.5"] == FAIL
    assert status["agreement.trajectory.coupled"] == FAIL
    assert status["agreement.log10_rms.single"] == INCONCLUSIVE  # no estimate: NaN
    (rms,) = [c for c in res["checks"] if c["name"] == "agreement.log10_rms.single"]
    assert "the engine's run stopped between t = 0.5 and 0.6 s (non-finite state" in rms["details"]
    stages = {d["stage"] for d in res["divergence"]}
    assert {"time-series agreement", "lambda1 agreement", "rod-length study"} <= stages
