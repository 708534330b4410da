"""Wall and CPU time of ``cip-validate run`` at the quick and smoke profiles, per stage.

Each profile runs once as a fresh process (``python -m validation.cli.main run
--profile P --seed S --out TMP --quiet``, figures included unless
``--no-figures``); the script prints the whole process's wall time, its CPU
time (user + system of it and its children), the run's own elapsed time, and
per stage the wall time and CPU time the run records (``timings_s``,
``cpu_s`` of ``results.json``), with the load average before and after each
run, and the host's speed (:mod:`hostspeed`: us per MuJoCo step) before each
run and after the last.  On a shared machine the wall times follow the load and
the host's speed; the CPU times follow the speed only, so compare those, and only
between runs whose host speeds agree.

Other options go to ``cip-validate run`` as they are (e.g. ``--baseline
validation/data/baseline_quick.json``: its regression line is printed too).

Usage:  python benchmarks/bench_run.py [--profiles quick,smoke] [--seed 2011]
        [--no-figures] [--json times.json] [RUN OPTIONS]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import hostspeed


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def time_run(profile: str, seed: int, figures: bool, extra: list[str]) -> dict:
    """One ``cip-validate run`` in a fresh process: wall, CPU, per-stage times, load."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "validation.cli.main", "run", "--profile", profile,
               "--seed", str(seed), "--out", tmp, "--quiet", *extra]  # fmt: skip
        if not figures:
            cmd.append("--no-figures")
        load_before = hostspeed.load()
        c0, t0 = _children_cpu(), time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        res_path = Path(tmp) / "results.json"
        res = json.loads(res_path.read_text()) if res_path.is_file() else {}
    return {
        "profile": profile, "seed": seed, "figures": figures, "exit": proc.returncode,
        "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "elapsed_s": res.get("elapsed_s"),
        "stages_wall_s": res.get("timings_s", {}), "stages_cpu_s": res.get("cpu_s", {}),
        "counts": res.get("counts"), "load_before": load_before, "load_after": hostspeed.load(),
        "stderr_tail": proc.stderr.strip().splitlines()[-3:] if proc.returncode else [],
        "regression": [ln for ln in proc.stdout.splitlines() if ln.startswith("regression vs")],
    }  # fmt: skip


def report(r: dict) -> None:
    fig = "figures" if r["figures"] else "no figures"
    print(f"\n{r['profile']} (seed {r['seed']}, {fig}): exit {r['exit']}, "
          f"wall {r['wall_s']:.1f} s (run's own {r['elapsed_s']} s), CPU {r['cpu_s']:.1f} s; "
          f"checks {r['counts']}")  # fmt: skip
    print(f"  load average before: {r['load_before']}; after: {r['load_after']}")
    print(f"  {'stage':28s} {'wall s':>8s} {'CPU s':>8s}")
    for name, w in r["stages_wall_s"].items():
        c = r["stages_cpu_s"].get(name)
        print(f"  {name:28s} {w:8.2f} {'' if c is None else f'{c:8.2f}'}")
    for line in r["regression"]:
        print(f"  {line}")
    for line in r["stderr_tail"]:
        print(f"  stderr: {line}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profiles", default="quick,smoke", help="comma-separated profiles")
    ap.add_argument("--seed", type=int, default=2011)
    ap.add_argument("--no-figures", action="store_true", help="time the runs without figures")
    ap.add_argument("--json", help="also write the measurements to this JSON file")
    a, extra = ap.parse_known_args()
    print(f"cores: {os.cpu_count()}; python {sys.version.split()[0]}")
    out = []
    for profile in a.profiles.split(","):
        host = hostspeed.line()
        print(f"\n{host}")
        r = time_run(profile, a.seed, not a.no_figures, extra)
        r["host_before"] = host
        report(r)
        out.append(r)
    host = hostspeed.line()
    print(f"\n{host}")
    out[-1]["host_after"] = host
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
