"""The run's ``paper.beta_star`` checks over seeds: offsets, spreads and false failures.

For each profile (``--profiles``) and seed (``--seeds``), the run's beta* stage alone
(:func:`validation.paper.claims.critical_gains`, the profile with its seed replaced)
gives beta* single, coupled and their shift, each check's verdict and tolerance.
Printed per profile and check: the mean over seeds of the estimate minus the paper's value and
its distance from the paper's value in standard errors of that mean, the per-run
standard deviation beside the mean bootstrap SE, the failures (the model is correct:
every failure is a false one), the largest |deviation| / tolerance, and the per-run
false-failure rate the 20-seed mean and spread imply (normal approximation).

    python benchmarks/beta_star_seeds.py --profiles quick --seeds 1-20
    python benchmarks/beta_star_seeds.py --profiles smoke,quick,paper --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.stats import norm
from seed_robustness import seeds_arg  # '1-20' or '1,5,7'

from cipcore.atomic import write_text
from validation.paper.claims import critical_gains
from validation.profiles import PROFILES


def one_seed(profile: str, seed: int, threads: int | None) -> dict[str, dict]:
    """Every beta* check of one run of the stage: its values and verdict."""
    checks, _, _ = critical_gains(replace(PROFILES[profile], seed=seed), threads)
    return {c.name.rsplit(".", 1)[1]: {**c.values, "status": c.status} for c in checks}


def summary(rows: list[dict[str, dict]]) -> dict[str, dict]:
    """Per check: the mean offset, its SE, the spread, failures and the implied rate."""
    out = {}
    names = list(dict.fromkeys(("single", "coupled", "shift", *(k for r in rows for k in r))))
    for name in names:
        every = [r[name] for r in rows if name in r]
        if not every:
            continue
        # a run whose fit did not cross the target has no value: a failure, no number
        v = [x for x in every if "value" in x]
        uncrossed = len(every) - len(v)
        corrected = np.array([x["value"] for x in v])
        paper = every[0]["paper"]
        dev = corrected - paper
        sd = float(dev.std(ddof=1))
        mean = float(dev.mean())
        tol = np.array([x["tolerance"] for x in v])
        # implied per-run rate: P(|N(mean, sd)| > median tolerance)
        t = float(np.median(tol))
        rate = float(norm.sf((t - mean) / sd) + norm.cdf((-t - mean) / sd)) if sd > 0 else 0.0
        out[name] = {
            "paper": paper, "offset": mean, "se_of_mean": sd / np.sqrt(len(v)),
            "offset_in_se": mean / (sd / np.sqrt(len(v))), "sd_per_run": sd,
            "mean_bootstrap_se": float(np.mean([x["se"] for x in v])),
            "fails": sum(x["status"] != "pass" for x in every), "runs": len(every),
            "uncrossed": uncrossed,
            "worst_fraction": float(np.max(np.abs(dev) / tol)), "implied_rate": rate,
        }  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--profiles", default="quick", help="comma list of profiles")
    p.add_argument("--seeds", type=seeds_arg, default=list(range(1, 21)), help="'1-20' or '1,5'")
    p.add_argument("--threads", type=int, default=None, help="worker threads")
    p.add_argument("--json", type=Path, default=None, help="write every number here")
    a = p.parse_args(argv)
    out = {}
    for profile in a.profiles.split(","):
        t0 = time.perf_counter()
        rows = [one_seed(profile, s, a.threads) for s in a.seeds]
        took = time.perf_counter() - t0
        load = os.getloadavg()
        out[profile] = {"summary": summary(rows), "runs": rows, "seconds": took}
        pr = PROFILES[profile]
        print(f"\n{profile}: {pr.beta_star_realizations} x {pr.beta_star_duration:g} s, "
              f"{pr.beta_star_gains} gains, seeds {a.seeds[0]}-{a.seeds[-1]}: {took:.0f} s "
              f"(load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f})")  # fmt: skip
        for name, s in out[profile]["summary"].items():
            print(f"  {name:8s} paper {s['paper']:.3f}: offset {s['offset']:+.4f} +- "
                  f"{s['se_of_mean']:.4f} ({s['offset_in_se']:+.1f} SE), per-run SD "
                  f"{s['sd_per_run']:.4f} (mean bootstrap SE {s['mean_bootstrap_se']:.4f}), "
                  f"fails {s['fails']}/{s['runs']} ({s['uncrossed']} without a crossing), "
                  f"worst {s['worst_fraction']:.2f} of the "
                  f"tolerance, implied rate {s['implied_rate']:.1e}")  # fmt: skip
    if a.json is not None:
        write_text(a.json, json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
