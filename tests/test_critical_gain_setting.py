"""beta* with its numerical setting: critical-gain states what it computed lambda1 with."""

from __future__ import annotations

import json


def test_critical_gain_states_its_numerical_setting(capsys):
    from validation.cli.main import main

    code = main(["critical-gain", "--model", "single", "--beta-range", "18", "26", "--dt",
                 "0.002", "--duration", "30", "--realizations", "2", "--gains", "3",
                 "--json"])  # fmt: skip
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    s = doc["setting"]
    assert s["dt_s"] == 0.002 and s["delay_steps"] == 50 and s["realizations"] == 2
    assert s["duration_s"] == 30.0 and s["transient_s"] == 3.0
    assert "Benettin" in s["estimator"] and "sqrt(dt)" in s["noise"]
    assert s["stepper"] == "semi-implicit"
