"""The study schema: what a parameter study fixes, sweeps and computes (TOML or Python).

A study names the model, the engine (from :mod:`cipcore.registry`), fixed
settings, a grid of swept settings and the metrics to compute.  Its seeds are
derived per grid point from the study seed (:func:`point_seed`), so results
never depend on the scheduler.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import tomllib
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.models import get_model
from cipcore.params import ParameterError
from cipcore.registry import get_engine
from validation.cli.domains import DOMAINS, STUDY_METRICS, check_key
from validation.profiles import Profile
from validation.regression.versions import package_versions
from validation.sweeps.mapping import (
    ROD_KEYS,
    SETTING_DOMAINS,
    SETTINGS,
    WORD_SETTINGS,
    point_params,
)

METRICS = STUDY_METRICS
#: metrics defined only for an engine with ``capabilities.rigid_body``
RIGID_BODY_METRICS = ("max_angle", "agreement")
#: STCC settings of the tau_hat metric: the profiles' (paper: window Dt = 5 s)
STCC = Profile(name="sweep")
STCC_MIN_DURATION = STCC.stcc_window + STCC.stcc_max_lag + 1.0
#: the tau_hat estimator's settings a study may set in its ``[stcc]`` table, with defaults:
#: window Dt (s, paper: 5 s), largest lag (s), window stride (s), peak dominance (a peak
#: counts when R >= dominance x the largest R over the lags) and the Bartlett significance
#: level z (R must exceed z / sqrt(n_eff); 0 switches the significance test off)
STCC_DEFAULTS = {"window": STCC.stcc_window, "max_lag": STCC.stcc_max_lag,
                 "stride": STCC.stcc_stride, "dominance": 0.8, "significance_z": 3.0}  # fmt: skip
#: the target-gain settings of a study's ``[gain]`` table, with defaults: beta per point is
#: beta*, where lambda1 of the reduced model equals ``target_lambda1`` (1/s), found by
#: :func:`reduced.lyapunov.critical_gain` over ``gains`` gains spread over the model's
#: paper gain +- ``half_width`` (1/s^2), ``realizations`` x ``duration`` s each
GAIN_DEFAULTS = {"target_lambda1": 5e-4, "half_width": 0.8, "gains": 5, "realizations": 16,
                 "duration": 1000.0}  # fmt: skip


@dataclass
class Study:
    """A parameter study (see :mod:`validation.sweeps`)."""

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
    compare: tuple[str, ...] = ()
    gain: dict[str, Any] = field(default_factory=dict)
    stcc: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, domain in STUDY_KEYS.items():  # the declared domain of every [study] key
            if key != "compare" or self.compare:
                setattr(self, key, check_key("", key, getattr(self, key), domain))
        self.compare = tuple(self.compare or ())
        if self.compare and len(self.compare) != 2:
            raise ParameterError(
                f"compare: name two different models (reference first), got {list(self.compare)!r}"
            )
        self.gain = _settings("gain", self.gain, GAIN_DEFAULTS)
        self.stcc = _settings("stcc", self.stcc, STCC_DEFAULTS)
        rigid = get_engine(self.engine).capabilities.rigid_body
        for m in self.metrics:
            if m in RIGID_BODY_METRICS and not rigid:
                raise ParameterError(
                    f"metrics: {m} needs a rigid-body engine, {self.engine!r} is not one"
                )
        if not isinstance(self.grid, dict) or not self.grid:
            raise ParameterError("grid: a study needs at least one swept parameter")
        for k in [*self.fixed, *self.grid]:
            if k == "model":
                raise ParameterError(
                    'model: compare two models with compare = ["single", "coupled"] in '
                    "[study] (or --compare single,coupled): paired, with the same seeds"
                )
            if k not in SETTINGS:
                raise ParameterError(f"unknown setting {k!r}; allowed: {', '.join(SETTINGS)}")
        for k, vals in self.grid.items():
            if not isinstance(vals, list) or not vals:
                raise ParameterError(f"grid.{k} must be a non-empty list, got {vals!r}")
            for v in vals:
                _check_value(f"grid.{k}", k, v)
            seen = [v if isinstance(v, str) else float(v) for v in vals]
            twice = [v for i, v in enumerate(seen) if v in seen[:i]]
            if twice:
                raise ParameterError(
                    f"grid.{k}: the value {twice[0]:g} is given twice; each value once"
                    if not isinstance(twice[0], str)
                    else f"grid.{k}: the value {twice[0]!r} is given twice; each value once"
                )
        for k, v in self.fixed.items():
            _check_value(f"fixed.{k}", k, v)
        if self.gain and ("beta" in self.fixed or "beta" in self.grid):
            raise ParameterError(
                "beta: set beta or a [gain] target (beta = beta* per point), not both"
            )
        self._check_no_effect(rigid)
        st = self.stcc
        stcc_min = st["window"] + st["max_lag"] + 1.0
        if "tau_hat" in self.metrics and self.duration < stcc_min:
            raise ParameterError(
                f"duration must be >= {stcc_min:g} s for the tau_hat metric "
                f"(STCC window {st['window']:g} s + lags {st['max_lag']:g} s), "
                f"got {self.duration}"
            )
        # validate every point's parameters up front: a bad value fails before any work
        for point in self.points():
            try:
                point_params(self, point)
            except ParameterError as exc:  # name the setting: grid.integrator, fixed.tau
                k = str(exc).split(" ", 1)[0]
                where = "grid" if k in self.grid else "fixed" if k in self.fixed else None
                if where is None:
                    raise
                raise ParameterError(f"{where}.{k}: {exc}") from None

    @classmethod
    def from_toml(cls, path: str | Path) -> Study:
        """The study of a TOML file; every error one line naming the file and the key."""
        path = Path(path)
        d = _read_toml(path)
        try:
            return cls(**d["study"], **{t: d.get(t, {}) for t in TABLES if t != "study"})
        except ParameterError as exc:
            text = str(exc)
            table = "[study] " if text.split(" ", 1)[0].rstrip(":") in STUDY_KEYS else ""
            raise ParameterError(f"study file {path}: {table}{text}") from None

    def _check_no_effect(self, rigid: bool) -> None:
        """Refuse, in one line, a setting that cannot change any result of this study."""
        where = {**{k: "fixed" for k in self.fixed}, **{k: "grid" for k in self.grid}}
        physical = [k for k in where if k in PHYSICAL_ONLY]
        if physical and not rigid:
            k = physical[0]
            raise ParameterError(
                f"{where[k]}.{k} is a rigid-body setting with no effect on the {self.engine} "
                "engine: it integrates the reduced model (eqs. (3), (5)), which has no rigid "
                "body, rod or cart mass"
            )
        models = self.compare or (self.model,)
        rod = [k for k in where if k in ROD_KEYS]
        single = [m for m in models if get_model(m).n_controllers < 2]
        if rod and single:
            raise ParameterError(
                f"{where[rod[0]]}.{rod[0]}: no effect on the {single[0]} model: it has one "
                "stick and no rod (the rod joins the tips of two sticks)"
            )

    def axes(self) -> dict[str, list]:
        """The study's dimensions and their values: ``model`` (with ``compare``), then the grid."""
        return {"model": list(self.compare), **self.grid} if self.compare else dict(self.grid)

    def points(self) -> list[dict[str, Any]]:
        ax = self.axes()
        keys = list(ax)
        return [dict(zip(keys, vals, strict=True))
                for vals in itertools.product(*(ax[k] for k in keys))]  # fmt: skip

    def model_of(self, point: dict[str, Any]) -> str:
        """The model of one grid point (``compare`` puts it in the point)."""
        return str(point.get("model", self.model))

    def as_dict(self) -> dict:
        d = asdict(self)
        d["metrics"] = list(self.metrics)
        d["compare"] = list(self.compare)
        return d

    def fingerprint(self) -> str:
        """Hash of what determines the results: the study and the package versions.

        Point files carry it in their names, and a sweep directory holding
        another fingerprint is never reused, so points computed for another
        study or with another engine or library version are never mixed in.
        """
        key = {"study": self.as_dict(), "versions": package_versions()}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


#: the tables of a study TOML file
TABLES = ("study", "fixed", "grid", "gain", "stcc")
#: the keys of a study's ``[study]`` table and their declared domains
#: (:data:`validation.cli.domains.DOMAINS`: the command line's options read the same)
STUDY_KEYS = {"name": "text", "model": "model", "engine": "engine", "metrics": "metrics",
              "realizations": "study realizations", "duration": "duration", "seed": "seed",
              "common_random_numbers": "switch", "decimate": "decimate",
              "compare": "compare"}  # fmt: skip


def _read_toml(path: Path) -> dict[str, Any]:
    """A study file's tables, checked for their names, kinds and ``[study]`` keys."""
    try:
        d = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ParameterError(f"study file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterError(f"study file {path}: cannot read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"study file {path}: {exc}") from None
    unknown = set(d) - set(TABLES)
    if unknown:
        raise ParameterError(
            f"study file {path}: unknown table(s) {', '.join(sorted(unknown))}; "
            f"allowed: {', '.join(f'[{t}]' for t in TABLES)}"
        )
    for t in TABLES:
        if t in d and not isinstance(d[t], dict):
            raise ParameterError(f"study file {path}: [{t}] must be a table, got {d[t]!r}")
    if "study" not in d:
        raise ParameterError(f'study file {path}: no [study] table (it needs name = "...")')
    both = set(d.get("fixed", {})) & set(d.get("grid", {}))
    if both:
        raise ParameterError(
            f"study file {path}: {', '.join(sorted(both))} both in [fixed] and [grid]; "
            "a setting is fixed or swept, not both"
        )
    for k in d["study"]:
        if k not in STUDY_KEYS:
            raise ParameterError(
                f"study file {path}: unknown key {k!r} in [study]; allowed: {', '.join(STUDY_KEYS)}"
            )
    if "name" not in d["study"]:
        raise ParameterError(f'study file {path}: [study] has no name (name = "...")')
    return d


#: settings of the rigid body alone: the reduced model has none of them
PHYSICAL_ONLY = tuple(k for k in SETTINGS if k not in ("beta", "alpha", "gamma", "nu", "tau",
                                                        "dt", "amplitude"))  # fmt: skip


#: the declared domain of each key of the ``[gain]`` and ``[stcc]`` tables
#: (:data:`validation.cli.domains.DOMAINS`)
TABLE_KEYS = {
    "gain": {"target_lambda1": "target", "half_width": "half width", "gains": "gains",
             "realizations": "study realizations", "duration": "duration"},
    "stcc": {"window": "duration", "max_lag": "duration", "stride": "duration",
             "dominance": "fraction", "significance_z": "z score"},
}  # fmt: skip


def _settings(table: str, given: Any, defaults: dict[str, Any]) -> dict[str, Any]:
    """A ``[gain]`` / ``[stcc]`` table with its defaults filled in ({} when not given, for
    ``gain``); unknown keys refused, each value in its declared domain (:data:`TABLE_KEYS`)."""
    if not given:
        return {} if table == "gain" else dict(defaults)
    if not isinstance(given, dict):
        raise ParameterError(f"{table}: expected a table of settings, got {given!r}")
    out = dict(defaults)
    for k, v in given.items():
        if k not in defaults:
            raise ParameterError(f"{table}.{k}: unknown setting; allowed: {', '.join(defaults)}")
        domain = DOMAINS[TABLE_KEYS[table][k]]
        v = check_key(f"{table}.", k, v, domain)
        out[k] = float(v) if domain.kind == "float" else v
    return out


def _check_value(where: str, key: str, value: Any) -> None:
    if key in WORD_SETTINGS:
        if not isinstance(value, str):
            raise ParameterError(f"{where}: expected a word, got {value!r}")
    elif isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ParameterError(f"{where}: expected a finite number, got {value!r}")
    elif key in SETTING_DOMAINS:
        check_key(f"{where}: ", key, value, SETTING_DOMAINS[key])


def point_key(point: dict[str, Any]) -> str:
    return json.dumps(point, sort_keys=True)


def point_seed(study: Study, point: dict[str, Any]) -> int:
    """The seed of one grid point: the study seed, or one derived from it and the point.

    The ``model`` of a ``compare`` study is left out of the derivation: the
    compared models draw from the same random stream at every point (common
    random numbers across models), so their realisations pair up.
    """
    if study.common_random_numbers:
        return study.seed
    rest = {k: v for k, v in point.items() if k != "model"}
    key = zlib.crc32(point_key(rest).encode())
    return int(np.random.SeedSequence(study.seed, spawn_key=(key,)).generate_state(1)[0])


def default_studies_dir() -> Path:
    """The shipped studies (``validation/studies``)."""
    return Path(__file__).resolve().parent.parent / "studies"


def parse_grid(items: list[str], option: str = "--grid") -> dict[str, list]:
    """``name=v1,v2,...`` (numbers or words) -> {name: [values]}."""
    grid = {}
    for item in items:
        if "=" not in item:
            raise ParameterError(f"{option} expects NAME=V1,V2,..., got {item!r}")
        k, vals = item.split("=", 1)
        values = [_value(v) for v in vals.split(",") if v.strip()]
        if not values:
            raise ParameterError(f"{option} {k.strip()}: no values given in {item!r}")
        if k.strip() in grid:
            raise ParameterError(
                f"{option} {k.strip()} is given twice; give every value in one {option} "
                f"{k.strip()}=V1,V2,..."
            )
        grid[k.strip()] = values
    return grid


def _value(text: str):
    text = text.strip()
    try:
        return int(text) if text.lstrip("-").isdigit() else float(text)
    except ValueError:
        return text
