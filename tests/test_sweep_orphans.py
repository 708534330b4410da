"""A ``kill -9`` of a running sweep leaves no process of it behind (local pool and Dask)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")


def session_processes(sid: int) -> dict[int, int]:
    """{pid: ppid} of every live (not zombie) process in session ``sid``."""
    out = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2 :].split()  # after "pid (comm) "
        state, ppid, session = fields[0], int(fields[1]), int(fields[3])
        if session == sid and state != "Z":
            out[int(stat.parent.name)] = ppid
    return out


def kill_and_count(cmd: list[str], ready, tmp_path: Path) -> tuple[int, dict]:
    """Start ``cmd`` in a new session, wait until ``ready(procs)``, kill -9 its leader,
    and return (processes when killed, processes left once none is, or 5 s later)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    log = open(tmp_path / "log.txt", "w")
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=log, stderr=log, env=env)
    try:
        deadline = time.monotonic() + 240
        while not ready(session_processes(proc.pid)):
            assert proc.poll() is None, (tmp_path / "log.txt").read_text()[-2000:]
            assert time.monotonic() < deadline, "the run never started its workers"
            time.sleep(0.2)
        before = len(session_processes(proc.pid))
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        gone_by = time.monotonic() + 5.0  # orphans poll for their parent every second
        while session_processes(proc.pid) and time.monotonic() < gone_by:
            time.sleep(0.1)
        return before, session_processes(proc.pid)
    finally:
        for pid in session_processes(proc.pid):
            os.kill(pid, signal.SIGKILL)
        log.close()


def test_kill_9_of_a_local_sweep_leaves_no_process(tmp_path):
    cmd = [sys.executable, "-m", "validation.cli.main", "sweep", "--engine", "reduced", "--grid",
           "beta=20,21,22,23,24,25,26,27", "--metrics", "rms", "--duration", "400",
           "--realizations", "4", "--workers", "2", "--out", str(tmp_path / "sw")]  # fmt: skip

    def workers_up(procs: dict[int, int]) -> bool:
        # leader, forkserver (child of the leader) and two workers (children of it)
        forkservers = [p for p, pp in procs.items() if pp in procs and procs[pp] not in procs]
        return sum(pp in forkservers for pp in procs.values()) >= 2

    before, left = kill_and_count(cmd, workers_up, tmp_path)
    assert before >= 4
    assert left == {}, f"{len(left)} process(es) of the killed sweep still running: {left}"


DASK_SCRIPT = """
import time
from dask.distributed import LocalCluster
if __name__ == "__main__":
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None):
        print("up", flush=True)
        time.sleep(600)
"""


@pytest.mark.slow
def test_kill_9_of_a_dask_local_cluster_leaves_no_process(tmp_path):
    pytest.importorskip("dask.distributed")
    script = tmp_path / "cluster.py"
    script.write_text(DASK_SCRIPT)
    _, left = kill_and_count([sys.executable, str(script)], lambda procs: len(procs) >= 3, tmp_path)
    assert left == {}, f"{len(left)} process(es) of the killed cluster still running: {left}"
