"""Storage of a sweep directory: one study per directory, locked while a sweep writes.

Layout of ``DIR``::

    .lock                     fcntl lock held by the running sweep (pid, host, start)
    study.json                name, fingerprint and the study
    points/<fp>-<key>.json    one finished grid point, named by the study
                              fingerprint and the point
    sweep.nc                  the assembled dataset

Every file is written to a per-process temporary name and moved into place
with :func:`os.replace`, so a reader never sees half a file.  A second sweep
into a directory that a running sweep holds fails at once naming the holder
(or waits for it with ``wait=True``); a directory holding another study is
refused, so two studies can never mix.
"""

from __future__ import annotations

import dataclasses
import datetime
import fcntl
import hashlib
import json
import os
import socket
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.atomic import write_text, write_with
from cipcore.params import ParameterError
from validation.regression.versions import package_versions
from validation.sweeps.study import Study, point_key

LOCK_NAME = ".lock"


def _note(text: str) -> None:
    from tqdm.auto import tqdm

    tqdm.write(f"cip-validate: {text}", file=sys.stderr)


def atomic_write(path: Path, text: str) -> None:
    """Write ``path`` through a temporary name unique to this process, then os.replace."""
    write_text(path, text)


class DirectoryLock:
    """An exclusive ``fcntl.flock`` on ``DIR/.lock``, naming its holder inside the file."""

    def __init__(self, directory: Path, *, wait: bool = False) -> None:
        self.path = Path(directory) / LOCK_NAME
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not wait:
                holder = self._holder()
                os.close(self.fd)
                raise ParameterError(
                    f"--out {directory} is in use by another sweep ({holder}); "
                    "wait for it to finish, pass --wait, or use another directory"
                ) from None
            fcntl.flock(self.fd, fcntl.LOCK_EX)
        stamp = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
        info = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": stamp})
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, info.encode(), 0)
        os.fsync(self.fd)

    def _holder(self) -> str:
        for _ in range(20):  # the holder writes its name right after taking the lock
            try:
                d = json.loads(self.path.read_text() or "null")
            except (OSError, ValueError):
                d = None
            if d:
                return f"pid {d.get('pid')} on {d.get('host')} since {d.get('started')}"
            time.sleep(0.05)
        return "holder unknown"

    def release(self) -> None:
        if self.fd >= 0:
            os.ftruncate(self.fd, 0)
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = -1

    def __enter__(self) -> DirectoryLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class Store:
    """The sweep directory of one study (see the module docstring).

    Take the lock (:class:`DirectoryLock`) before opening a store for writing.
    """

    def __init__(self, directory: Path, study: Study) -> None:
        self.dir = Path(directory)
        self.fingerprint = study.fingerprint()
        self.points_dir = self.dir / "points"
        self.points_dir.mkdir(parents=True, exist_ok=True)
        meta = self.dir / "study.json"
        old = None
        if meta.exists():
            try:
                old = json.loads(meta.read_text())
                if not isinstance(old, dict) or "fingerprint" not in old:
                    raise ValueError("no study fingerprint in it")
            except (OSError, ValueError) as exc:  # point files carry their fingerprint:
                old = None  # rewriting study.json cannot mix another study's points in
                _note(f"{meta} is damaged ({' '.join(str(exc).split())}); rewritten for "
                      f"this study (its finished points are found by fingerprint)")  # fmt: skip
        if old is not None:
            if old.get("fingerprint") != self.fingerprint:
                raise ParameterError(
                    f"--out {self.dir} holds another study or one made with other package "
                    f"versions ({old.get('name')!r}, fingerprint {old.get('fingerprint')}); "
                    "use a new directory"
                )
        else:
            atomic_write(meta, json.dumps({"name": study.name, "fingerprint": self.fingerprint,
                                           "study": study.as_dict()}, indent=1))  # fmt: skip

    def path(self, point: dict) -> Path:
        h = hashlib.sha256(point_key(point).encode()).hexdigest()[:20]
        return self.points_dir / f"{self.fingerprint}-{h}.json"

    def load(self, point: dict) -> dict | None:
        p = self.path(point)
        if not p.exists():
            return None
        try:
            rec = json.loads(p.read_text())
            ok = rec.get("point") == point and rec.get("fingerprint") == self.fingerprint
            if not ok or not isinstance(rec.get("result"), dict):
                raise ValueError("not a record of this grid point")
        except (OSError, ValueError, AttributeError) as exc:
            _note(f"sweep point file {p} is damaged ({' '.join(str(exc).split())}); the "
                  "point is recomputed")  # fmt: skip
            return None
        return rec["result"]

    def save(self, point: dict, result: dict) -> None:
        rec = {"fingerprint": self.fingerprint, "point": point, "result": result}
        atomic_write(self.path(point), json.dumps(rec))


# ---------------------------------------------------------- the dataset
def assemble(study: Study, results: Iterable[tuple[dict, dict]]):
    """xarray.Dataset from (point, result) pairs in grid order.

    Dimensions: ``model`` (a ``compare`` study), the swept settings, and
    ``realization`` for per-realisation metrics.  Every variable and
    coordinate carries CF ``long_name`` and ``units``
    (:mod:`validation.sweeps.attrs`); a ``compare`` study adds the paired
    comparisons (:mod:`validation.sweeps.paired`); the global attributes hold
    the study, the settings in force (:func:`effective_settings`), the seed
    rule and the package versions.
    """
    import xarray as xr

    from validation.sweeps.attrs import coord_attrs, variable_attrs

    axes = study.axes()
    dims = list(axes)
    shape = [len(axes[k]) for k in dims]
    index = {k: {json.dumps(v): i for i, v in enumerate(axes[k])} for k in dims}
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
    coords = {k: _coord(axes[k]) for k in dims}
    coords["realization"] = np.arange(n)
    ds = xr.Dataset(data_vars, coords=coords)
    if study.compare and "realization" in ds.dims:
        from validation.sweeps.paired import paired_variables

        for name, v in paired_variables(ds, list(study.compare), study.seed).items():
            ds[name] = v
    for name in ds.data_vars:
        ds[name].attrs = variable_attrs(name)
        if study.compare and "compared" in ds[name].attrs.get("long_name", ""):
            ln = ds[name].attrs["long_name"]
            ref, other = study.compare
            ds[name].attrs["long_name"] = ln.replace("compared", other).replace("reference", ref)
    for name in ds.coords:
        ds[name].attrs = coord_attrs(name)
    ds.attrs = {
        "Conventions": "CF-1.8",
        "title": f"cipval parameter study {study.name}",
        "study": json.dumps(study.as_dict()),
        "fingerprint": study.fingerprint(),
        # text: a NetCDF3 attribute holds int32 at most, a seed up to 2^63 - 1
        "seed": str(study.seed),
        "seed_rule": "common random numbers" if study.common_random_numbers
        else "SeedSequence(seed, spawn_key=(crc32(point json without model),))",
        "versions": json.dumps(package_versions()),
        "units": json.dumps({"lambda1": "1/s", "rms": "log10 m", "max_angle": "rad",
                             "agreement": "relative L2", "tau_hat": "s",
                             "divergence_time": "s"}),
        **effective_settings(study),
    }  # fmt: skip
    return ds


def effective_settings(study: Study) -> dict[str, Any]:
    """Global attributes: every parameter in force that the grid does not sweep, and every
    estimator setting (NetCDF attributes are numbers or text).

    ``param_<name>`` are the reduced-model parameters (beta, alpha 1/s^2, gamma
    1/s, nu s^1/2, tau, dt s) and, for a rigid-body engine, the physical ones
    (lengths m, masses kg) of the study's first grid point, for those the grid
    does not sweep (a swept one is a coordinate; beta under a ``[gain]``
    target is the variable ``beta_star``); ``stcc_<name>`` the tau_hat
    estimator's settings, ``gain_<name>`` the target-gain settings.
    """
    from validation.sweeps.mapping import DEFAULT_AMPLITUDE, point_params

    point = study.points()[0]
    params, phys, amplitude = point_params(study, point, beta=1.0 if study.gain else None)
    swept = set(study.axes())
    out: dict[str, Any] = {}
    for k, v in params.as_dict().items():
        if k not in swept and not (k == "beta" and study.gain):
            out[f"param_{k}"] = float(v)
    if "amplitude" not in swept:
        out["param_amplitude"] = float(amplitude if amplitude is not None else DEFAULT_AMPLITUDE)
    if phys is not None:
        for k, v in dataclasses.asdict(phys).items():
            if k in swept or k in ("alpha", "gamma", "nu", "tau", "dt", "beta"):
                continue
            if isinstance(v, bool) or not isinstance(v, int | float | str | tuple | list):
                continue
            out[f"param_{k}"] = list(v) if isinstance(v, tuple) else v
    if "model" not in swept:
        out["param_model"] = study.model
    out["engine"] = study.engine
    out["realizations"] = study.realizations
    out["duration_s"] = float(study.duration)
    out["decimate"] = study.decimate
    if "tau_hat" in study.metrics:
        out.update({f"stcc_{k}": float(v) for k, v in study.stcc.items()})
        out["stcc_significance"] = ("Bartlett: R > z / sqrt(n_eff) per window"
                                    if study.stcc["significance_z"] > 0 else "none")  # fmt: skip
    out.update({f"gain_{k}": v for k, v in study.gain.items()})
    return out


def is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _coord(values: list) -> np.ndarray:
    if all(is_number(v) for v in values):
        return np.array(values, dtype=float)
    return np.array([str(v) for v in values])


def write_dataset(study: Study, store: Store) -> Path:
    """Assemble every point of ``store`` into ``DIR/sweep.nc`` (atomically)."""
    ds = assemble(study, [(p, store.load(p)) for p in study.points()])
    ds.attrs["content_sha256"] = dataset_digest(ds)
    path = store.dir / "sweep.nc"
    return write_with(path, lambda tmp: ds.to_netcdf(tmp, engine="scipy"))


def dataset_digest(ds) -> str:
    """SHA-256 of every variable's name, dimensions and values (checked on reading)."""
    h = hashlib.sha256()
    for name in sorted(ds.variables, key=str):
        v = ds.variables[name]
        values = np.asarray(v.values)
        h.update(f"{name}{tuple(v.dims)}{values.shape}".encode())
        if values.dtype.kind in "fiub":
            h.update(np.ascontiguousarray(values, dtype="<f8").tobytes())
        else:
            h.update("\x00".join(map(str, values.ravel())).encode())
    return h.hexdigest()


def read_dataset(path: Path, option: str = "dataset"):
    """A ``sweep.nc`` written by :func:`write_dataset`, loaded; a damaged one is refused.

    Raises
    ------
    ParameterError
        One line naming the file and what is wrong: not NetCDF, truncated, not a
        sweep dataset, or values that do not match the stored content hash.
    """
    import xarray as xr

    try:
        with xr.open_dataset(path, engine="scipy") as f:
            ds = f.load()
    except Exception as exc:  # any reader error: the file is truncated or not NetCDF
        why = " ".join(f"{type(exc).__name__}: {exc}".split())
        raise ParameterError(
            f"{option}: {str(path)!r} is damaged or not a sweep dataset ({why})"
        ) from None
    if "fingerprint" not in ds.attrs or "study" not in ds.attrs:
        raise ParameterError(f"{option}: {str(path)!r} is not a sweep dataset (no study in it)")
    stored = ds.attrs.get("content_sha256")
    if stored is not None and stored != dataset_digest(ds):
        raise ParameterError(
            f"{option}: {str(path)!r} is damaged (its values do not match the content hash "
            "stored when it was written); rerun the sweep to rebuild it from DIR/points"
        )
    return ds
