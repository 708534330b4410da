"""Wall and CPU time of the README's test command, ``pytest``, with the load average.

Runs ``python -m pytest -q -p no:cacheprovider [PYTEST OPTIONS]`` in a fresh
process (by default the plain command: pyproject's options, i.e. the default
markers and one pytest-xdist worker per core and one more) and prints its summary
line, the wall time, the CPU time (user + system of pytest, its workers and every child
process they waited for) and the load average before and after.  On a shared
machine the wall time follows the load; the CPU time much less, so compare
that between runs made under different loads, and only between runs whose host
speeds (:mod:`hostspeed`, printed before and after) agree.

Usage:  python benchmarks/bench_tests.py [--json times.json] [PYTEST OPTIONS]
        e.g. ``-n 0`` (serial), ``-m slow``, ``--durations 20``
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import hostspeed


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def time_pytest(extra: list[str]) -> dict:
    """One pytest run in a fresh process: exit status, summary, wall, CPU, load."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *extra]
    root = Path(__file__).resolve().parent.parent
    load_before = hostspeed.load()
    c0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run(cmd, cwd=root, capture_output=True, text=True, check=False)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    lines = proc.stdout.strip().splitlines()
    return {
        "command": " ".join(["pytest", *extra]), "exit": proc.returncode,
        "summary": lines[-1].strip("= ") if lines else "", "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1), "cores": os.cpu_count(), "load_before": load_before,
        "load_after": hostspeed.load(), "output_tail": lines[-40:] if proc.returncode else [],
    }  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="also write the numbers to this file")
    a, extra = ap.parse_known_args()
    host_before = hostspeed.line()
    r = time_pytest(extra)
    r["host_before"], r["host_after"] = host_before, hostspeed.line()
    print(f"{r['command']}: {r['summary']}")
    print(f"  wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s (user + sys), "
          f"{r['cores']} cores, load average {r['load_before']} -> {r['load_after']}")  # fmt: skip
    print(f"  before: {r['host_before']}\n  after:  {r['host_after']}")
    for line in r["output_tail"]:
        print("  | " + line)
    if a.json:
        a.json.write_text(json.dumps(r, indent=1) + "\n")
    return r["exit"]


if __name__ == "__main__":
    sys.exit(main())
