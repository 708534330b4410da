"""The exact twin's floor: full MuJoCo model vs its linear twin under the same noise.

    python benchmarks/twin_floor.py [--seed 1] [--realizations 4] [--duration 10]

Prints, per model and initial amplitude, the relative L2 distance of the
balancing errors (full vs twin, and full vs the paper's reduced model) and the
largest angle.  Below ~1e-7 m (coupled) the rod's absolute round-off sets the
floor; above it the angles' second-order terms (growing as amplitude^2).
"""

from __future__ import annotations

import argparse

import numpy as np

from cip.mjcf_params import load_model_file, read_mapping, shipped_model_path
from cip.simulate import simulate_full
from reduced import BalanceParams, simulate
from reduced.twin import TwinParams, simulate_twin
from validation.profiles import PAPER_BETA


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--realizations", type=int, default=4)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--amplitudes", default="1e-8,1e-7,1e-6,1e-5,1e-4")
    a = ap.parse_args()
    print(
        f"{'model':<8} {'amplitude':>9} {'full-twin':>10} {'full-reduced':>12} {'max|theta|':>10}"
    )
    for model, beta in PAPER_BETA.items():
        m = load_model_file(shipped_model_path(model))
        mp = read_mapping(m)
        p = BalanceParams(beta=beta)
        tw = TwinParams(**mp.twin_terms())
        for amp in (float(x) for x in a.amplitudes.split(",")):
            kw = {"amplitude": amp, "fields": ("balancing_error",)}
            args = (a.duration, a.realizations, a.seed)
            full = simulate_full(model, p, *args, physical=mp.physical(), mj_model=m,
                                 fields=("balancing_error", "angle"), amplitude=amp)  # fmt: skip
            et = simulate_twin(model, p, tw, *args, **kw)["balancing_error"]
            er = simulate(model, p, *args, **kw)["balancing_error"]
            ef = full["balancing_error"]
            print(f"{model:<8} {amp:>9.0e} {np.linalg.norm(ef - et) / np.linalg.norm(et):>10.2e} "
                  f"{np.linalg.norm(ef - er) / np.linalg.norm(er):>12.2e} "
                  f"{np.max(full.attrs['max_abs_angle']):>10.2e}")  # fmt: skip


if __name__ == "__main__":
    main()
