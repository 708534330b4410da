"""``cip-validate run``: every check, the paper table, figures and the report.

Stages (each seeded from the profile's seed, so a rerun gives the same numbers
whatever the number of workers):

1. lambda1 of the MuJoCo and the reduced model at a few gains (agreement);
2. time series of both engines at the paper's gains under the same noise,
   small amplitude: RMS, spectra, STCC peaks, velocity spread (agreement);
3. an amplitude scan: where the agreement breaks down;
4. paper reproduction with the reduced model: beta*, RMS, velocity density
   ratio, STCC at t = 36, tau_hat densities, spectral slopes, laminar phases;
5. figures redoing the paper's (from both models where it makes sense).
"""

from __future__ import annotations

import platform
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from . import agreement, paper, plots
from .profiles import Profile
from .stats import FAIL, INCONCLUSIVE, PASS


def package_versions() -> dict[str, str]:
    """Versions of Python, the numerical stack, MuJoCo and cipval itself."""
    from importlib.metadata import PackageNotFoundError, version

    import matplotlib
    import mujoco
    import numba
    import scipy

    try:
        cipval = version("cipval")
    except PackageNotFoundError:
        cipval = "not installed"
    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__, "mujoco": mujoco.__version__,
            "matplotlib": matplotlib.__version__, "cipval": cipval}  # fmt: skip


def run_validation(
    profile: Profile, out_dir: Path, workers: int | None = None, progress: bool = True,
    figures: bool = True,
) -> dict[str, Any]:  # fmt: skip
    """Run every stage; returns the results dictionary written to results.json."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    stages = ["lambda1 agreement", "time-series agreement", "amplitude scan",
              "critical gains", "lambda1 curve", "RMS and velocity", "STCC and spectra",
              "robustness", "nonlinear stick", "rod-length study", "figures"]  # fmt: skip
    bar = tqdm(stages, desc="cip-validate", disable=not progress, unit="stage")
    timings: dict[str, float] = {}
    checks, paper_rows = [], []

    @contextmanager
    def stage(name: str):
        bar.set_postfix_str(name)
        t = time.perf_counter()
        yield
        timings[name] = round(time.perf_counter() - t, 2)
        bar.update(1)

    with stage("lambda1 agreement"):
        c, d = agreement.lyapunov_checks(profile, workers)
        checks += c
    with stage("time-series agreement"):
        c, series = agreement.series_checks(profile, workers)
        checks += c
    with stage("amplitude scan"):
        c, scan_rows = agreement.amplitude_scan(profile, workers)
        checks += c
    with stage("critical gains"):
        c, rows, bstar = paper.critical_gains(profile, workers)
        checks += c
        paper_rows += rows
    with stage("lambda1 curve"):
        curve = paper.lyapunov_curve(profile, workers)
    with stage("RMS and velocity"):
        rows, rms_data = paper.rms_and_velocity(profile, workers)
        paper_rows += rows
    with stage("STCC and spectra"):
        rows, peak_data = paper.peaks_and_spectra(profile, workers)
        paper_rows += rows
    with stage("robustness"):
        robust = paper.robustness(profile, workers)
    with stage("nonlinear stick"):
        nonlinear = paper.nonlinear_comparison(profile, workers)
        paper.clear_cache()
    with stage("rod-length study"):
        c, rod_rows, rod_ds = agreement.rod_length_study(profile, out_dir, workers)
        checks += c
    figure_files = []
    with stage("figures"):
        if figures:
            figure_files = plots.paper_figures(
                out_dir, curve=curve, lyapunov_points=d["lyapunov"], bstar=bstar,
                series=series, rms=rms_data, peaks=peak_data, scan=scan_rows,
            )  # fmt: skip
            from .sweep import plot_metric

            for metric in ("max_angle", "agreement"):
                png = out_dir / f"fig_rod_length_{metric}.png"
                figure_files.append(plot_metric(rod_ds, metric, "rod_length_ratio", png))
    bar.close()

    counts = {s: sum(ch.status == s for ch in checks) for s in (PASS, FAIL, INCONCLUSIVE)}
    return {
        "cipval_results": 1,
        "profile": profile.name,
        "settings": profile.as_dict(),
        "status": FAIL if counts[FAIL] else (INCONCLUSIVE if counts[INCONCLUSIVE] else PASS),
        "counts": counts,
        "checks": [ch.as_dict() for ch in checks],
        "paper": paper_rows,
        "robustness": robust,
        "nonlinear": nonlinear,
        "amplitude_scan": scan_rows,
        "rod_length": rod_rows,
        "figures": [str(p.name) for p in figure_files],
        "versions": package_versions(),
        "workers": workers,
        "timings_s": timings,
        "elapsed_s": round(time.perf_counter() - t0, 1),
    }
