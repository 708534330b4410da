"""``experiment analyze`` keeps every trial: duplicates reported, incomplete trials marked and
left out of the averages unless asked for, units stated, the paper compared like with like."""

from __future__ import annotations

import json

import numpy as np
import pytest

from validation.cli.main import main
from validation.experiment.analysis import analyse_directory, duplicates, table
from validation.experiment.bot import BotSpec
from validation.experiment.headless import run_bot_trial
from validation.experiment.task import TaskSettings


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Single subject A: trial 1 twice (a duplicate), trial 2 complete, trial 3 killed."""
    d = tmp_path_factory.mktemp("rec")
    s = TaskSettings(mode="single", duration=2.0)
    for seed, index in ((1, 1), (2, 1), (3, 2), (4, 3)):
        out = run_bot_trial(s, [BotSpec(21.0, 0.1, 0.6, seed)], ["A"], index, d)
    # trial 3: keep only its log without the end record, as a killed server leaves it
    log = out.with_suffix(".jsonl")
    lines = log.read_text().splitlines()
    out.unlink()
    log.write_text("\n".join(line for line in lines if not line.startswith('{"end"')) + "\n")
    return d


def test_every_trial_is_kept_and_duplicates_are_reported(recordings):
    results, trajs = analyse_directory(recordings)
    assert len(trajs) == len(results) == 4
    rows = table(results, "rms_px")[("single", "A")]
    assert len(rows["trials"][1]) == 2  # both recordings of trial 1, not one replacing the other
    (dup,) = duplicates(results)
    assert (dup["mode"], dup["subject"], dup["trial_index"]) == ("single", "A", 1)
    assert len(dup["files"]) == 2


def test_incomplete_trials_are_left_out_of_averages_unless_asked(recordings):
    results, _ = analyse_directory(recordings)
    killed = [r for r in results if r.trial_index == 3]
    assert [r.end for r in killed] == ["unfinalised"] and not killed[0].complete
    complete = [r.rms_px for r in results if r.trial_index != 3]
    row = table(results, "rms_px")[("single", "A")]
    assert row["n"] == 3 and row["excluded"] == 1 and row["used"][3] == [False]
    assert row["average"] == pytest.approx(np.mean(complete))
    every = table(results, "rms_px", include_incomplete=True)[("single", "A")]
    assert every["n"] == 4 and every["excluded"] == 0
    assert every["average"] == pytest.approx(np.mean([r.rms_px for r in results]))


def test_report_states_units_and_compares_pixels_with_pixels(recordings, tmp_path, capsys):
    out = tmp_path / "an"
    assert main(["experiment", "analyze", str(recordings), "--out", str(out),
                 "--no-figures"]) == 0  # fmt: skip
    md = (out / "report.md").read_text()
    assert "## Duplicates" in md and "[unfinalised]" in md and "**left out**" in md
    px = md.split("### ours, pixels")[1].split("###")[0]
    units = md.split("### ours, model units")[1].split("\n", 1)[1].split("##")[0]
    assert "average (px)" in px and "3.62" in px  # the paper's single-A average, beside pixels
    assert "average (model units)" in units and "3.62" not in units and "paper" not in units
    assert "average (s)" in md.split("### ours (s)")[1].split("##")[0]
    res = json.loads((out / "results.json").read_text())
    assert res["table_rms_px"]["single A"]["excluded"] == 1 and len(res["duplicates"]) == 1

    assert main(["experiment", "analyze", str(recordings), "--out", str(out),
                 "--no-figures", "--include-incomplete"]) == 0  # fmt: skip
    md = (out / "report.md").read_text()
    assert "**included**" in md and "[unfinalised]" not in md
