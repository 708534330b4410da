"""Rigid-body engines vs the reduced model under the same noise, by mass ratio m/M.

Paper parameters, beta = 20.306, 10 s, 4 realisations, seed 1, initial
balancing error 1e-6 m (the linear regime): the relative L2 distance of the
balancing errors ||e_engine - e_reduced|| / ||e_reduced|| for each engine and
m/M, and each engine's distance to the baseline engine (MuJoCo on the CPU).
At small amplitude the distance to the reduced model is the cart reaction,
proportional to m/M; what remains as m/M -> 0 is each engine's own scheme
(integrator, rod constraint).
Usage:  python benchmarks/engine_distance_table.py [--engines mujoco,drake] [--amplitude 1e-6]
        [--mass-ratios 1e-3,1e-5,1e-7]
"""

from __future__ import annotations

import argparse

from cip.model import CIPParams
from cipcore.params import BalanceParams
from cipcore.registry import REFERENCE, availability, get_engine
from validation.checks.metrics import relative_l2

MASS_RATIOS = "1e-3,1e-5,1e-7"
BASELINE = "mujoco"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--engines", default="mujoco,drake")
    ap.add_argument("--amplitude", type=float, default=1e-6)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--realizations", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--mass-ratios", default=MASS_RATIOS, help="comma-separated m/M")
    a = ap.parse_args()
    names = [BASELINE] + [n for n in a.engines.split(",") if n and n != BASELINE]
    p = BalanceParams(beta=20.306)
    run = dict(amplitude=a.amplitude, seed=a.seed)
    print(f"amplitude {a.amplitude:g} m, {a.duration:g} s, {a.realizations} realisations, "
          f"seed {a.seed}")  # fmt: skip
    print(f"| model | m/M | engine | distance to {REFERENCE} | distance to {BASELINE} |")
    print("|---|---|---|---|---|")
    for model in ("single", "coupled"):
        ref = get_engine(REFERENCE).simulate(model, p, a.duration, a.realizations, **run)
        for mr in (float(v) for v in a.mass_ratios.split(",")):
            phys = CIPParams.from_reduced(p, mass_ratio=mr)
            base = None
            for name in names:
                why = availability(name)
                if why is not None:
                    print(f"| {model} | {mr:g} | {name} | skipped: {why} | |")
                    continue
                e = get_engine(name).simulate(
                    model, p, a.duration, a.realizations, physical=phys, **run
                )["balancing_error"]
                base = e if base is None else base
                print(f"| {model} | {mr:g} | {name} | {relative_l2(e, ref['balancing_error']):.4e}"
                      f" | {relative_l2(e, base):.3e} |")  # fmt: skip


if __name__ == "__main__":
    main()
