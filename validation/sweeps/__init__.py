"""Parameter studies: a grid of model / engine / controller settings, resumable, local or Dask.

A *study* (:mod:`.study`) names the model, the engine (any registered in
:mod:`cipcore.registry`), fixed settings, a grid of swept settings and the
metrics to compute.  Every grid point is an independent job:

* its seed is derived from the study seed and the point's settings
  (``SeedSequence(seed, spawn_key=(crc32(point),))``), or, with
  ``common_random_numbers = true``, is the study seed for every point (the
  same noise everywhere, so differences between points come from the
  parameters alone); either way results do not depend on the scheduler, the
  number of workers or the order of completion;
* its result is written to ``DIR/points/<fingerprint>-<key>.json``
  (atomically) as soon as it finishes (:mod:`.store`), so an interrupted sweep
  rerun with the same study computes only the missing points, and the
  assembled dataset is identical to that of an uninterrupted run; the
  directory is locked while a sweep writes, and holds one study only;
* it runs in a local process pool (``workers``) or on an existing Dask
  cluster (``scheduler`` address, ``dask.distributed``) (:mod:`.schedule`).

The result is an ``xarray.Dataset`` with one dimension per swept parameter
(plus ``realization`` for per-realisation metrics), written to
``DIR/sweep.nc`` (NetCDF) with the study, seeds and package versions as
attributes.

Settings (any may be fixed or swept; mapping in :mod:`.mapping`):

===================  =========================================================
beta, alpha, gamma,  reduced-model parameters (1/s^2, 1/s^2, 1/s, s^1/2, s, s)
nu, tau, dt
amplitude            initial balancing error (m)
rod_length           rod length l (m);  rod_length_ratio: l / L
mass_ratio           bob / cart mass m/M
rod_mass, bob_radius kg, m
solref_timeconst     rod constraint time constant (s); solref_dampratio
solimp_width         solimp width (m)
integrator           Euler, implicitfast, implicit, RK4
===================  =========================================================

Metrics (:mod:`.evaluate`): ``lambda1`` (per realisation, 1/s), ``rms``
(log10 RMS of the balancing error, per realisation), ``max_angle`` (rad, per
realisation, rigid-body engines), ``agreement`` (relative L2 distance to the
reduced model under the same noise over the first 10 s, per realisation,
rigid-body engines), ``tau_hat`` (median first STCC peak, s, with
``tau_hat_fraction`` and ``tau_hat_avg``, per realisation; settings in the
study's ``[stcc]`` table), ``slopes`` (two spectral slopes of the mean
spectrum with bootstrap SEs).  Every point also records ``diverged`` and
per-realisation ``divergence_time``.

Research studies: ``compare = [A, B]`` runs two models at every point with
the same seeds and stores paired ratios and differences with bootstrap
intervals (:mod:`.paired`); a ``[gain]`` table sets beta per point to beta*
of a target lambda1 (:mod:`.gains`); every variable and coordinate carries
CF ``long_name`` / ``units`` and the settings in force are global attributes
(:mod:`.attrs`, :func:`.store.effective_settings`).  A setting that cannot
change a result (a rigid-body setting on the reduced engine, a rod setting on
a one-stick model) is refused.
"""

from validation.sweeps.evaluate import evaluate_point
from validation.sweeps.mapping import point_params
from validation.sweeps.report import LABELS, mean_ci, plot_metric, write_sweep_report
from validation.sweeps.schedule import SweepPool, SweepReport, run_sweep
from validation.sweeps.store import DirectoryLock, Store, assemble, write_dataset
from validation.sweeps.study import (
    METRICS,
    SETTINGS,
    STCC_MIN_DURATION,
    Study,
    default_studies_dir,
    parse_grid,
    point_key,
    point_seed,
)

__all__ = [
    "LABELS", "METRICS", "SETTINGS", "STCC_MIN_DURATION", "DirectoryLock", "Store", "Study",
    "SweepPool", "SweepReport", "assemble", "default_studies_dir", "evaluate_point", "mean_ci",
    "parse_grid", "plot_metric", "point_key", "point_params", "point_seed", "run_sweep",
    "write_dataset", "write_sweep_report",
]  # fmt: skip
