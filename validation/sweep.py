"""Parameter studies: a grid of model / engine / controller settings, resumable, local or Dask.

A *study* names the model, the engine, fixed settings, a grid of swept
settings and the metrics to compute (from :mod:`validation.metrics` and the
engines' Lyapunov exponents).  Every grid point is an independent job:

* its seed is derived from the study seed and the point's settings
  (``SeedSequence(seed, spawn_key=(crc32(point),))``), or, with
  ``common_random_numbers = true``, is the study seed for every point (the
  same noise everywhere, so differences between points come from the
  parameters alone); either way results do not depend on the scheduler, the
  number of workers or the order of completion;
* its result is written to ``DIR/points/<key>.json`` (atomically) as soon as
  it finishes, so an interrupted sweep rerun with the same study computes only
  the missing points, and the assembled dataset is identical to that of an
  uninterrupted run;
* it runs in a local process pool (``workers``) or on an existing Dask
  cluster (``scheduler`` address, ``dask.distributed``).

The result is an ``xarray.Dataset`` with one dimension per swept parameter
(plus ``realization`` for per-realisation metrics), written to
``DIR/sweep.nc`` (NetCDF) with the study, seeds and package versions as
attributes.

Settings (any may be fixed or swept):

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

Metrics: ``lambda1`` (per realisation, 1/s), ``rms`` (log10 RMS of the
balancing error, per realisation), ``max_angle`` (rad, per realisation, MuJoCo),
``agreement`` (relative L2 distance to the reduced model under the same noise
over the first 10 s, per realisation, MuJoCo), ``tau_hat`` (median first STCC
peak, s, per realisation), ``slopes`` (two spectral slopes of the mean
spectrum).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import tomllib
import warnings
import zlib
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.params import BalanceParams, ParameterError

REDUCED_KEYS = ("beta", "alpha", "gamma", "nu", "tau", "dt")
PHYSICAL_KEYS = (
    "rod_length", "rod_length_ratio", "mass_ratio", "rod_mass", "bob_radius",
    "solref_timeconst", "solref_dampratio", "solimp_width", "integrator",
)  # fmt: skip
RUN_KEYS = ("amplitude",)
SETTINGS = REDUCED_KEYS + PHYSICAL_KEYS + RUN_KEYS
METRICS = ("lambda1", "rms", "max_angle", "agreement", "tau_hat", "slopes")
STCC_MIN_DURATION = 5.3 + 1.0
LABELS = {
    "lambda1": "largest Lyapunov exponent lambda1 (1/s)",
    "rms": "log10 RMS of the balancing error (log10 m)",
    "max_angle": "largest |theta| (rad)",
    "agreement": "relative L2 distance to the reduced model (first 10 s)",
    "tau_hat": "median first STCC peak tau_hat (s)",
    "rod_length_ratio": "rod length l / pendulum length L",
    "mass_ratio": "bob / cart mass m/M",
    "dt": "time step (s)",
    "amplitude": "initial balancing error (m)",
}


@dataclass
class Study:
    """A parameter study (see the module docstring)."""

    name: str
    model: str = "coupled"
    engine: str = "mujoco"
    metrics: tuple[str, ...] = ("rms", "agreement", "max_angle")
    realizations: int = 8
    duration: float = 30.0
    seed: int = 0
    common_random_numbers: bool = False
    decimate: int = 5
    fixed: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.model not in ("single", "coupled"):
            raise ParameterError(f"model must be single or coupled, got {self.model!r}")
        if self.engine not in ("reduced", "mujoco"):
            raise ParameterError(f"engine must be reduced or mujoco, got {self.engine!r}")
        self.metrics = tuple(self.metrics)
        for m in self.metrics:
            if m not in METRICS:
                raise ParameterError(
                    f"metrics: unknown metric {m!r}; allowed: {', '.join(METRICS)}"
                )
            if m in ("max_angle", "agreement") and self.engine != "mujoco":
                raise ParameterError(f"metrics: {m} needs engine = mujoco")
        if not self.grid:
            raise ParameterError("grid: a study needs at least one swept parameter")
        for k in [*self.fixed, *self.grid]:
            if k not in SETTINGS:
                raise ParameterError(f"unknown setting {k!r}; allowed: {', '.join(SETTINGS)}")
        for k, vals in self.grid.items():
            if not isinstance(vals, list) or not vals:
                raise ParameterError(f"grid.{k} must be a non-empty list, got {vals!r}")
        if "tau_hat" in self.metrics and self.duration < STCC_MIN_DURATION:
            raise ParameterError(
                f"duration must be >= {STCC_MIN_DURATION} s for the tau_hat metric "
                f"(STCC window 5 s + lags 0.3 s), got {self.duration}"
            )
        if self.realizations < 2:
            raise ParameterError(f"realizations must be >= 2, got {self.realizations}")
        # validate every point's parameters up front: a bad value fails before any work
        for point in self.points():
            point_params(self, point)

    @classmethod
    def from_toml(cls, path: str | Path) -> Study:
        path = Path(path)
        try:
            d = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise ParameterError(f"study file not found: {path}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ParameterError(f"study file {path}: {exc}") from None
        s = d.get("study", {})
        return cls(**s, fixed=d.get("fixed", {}), grid=d.get("grid", {}))

    def points(self) -> list[dict[str, Any]]:
        keys = list(self.grid)
        return [dict(zip(keys, vals, strict=True))
                for vals in itertools.product(*(self.grid[k] for k in keys))]  # fmt: skip

    def as_dict(self) -> dict:
        d = asdict(self)
        d["metrics"] = list(self.metrics)
        return d

    def fingerprint(self) -> str:
        """Hash of what determines the results: the study and the package versions.

        A sweep directory holding another fingerprint is never reused, so
        points computed with another engine or library version are not mixed in.
        """
        from .harness import package_versions

        key = {"study": self.as_dict(), "versions": package_versions()}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def point_key(point: dict[str, Any]) -> str:
    return json.dumps(point, sort_keys=True)


def point_seed(study: Study, point: dict[str, Any]) -> int:
    if study.common_random_numbers:
        return study.seed
    key = zlib.crc32(point_key(point).encode())
    return int(np.random.SeedSequence(study.seed, spawn_key=(key,)).generate_state(1)[0])


def point_params(study: Study, point: dict[str, Any]):
    """(BalanceParams, CIPParams or None, amplitude) of one grid point."""
    s = {**study.fixed, **point}
    red = {k: float(s[k]) for k in REDUCED_KEYS if k in s}
    red.setdefault("beta", 21.032 if study.model == "coupled" else 20.306)
    params = BalanceParams(**red)
    amplitude = float(s.get("amplitude", 1e-3))
    phys = None
    if study.engine == "mujoco":
        from cip.model import CIPParams

        kw: dict[str, Any] = {}
        L = 9.81 / params.alpha if params.alpha > 0 else None
        if "rod_length" in s and "rod_length_ratio" in s:
            raise ParameterError("set rod_length or rod_length_ratio, not both")
        if "rod_length" in s:
            kw["rod_length"] = float(s["rod_length"])
        if "rod_length_ratio" in s:
            kw["rod_length"] = float(s["rod_length_ratio"]) * L
        for k in ("rod_mass", "bob_radius"):
            if k in s:
                kw[k] = float(s[k])
        if "integrator" in s:
            kw["integrator"] = str(s["integrator"])
        base = CIPParams()
        sr = list(base.solref)
        si = list(base.solimp)
        if "solref_timeconst" in s:
            sr[0] = float(s["solref_timeconst"])
        if "solref_dampratio" in s:
            sr[1] = float(s["solref_dampratio"])
        if "solimp_width" in s:
            si[2] = float(s["solimp_width"])
        kw["solref"], kw["solimp"] = tuple(sr), tuple(si)
        phys = CIPParams.from_reduced(params, mass_ratio=float(s.get("mass_ratio", 1e-3)), **kw)
        if not abs(amplitude) < phys.pendulum_length:
            raise ParameterError(
                f"amplitude must be < L = {phys.pendulum_length:.4g} m, got {amplitude}"
            )
    return params, phys, amplitude


def evaluate_point(study_dict: dict, point: dict[str, Any], threads: int = 1) -> dict[str, Any]:
    """Compute the study's metrics at one grid point (pure; runs in a worker)."""
    from cip.simulate import simulate_full
    from reduced import lyapunov, simulate

    from . import metrics as mt
    from .agreement import TRAJECTORY_WINDOW

    study = Study(**study_dict)
    params, phys, amplitude = point_params(study, point)
    seed = point_seed(study, point)
    n, dur = study.realizations, study.duration
    out: dict[str, Any] = {"seed": seed}
    need_series = set(study.metrics) & {"rms", "max_angle", "agreement", "tau_hat", "slopes"}
    if need_series:
        fields = ("balancing_error", "tip_velocity", "base_velocity")
        kw = {"amplitude": amplitude, "decimate": study.decimate, "threads": threads}
        if study.engine == "mujoco":
            from cip.simulate import DivergenceWarning

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DivergenceWarning)
                tr = simulate_full(study.model, params, dur, n, seed, physical=phys,
                                   fields=(*fields, "angle"), **kw)  # fmt: skip
            out["diverged"] = tr.attrs["diverged"] is not None
        else:
            tr = simulate(study.model, params, dur, n, seed, fields=fields, **kw)
        e = tr["balancing_error"][..., 0].astype(float)
        dt = tr.sample_interval
        if "rms" in study.metrics:
            out["rms"] = np.log10(mt.rms(e)).tolist()
        if "max_angle" in study.metrics:
            out["max_angle"] = list(tr.attrs["max_abs_angle"])
        if "agreement" in study.metrics:
            ref = simulate(study.model, params, min(dur, TRAJECTORY_WINDOW), n, seed,
                           amplitude=amplitude,
                           decimate=study.decimate, fields=("balancing_error",),
                           threads=threads)  # fmt: skip
            k = ref.time.size
            ef = tr["balancing_error"][:, :k, 0].astype(float)
            er = ref["balancing_error"][..., 0]
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = np.linalg.norm(ef - er, axis=1) / np.linalg.norm(er, axis=1)
            out["agreement"] = rel.tolist()
        if "tau_hat" in study.metrics:
            _, lags, r = mt.stcc(tr["tip_velocity"][..., 0], tr["base_velocity"][..., 0], dt,
                                 5.0, 0.3, 0.25)  # fmt: skip
            th = mt.first_dominant_peak(r, lags, significance=mt.stcc_significance(int(5.0 / dt)))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN: no dominant peak
                out["tau_hat"] = np.nanmedian(th, axis=-1).tolist()
        if "slopes" in study.metrics:
            f, sp = mt.power_spectrum(e, dt, segment=dur / 4)
            fit = mt.fit_two_power_laws(f, sp, 8.0 / dur, 20.0, n_bins=16, n_bootstrap=50)
            out["slope_low"] = fit.slope_low
            out["slope_high"] = fit.slope_high
    if "lambda1" in study.metrics:
        if study.engine == "mujoco":
            from cip.lyapunov import lyapunov_full

            res = lyapunov_full(study.model, params, dur, n, seed, physical=phys, threads=threads)
        else:
            res = lyapunov(study.model, params, dur, n, seed, threads=threads)
        out["lambda1"] = res.per_realization.tolist()
    return {k: _nan_to_none(v) for k, v in out.items()}


def _nan_to_none(v):
    if isinstance(v, list):
        return [None if isinstance(x, float) and not np.isfinite(x) else x for x in v]
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


# ------------------------------------------------------------ execution
class Store:
    """The sweep directory: study.json, points/<key>.json, sweep.nc."""

    def __init__(self, directory: Path, study: Study) -> None:
        self.dir = Path(directory)
        self.points_dir = self.dir / "points"
        self.points_dir.mkdir(parents=True, exist_ok=True)
        meta = self.dir / "study.json"
        if meta.exists():
            old = json.loads(meta.read_text())
            if old.get("fingerprint") != study.fingerprint():
                raise ParameterError(
                    f"--out {self.dir} holds another study or one made with other package "
                    f"versions ({old.get('name')!r}, fingerprint {old.get('fingerprint')}); "
                    "use a new directory"
                )
        else:
            _atomic_write(meta, json.dumps({"name": study.name,
                                            "fingerprint": study.fingerprint(),
                                            "study": study.as_dict()}, indent=1))  # fmt: skip

    def path(self, point: dict) -> Path:
        h = hashlib.sha256(point_key(point).encode()).hexdigest()[:20]
        return self.points_dir / f"{h}.json"

    def load(self, point: dict) -> dict | None:
        p = self.path(point)
        if not p.exists():
            return None
        rec = json.loads(p.read_text())
        return rec["result"] if rec.get("point") == point else None

    def save(self, point: dict, result: dict) -> None:
        _atomic_write(self.path(point), json.dumps({"point": point, "result": result}))


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_suffix(path.suffix + f".tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


@dataclass
class SweepReport:
    computed: int
    reused: int
    dataset_path: Path


def run_sweep(
    study: Study,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    on_point: Callable[[dict], None] | None = None,
) -> SweepReport:
    """Compute every missing grid point, persist each, assemble ``sweep.nc``.

    ``workers`` single-threaded processes (default: one per core; 1 runs in
    this process), or the Dask cluster at ``scheduler``.
    """
    from tqdm.auto import tqdm

    store = Store(Path(out_dir), study)
    points = study.points()
    todo = [p for p in points if store.load(p) is None]
    reused = len(points) - len(todo)
    bar = tqdm(total=len(points), initial=reused, desc=f"sweep {study.name}", unit="point",
               disable=not progress)  # fmt: skip
    sd = study.as_dict()

    def finished(point: dict, result: dict) -> None:
        store.save(point, result)
        bar.update(1)
        if on_point:
            on_point(point)

    try:
        if not todo:
            pass
        elif scheduler:
            _run_dask(scheduler, sd, todo, finished)
        elif (workers or os.cpu_count() or 1) <= 1:
            for p in todo:
                finished(p, evaluate_point(sd, p, threads=1))
        else:
            _run_local(workers or os.cpu_count() or 1, sd, todo, finished)
    finally:
        bar.close()
    path = write_dataset(study, store)
    return SweepReport(computed=len(todo), reused=reused, dataset_path=path)


def _run_local(workers: int, sd: dict, todo: list[dict], finished) -> None:
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futs = {pool.submit(evaluate_point, sd, p, 1): p for p in todo}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                finished(futs[f], f.result())


def _run_dask(address: str, sd: dict, todo: list[dict], finished) -> None:
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise ParameterError(
            "--scheduler needs dask.distributed: pip install 'cipval[dask]'"
        ) from None
    try:
        client = Client(address, timeout="10s")
    except OSError as exc:
        raise ParameterError(f"--scheduler: cannot reach {address!r} ({exc})") from None
    with client:
        futs = [client.submit(evaluate_point, sd, p, 1, pure=False) for p in todo]
        point_of = {f.key: p for f, p in zip(futs, todo, strict=True)}
        for fut in as_completed(futs):
            finished(point_of[fut.key], fut.result())


# ---------------------------------------------------------- the dataset
def assemble(study: Study, results: Iterable[tuple[dict, dict]]):
    """xarray.Dataset from (point, result) pairs in grid order."""
    import xarray as xr

    dims = list(study.grid)
    shape = [len(study.grid[k]) for k in dims]
    index = {k: {json.dumps(v): i for i, v in enumerate(study.grid[k])} for k in dims}
    n = study.realizations
    names: dict[str, np.ndarray] = {}
    for point, res in results:
        pos = tuple(index[k][json.dumps(point[k])] for k in dims)
        for name, val in res.items():
            if name not in names:
                extra = (n,) if isinstance(val, list) else ()
                dtype = bool if isinstance(val, bool) else float
                names[name] = np.full(shape + list(extra), np.nan if dtype is float else False,
                                      dtype=dtype)  # fmt: skip
            arr = names[name]
            arr[pos] = np.array(val, dtype=float) if isinstance(val, list) else val
    data_vars = {}
    for name, arr in names.items():
        d = dims + (["realization"] if arr.ndim > len(dims) else [])
        data_vars[name] = (d, arr.astype(np.int32) if arr.dtype == bool else arr)
    coords = {k: _coord(study.grid[k]) for k in dims}
    coords["realization"] = np.arange(n)
    ds = xr.Dataset(data_vars, coords=coords)
    from .harness import package_versions

    ds.attrs = {
        "study": json.dumps(study.as_dict()),
        "fingerprint": study.fingerprint(),
        "seed_rule": "common random numbers" if study.common_random_numbers
        else "SeedSequence(seed, spawn_key=(crc32(point json),))",
        "versions": json.dumps(package_versions()),
        "units": json.dumps({"lambda1": "1/s", "rms": "log10 m", "max_angle": "rad",
                             "agreement": "relative L2", "tau_hat": "s"}),
    }  # fmt: skip
    return ds


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _coord(values: list) -> np.ndarray:
    if all(_is_number(v) for v in values):
        return np.array(values, dtype=float)
    return np.array([str(v) for v in values])


def write_dataset(study: Study, store: Store) -> Path:
    ds = assemble(study, [(p, store.load(p)) for p in study.points()])
    path = store.dir / "sweep.nc"
    tmp = store.dir / "sweep.nc.tmp"
    ds.to_netcdf(tmp, engine="scipy")
    os.replace(tmp, path)
    return path


def default_studies_dir() -> Path:
    return Path(__file__).resolve().parent / "studies"


def parse_grid(items: list[str]) -> dict[str, list]:
    """``name=v1,v2,...`` (numbers or words) -> {name: [values]}."""
    grid = {}
    for item in items:
        if "=" not in item:
            raise ParameterError(f"--grid expects NAME=V1,V2,..., got {item!r}")
        k, vals = item.split("=", 1)
        grid[k.strip()] = [_value(v) for v in vals.split(",") if v.strip()]
    return grid


def _value(text: str):
    text = text.strip()
    try:
        return int(text) if text.lstrip("-").isdigit() else float(text)
    except ValueError:
        return text


# ----------------------------------------------------------- reporting
def mean_ci(ds, name: str):
    """Mean over realisations and its Student-t 95 % half-width (NaNs ignored)."""
    import scipy.stats

    a = ds[name]
    if "realization" not in a.dims:
        return a, a * np.nan
    n = a.count("realization")
    m = a.mean("realization")
    sd = a.std("realization", ddof=1)
    t = scipy.stats.t.ppf(0.975, np.maximum(n - 1, 1))
    return m, t * sd / np.sqrt(n)


def plot_metric(ds, metric: str, x: str, path: Path) -> Path:
    """A metric against one swept parameter, one line per value of the others,
    with 95 % confidence bands over realisations."""
    from .plots import plt

    if metric not in ds:
        raise ParameterError(
            f"--metric: {metric!r} not in the sweep; has {', '.join(ds.data_vars)}"
        )
    if x not in ds.dims:
        dims = [d for d in ds.dims if d != "realization"]
        raise ParameterError(f"--x: {x!r} is not a swept parameter; swept: {', '.join(dims)}")
    m, h = mean_ci(ds, metric)
    others = [d for d in m.dims if d != x]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    stacked = m.stack(line=others) if others else m.expand_dims(line=[0])
    hw = h.stack(line=others) if others else h.expand_dims(line=[0])
    xs = ds[x].values
    for k in range(stacked.sizes["line"]):
        y = stacked.isel(line=k).transpose(x).values
        e = hw.isel(line=k).transpose(x).values
        vals = np.atleast_1d(stacked["line"].values[k])
        label = ", ".join(f"{d}={v}" for d, v in zip(others, vals, strict=False)) or metric
        ax.plot(xs, y, "o-", ms=3, label=label)
        ax.fill_between(xs, y - e, y + e, alpha=0.2)
    if (
        np.issubdtype(np.asarray(xs).dtype, np.number)
        and np.all(xs > 0)
        and xs.max() / xs.min() > 20
    ):
        ax.set_xscale("log")
    ax.set_xlabel(LABELS.get(x, x))
    ax.set_ylabel(LABELS.get(metric, metric))
    n = ds.sizes.get("realization", 1)
    ax.set_title(f"mean over realisations, 95% band ({n} realisations)", fontsize=8)
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_sweep_report(study: Study, out_dir: Path) -> Path:
    """DIR/report.md: one figure per metric against the first swept parameter, and a table."""
    import xarray as xr

    out_dir = Path(out_dir)
    with xr.open_dataset(out_dir / "sweep.nc", engine="scipy") as ds:
        ds = ds.load()
    x = next(iter(study.grid))
    lines = [f"# Sweep {study.name}", "",
             f"{study.model} model, engine {study.engine}, {study.realizations} realisations x "
             f"{study.duration:g} s per point, seed {study.seed} "
             f"({'common random numbers' if study.common_random_numbers else 'seed per point'}).",
             "", f"Fixed: {json.dumps(study.fixed)}", ""]  # fmt: skip
    per = [m for m in ds.data_vars if "realization" in ds[m].dims]
    for metric in per:
        png = plot_metric(ds, metric, x, out_dir / f"sweep_{metric}.png")
        lines += [f"![{metric}]({png.name})", ""]
    dims = [d for d in study.grid]
    head = dims + [f"{m} (mean +- 95%)" for m in per]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for point in study.points():
        sel = {k: (float(v) if _is_number(v) else str(v)) for k, v in point.items()}
        cells = [str(point[k]) for k in dims]
        for m in per:
            mean, hw = mean_ci(ds, m)
            cells.append(f"{float(mean.sel(sel)):.4g} +- {float(hw.sel(sel)):.2g}")
        lines.append("| " + " | ".join(cells) + " |")
    path = out_dir / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
