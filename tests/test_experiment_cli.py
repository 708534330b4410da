"""``cip-validate experiment``: bad input is one line and exit 2; bots -> analyze works."""

from __future__ import annotations

import pytest

from validation.cli.main import main


@pytest.mark.parametrize(
    ("argv", "name"),
    [
        (["experiment", "analyze", "/nonexistent/dir"], "DIR"),
        (["experiment", "bots", "--subjects", "A"], "--subjects"),
        (["experiment", "bots", "--trials", "0"], "--trials"),
        (["experiment", "bots", "--trial-duration", "-5"], "--trial-duration"),
        (["experiment", "bots", "--trial-duration", "1e23"], "--trial-duration"),
        (["experiment", "bots", "--trials", "99999999999999999999"], "--trials"),
        (["experiment", "bots", "--trials", "10001", "--force"], "--trials"),
        (["experiment", "bots", "--tau", "0.0005"], "tau"),
        (["experiment", "serve", "--port", "70000"], "--port"),
        (["experiment", "serve", "--trial-duration", "0"], "--trial-duration"),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, tmp_path, argv, name):
    if argv[1] == "bots":
        argv = [*argv, "--out", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cip-validate: error: ") and name in err[0]


def test_analyze_empty_directory_is_a_usage_error(capsys, tmp_path):
    assert main(["experiment", "analyze", str(tmp_path)]) == 2
    assert "holds no recordings" in capsys.readouterr().err


def test_bots_then_analyze_writes_the_tables_and_figures(tmp_path, capsys):
    rec = tmp_path / "rec"
    assert main(["experiment", "bots", "--out", str(rec), "--trials", "2",
                 "--trial-duration", "45", "--seed", "3"]) == 0  # fmt: skip
    assert len(list(rec.glob("*.npz"))) == 6  # 2 x single A, single B, coupled (A,B)
    assert main(["experiment", "analyze", str(rec), "--out", str(tmp_path / "an")]) == 0
    md = (tmp_path / "an" / "report.md").read_text()
    assert "Table STCC" in md and "Table RMS" in md and "0.132" in md  # paper's (A,B) beside
    for fig in ("move_s", "move_c", "stcc_s", "stcc_c", "rmstau"):
        assert (tmp_path / "an" / f"{fig}.png").stat().st_size > 5000
    assert "<table>" in (tmp_path / "an" / "report.html").read_text()
