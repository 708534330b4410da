"""Parameter studies: the public names of :mod:`validation.sweeps` in one place.

The implementation lives in :mod:`validation.sweeps` (study schema, parameter
mapping, metric evaluation, storage, schedulers, plots); this module keeps
``from validation.sweep import Study, run_sweep, ...`` working.
"""

from validation.sweeps import (
    LABELS,
    METRICS,
    SETTINGS,
    STCC_MIN_DURATION,
    DirectoryLock,
    Store,
    Study,
    SweepPool,
    SweepReport,
    assemble,
    default_studies_dir,
    evaluate_point,
    mean_ci,
    parse_grid,
    plot_metric,
    point_key,
    point_params,
    point_seed,
    run_sweep,
    write_dataset,
    write_sweep_report,
)

__all__ = [
    "LABELS", "METRICS", "SETTINGS", "STCC_MIN_DURATION", "DirectoryLock", "Store", "Study",
    "SweepPool", "SweepReport", "assemble", "default_studies_dir", "evaluate_point", "mean_ci",
    "parse_grid", "plot_metric", "point_key", "point_params", "point_seed", "run_sweep",
    "write_dataset", "write_sweep_report",
]  # fmt: skip
