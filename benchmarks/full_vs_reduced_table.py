"""Full (MuJoCo) vs reduced model under the same noise: relative L2 table.

Paper parameters, beta = 20.306, 10 s, 4 realisations, seed 1; the relative L2
distance of the balancing errors for initial amplitudes x mass ratios m/M,
with the largest |theta| reached.  At small amplitude the distance is
proportional to m/M (the cart reaction); at fixed m/M it grows with the
amplitude (the pendulum's nonlinearity).
Usage:  python benchmarks/full_vs_reduced_table.py
"""

from __future__ import annotations

import numpy as np

from cip.model import CIPParams
from cip.runner import RigidBody
from cip.simulate import simulate_full
from cipcore.scenario import Scenario
from reduced import BalanceParams, simulate

MASS_RATIOS = (1e-3, 1e-4, 1e-5)


def main() -> None:
    p = BalanceParams(beta=20.306)
    print("| model | amplitude (m) | " + " | ".join(f"m/M {m:g}" for m in MASS_RATIOS)
          + " | largest theta (rad) |")  # fmt: skip
    print("|---" * (3 + len(MASS_RATIOS)) + "|")
    for model in ("single", "coupled"):
        for amp in (1e-6, 1e-3, 1e-2, 3e-2):
            red = simulate(Scenario(model, p, 10.0, 4, 1, amplitude=amp))["balancing_error"]
            row = []
            for mr in MASS_RATIOS:
                full = simulate_full(
                    Scenario(model, p, 10.0, 4, 1, amplitude=amp),
                    body=RigidBody(physical=CIPParams.from_reduced(p, mass_ratio=mr)),
                )
                row.append(np.linalg.norm(full["balancing_error"] - red) / np.linalg.norm(red))
            angle = max(full.attrs["max_abs_angle"])
            print(f"| {model} | {amp:g} | " + " | ".join(f"{v:.2e}" for v in row)
                  + f" | {angle:.2g} |")  # fmt: skip


if __name__ == "__main__":
    main()
