"""Engines side by side (:mod:`validation.engine_jobs`): values, errors, dead processes,
one accelerator job at a time, and no process left running after a failure.

The jobs' work is :func:`eval` of the job's name, so that a job can return a value,
raise, exit or be killed without a helper module the worker processes must import.
"""

from __future__ import annotations

import os
import time

import pytest

from validation.engine_jobs import EngineJob, EngineJobError, run_side_by_side

SLEEP = "(__import__('time').time(), __import__('time').sleep({s}), __import__('time').time())"


def test_values_come_back_by_name_in_the_given_order_whatever_the_workers():
    jobs = [EngineJob("1 + 1", cost=1.0), EngineJob("'a' * 3", cost=5.0), EngineJob("[2] * 2")]
    for workers in (1, 2, 3):
        out = run_side_by_side(jobs, eval, workers)
        assert list(out) == [j.name for j in jobs]
        assert [v for v, _ in out.values()] == [2, "aaa", [2, 2]]
        assert all(s >= 0 for _, s in out.values())


def test_a_job_here_runs_in_this_process_beside_the_others():
    pid = "__import__('os').getpid()"
    out = run_side_by_side([EngineJob(pid), EngineJob(pid + " + 0", here=True)], eval, 2)
    assert out[pid + " + 0"][0] == os.getpid() != out[pid][0]


def test_started_is_told_each_job_longest_first():
    seen: list[str] = []
    jobs = [EngineJob("1", cost=1.0), EngineJob("2", cost=3.0), EngineJob("3", cost=2.0)]
    run_side_by_side(jobs, eval, 2, started=seen.append)
    assert seen == ["2", "3", "1"]


def test_an_exception_comes_back_with_its_type_and_message():
    with pytest.raises(ZeroDivisionError, match="division by zero"):
        run_side_by_side([EngineJob("1"), EngineJob("1 / 0")], eval, 2)


def test_a_process_that_exits_or_is_killed_names_the_engine():
    with pytest.raises(EngineJobError, match=r"exited with status 3 without a result"):
        run_side_by_side([EngineJob("__import__('os')._exit(3)")], eval, 2)
    kill = "__import__('os').kill(__import__('os').getpid(), 9)"
    with pytest.raises(EngineJobError, match=r"engine .*kill.*: its process killed by SIGKILL"):
        run_side_by_side([EngineJob(kill), EngineJob("2")], eval, 2)


def _meet(mine: str, other: str) -> str:
    """A job that leaves file ``mine`` and waits (up to 20 s) for ``other``: True when they
    met, i.e. both jobs ran at once."""
    exists = f"__import__('os').path.exists({other!r})"
    return (
        f"(open({mine!r}, 'w').close(), [__import__('time').sleep(0.01) for _ in "
        f"range(2000) if not {exists}], {exists})[-1]"
    )


def test_accelerator_jobs_run_one_at_a_time_and_cpu_jobs_side_by_side(tmp_path):
    a, b = SLEEP.format(s=0.5), SLEEP.format(s=0.5) + " "
    gpu = run_side_by_side([EngineJob(a, device="gpu"), EngineJob(b, device="gpu")], eval, 2)
    (s1, _, e1), (s2, _, e2) = (v for v, _ in gpu.values())
    assert s2 >= e1 or s1 >= e2  # never both at once
    a, b = (
        _meet(str(tmp_path / "a"), str(tmp_path / "b")),
        _meet(str(tmp_path / "b"), str(tmp_path / "a")),
    )
    cpu = run_side_by_side([EngineJob(a), EngineJob(b)], eval, 2)
    assert [v for v, _ in cpu.values()] == [True, True]  # both at once


def test_a_failure_stops_the_jobs_still_running(tmp_path):
    pid_file = tmp_path / "pid"
    sleeper = (f"open({str(pid_file)!r}, 'w').write(str(__import__('os').getpid())) "
               "and __import__('time').sleep(120)")  # fmt: skip
    fail = "__import__('time').sleep(1.0) or 1 / 0"
    t0 = time.monotonic()
    with pytest.raises(ZeroDivisionError):
        run_side_by_side([EngineJob(sleeper, cost=2.0), EngineJob(fail, cost=1.0)], eval, 2)
    assert time.monotonic() - t0 < 60
    pid = int(pid_file.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_engines_side_by_side_give_the_numbers_of_one_at_a_time():
    """`cip-validate engines --jobs 2` against `--jobs 1`: every check the same, value for
    value, though the engines get other thread counts; the throughput is measured first in
    either case (one engine at a time)."""
    from validation.engines import EnginesSetting, compare_engines

    names = ["reduced", "mujoco"]
    # threads None: one at a time every core, side by side cores // jobs each
    one, two = (compare_engines(names, EnginesSetting("smoke", jobs=j)) for j in (1, 2))
    assert (one["jobs"], two["jobs"]) == (1, 2)
    for a, b in zip(one["engines"], two["engines"], strict=True):
        assert a["engine"] == b["engine"] and a["status"] == b["status"] == "pass"
        assert a["checks"] == b["checks"]
        assert set(a["stage_seconds"]) == set(b["stage_seconds"])


def test_a_kept_error_is_the_jobs_value_and_the_others_go_on():
    kill = "__import__('os').kill(__import__('os').getpid(), 9)"
    jobs = [EngineJob("1 / 0"), EngineJob("2 + 2"), EngineJob("[] + 1", here=True)]
    for workers, extra in ((1, []), (2, [EngineJob(kill)])):  # one process: no kill here
        out = run_side_by_side(jobs + extra, eval, workers, kept=lambda e: True)
        assert isinstance(out["1 / 0"][0], ZeroDivisionError)
        assert isinstance(out["[] + 1"][0], TypeError) and out["2 + 2"][0] == 4
        if extra:
            assert isinstance(out[kill][0], EngineJobError)
    with pytest.raises(ZeroDivisionError):  # one it does not keep ends the run
        run_side_by_side(jobs, eval, 2, kept=lambda e: isinstance(e, TypeError))


def test_an_engine_that_crashes_is_a_row_and_the_others_are_written(tmp_path, capsys):
    """`engines` with an --engine-cmd program that answers its handshake and then exits
    with status 5: its row is "crashed" with the reason, the reference's row is checked
    and written, the JUnit file has an error, and the command exits 4."""
    import json
    import shlex
    import sys
    import xml.etree.ElementTree as ET
    from pathlib import Path

    from validation.cli.main import main

    example = Path(__file__).resolve().parents[1] / "examples" / "chunk_engine.py"
    count = tmp_path / "starts"
    script = (f"import os, pathlib, sys; p = pathlib.Path({str(count)!r}); "
              "n = int(p.read_text()) if p.exists() else 0; p.write_text(str(n + 1)); "
              f"sys.exit(5) if n >= 1 else os.execv(sys.executable, "
              f"[sys.executable, {str(example)!r}])")  # fmt: skip
    cmd = shlex.join([sys.executable, "-c", script])
    junit = tmp_path / "e.xml"
    code = main(["engines", "--engine-cmd", cmd, "--engines", "reduced", "--profile", "smoke",
                 "--json", "--no-figures", "--out", str(tmp_path / "o"), "--jobs", "2",
                 "--junit", str(junit)])  # fmt: skip
    captured = capsys.readouterr()
    assert code == 4 and "an engine crashed: command" in captured.err
    assert "exited with status 5" in captured.err
    doc = json.loads(captured.out)
    rows = {r["engine"]: r for r in doc["engines"]}
    assert rows["reduced"]["status"] == "pass" and rows["command"]["status"] == "crashed"
    assert doc["crashed"] == ["command"] and "exited with status 5" in rows["command"]["reason"]
    saved = json.loads((tmp_path / "o" / "results.json").read_text())
    assert [r["status"] for r in saved["engines"]] == ["pass", "crashed"]
    assert "| command | crashed |" in (tmp_path / "o" / "report.md").read_text()
    root = ET.parse(junit).getroot()
    assert root.get("errors") == "1" and root.get("failures") == "0"


def _marked(mark: str) -> list[int]:
    """Processes whose environment holds ``mark`` (this machine's /proc)."""
    from pathlib import Path

    pids = []
    for d in Path("/proc").iterdir():
        try:
            if d.name.isdigit() and mark.encode() in (d / "environ").read_bytes():
                pids.append(int(d.name))
        except OSError:  # gone, or not ours
            continue
    return pids


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc to find the processes")
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_an_interrupted_engines_command_leaves_no_engine_process(tmp_path, sig):
    """SIGINT or SIGTERM while MuJoCo is checked in a process of its own and an engine in
    another program (the chunk-protocol example) in the command's: the command ends within
    seconds with 130 or 143, no engine process (nor the forkserver, nor the example's
    processes) outlives it, and results.json keeps what was measured (partial: each
    engine's throughput; an engine whose checks did not finish is "interrupted")."""
    import json
    import re
    import shlex
    import signal
    import subprocess
    import sys
    import uuid
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "chunk_engine.py"
    mark = f"CIPVAL_TEST_MARK={uuid.uuid4().hex}"
    env = {**os.environ, mark.split("=")[0]: mark.split("=")[1]}
    cmd = [sys.executable, "-m", "validation.cli.main", "engines", "--engines", "mujoco",
           "--engine-cmd", shlex.join([sys.executable, str(example)]), "--profile", "quick",
           "--no-figures", "--jobs", "2", "--out", str(tmp_path)]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, text=True)
    lines = []
    for line in proc.stderr:  # wait until both engines' checks have started
        lines.append(line)
        if sum("checks" in x for x in lines) == 2:
            break
    time.sleep(0.5)
    assert len(_marked(mark)) >= 3  # the command, the forkserver, MuJoCo's process, ...
    proc.send_signal(getattr(signal, sig))
    err = proc.stderr.read()
    assert proc.wait(timeout=30) == {"SIGINT": 130, "SIGTERM": 143}[sig], err
    assert re.search(rf"interrupted by {sig}: kept [01] of 2 engines", err), err
    doc = json.loads((tmp_path / "results.json").read_text())
    rows = {r["engine"]: r for r in doc["engines"]}
    assert doc["partial"] is True and rows["command"]["status"] == "interrupted"
    assert rows["mujoco"]["status"] in ("interrupted", "pass")
    assert all(r["throughput"]["realization_steps_per_s"] > 0 for r in doc["engines"])
    deadline = time.monotonic() + 10
    while _marked(mark) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _marked(mark) == []


def test_an_error_the_parent_cannot_rebuild_and_an_exit_become_engine_job_errors():
    """A job that raises an exception whose class does not pickle, or calls sys.exit, is an
    EngineJobError with its text, never a SystemExit here."""
    unpicklable = ("exec('class E(Exception):\\n def __init__(s, a, b): super().__init__(a)"
                   "\\nraise E(1, 2)')")  # fmt: skip
    leave = "__import__('sys').exit(0)"
    out = run_side_by_side([EngineJob(unpicklable), EngineJob(leave)], eval, 2,
                           kept=lambda e: True)  # fmt: skip
    assert isinstance(out[unpicklable][0], EngineJobError) and "E: 1" in str(out[unpicklable][0])
    assert isinstance(out[leave][0], EngineJobError) and "SystemExit" in str(out[leave][0])
    with pytest.raises(EngineJobError, match="SystemExit"):
        run_side_by_side([EngineJob(leave)], eval, 2)


def test_an_interrupt_keeps_the_answers_already_in(tmp_path):
    """A job here is interrupted after a job in a process finished: ``finished`` has the
    finished one's value before the interrupt ends the call."""
    got: dict = {}
    flag = str(tmp_path / "done")
    answer = f"open({flag!r}, 'w').close() or 42"  # its value is sent right after
    wait_then_stop = (f"[__import__('time').sleep(0.01) for _ in range(2000) if not "
                      f"__import__('os').path.exists({flag!r})], __import__('time').sleep(0.5),"
                      " (_ for _ in ()).throw(KeyboardInterrupt)")  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        run_side_by_side([EngineJob(answer), EngineJob(wait_then_stop, here=True)], eval, 2,
                         finished=lambda n, v, s: got.update({n: v}))  # fmt: skip
    assert got == {answer: 42}


def test_a_job_process_has_the_environment_of_its_start(monkeypatch):
    """A job's process sees this process's environment as it is when the job starts (not
    the forkserver's, started earlier), with JAX's preallocation of 75 % of a GPU off
    unless it is set."""
    run_side_by_side([EngineJob("1")], eval, 2)  # the forkserver runs from here on
    monkeypatch.setenv("CIPVAL_TEST_LATE", "late")
    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
    late, jax = ("__import__('os').environ.get('CIPVAL_TEST_LATE')",
                 "__import__('os').environ.get('XLA_PYTHON_CLIENT_PREALLOCATE')")  # fmt: skip
    out = run_side_by_side([EngineJob(late), EngineJob(jax)], eval, 2)
    assert (out[late][0], out[jax][0]) == ("late", "false")
    monkeypatch.setenv("XLA_PYTHON_CLIENT_PREALLOCATE", "true")
    assert run_side_by_side([EngineJob(jax)], eval, 2)[jax][0] == "true"
