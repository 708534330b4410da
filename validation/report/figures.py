"""The report's figures drawn in a child process: ``python -m validation.report.figures``.

Started with the run (:func:`validation.run.spawn_figure_worker`), it
imports matplotlib and the figure code while the stages compute, then reads
jobs from stdin, one a line: the path of a pickle of ``{"out_dir": str,
"kind": "paper" | "rod", "kwargs": dict}`` (removed once read).  A ``paper``
job draws the paper figures named in its ``only`` (:func:`validation.report.plots.
paper_figures`), sent as soon as the stages whose data they draw have finished
(:data:`PAPER_FIGURES`), so that drawing overlaps the later stages; a ``rod``
job (written once the rod-length study has finished) draws its two figures
(:func:`validation.sweeps.report.plot_metric` of the study's dataset).  The
figures go into ``out_dir``; their paths are printed, one a line, in the
order of the jobs.  The end of stdin (the run finished, or ended first) ends
it.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path


def main() -> int:
    # loaded while the stages compute, not when a job arrives: the classes of the pickled
    # stage results, and the rod-length study's dataset (xarray) and its figure code
    import xarray  # noqa: F401

    import reduced  # noqa: F401
    from validation import sweep  # noqa: F401
    from validation.report.plots import paper_figures

    for line in sys.stdin:
        if not line.strip():
            continue
        path = Path(line.strip())
        job = pickle.loads(path.read_bytes())
        path.unlink(missing_ok=True)
        out_dir = Path(job["out_dir"])
        if job.get("kind", "paper") == "paper":
            data = dict(job["kwargs"])
            paths = paper_figures(out_dir, data, only=data.pop("only", None))
        else:
            paths = rod_figures(out_dir, **job["kwargs"])
        for path in paths:
            print(path, flush=True)
    return 0


#: the report's paper figures in its order: file name -> the data each draws (keyword
#: arguments of :func:`validation.report.plots.paper_figures`, each computed by one stage:
#: :data:`validation.run.FIGURE_DATA_STAGES`)
PAPER_FIGURES = {
    "fig_lLe.png": ("curve", "lyapunov_points", "bstar"),
    "fig_Be.png": ("series",),
    "fig_pwsp.png": ("series", "peaks"),
    "fig_rms.png": ("rms",),
    "fig_velo.png": ("rms",),
    "fig_scc.png": ("peaks", "series"),
    "fig_sccpeak.png": ("peaks",),
    "fig_sccpeak_pdf.png": ("peaks", "series"),
    "fig_amplitude_scan.png": ("scan",),
}

#: the rod-length study's metrics drawn against the rod length ratio l / L
ROD_METRICS = ("max_angle", "agreement")


def rod_figures(out_dir: Path, rod_ds) -> list[Path]:
    """``fig_rod_length_<metric>.png`` of the rod-length study's dataset, per
    :data:`ROD_METRICS`, against ``rod_length_ratio``."""
    from validation.sweep import plot_metric

    return [plot_metric(rod_ds, metric, "rod_length_ratio",
                        out_dir / f"fig_rod_length_{metric}.png")
            for metric in ROD_METRICS]  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
