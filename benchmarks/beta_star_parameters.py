"""How precisely do the paper's printed parameters fix beta*? (issue 45, the offset's cause)

The numerical setting does not explain the offset of cipval's beta* above the paper's
(+0.06 single, +0.04 coupled at 10,000 s: ``benchmarks/beta_star_study.py``).  The
paper prints its parameters to one or two significant digits (section 3: gamma = 50,
alpha = 22, nu = 0.6, tau = 0.1), and beta* is printed to five (20.306, 21.032,
Fig. 4's caption).  This script measures d beta* / d p for each printed parameter p
(alpha 1/s^2, gamma 1/s, nu s^1/2, tau s) by central differences of +-``--step`` times
half a unit in the printed parameter's last digit (0.2: +-0.1 in alpha), on common random
numbers (every parameter set reads the seed's draws; lambda1 at each of ``--gains``
gains over the model's range, :func:`reduced.lyapunov.lyapunov_gains`), and states:

* the change of each parameter alone that would move beta* by the offset, and that
  change as a fraction of the printed precision (half a unit in the last printed digit:
  alpha +-0.5, gamma +-0.5, nu +-0.05, tau +-0.05 s);
* the span of beta* over each parameter's printed-precision interval (linear in the
  derivative).

Intervals: a paired bootstrap over realisations (the same resamples for every
parameter set, :func:`reduced.beta_star.bootstrap_indices`).

    python benchmarks/beta_star_parameters.py                  # 16 x 1000 s, seed 1
    python benchmarks/beta_star_parameters.py --realizations 4 --duration 200  # smoke
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace

import numpy as np

from cipcore.params import BalanceParams
from cipcore.scenario import Execution, Scenario
from reduced.beta_star import bootstrap_indices, fit_beta_star
from reduced.lyapunov import lyapunov_gains

PAPER = {"single": 20.306, "coupled": 21.032}
#: cipval's beta* at 10,000 s (docs/paper.md, "Where beta* comes from"): the offset
OURS_LONG = {"single": 20.367, "coupled": 21.071}
GRIDS = {"single": (19.6, 21.0), "coupled": (20.3, 21.7)}
#: the printed parameters (paper section 3) and half a unit of their last printed digit
PRINTED = {"alpha": (22.0, 0.5), "gamma": (50.0, 0.5), "nu": (0.6, 0.05), "tau": (0.1, 0.05)}
UNITS = {"alpha": "1/s^2", "gamma": "1/s", "nu": "s^1/2", "tau": "s"}


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realizations", type=int, default=16)
    p.add_argument("--duration", type=float, default=1000.0, help="s")
    p.add_argument("--gains", type=int, default=8)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--step",
        type=float,
        default=0.2,
        help="central-difference step as a fraction of the printed half unit",
    )
    p.add_argument("--boot", type=int, default=2000)
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--json", default=None, help="write the results here")
    return p.parse_args(argv)


def lambdas(model: str, params: BalanceParams, betas: np.ndarray, a) -> np.ndarray:
    """lambda1 (G, R) per gain and realisation under the seed's draws."""
    scen = Scenario(model, params, a.duration, a.realizations, a.seed)
    res = lyapunov_gains(scen, [replace(params, beta=float(b)) for b in betas],
                         execution=Execution(threads=a.threads))  # fmt: skip
    return np.array([r.per_realization for r in res])


def sensitivity(model: str, base: BalanceParams, betas: np.ndarray, name: str, h: float, a,
                idx: np.ndarray) -> tuple[float, tuple[float, float]]:  # fmt: skip
    """d beta* / d ``name`` by central differences +-``h`` about ``base`` on the seed's
    draws, and its paired bootstrap 95 % interval over the resamples ``idx``."""
    ends = []
    for sign in (+1, -1):
        p = replace(base, **{name: getattr(base, name) + sign * h})
        ends.append(fit_beta_star(betas, lambdas(model, p, betas, a), 5e-4, idx))
    (bp, bootp), (bm, bootm) = ends
    lo, hi = np.nanpercentile((bootp - bootm) / (2 * h), [2.5, 97.5])
    return (bp - bm) / (2 * h), (float(lo), float(hi))


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    t0 = time.perf_counter()
    idx = bootstrap_indices(a.seed, a.realizations, a.boot)
    base = BalanceParams(beta=20.0)
    out: dict = {"setting": vars(a) | {"load": os.getloadavg()}, "models": {}}
    for model in PAPER:
        betas = np.linspace(*GRIDS[model], a.gains)
        b0, boot0 = fit_beta_star(betas, lambdas(model, base, betas, a), 5e-4, idx)
        offset = OURS_LONG[model] - PAPER[model]
        rows = {}
        for name, (value, half) in PRINTED.items():
            deriv, (lo, hi) = sensitivity(model, base, betas, name, a.step * half, a, idx)
            rows[name] = {
                "printed": value, "half_unit": half, "unit": UNITS[name],
                "d_beta_star": deriv, "ci95": [float(lo), float(hi)],
                "change_for_offset": -offset / deriv if deriv else float("inf"),
                "fraction_of_half_unit": abs(offset / deriv) / half if deriv else float("inf"),
                "span_over_printed_precision": abs(deriv) * half,
            }  # fmt: skip
        lo0, hi0 = np.nanpercentile(boot0, [2.5, 97.5])
        out["models"][model] = {"beta_star": b0, "ci95": [float(lo0), float(hi0)],
                                "offset_at_10000_s": offset, "parameters": rows}  # fmt: skip
        print(f"\n{model}: beta* {b0:.4f} [{lo0:.4f}, {hi0:.4f}] at {a.realizations} x "
              f"{a.duration:g} s, seed {a.seed}; offset to explain {offset:+.3f}")  # fmt: skip
        print(f"{'parameter':<10} {'d beta*/dp':>12} {'95 % CI':>22} {'change for offset':>18} "
              f"{'of half unit':>12} {'beta* span':>11}")  # fmt: skip
        for name, r in rows.items():
            print(
                f"{name:<10} {r['d_beta_star']:>12.4g} "
                f"[{r['ci95'][0]:>9.4g}, {r['ci95'][1]:>9.4g}] "
                f"{r['change_for_offset']:>+15.3g} {r['unit']:<2} "
                f"{r['fraction_of_half_unit']:>10.2f} {r['span_over_printed_precision']:>+11.3f}"
            )
    wall = time.perf_counter() - t0
    out["wall_s"] = wall
    print(f"\n{wall:.0f} s, load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
