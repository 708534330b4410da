"""Trajectory floors of the rigid-body engines: distance to the reduced model and to MuJoCo.

For each engine and model, the relative L2 distance of the balancing errors
(:func:`validation.checks.metrics.relative_l2`) over the first 1, 2, 5 and 10 s of one
run (amplitude 1e-6 m, paper gains, ``--realizations`` realisations per seed),
to the reduced model (eq. (3) with the delayed random-gain force of eq. (5)) and
to MuJoCo CPU under the same noise draws, at the default m/M = 1e-3 and at
m/M = 1e-7, where the cart reaction vanishes and what remains is the engine's
own time discretisation.  With ``--late`` the engine runs with every control one
step late (the fault ``delay_late`` of :mod:`validation.faults.catalogue`), the distance the
trajectory check must tell from the floor.

    python benchmarks/engine_floor.py --engines bullet,exudyn,simbody --seeds 0,1
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from cip.model import CIPParams
from cip.runner import RigidBody
from cip.simulate import simulate_full
from cipcore.params import BalanceParams
from cipcore.registry import get_engine
from cipcore.scenario import Execution, Scenario
from validation.checks.metrics import relative_l2
from validation.faults.catalogue import make_fault
from validation.profiles import PAPER_BETA

WINDOWS = (1.0, 2.0, 5.0, 10.0)


def late_backend(base: type) -> type:
    """``base`` with every control one step late (the ``delay_late`` fault's control edit)."""
    edit = make_fault("delay_late", 1).edit_ctrl

    class Late(base):
        def __init__(self, model, n_realizations, threads):
            super().__init__(model, n_realizations, threads)
            self._m, self._memory = model, {}

        def __call__(self, state, ctrl, out):
            super().__call__(state, np.ascontiguousarray(edit(self._m, ctrl, self._memory)), out)

    return Late


def run(name: str, model: str, seed: int, n: int, mass_ratio: float, late: bool) -> np.ndarray:
    p = BalanceParams(beta=PAPER_BETA[model])
    phys = CIPParams.from_reduced(p, mass_ratio=mass_ratio)
    if name == "reduced":
        return get_engine("reduced").simulate(model, p, max(WINDOWS), n, seed, amplitude=1e-6)[
            "balancing_error"
        ]
    backend = get_engine(name).backend()
    if late:
        backend = late_backend(backend)
    tr = simulate_full(
        Scenario(model, p, max(WINDOWS), n, seed, amplitude=1e-6),
        body=RigidBody(physical=phys, backend=backend, name=name),
        execution=Execution(threads=1),
    )
    return tr["balancing_error"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", default="mujoco,bullet,exudyn,simbody")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--realizations", type=int, default=4)
    ap.add_argument("--mass-ratios", default="1e-3,1e-7")
    ap.add_argument("--late", action="store_true")
    a = ap.parse_args()
    rows = []
    for seed in [int(s) for s in a.seeds.split(",")]:
        for model in ("single", "coupled"):
            ref = run("reduced", model, seed, a.realizations, 1e-3, False)
            for mr in [float(x) for x in a.mass_ratios.split(",")]:
                mj = run("mujoco", model, seed, a.realizations, mr, False)
                for name in a.engines.split(","):
                    e = run(name, model, seed, a.realizations, mr, a.late)
                    for w in WINDOWS:
                        k = round(w / 1e-3)
                        rows.append({
                            "engine": name, "model": model, "seed": seed, "mass_ratio": mr,
                            "late": a.late, "window_s": w,
                            "to_reduced": relative_l2(e[:, :k], ref[:, :k]),
                            "to_mujoco": relative_l2(e[:, :k], mj[:, :k]),
                        })  # fmt: skip
                        print(json.dumps(rows[-1]), flush=True)


if __name__ == "__main__":
    main()
