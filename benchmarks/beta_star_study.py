"""Where the paper's beta* comes from: beta* against each numerical reading (issue 45).

beta* (lambda1 = target) of both reduced models, the paper's parameters, under one
factor changed at a time from today's setting (Benettin over the delay state, dt 1 ms,
one draw per step of variance 1/dt, semi-implicit Euler, a random tangent vector,
10 s transient, target 5e-4), every reading on common random numbers
(:mod:`reduced.beta_star`):

* pass 1 (``--realizations`` x ``--duration`` s, noise on a 0.1 ms base grid): the
  estimator, dt, the noise's hold, the scheme, the initial state, the target;
* pass 2 (``--long-realizations`` x ``--long-duration`` s, 1 ms grid): the duration
  (the estimate at 100, 300, 1000, 3000, 10000 s of the same runs).

Intervals: bootstrap over realisations (the same resamples for every reading, so a
difference's interval is paired).  Prints the table of d beta* per factor step, the
readings' distances from the paper in standard errors, and the run time.

    python benchmarks/beta_star_study.py                         # the full study
    python benchmarks/beta_star_study.py --realizations 4 --duration 200 \\
        --long-realizations 2 --long-duration 320 --json out.json # a smoke run
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
from cipcore.params import BalanceParams, ParameterError
from reduced.beta_star import (
    Discretisation,
    Records,
    RunPlan,
    bootstrap_indices,
    fit_beta_star,
    run_records,
    step_count,
)

PAPER = {"single": 20.306, "coupled": 21.032}
GRIDS = {"single": (19.6, 21.0), "coupled": (20.3, 21.7)}
TIMES = (100.0, 300.0, 1000.0, 3000.0, 10000.0)
D = Discretisation
#: pass 1's settings: today's first, then one factor changed each
SETTINGS = (
    D(1e-3),
    D(1e-4),
    D(5e-4),
    D(2e-3),
    D(5e-3),
    D(1e-2),
    D(1e-3, hold=1e-2),
    D(1e-3, hold=2e-2),
    D(1e-3, scheme="explicit"),
    D(1e-3, scheme="heun"),
    D(1e-3, init="unit-error"),
)
LONG_SETTINGS = (D(1e-3), D(1e-3, init="unit-error"))
#: (factor, label, setting index, norm, origin, target) of every reading in the table
ESTIMATORS = (
    ("delay-state", "transient"),
    ("state", "transient"),
    ("positions", "transient"),
    ("balancer-1", "transient"),
    ("state", "zero"),
)


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realizations", type=int, default=32, help="pass 1 realisations")
    p.add_argument("--duration", type=float, default=1000.0, help="pass 1 duration (s)")
    p.add_argument("--long-realizations", type=int, default=16, help="pass 2 realisations")
    p.add_argument("--long-duration", type=float, default=10000.0, help="pass 2 duration (s)")
    p.add_argument("--gains", type=int, default=8, help="gains per model grid (>= 4)")
    p.add_argument("--seed", type=int, default=1, help="noise seed (>= 0)")
    p.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples (>= 100)")
    p.add_argument("--threads", type=int, default=None, help="worker threads")
    p.add_argument("--json", type=Path, default=None, help="write every reading here")
    a = p.parse_args(argv)
    for name, lo in (
        ("realizations", 2),
        ("long_realizations", 2),
        ("gains", 4),
        ("bootstrap", 100),
        ("seed", 0),
    ):
        if getattr(a, name) < lo:
            p.error(f"--{name.replace('_', '-')} must be >= {lo}, got {getattr(a, name)}")
    for name in ("duration", "long_duration"):
        v = getattr(a, name)
        if not (np.isfinite(v) and v >= 20 and v % 20 == 0):
            p.error(f"--{name.replace('_', '-')} must be a multiple of 20 s >= 20, got {v:g}")
    return a


def checkpoints(duration: float) -> tuple[float, ...]:
    """The times (s) of :data:`TIMES` below ``duration``, and ``duration``."""
    return (*(t for t in TIMES if t < duration), duration)


def readings(
    model: str, recs: list[Records], plan: RunPlan, betas: np.ndarray, idx: np.ndarray
) -> list[dict]:
    """beta* of every (setting, estimator, checkpoint, target) of one pass."""
    out = []
    for rec in recs:
        for t in plan.checkpoints:
            n = step_count(rec, t)
            for norm, origin in ESTIMATORS:
                lam = rec.lambdas(norm, origin, n)
                for target in (5e-4, 5e-5):
                    point, boots = fit_beta_star(betas, lam, target, idx)
                    out.append(
                        {
                            "model": model,
                            "setting": rec.setting.label(),
                            "norm": norm,
                            "origin": origin,
                            "t": t,
                            "target": target,
                            "beta": point,
                            "boots": boots,
                        }
                    )
    return out


def run_pass(model: str, settings, plan: RunPlan, a: argparse.Namespace) -> list[dict]:
    betas = np.linspace(*GRIDS[model], a.gains)
    recs = run_records(model, BalanceParams(beta=20.0), betas, settings, plan, a.threads)
    idx = bootstrap_indices(plan.seed, plan.n_realizations, a.bootstrap)
    return readings(model, recs, plan, betas, idx)


def find(rows: list[dict], **key) -> dict | None:
    for r in rows:
        if all(r[k] == v for k, v in key.items()):
            return r
    return None


def diff(a: dict, b: dict) -> tuple[float, float, float, float]:
    """d beta* = a - b, its bootstrap SE and 95 % interval (paired resamples)."""
    d = a["boots"] - b["boots"]
    d = d[np.isfinite(d)]
    if a["beta"] != a["beta"] or b["beta"] != b["beta"] or d.size < 10:
        return float("nan"), float("nan"), float("nan"), float("nan")
    lo, hi = np.percentile(d, [2.5, 97.5])
    return a["beta"] - b["beta"], float(d.std(ddof=1)), float(lo), float(hi)


def se(r: dict) -> float:
    b = r["boots"][np.isfinite(r["boots"])]
    return float(b.std(ddof=1)) if b.size > 10 else float("nan")


def factor_steps(rows: list[dict], long_t: float, short_t: float) -> list[tuple]:
    """(factor, step, model, d beta*, SE, lo, hi) of one factor changed from today's."""
    base = {"setting": "dt 1 ms", "norm": "delay-state", "origin": "transient", "target": 5e-4}
    steps = []
    for s in SETTINGS[1:]:
        steps.append(("discretisation", s.label(), {"setting": s.label()}, 1, short_t))
    for norm, origin in ESTIMATORS[1:]:
        lab = f"{norm} norm" + (" from t = 0" if origin == "zero" else "")
        steps.append(("estimator", lab, {"norm": norm, "origin": origin}, 1, short_t))
    steps.append(
        (
            "estimator",
            "state norm from t = 0, unit-error start",
            {"norm": "state", "origin": "zero", "setting": "dt 1 ms, unit-error"},
            1,
            short_t,
        )
    )
    steps.append(("target", "5e-5 instead of 5e-4", {"target": 5e-5}, 1, short_t))
    for t in TIMES:
        if t != 1000.0:
            steps.append(("duration", f"t = {t:g} s (vs 1000 s)", {"t": t}, 2, 1000.0))
    steps.append(
        (
            "duration",
            f"unit-error, state from 0, t = {long_t:g} s (vs 1000 s)",
            {"t": long_t, "setting": "dt 1 ms, unit-error", "norm": "state", "origin": "zero"},
            2,
            1000.0,
        )
    )
    out = []
    for factor, label, change, pas, ref_t in steps:
        for model in PAPER:
            rs = [r for r in rows if r["model"] == model and r["pass"] == pas]
            t_new = change.get("t", ref_t)
            a = find(rs, **{**base, "t": t_new, **change})
            b = find(rs, **base, t=ref_t)
            if a is None or b is None:
                continue
            out.append((factor, label, model, *diff(a, b)))
    return out


def _z(r: dict, paper: float) -> float:
    """(beta* - paper) / SE; NaN without an SE."""
    s = se(r)
    return (r["beta"] - paper) / s if s > 0 else float("nan")


def closest(rows: list[dict]) -> list[tuple]:
    """Readings ranked by their larger distance from the paper, in standard errors."""
    keyed: dict = {}
    for r in rows:
        k = (r["pass"], r["setting"], r["norm"], r["origin"], r["t"], r["target"])
        keyed.setdefault(k, {})[r["model"]] = r
    ranked = []
    for k, pair in keyed.items():
        if len(pair) < 2:
            continue
        z = {m: _z(pair[m], PAPER[m]) for m in PAPER}
        if all(np.isfinite(v) for v in z.values()):
            ranked.append((max(abs(v) for v in z.values()), k, pair, z))
    ranked.sort(key=lambda x: x[0])
    return ranked


def report(rows: list[dict], a: argparse.Namespace, seconds: float) -> str:
    lines = []
    for pas, t in ((1, a.duration), (2, a.long_duration)):
        for m in PAPER:
            r = find(
                rows,
                model=m,
                **{"pass": pas},
                setting="dt 1 ms",
                norm="delay-state",
                origin="transient",
                t=t,
                target=5e-4,
            )
            lines.append(
                f"today's setting, pass {pas}, {m}, t = {t:g} s: beta* "
                f"{r['beta']:.3f} +- {se(r):.3f} (paper {PAPER[m]})"
            )
    lines.append("")
    ref_t = min(1000.0, a.duration)
    lines.append(
        f"| factor | step (from dt 1 ms, Benettin, {ref_t:g} s, 5e-4) | model | d beta* | SE "
        "| 95 % CI |"
    )
    lines.append("|---|---|---|---|---|---|")
    for f, lab, m, d, s, lo, hi in factor_steps(rows, a.long_duration, ref_t):
        lines.append(f"| {f} | {lab} | {m} | {d:+.3f} | {s:.3f} | [{lo:+.3f}, {hi:+.3f}] |")
    lines.append("")
    ranked = closest(rows)
    hits = [x for x in ranked if x[0] <= 1.0]
    lines.append(f"readings with both beta* within 1 SE of the paper: {len(hits)} of {len(ranked)}")
    for dist, k, pair, z in ranked[:8]:
        lines.append(
            f"  {dist:5.2f} SE  pass {k[0]}, {k[1]}, {k[2]} from {k[3]}, t {k[4]:g} s, "
            f"target {k[5]:g}: single {pair['single']['beta']:.3f} ({z['single']:+.1f} SE),"
            f" coupled {pair['coupled']['beta']:.3f} ({z['coupled']:+.1f} SE)"
        )
    load = os.getloadavg()
    lines.append(
        f"run time {seconds:.0f} s, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    t0 = time.perf_counter()
    rows = []
    try:
        plans = (
            (1, SETTINGS, RunPlan(checkpoints(a.duration), a.realizations, a.seed, 1e-4)),
            (
                2,
                LONG_SETTINGS,
                RunPlan(checkpoints(a.long_duration), a.long_realizations, a.seed, 1e-3),
            ),
        )
        for pas, settings, plan in plans:
            for model in PAPER:
                for r in run_pass(model, settings, plan, a):
                    rows.append({**r, "pass": pas})
                print(f"pass {pas} {model}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    except ParameterError as exc:
        print(f"beta_star_study: error: {exc}", file=sys.stderr)
        return 2
    text = report(rows, a, time.perf_counter() - t0)
    print(text)
    if a.json:
        doc = [{**{k: v for k, v in r.items() if k != "boots"}, "se": se(r)} for r in rows]
        write_text(
            a.json, json.dumps({"args": vars(a) | {"json": str(a.json)}, "readings": doc}, indent=1)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
