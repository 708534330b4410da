"""Start-up time of ``cip-validate``: ``--version``, ``--help`` and an argument error.

Each command is run ``--repeat`` times as a fresh process; the script prints the
median and the fastest wall time of each beside ``python -c pass`` (the
interpreter's own start-up) measured in the same run, and the load average before
and after (start-up times on a shared machine mean little without it).  With
``--importtime`` it also prints the ten slowest imports of ``--version`` from
``python -X importtime`` (cumulative microseconds), which is where a regression shows.

Usage:  python benchmarks/startup.py [--repeat 7] [--importtime]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

CASES: tuple[tuple[str, list[str]], ...] = (
    ("python -c pass", [sys.executable, "-c", "pass"]),
    ("cip-validate --version", [sys.executable, "-m", "validation.cli.main", "--version"]),
    ("cip-validate --help", [sys.executable, "-m", "validation.cli.main", "--help"]),
    ("cip-validate run --help", [sys.executable, "-m", "validation.cli.main", "run", "--help"]),
    (
        "cip-validate simulate --beta -1 (usage error)",
        [sys.executable, "-m", "validation.cli.main", "simulate", "--beta", "-1"],
    ),
)


def wall_times(cmd: list[str], repeat: int) -> list[float]:
    """Wall time (s) of ``repeat`` fresh runs of ``cmd``, output discarded."""
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        out.append(time.perf_counter() - t0)
    return out


def slowest_imports(cmd: list[str], n: int = 10) -> list[tuple[int, str]]:
    """The ``n`` imports with the largest cumulative time (us) under ``-X importtime``."""
    proc = subprocess.run(
        [cmd[0], "-X", "importtime", *cmd[1:]], capture_output=True, text=True, check=False
    )
    rows = []
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _self, cumulative, name = line[len("import time:") :].split("|", 2)
        rows.append((int(cumulative), name.strip()))
    return sorted(rows, reverse=True)[:n]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7, help="fresh processes per command")
    ap.add_argument("--importtime", action="store_true", help="also list the slowest imports")
    a = ap.parse_args()
    load_before = os.getloadavg()
    print(f"load average before: {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}")
    print(f"{'command':48s} {'median s':>9s} {'min s':>7s}")
    for label, cmd in CASES:
        t = wall_times(cmd, a.repeat)
        print(f"{label:48s} {statistics.median(t):9.3f} {min(t):7.3f}")
    load_after = os.getloadavg()
    print(f"load average after:  {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}")
    if a.importtime:
        print("slowest imports of --version (cumulative us):")
        for us, name in slowest_imports(CASES[1][1]):
            print(f"  {us:9d}  {name}")


if __name__ == "__main__":
    main()
