"""False failures of the unmodified model over seeds: every check's count.

Runs ``cip-validate run`` (no figures) on the shipped model files at the
smoke and the quick profile for seeds 1 to 20 each (by default; ``--profile`` and
``--seeds`` choose), and prints, per check, how many seeds failed it (and how many
were inconclusive).  A correct model should fail no check at any seed: every count
above zero is a check whose tolerance a correct model can miss.  On 2 cores a smoke
seed takes about 4 s and a quick seed about 23 s (10 minutes in all).

    python benchmarks/seed_robustness.py                       # smoke x 20, quick x 20
    python benchmarks/seed_robustness.py --profile quick --seeds 1-40 --json out.json
    python benchmarks/seed_robustness.py --profile smoke --engine bullet   # another engine
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

from cipcore.params import ParameterError
from cipcore.registry import engine_names
from cipcore.scenario import EngineTarget
from validation.checks.agreement import rigid_engine
from validation.profiles import PROFILES
from validation.run import RunSetting, run_validation

DEFAULT = {"smoke": 20, "quick": 20}


def seeds_arg(text: str) -> list[int]:
    """'1-20' or '1,5,7'."""
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def run_seeds(profile: str, seeds: list[int], workers: int | None, engine: str = "mujoco") -> dict:
    fails: Counter = Counter()
    inconclusive: Counter = Counter()
    names: set[str] = set()
    per_seed = {}
    for seed in seeds:
        t = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            setting = RunSetting(replace(PROFILES[profile], seed=seed), EngineTarget(engine),
                                 workers=workers, figures=False, progress=False)  # fmt: skip
            res = run_validation(setting, Path(tmp))
        bad = [c["name"] for c in res["checks"] if c["status"] == "fail"]
        inc = [c["name"] for c in res["checks"] if c["status"] == "inconclusive"]
        names.update(c["name"] for c in res["checks"])
        fails.update(bad)
        inconclusive.update(inc)
        per_seed[seed] = {
            "failed": bad,
            "inconclusive": inc,
            "seconds": round(time.perf_counter() - t, 1),
        }
        print(
            f"{engine} {profile} seed {seed}: {len(bad)} failed {bad}, {len(inc)} inconclusive, "
            f"{per_seed[seed]['seconds']} s",
            file=sys.stderr,
            flush=True,
        )
    return {
        "engine": engine,
        "profile": profile,
        "seeds": seeds,
        "checks": sorted(names),
        "failures": dict(fails),
        "inconclusive": dict(inconclusive),
        "per_seed": per_seed,
    }


def table(r: dict) -> str:
    n = len(r["seeds"])
    out = [
        f"{r['engine']}, {r['profile']} profile, "
        f"seeds {r['seeds'][0]}..{r['seeds'][-1]} ({n} runs):",
        f"  {'check':<52} {'failed':>7} {'inconcl.':>9}",
    ]
    for name in r["checks"]:
        out.append(
            f"  {name:<52} {r['failures'].get(name, 0):>4}/{n:<2} "
            f"{r['inconclusive'].get(name, 0):>6}/{n:<2}"
        )
    runs_failed = sum(bool(s["failed"]) for s in r["per_seed"].values())
    out.append(f"  runs with any failed check: {runs_failed} of {n}")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", choices=tuple(DEFAULT), action="append")
    ap.add_argument("--seeds", type=seeds_arg, help="e.g. 1-20 (default: 1..20)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument(
        "--engine",
        default="mujoco",
        choices=engine_names(),
        help="the engine validated (default: mujoco)",
    )
    ap.add_argument("--json", metavar="FILE", help="also write the counts as JSON")
    a = ap.parse_args()
    try:  # as `cip-validate run --engine`: installed, and a rigid-body engine
        rigid_engine(a.engine)
    except ParameterError as exc:
        ap.error(f"--engine: {exc}")
    results = []
    for profile in a.profile or list(DEFAULT):
        seeds = a.seeds or list(range(1, DEFAULT[profile] + 1))
        r = run_seeds(profile, seeds, a.workers, a.engine)
        print(table(r), flush=True)
        results.append(r)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
