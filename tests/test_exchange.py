"""Engines in other programs: the chunk protocol end to end with the shipped example engine."""

from __future__ import annotations

import json
import shlex
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from helpers import running

from cipcore.scenario import EngineTarget
from validation.cli.main import main

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "chunk_engine.py"
CMD = shlex.join([sys.executable, str(EXAMPLE)])


def test_example_engine_is_bit_identical_to_mujoco_in_process():
    from cip.engines.process import process_engine
    from cipcore.params import BalanceParams
    from cipcore.registry import get_engine

    p = BalanceParams(beta=21.032)
    ext = process_engine(CMD).simulate("coupled", p, 0.5, 2, seed=3, amplitude=1e-3)
    own = get_engine("mujoco").simulate("coupled", p, 0.5, 2, seed=3, amplitude=1e-3)
    for field in ("balancing_error", "base_velocity", "angle"):
        assert np.array_equal(ext[field], own[field])


def test_an_engine_serving_many_sessions_is_started_once_and_ended_with_cipval():
    """The example answers "sessions": "many": two runs in a row use one process, each
    bit-identical to in-process MuJoCo; `--one-session` is started per run and kept by
    nobody; closing the kept engines ends them (no process left behind)."""
    import os

    from cip.engines.process import close_idle_engines, idle_engines, process_engine
    from cipcore.params import BalanceParams
    from cipcore.registry import get_engine

    p = BalanceParams(beta=21.032)
    for command, kept in ((CMD, 1), (f"{CMD} --one-session", 0)):
        close_idle_engines()
        ext, pids = process_engine(command), []
        for model in ("single", "coupled"):
            got = ext.simulate(model, p, 0.3, 2, seed=5, amplitude=1e-3)
            own = get_engine("mujoco").simulate(model, p, 0.3, 2, seed=5, amplitude=1e-3)
            assert np.array_equal(got["balancing_error"], own["balancing_error"]), command
            pids.append(idle_engines(command))
        assert len(pids[0]) == kept and pids[0] == pids[1], (command, pids)
    assert idle_engines(CMD) == []  # ended by close_idle_engines before the second command
    ext = process_engine(CMD)
    ext.simulate("single", p, 0.2, 1, seed=1)
    (pid,) = idle_engines(CMD)
    close_idle_engines()
    assert idle_engines(CMD) == []
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # reaped: it exited when its stdin closed


def test_a_session_cut_mid_frame_is_not_kept_and_a_dead_kept_engine_is_replaced():
    import os
    import signal

    import mujoco

    from cip.engines.process import close_idle_engines, idle_engines, process_engine
    from cip.model import mjcf
    from cipcore.params import BalanceParams

    close_idle_engines()
    backend = process_engine(CMD).backend()
    m = mujoco.MjModel.from_xml_string(mjcf("single"))
    ns = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state, ctrl = np.zeros((1, ns)), np.zeros((1, 5, m.nu))
    out = np.empty((1, 5, ns))
    r = backend(m, 1, 1)
    r(state, ctrl, out)  # a whole frame

    def cut(*args, **kwargs):
        raise KeyboardInterrupt

    import cip.engines.process as process

    with pytest.MonkeyPatch.context() as mp, pytest.raises(KeyboardInterrupt):
        mp.setattr(process, "_read", cut)  # interrupted between request and answer
        r(state, ctrl, out)
    proc = r.proc
    r.close()
    assert idle_engines(CMD) == [] and proc.poll() is not None
    # a kept engine that died meanwhile is replaced by a new one
    ext = process_engine(CMD)
    ext.simulate("single", BalanceParams(beta=21.032), 0.2, 1, seed=1)
    (pid,) = idle_engines(CMD)
    os.kill(pid, signal.SIGKILL)
    ext.simulate("single", BalanceParams(beta=21.032), 0.2, 1, seed=1)
    assert len(idle_engines(CMD)) == 1 and idle_engines(CMD) != [pid]
    close_idle_engines()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_kept_engines_end_when_cipval_is_killed():
    """A kept engine waits on its stdin: SIGKILL of cipval closes it and the engine exits
    (no orphan), whether it was idle or in a session."""
    import os
    import signal
    import subprocess
    import time

    code = (
        "import sys, time\n"
        "from cip.engines.process import idle_engines, process_engine\n"
        "from cipcore.params import BalanceParams\n"
        f"cmd = {CMD!r}\n"
        "process_engine(cmd).simulate('single', BalanceParams(beta=21.032), 0.2, 1, seed=1)\n"
        "print(*idle_engines(cmd), flush=True)\n"
        "time.sleep(60)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env=env)  # fmt: skip
    try:
        (pid,) = map(int, parent.stdout.readline().split())
        assert running(pid)  # the kept engine waits for the next session
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if not running(pid):
                break
            time.sleep(0.05)
        else:
            os.kill(pid, signal.SIGKILL)
            pytest.fail(f"engine {pid} outlived its killed parent by 10 s")
    finally:
        parent.kill()
        parent.wait()


def test_contract_passes_for_the_example_and_fails_with_a_one_step_delay_error(tmp_path, capsys):
    junit = tmp_path / "c.xml"
    assert main(["contract", "--engine-cmd", CMD, "--junit", str(junit)]) == 0
    out = capsys.readouterr().out
    assert "engine command passes the contract" in out
    assert ET.parse(junit).getroot().get("failures") == "0"
    assert main(["contract", "--engine-cmd", f"{CMD} --delay-error", "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    status = {r["check"]: r["status"] for r in doc["checks"]}
    assert status["delay"] == "fail" and status["reduced_trajectory.single"] == "pass"


def test_an_engine_that_dies_is_a_crash_not_a_failure(capsys):
    dead = shlex.join([sys.executable, "-c", "import sys; sys.exit(3)"])
    assert main(["contract", "--engine-cmd", dead, "--json"]) == 4
    doc = json.loads(capsys.readouterr().out)
    assert {r["status"] for r in doc["checks"]} == {"error"}
    assert "exited with status 3" in doc["checks"][0]["message"]


def test_engines_command_validates_an_engine_cmd_beside_the_reference(tmp_path, capsys):
    """The fast version of the test below: the command and the reference only."""
    junit = tmp_path / "e.xml"
    code = main(["engines", "--engine-cmd", CMD, "--engines", "reduced", "--profile", "smoke",
                 "--json", "--no-figures", "--out", str(tmp_path),
                 "--junit", str(junit)])  # fmt: skip
    doc = json.loads(capsys.readouterr().out)
    rows = {r["engine"]: r for r in doc["engines"]}
    assert set(rows) == {"reduced", "command"}
    assert code == 0 and rows["command"]["status"] == "pass"
    assert 0 < rows["command"]["trajectory_distance"]["coupled"] < 1e-2
    suites = {s.get("name") for s in ET.parse(junit).getroot().iter("testsuite")}
    assert suites == {"engines.reduced", "engines.command"}


@pytest.mark.slow
def test_engines_command_validates_an_engine_cmd(tmp_path, capsys):
    junit = tmp_path / "e.xml"
    code = main(["engines", "--engine-cmd", CMD, "--profile", "smoke", "--json",
                 "--no-figures", "--out", str(tmp_path), "--junit", str(junit)])  # fmt: skip
    doc = json.loads(capsys.readouterr().out)
    rows = {r["engine"]: r for r in doc["engines"]}
    assert set(rows) == {"reduced", "mujoco", "command"}
    assert code == 0 and rows["command"]["status"] == "pass"
    assert rows["command"]["trajectory_distance"] == rows["mujoco"]["trajectory_distance"]
    suites = {s.get("name") for s in ET.parse(junit).getroot().iter("testsuite")}
    assert suites == {"engines.reduced", "engines.mujoco", "engines.command"}


def test_run_checks_pass_for_the_example_and_fail_with_a_one_step_delay_error():
    """`run --engine-cmd` validates the program through the run's direct checks (its exact
    twin, the delay measured from its response, the rod): the example passes them, the
    same program one step late fails the twin and measures 101 steps."""
    import argparse

    from validation.checks.agreement import instrument_checks
    from validation.cli.engine_options import check_engine_options

    for command, good in ((CMD, True), (f"{CMD} --delay-error", False)):
        a = argparse.Namespace(engine=None, engine_cmd=command, integrator=None)
        check_engine_options(a)
        checks = {c.name: c for c in instrument_checks(1, 2, target=EngineTarget(a.engine))}
        for name in ("twin.trajectory.single", "delay.single", "twin.trajectory.coupled"):
            assert (checks[name].status == "pass") is good, (command, checks[name])
        if not good:
            assert checks["delay.single"].values["measured_steps"] == 101


def test_run_refuses_engine_and_engine_cmd_together_and_a_resume(capsys, tmp_path):
    out = str(tmp_path / "o")
    assert main(["run", "--engine", "mujoco", "--engine-cmd", CMD, "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--engine-cmd" in err[0]
    assert main(["run", "--engine-cmd", CMD, "--resume", "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--resume" in err[0]
