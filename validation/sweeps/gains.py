"""Target gains: beta per grid point set to beta*, the gain of a target lambda1 (equal stability).

The paper compares the single and coupled balancers at equal stability, at
the gains where the largest Lyapunov exponent of the reduced model is
lambda1 = 5e-4 1/s (section 3.1, Figs. 3, 4): beta* = 20.306 (single) and 21.032
(coupled) 1/s^2 at tau = 0.1 s.  beta* moves with the delay and the other
reduced-model parameters, so a study with a ``[gain]`` table sets beta per
point to beta*(model, tau, alpha, gamma, nu, dt), computed with
:func:`reduced.lyapunov.critical_gain` on the reduced model (whatever the
study's engine: the reduced model is the reference that defines the paper's
operating point), with its bootstrap 95 % interval recorded beside it.

Every beta* is cached in ``DIR/gains/<hash>.json``, keyed by the model, the
reduced parameters, the ``[gain]`` settings, the seed and the package
versions, so a resumed or repeated sweep never recomputes one.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from cipcore.models import get_model
from cipcore.params import ParameterError
from cipcore.scenario import Execution, Scenario
from validation.profiles import PAPER_BETA
from validation.regression.versions import package_versions
from validation.sweeps.mapping import point_params
from validation.sweeps.store import atomic_write
from validation.sweeps.study import Study, point_key


def gain_seed(study: Study) -> int:
    """The seed of every beta* of a study (its own stream, beside the points' seeds)."""
    import numpy as np

    return int(np.random.SeedSequence(study.seed, spawn_key=(0x6A1,)).generate_state(1)[0])


def gain_key(study: Study, point: dict[str, Any]) -> dict[str, Any]:
    """What beta* of one point depends on: model, reduced parameters but beta, settings, seed."""
    params, _, _ = point_params(study, point, beta=1.0)
    red = {k: v for k, v in params.as_dict().items() if k != "beta"}
    return {"model": study.model_of(point), "params": red, "gain": study.gain,
            "seed": gain_seed(study)}  # fmt: skip


def point_gains(study: Study, out_dir: str | Path, threads: int = 1) -> dict[str, dict]:
    """{point key: {"beta_star", "beta_star_ci_low", "beta_star_ci_high"}} (1/s^2) for every
    point of a study with a ``[gain]`` target ({} without one).

    Raises :class:`ParameterError` (one line) when lambda1 does not cross the
    target within the searched gains.
    """
    from reduced.lyapunov import critical_gain

    if not study.gain:
        return {}
    g = study.gain
    cache = Path(out_dir) / "gains"
    cache.mkdir(parents=True, exist_ok=True)
    versions = package_versions()
    out: dict[str, dict] = {}
    for point in study.points():
        key = gain_key(study, point)
        h = hashlib.sha256(json.dumps({**key, "versions": versions}, sort_keys=True)
                           .encode()).hexdigest()[:20]  # fmt: skip
        path = cache / f"{h}.json"
        rec = None
        if path.exists():
            try:
                rec = json.loads(path.read_text())
            except ValueError:
                rec = None
        if rec is None or rec.get("key") != key:
            params, _, _ = point_params(study, point, beta=1.0)
            centre = PAPER_BETA[get_model(key["model"]).name]
            lo, hi = centre - g["half_width"], centre + g["half_width"]
            try:
                scenario = Scenario(key["model"], params, g["duration"], g["realizations"],
                                    key["seed"])  # fmt: skip
                res = critical_gain(
                    scenario, (max(lo, 0.0), hi), target=g["target_lambda1"],
                    n_gains=g["gains"], execution=Execution(threads=threads),
                )  # fmt: skip
            except ParameterError as exc:
                raise ParameterError(f"gain: point {point_key(point)}: {exc}") from None
            rec = {"key": key, "beta_star": res.beta_star, "ci95": list(res.ci95),
                   "betas": res.betas.tolist(), "lambdas": res.lambdas.tolist()}  # fmt: skip
            atomic_write(path, json.dumps(rec))
        out[point_key(point)] = {"beta_star": rec["beta_star"],
                                 "beta_star_ci_low": rec["ci95"][0],
                                 "beta_star_ci_high": rec["ci95"][1]}  # fmt: skip
    return out
