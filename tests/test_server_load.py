"""The experiment server under load (``benchmarks/bench_server_load.py``), fast: two
sessions of two WebSocket bots for 2 s lose no sample and give finite lateness numbers;
the loss count sees a mouse message or a frame taken out of a recording."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("aiohttp", reason="the experiment server needs aiohttp")

from validation.experiment.recording import load_trial

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "bench_server_load.py"
SESSIONS, DURATION = 2, 2.0


def _bench():
    spec = importlib.util.spec_from_file_location("bench_server_load", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


bench = _bench()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Two coupled sessions of 2 s, starts 0.5 s apart, against a server process."""
    return bench.run_trial(SESSIONS, DURATION, 0.5, 0, tmp_path_factory.mktemp("load"))


def test_two_sessions_lose_no_sample_and_give_finite_lateness(run):
    r = bench.summarise(run)
    frames = round(DURATION / bench.FRAME) + 1
    assert r.ends == {"time": SESSIONS}
    assert r.lost == 0
    assert r.frames == r.late_server.size == SESSIONS * frames
    assert r.late_bots.size == 2 * SESSIONS * frames  # every frame reached both bots
    assert r.round_trip.size == 2 * SESSIONS * (frames - 1)  # every answer recorded
    for x in (r.late_server, r.late_bots, r.round_trip):
        assert np.all(np.isfinite(x))
        assert all(math.isfinite(bench.pct(x, q)) for q in (50, 99))
    assert np.all(r.late_server >= 0) and np.all(r.round_trip > 0)
    assert math.isfinite(r.server_cpu) and r.server_cpu > 0
    assert math.isfinite(r.bots_cpu) and r.bots_cpu > 0
    p50 = f"{bench.pct(r.late_server, 50):.2f}"
    assert bench.row(r).split()[:3] == [str(SESSIONS), str(SESSIONS * frames), p50]


def _doctored(run, drop) -> int:
    """Lost samples of the first session once ``drop(line)`` lines leave its log."""
    bots = run.sessions[0]
    npz = run.out / bots[0].end["file"]
    log = npz.with_suffix(".jsonl")
    lines = log.read_text().splitlines(keepends=True)
    kept = [x for x in lines if not drop(json.loads(x))]
    assert len(kept) == len(lines) - 1
    doctored = run.out / "doctored" / log.name
    doctored.parent.mkdir(exist_ok=True)
    doctored.write_text("".join(kept))
    return bench.session_numbers(load_trial(doctored), bots).lost


def test_a_mouse_message_missing_from_the_recording_is_counted_lost(run):
    x = run.sessions[0][1].sent[40]  # seat 2's answer to frame 40
    assert _doctored(run, lambda d: d.get("mouse", [None] * 4)[::3] == [1, x]) == 1


def test_a_frame_missing_from_the_recording_is_counted_lost(run):
    assert _doctored(run, lambda d: d.get("k") == 50) >= 1


def test_count_lost_matches_in_order_by_value():
    assert bench.count_lost([1.0, 2.0, 3.0], [1.0, 2.0, 3.0]) == (0, 0)
    assert bench.count_lost([1.0, 2.0, 3.0], [1.0, 3.0]) == (1, 0)
    assert bench.count_lost([1.0, 2.0], [1.0, 2.5, 2.0]) == (0, 1)
    assert bench.count_lost([1.0, 2.0], [2.0, 1.0]) == (1, 1)


@pytest.mark.parametrize(
    ("args", "name"),
    [(["--sessions", "0"], "--sessions"), (["--sessions", "2,2"], "--sessions"),
     (["--duration", "nan"], "--duration"), (["--stagger", "-1"], "--stagger"),
     (["--seed", "x"], "--seed")],
)  # fmt: skip
def test_bad_input_is_one_line_and_exit_2(args, name):
    out = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True,
                         timeout=60, check=False)  # fmt: skip
    assert out.returncode == 2 and out.stdout == ""
    assert len(out.stderr.splitlines()) == 1 and name in out.stderr, out.stderr
