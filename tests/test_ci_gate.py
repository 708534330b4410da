"""What a CI gate relies on: distinct exit codes, JUnit XML, the log, the regression mode."""

from __future__ import annotations

import copy
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from validation.cli import exitcodes
from validation.cli.main import main

BASELINE = Path(__file__).resolve().parent.parent / "validation" / "data" / "baseline_quick.json"


@pytest.fixture
def canned(monkeypatch):
    """``run`` returns a finished results dict (the shipped quick baseline's) at once."""
    results = json.loads(BASELINE.read_text())
    box = {"results": results}

    def fake_run(profile, out_dir, **kw):
        return copy.deepcopy(box["results"])

    import validation.run

    monkeypatch.setattr(validation.run, "run_validation", fake_run)
    return box


def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_exit_0_when_every_check_passes_and_junit_has_one_case_per_check(canned, tmp_path, capsys):
    junit = tmp_path / "r.xml"
    code, out, _ = _run(capsys, "run", "--no-figures", "--out", str(tmp_path / "o"),
                        "--junit", str(junit))  # fmt: skip
    assert code == exitcodes.EXIT_OK == 0
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites"
    cases = root.findall(".//testcase")
    checks = canned["results"]["checks"]
    assert [c.get("name") for c in cases] == [c["name"] for c in checks]
    assert root.get("tests") == str(len(checks)) and root.get("failures") == "0"
    # the table: a value and a tolerance on every row
    rows = [ln for ln in out.splitlines() if ln.split()[:1] and ln.split()[0] in
            {c["name"] for c in checks}]  # fmt: skip
    assert len(rows) == len(checks)
    for ln in rows:
        assert "n/a" not in ln and len(ln.split()) >= 5, ln
    assert "tolerance" in out.splitlines()[0]


def test_exit_1_when_a_check_fails_failures_and_skips_in_junit(canned, tmp_path, capsys):
    r = canned["results"]
    r["checks"][0]["status"] = "fail"
    r["checks"][1]["status"] = "inconclusive"
    r["status"] = "fail"
    junit = tmp_path / "r.xml"
    code, out, _ = _run(capsys, "run", "--quiet", "--out", str(tmp_path / "o"),
                        "--junit", str(junit))  # fmt: skip
    assert code == exitcodes.EXIT_FAIL == 1
    assert r["checks"][0]["name"] in out  # --quiet still prints the table when a check fails
    root = ET.parse(junit).getroot()
    cases = {c.get("name"): c for c in root.iter("testcase")}
    assert cases[r["checks"][0]["name"]].find("failure") is not None
    assert cases[r["checks"][1]["name"]].find("skipped") is not None
    assert root.get("failures") == "1" and root.get("skipped") == "1"


def test_quiet_passing_run_prints_no_table(canned, tmp_path, capsys):
    code, out, err = _run(capsys, "run", "--quiet", "--out", str(tmp_path / "o"))
    assert code == 0 and "tolerance" not in out and "stage" not in err


def test_exit_3_when_a_regression_number_moves_grouped_with_relative_change(
    canned, tmp_path, capsys
):
    base = json.loads(BASELINE.read_text())
    base.pop("fingerprint", None)  # a baseline made before fingerprints: compared at round-off
    for c in base["checks"]:
        if c["name"] == "paper.beta_star.single":
            c["values"]["value"] *= 1.01
            c["values"]["se"] *= 1.01
    f = tmp_path / "base.json"
    f.write_text(json.dumps(base))
    junit = tmp_path / "r.xml"
    code, out, _ = _run(capsys, "run", "--out", str(tmp_path / "o"), "--baseline", str(f),
                        "--junit", str(junit))  # fmt: skip
    assert code == exitcodes.EXIT_REGRESSION == 3
    reg = ET.parse(junit).getroot().find("testsuite[@name='run.regression']")
    names = [c.get("name") for c in reg.iter("testcase")]
    assert names == ["regression (roundoff mode)", "regression.paper.beta_star.single.se",
                     "regression.paper.beta_star.single.value"]  # fmt: skip
    # same versions, the baseline records no CPU fingerprint: every number at round-off
    assert "roundoff mode" in out and "within tolerance" in out
    assert "paper.beta_star.single: 2 number(s) moved" in out
    assert "value: " in out and "relative change -0.0099" in out
    assert "se: " not in out  # a derived number: only with --verbose
    code, out, _ = _run(capsys, "run", "--out", str(tmp_path / "o"), "--baseline", str(f),
                        "--verbose")  # fmt: skip
    assert code == 3 and "se: " in out
    # a failed check takes precedence over a moved number
    canned["results"]["status"] = "fail"
    canned["results"]["checks"][0]["status"] = "fail"
    code, _, _ = _run(capsys, "run", "--out", str(tmp_path / "o"), "--baseline", str(f))
    assert code == 1


def test_exit_4_when_the_engine_crashes_with_partial_results_naming_the_stage(
    monkeypatch, tmp_path, capsys
):
    import validation.checks.agreement

    def boom(*a, **k):
        raise FloatingPointError("engine returned garbage")

    monkeypatch.setattr(validation.checks.agreement, "series_checks", boom)
    out = tmp_path / "o"
    junit = tmp_path / "r.xml"
    code, _, err = _run(capsys, "run", "--profile", "smoke", "--no-figures", "--out", str(out),
                        "--junit", str(junit))  # fmt: skip
    assert code == exitcodes.EXIT_CRASH == 4
    assert "time-series agreement" in err and "crashed" in err
    r = json.loads((out / "results.json").read_text())
    assert r["partial"] is True
    from validation.run import STAGES

    assert r["stages_done"] == list(STAGES[: STAGES.index("time-series agreement")])
    assert r["crashed"]["stage"] == "time-series agreement"
    assert "engine returned garbage" in r["crashed"]["error"]
    from validation.schemas import validate

    validate(r, "run")  # a partial, crashed results.json follows the run schema too
    fails = [c for c in ET.parse(junit).getroot().iter("testcase") if c.find("failure")
             is not None]  # fmt: skip
    assert [c.get("name") for c in fails] == ["stage.time-series agreement"]


def test_exit_2_on_bad_input(capsys):
    code, _, err = _run(capsys, "run", "--profile", "nope")
    assert code == exitcodes.EXIT_USAGE == 2 and err.count("\n") == 1


def test_exit_codes_are_distinct_and_documented():
    codes = [exitcodes.EXIT_OK, exitcodes.EXIT_FAIL, exitcodes.EXIT_USAGE,
             exitcodes.EXIT_REGRESSION, exitcodes.EXIT_CRASH, exitcodes.EXIT_SIGINT,
             exitcodes.EXIT_SIGTERM]  # fmt: skip
    assert len(set(codes)) == 7 and set(exitcodes.MEANING) == set(codes)
    readme = (BASELINE.parent.parent.parent / "README.md").read_text()
    for code in codes:
        assert f"| {code} |" in readme


def test_progress_bars_only_on_a_terminal(monkeypatch):
    import io
    import sys

    from validation.cli.ci_options import progress_enabled

    class Tty(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert progress_enabled() is False  # a CI log is no terminal
    monkeypatch.setattr(sys, "stderr", Tty())
    assert progress_enabled() is True
    assert progress_enabled(quiet=True) is False
    monkeypatch.setenv("TQDM_DISABLE", "1")
    assert progress_enabled() is False


def test_selftest_junit_has_the_unmodified_model_and_each_fault(selftest_run):
    code, _, junit, _, (_, rows) = selftest_run  # `selftest --junit FILE`
    assert code == 0
    root = ET.parse(junit).getroot()
    cases = [c.get("name") for c in root.iter("testcase")]
    assert cases == ["unmodified_model", *(f"fault.{r['fault']}" for r in rows)]
    assert "fault.gravity" in cases and root.get("failures") == "0"


def test_an_engine_crash_in_engines_is_exit_4(tmp_path, capsys):
    dead = f"{__import__('sys').executable} -c 'import sys; sys.exit(5)'"
    assert main(["engines", "--engine-cmd", dead, "--engines", "reduced", "--profile", "smoke",
                 "--no-figures", "--quiet", "--out", str(tmp_path)]) == 4  # fmt: skip
    assert "exited with status 5" in capsys.readouterr().err


def test_a_baseline_of_other_model_files_is_refused_before_the_run(canned, tmp_path, capsys):
    from validation.regression.fingerprint import model_digests

    base = json.loads(BASELINE.read_text())
    base["fingerprint"] = {"model_digests": {**model_digests(), "coupled": "0123456789abcdef"}}
    f = tmp_path / "base.json"
    f.write_text(json.dumps(base))
    code, _, err = _run(capsys, "run", "--out", str(tmp_path / "o"), "--baseline", str(f))
    assert code == 2 and err.count("\n") == 1 and "model files differ (coupled)" in err
    # named explicitly, the comparison runs and says so
    canned["results"]["fingerprint"] = {"model_digests": model_digests()}
    code, out, _ = _run(capsys, "run", "--out", str(tmp_path / "o"), "--baseline", str(f),
                        "--baseline-mode", "statistical")  # fmt: skip
    assert code == 0 and "statistical mode (requested (model files differ (coupled)" in out
