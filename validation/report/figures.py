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
it.  A figure it cannot write (a full disk: :class:`cipcore.atomic.WriteError`)
ends it with status :data:`WRITE_ERROR_STATUS` and a last stderr line naming the
file, which the run raises again (exit 2, one line), not as a crash.
"""

from __future__ import annotations

import json
import pickle
import sys
from pathlib import Path

from cipcore.atomic import WriteError


def main() -> int:
    # loaded while the stages compute, not when a job arrives: the classes of the pickled
    # stage results (plain records in light modules: no numba, no engine), and the
    # rod-length study's dataset (xarray) and its figure code
    import xarray  # noqa: F401

    import cipcore.results
    import cipcore.schema  # noqa: F401
    import validation.checks.metrics  # noqa: F401
    from validation import sweep  # noqa: F401
    from validation.report import plots  # noqa: F401

    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            _draw(Path(line.strip()))
        except WriteError as exc:  # the parent raises it again: one line naming the file
            print(WRITE_ERROR + json.dumps([exc.path, exc.reason]), file=sys.stderr)
            return WRITE_ERROR_STATUS
    return 0


#: how the worker says that it could not write a figure: its exit status, and a last
#: stderr line of this prefix and the JSON list [path, reason]
#: (:func:`validation.run.finish_paper_figures` raises the :class:`WriteError` again)
WRITE_ERROR, WRITE_ERROR_STATUS = "write error: ", 3


def _draw(job_file: Path) -> None:
    """Draw the figures of the job pickled in ``job_file``; print their paths, one a line."""
    from validation.report.plots import paper_figures

    job = pickle.loads(job_file.read_bytes())
    job_file.unlink(missing_ok=True)
    out_dir = Path(job["out_dir"])
    if job.get("kind", "paper") == "paper":
        data = dict(job["kwargs"])
        paths = paper_figures(out_dir, data, only=data.pop("only", None))
    else:
        paths = rod_figures(out_dir, **job["kwargs"])
    for path in paths:
        print(path, flush=True)


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
    from cipcore import quickexit

    quickexit.arm()  # the run waits for this process's exit: no module teardown
    quickexit.exit(main())
