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

``--against COMMIT`` times that commit of this repository side by side: a temporary
``git worktree`` of it runs on the same interpreter and packages (its tree first on
``PYTHONPATH``), alternated with the current tree ``--rounds`` times per profile
(reference first) after one uncounted warm-up run of each (a fresh worktree compiles
numba's cached kernels on its first run: ef8af27's smoke took 12.8 s then, 5.9 s
after), and a last line per profile gives the median wall time of each and
their ratio, current / reference (the issue's targets are ratios measured so: one run,
one machine).

Usage:  python benchmarks/bench_run.py [--profiles quick,smoke] [--seed 2011]
        [--no-figures] [--json times.json] [--against COMMIT --rounds 2] [RUN OPTIONS]
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

#: this repository's root: the tree timed by default, and where ``--against`` adds a worktree
REPO = Path(__file__).resolve().parent.parent


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _entry(root: Path) -> tuple[str, str]:
    """The console script ``cip-validate`` of the tree at ``root`` as its ``pyproject.toml``
    declares it: (module, function).  It moved from ``validation.cli:main`` to
    ``validation.cli.main:entry``, which ends the process without the module teardown
    (:mod:`cipcore.quickexit`); both are timed as a user's ``cip-validate`` runs them."""
    import tomllib

    spec = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    module, function = spec["cip-validate"].split(":")
    return module, function


def time_run(profile: str, seed: int, figures: bool, extra: list[str],
             root: Path | None = None) -> dict:  # fmt: skip
    """One ``cip-validate run`` in a fresh process: wall, CPU, per-stage times, load.

    ``root``: another tree of this repository to run instead (:func:`reference_tree`)."""
    tree = root or REPO
    with tempfile.TemporaryDirectory() as tmp:
        module, function = _entry(tree)
        main = f"import sys; from {module} import {function}; sys.exit({function}())"
        cmd = [sys.executable, "-c", main, "run", "--profile", profile,
               "--seed", str(seed), "--out", tmp, "--quiet", *extra]  # fmt: skip
        if not figures:
            cmd.append("--no-figures")
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}  # fmt: skip
        load_before = hostspeed.load()
        c0, t0 = _children_cpu(), time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=tree,
                              env=env)  # fmt: skip
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


def reference_tree(commit: str, where: Path) -> Path:
    """A detached ``git worktree`` of ``commit`` at ``where`` (removed by the caller with
    ``git worktree remove``); a one-line error naming the commit when git refuses."""
    proc = subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q",
                           str(where), commit], capture_output=True, text=True)  # fmt: skip
    if proc.returncode:
        sys.exit(f"bench_run.py: --against {commit}: {proc.stderr.strip().splitlines()[-1]}")
    return where


def side_by_side(a: argparse.Namespace, extra: list[str]) -> list[dict]:
    """``a.rounds`` alternations of the reference commit and the current tree per profile,
    each run reported; the last line per profile: median walls and their ratio."""
    import statistics

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        ref = reference_tree(a.against, Path(tmp) / "ref")
        try:
            for profile in a.profiles.split(","):
                walls: dict[str, list[float]] = {"reference": [], "current": []}
                for root in (ref, None):  # a fresh worktree compiles numba's kernels first
                    w = time_run(profile, a.seed, not a.no_figures, extra, root)["wall_s"]
                    print(f"\n[warm-up, not counted: {a.against if root else 'this tree'}] "
                          f"{profile} {w:.1f} s")  # fmt: skip
                for _ in range(a.rounds):
                    for label, root in (("reference", ref), ("current", None)):
                        print(f"\n[{label}: {a.against if root else 'this tree'}] "
                              f"{hostspeed.line()}")  # fmt: skip
                        r = time_run(profile, a.seed, not a.no_figures, extra, root)
                        r["tree"] = label
                        report(r)
                        walls[label].append(r["wall_s"])
                        out.append(r)
                mr, mc = (statistics.median(walls[k]) for k in ("reference", "current"))
                print(f"\n{profile}: median wall {mc:.2f} s (this tree) / {mr:.2f} s "
                      f"({a.against}) = {mc / mr:.3f}")  # fmt: skip
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(ref)],
                           capture_output=True)  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profiles", default="quick,smoke", help="comma-separated profiles")
    ap.add_argument("--seed", type=int, default=2011)
    ap.add_argument("--no-figures", action="store_true", help="time the runs without figures")
    ap.add_argument("--json", help="also write the measurements to this JSON file")
    ap.add_argument("--against", help="a commit to time side by side with this tree")
    ap.add_argument("--rounds", type=int, default=2, help="--against: alternations per profile")
    a, extra = ap.parse_known_args()
    print(f"cores: {os.cpu_count()}; python {sys.version.split()[0]}")
    if a.against:
        if a.rounds < 1:
            ap.error(f"--rounds must be >= 1, got {a.rounds}")
        out = side_by_side(a, extra)
        if a.json:
            Path(a.json).write_text(json.dumps(out, indent=1))
        return
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
