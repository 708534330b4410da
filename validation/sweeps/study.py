"""The study schema: what a parameter study fixes, sweeps and computes (TOML or Python).

A study names the model, the engine (from :mod:`cipcore.registry`), fixed
settings, a grid of swept settings and the metrics to compute.  Its seeds are
derived per grid point from the study seed (:func:`point_seed`), so results
never depend on the scheduler.
"""

from __future__ import annotations

import dataclasses
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
from cipcore.registry import check_engine_name, get_engine

from ..profiles import Profile
from ..versions import package_versions
from .mapping import PHYSICAL_KEYS, SETTINGS, WORD_SETTINGS, point_params

METRICS = ("lambda1", "rms", "max_angle", "agreement", "tau_hat", "slopes")
#: metrics defined only for an engine with ``capabilities.rigid_body``
RIGID_BODY_METRICS = ("max_angle", "agreement")
#: STCC settings of the tau_hat metric: the profiles' (paper: window Dt = 5 s)
STCC = Profile(name="sweep")
STCC_MIN_DURATION = STCC.stcc_window + STCC.stcc_max_lag + 1.0


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

    def __post_init__(self) -> None:
        get_model(self.model)
        check_engine_name(self.engine)
        rigid = get_engine(self.engine).capabilities.rigid_body
        if isinstance(self.metrics, str):
            self.metrics = (self.metrics,)
        self.metrics = tuple(self.metrics)
        for m in self.metrics:
            if m not in METRICS:
                raise ParameterError(
                    f"metrics: unknown metric {m!r}; allowed: {', '.join(METRICS)}"
                )
            if m in RIGID_BODY_METRICS and not rigid:
                raise ParameterError(
                    f"metrics: {m} needs a rigid-body engine, {self.engine!r} is not one"
                )
        _check_int("realizations", self.realizations, 2)
        _check_int("decimate", self.decimate, 1)
        _check_int("seed", self.seed, 0)
        if (
            isinstance(self.duration, bool)
            or not isinstance(self.duration, int | float)
            or not (np.isfinite(self.duration) and self.duration > 0)
        ):
            raise ParameterError(f"duration must be a number of seconds > 0, got {self.duration!r}")
        if not isinstance(self.grid, dict) or not self.grid:
            raise ParameterError("grid: a study needs at least one swept parameter")
        for k in [*self.fixed, *self.grid]:
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
        if not rigid:  # the rigid body's settings mean nothing to this engine
            for where, keys in (("fixed", self.fixed), ("grid", self.grid)):
                for k in keys:
                    if k in PHYSICAL_KEYS:
                        raise ParameterError(
                            f"{where}.{k} is a rigid-body setting; engine {self.engine!r} is "
                            f"not a rigid-body engine (its settings: "
                            f"{', '.join(k for k in SETTINGS if k not in PHYSICAL_KEYS)})"
                        )
        if "tau_hat" in self.metrics and self.duration < STCC_MIN_DURATION:
            raise ParameterError(
                f"duration must be >= {STCC_MIN_DURATION:g} s for the tau_hat metric "
                f"(STCC window {STCC.stcc_window:g} s + lags {STCC.stcc_max_lag:g} s), "
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
        path = Path(path)
        try:
            d = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise ParameterError(f"study file not found: {path}") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ParameterError(f"study file {path}: cannot read ({exc})") from None
        except tomllib.TOMLDecodeError as exc:
            raise ParameterError(f"study file {path}: {exc}") from None
        unknown = set(d) - {"study", "fixed", "grid"}
        if unknown:
            raise ParameterError(
                f"study file {path}: unknown table(s) {', '.join(sorted(unknown))}; "
                "allowed: [study], [fixed], [grid]"
            )
        both = set(d.get("fixed", {})) & set(d.get("grid", {}))
        if both:
            raise ParameterError(
                f"study file {path}: {', '.join(sorted(both))} both in [fixed] and [grid]; "
                "a setting is fixed or swept, not both"
            )
        s = d.get("study", {})
        allowed = [f.name for f in dataclasses.fields(cls) if f.name not in ("fixed", "grid")]
        for k in s:
            if k not in allowed:
                raise ParameterError(
                    f"study file {path}: unknown key {k!r} in [study]; allowed: "
                    f"{', '.join(allowed)}"
                )
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

        Point files carry it in their names, and a sweep directory holding
        another fingerprint is never reused, so points computed for another
        study or with another engine or library version are never mixed in.
        """
        key = {"study": self.as_dict(), "versions": package_versions()}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def _check_int(name: str, value: Any, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")


def _check_value(where: str, key: str, value: Any) -> None:
    if key in WORD_SETTINGS:
        if not isinstance(value, str):
            raise ParameterError(f"{where}: expected a word, got {value!r}")
    elif isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ParameterError(f"{where}: expected a finite number, got {value!r}")


def point_key(point: dict[str, Any]) -> str:
    return json.dumps(point, sort_keys=True)


def point_seed(study: Study, point: dict[str, Any]) -> int:
    """The seed of one grid point: the study seed, or one derived from it and the point."""
    if study.common_random_numbers:
        return study.seed
    key = zlib.crc32(point_key(point).encode())
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
