"""The finite-duration bias of the run's beta* estimator, measured and pinned (issue 45).

The run's ``paper.beta_star`` checks estimate beta* (lambda1 = 5e-4 1/s, paper Fig. 4
caption) from ``n`` realisations x ``T`` s at a few gains over the run's ranges
(:data:`validation.paper.claims.BETA_RANGE`; smoke 8 x 400 s at 4 gains, quick
16 x 1000 s at 5, paper 32 x 2000 s at 7), with lambda1 from Benettin's sum over the
delay state after a 10 s transient (:func:`reduced.lyapunov.critical_gain`).  This
script measures that estimator's bias against its own long-duration limit, on common
random numbers (:mod:`reduced.beta_star`: one run read at every checkpoint, the
estimate at t equal to a run of duration t):

1. **The bias, as the checks see it.** ``--realizations`` R (a multiple of every
   profile's n) realisations are split into R / n disjoint groups of n; each group's
   beta* (the profile's gains and fit) at each checkpoint T; the mean over groups is
   the expected estimate of a run of that profile at T.  Its distance from the limit
   b_inf is the bias; b_inf and c come from a fit b(T) = b_inf + c / (T - t0) of the
   all-realisation beta* at every checkpoint (t0 the transient), every interval from
   one bootstrap over realisations (the same resamples for every number).
2. **The cause.** The Benettin sum S(t) (the log growth of the tangent vector since
   the transient) of a stationary tangent direction grows as lambda1 t; a direction
   not yet settled at the transient adds a constant K, so (1/t) S is lambda1 + K / t
   and beta* is shifted by -K / (t dlambda1/dbeta).  K is measured as the intercept of
   a line fitted to the mean S(t) over the checkpoints, at each gain; the predicted
   c = -K / (dlambda1/dbeta) is printed beside the fitted c.  A second run with a
   ``--long-transient`` (the direction settled before the sum starts) measures K
   again: if K is the unsettled direction, it vanishes there.

    python benchmarks/beta_star_duration.py --threads 2 --json beta_star_duration.json
    python benchmarks/beta_star_duration.py --realizations 32 --duration 400 \\
        --checkpoints 100,200,400 --bootstrap 100                 # a smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from cipcore.atomic import write_text
from cipcore.params import BalanceParams
from reduced.beta_star import (
    Discretisation,
    RunPlan,
    bootstrap_indices,
    fit_beta_star,
    run_records,
    step_count,
)
from validation.paper.claims import BETA_RANGE
from validation.profiles import PAPER_BETA, PROFILES

TARGET = 5e-4
#: the profiles whose beta* check this measures: (realisations, duration, gains)
SIZES = {
    name: (PROFILES[name].beta_star_realizations, PROFILES[name].beta_star_duration,
           PROFILES[name].beta_star_gains)
    for name in ("smoke", "quick", "paper")
}  # fmt: skip


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", default="single,coupled", help="comma list")
    p.add_argument("--nu", type=float, default=0.6135,
                   help="noise strength (s^1/2); 0.6135 reproduces the paper's beta* "
                   "(docs/paper.md), the printed one is 0.6")  # fmt: skip
    p.add_argument("--realizations", type=int, default=256,
                   help="realisations, a multiple of every profile's n (8, 16, 32)")  # fmt: skip
    p.add_argument("--duration", type=float, default=4000.0, help="longest checkpoint (s)")
    p.add_argument("--checkpoints", default="100,200,400,700,1000,1500,2000,3000",
                   help="comma list of times (s) below --duration, multiples of 0.1 s")  # fmt: skip
    p.add_argument("--long-transient", type=float, default=200.0,
                   help="transient (s) of the second run (0: no second run)")  # fmt: skip
    p.add_argument("--seed", type=int, default=7, help="noise seed (>= 0)")
    p.add_argument("--bootstrap", type=int, default=1000, help="bootstrap resamples")
    p.add_argument("--threads", type=int, default=None, help="worker threads")
    p.add_argument("--json", type=Path, default=None, help="write every number here")
    a = p.parse_args(argv)
    a.models = [m.strip() for m in a.models.split(",")]
    if any(m not in BETA_RANGE for m in a.models):
        p.error(f"--models must name models from {', '.join(BETA_RANGE)}, got {a.models}")
    ns = sorted({n for n, _, _ in SIZES.values()})
    if a.realizations < max(ns) or any(a.realizations % n for n in ns):
        p.error(f"--realizations must be a multiple of {', '.join(map(str, ns))}, "
                f"got {a.realizations}")  # fmt: skip
    pts = sorted({float(t) for t in a.checkpoints.split(",")} | {a.duration})
    if not all(np.isfinite(t) and 20.0 <= t <= a.duration for t in pts):
        p.error(f"--checkpoints must lie in [20, --duration] s, got {a.checkpoints}")
    a.points = tuple(pts)
    return a


def gain_grid(model: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Every gain of the profiles' grids over the model's range, and each profile's
    indices into it."""
    lo, hi = BETA_RANGE[model]
    grids = {name: np.linspace(lo, hi, g) for name, (_, _, g) in SIZES.items()}
    betas = np.unique(np.round(np.concatenate(list(grids.values())), 12))
    where = {name: np.searchsorted(betas, np.round(g, 12)) for name, g in grids.items()}
    return betas, where


def fit_limit(times: np.ndarray, values: np.ndarray, t0: float) -> np.ndarray:
    """(b_inf, c) of the least-squares line b = b_inf + c / (t - t0); ``values`` (T,) or
    (T, B): one fit per column."""
    x = np.stack([np.ones_like(times), 1.0 / (times - t0)], axis=1)
    sol, *_ = np.linalg.lstsq(x, values, rcond=None)
    return sol


def benettin_offset(times: np.ndarray, lam: np.ndarray, t0: float, t_min: float) -> np.ndarray:
    """K (log units) per gain: the intercept of the line through the mean Benettin sum
    S(t) = (t - t0) lambda1(t) over the checkpoints t >= ``t_min``; ``lam`` (T, G, B)
    means over (resampled) realisations."""
    keep = times >= t_min
    s = lam[keep] * (times[keep] - t0)[:, None, None]
    x = np.stack([np.ones(keep.sum()), times[keep] - t0], axis=1)
    sol, *_ = np.linalg.lstsq(x, s.reshape(keep.sum(), -1), rcond=None)
    return sol[0].reshape(lam.shape[1:])


def interval(boots: np.ndarray) -> list[float]:
    b = boots[np.isfinite(boots)]
    return [float(np.percentile(b, 2.5)), float(np.percentile(b, 97.5))]


def measure(model: str, a: argparse.Namespace, transient: float) -> dict:
    """Every number of one model at one transient (module docstring)."""
    betas, where = gain_grid(model)
    base = BalanceParams(beta=PAPER_BETA[model], nu=a.nu)
    points = tuple(t for t in a.points if t >= transient + 50.0)  # a sum of 50 s at least
    plan = RunPlan(points, n_realizations=a.realizations, seed=a.seed, transient=transient)
    rec = run_records(model, base, betas, [Discretisation(1e-3)], plan, threads=a.threads)[0]
    times = np.array(points)
    lam = np.stack([rec.lambdas("delay-state", "transient", step_count(rec, t)) for t in times])
    idx = bootstrap_indices(a.seed, a.realizations, a.bootstrap)  # (B, R)
    lam_means = lam[:, :, idx].mean(axis=3)  # (T, G, B)
    # all realisations: beta*(T) at the finest grid, its limit and c
    full = [fit_beta_star(betas, lam[k], TARGET, idx) for k in range(times.size)]
    point = np.array([f[0] for f in full])
    boots = np.stack([f[1] for f in full])  # (T, B)
    b_inf, c = fit_limit(times, point, transient)
    ok = np.isfinite(boots).all(axis=0)
    b_inf_b, c_b = fit_limit(times, boots[:, ok], transient)
    # the cause: K per gain, dlambda/dbeta at b_inf from the longest checkpoint's fit
    k_point = benettin_offset(times, lam.mean(axis=2)[:, :, None], transient, 0.0)[:, 0]
    k_boot = benettin_offset(times, lam_means, transient, 0.0)  # (G, B)
    coef = np.polyfit(betas, lam[-1].mean(axis=1), 2)
    slope = float(np.polyval(np.polyder(coef), b_inf))
    near = int(np.argmin(np.abs(betas - b_inf)))
    out = {
        "model": model, "transient": transient, "betas": betas.tolist(),
        "times": times.tolist(), "beta_star": point.tolist(),
        "beta_star_ci": [interval(b) for b in boots],
        "b_inf": float(b_inf), "b_inf_ci": interval(b_inf_b),
        "c": float(c), "c_ci": interval(c_b),
        "K": k_point.tolist(), "K_ci": [interval(k) for k in k_boot],
        "dlambda_dbeta": slope, "gain_near": float(betas[near]),
        "c_predicted": float(-k_point[near] / slope),
        "c_predicted_ci": interval(-k_boot[near] / slope),
        "profiles": {},
    }  # fmt: skip
    # the checks' own estimator: disjoint groups of the profile's n, its gains
    for name, (n, duration, _) in SIZES.items():
        if not (times == duration).any():
            continue
        k = int(np.flatnonzero(times == duration)[0])
        g = where[name]
        groups = np.arange(a.realizations).reshape(-1, n)
        one = np.zeros((1, n), dtype=int)  # fit_beta_star's resamples: none needed here
        ests = np.array([fit_beta_star(betas[g], lam[k][g][:, grp], TARGET, one)[0]
                         for grp in groups])  # fmt: skip
        ests = ests[np.isfinite(ests)]
        mean, se = float(ests.mean()), float(ests.std(ddof=1) / np.sqrt(ests.size))
        out["profiles"][name] = {
            "n": n, "duration": duration, "gains": int(g.size), "groups": int(ests.size),
            "mean": mean, "se_of_mean": se, "sd_per_run": float(ests.std(ddof=1)),
            "bias": mean - float(b_inf), "bias_predicted": float(c / (duration - transient)),
        }  # fmt: skip
    return out


def report(r: dict) -> None:
    print(f"\n{r['model']}, transient {r['transient']:g} s: b_inf {r['b_inf']:.4f} "
          f"[{r['b_inf_ci'][0]:.4f}, {r['b_inf_ci'][1]:.4f}], c {r['c']:.2f} s "
          f"[{r['c_ci'][0]:.2f}, {r['c_ci'][1]:.2f}]; predicted from K at beta "
          f"{r['gain_near']:.3f}: {r['c_predicted']:.2f} s [{r['c_predicted_ci'][0]:.2f}, "
          f"{r['c_predicted_ci'][1]:.2f}] (dlambda1/dbeta {r['dlambda_dbeta']:.4g} s)")  # fmt: skip
    print("  T (s)   beta*(T) [95 % CI]            b_inf + c/(T - t0)")
    for t, b, ci in zip(r["times"], r["beta_star"], r["beta_star_ci"], strict=True):
        model = r["b_inf"] + r["c"] / (t - r["transient"])
        print(f"  {t:6.0f}  {b:.4f} [{ci[0]:.4f}, {ci[1]:.4f}]  {model:.4f}")
    print("  K per gain: " + ", ".join(
        f"{b:.3f}: {k:+.3f} [{lo:+.3f}, {hi:+.3f}]"
        for b, k, (lo, hi) in zip(r["betas"], r["K"], r["K_ci"], strict=True)))  # fmt: skip
    for name, p in r["profiles"].items():
        print(f"  {name} ({p['n']} x {p['duration']:g} s, {p['gains']} gains, {p['groups']} "
              f"runs): mean {p['mean']:.4f} +- {p['se_of_mean']:.4f}, per-run SD "
              f"{p['sd_per_run']:.4f}, bias {p['bias']:+.4f} (c/(T - t0): "
              f"{p['bias_predicted']:+.4f})")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    t0 = time.perf_counter()
    results = []
    transients = [10.0] + ([a.long_transient] if a.long_transient > 0 else [])
    for model in a.models:
        for tr in transients:
            r = measure(model, a, tr)
            report(r)
            results.append(r)
    took = time.perf_counter() - t0
    load = os.getloadavg()
    print(f"\n{a.realizations} realisations x {a.duration:g} s, seed {a.seed}, nu {a.nu:g}: "
          f"{took:.0f} s (load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f})")  # fmt: skip
    if a.json is not None:
        write_text(a.json, json.dumps({"settings": {k: v for k, v in vars(a).items()
                                                    if k != "json"},
                                       "results": results, "seconds": took}, indent=1,
                                      default=str))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
