"""The paper table and the robustness table without the MuJoCo stages, at a chosen size.

    python benchmarks/paper_claims.py --profile paper --realizations 32 --duration 600 \\
        --rms-realizations 100 --workers 2 --out paper-claims

Runs the reduced-model stages of ``cip-validate run`` (RMS and velocity, STCC
and spectra, robustness grid, nonlinear stick) with the profile's seeds and
estimator grid, overriding only the run sizes; prints the tables and writes
``report.md`` and ``results.json`` to ``--out``.  The critical gains
(lambda1 = 5e-4) are left to ``cip-validate run``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from cipcore.atomic import write_text
from validation.paper import claims as paper
from validation.profiles import PROFILES
from validation.report.document import jsonable, paper_section


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", choices=tuple(PROFILES), default="paper")
    ap.add_argument("--realizations", type=int, help="STCC / spectra / velocity realisations")
    ap.add_argument("--duration", type=float, help="their duration (s)")
    ap.add_argument("--rms-realizations", type=int)
    ap.add_argument("--rms-duration", type=float)
    ap.add_argument("--nonlinear-realizations", type=int)
    ap.add_argument("--nonlinear-duration", type=float)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="paper-claims")
    a = ap.parse_args()
    over = {k: v for k, v in {
        "peak_realizations": a.realizations, "peak_duration": a.duration,
        "rms_realizations": a.rms_realizations, "rms_duration": a.rms_duration,
        "nonlinear_realizations": a.nonlinear_realizations,
        "nonlinear_duration": a.nonlinear_duration}.items() if v is not None}  # fmt: skip
    profile = dataclasses.replace(PROFILES[a.profile], **over)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    timings = {}
    rows, _ = paper.rms_and_velocity(profile, a.workers)
    timings["rms_and_velocity"] = time.perf_counter() - t0
    rows2, _ = paper.peaks_and_spectra(profile, a.workers)
    timings["peaks_and_spectra"] = time.perf_counter() - t0
    robust = paper.robustness(profile, a.workers)
    timings["robustness"] = time.perf_counter() - t0
    nonlinear = paper.nonlinear_comparison(profile, a.workers)
    timings["nonlinear"] = time.perf_counter() - t0
    results = {"profile": profile.name, "overrides": over, "seed": profile.seed,
               "paper": rows + rows2, "robustness": robust, "nonlinear": nonlinear,
               "timings_s": timings}  # fmt: skip
    md = "\n".join([f"# Paper claims, profile {profile.name} (seed {profile.seed}), "
                    f"overrides {json.dumps(over)}", *paper_section(results), ""])  # fmt: skip
    write_text(out / "report.md", md)
    write_text(out / "results.json", json.dumps(jsonable(results), indent=1))
    print(md)
    print({k: round(v, 1) for k, v in timings.items()})


if __name__ == "__main__":
    main()
