"""The time-series schema shared by the reduced model and the MuJoCo model.

Every simulation, whatever its engine, returns a :class:`Trajectory`: a time
axis and a set of arrays shaped (realisations, samples, controllers), named
after the paper's quantities.  Positions are horizontal displacements from
each balancer's own upright reference (so the two tips of the coupled model,
which the rod keeps a distance l apart, have equal coordinates).

=========================  ======  ===========================================
field                      unit    meaning (paper symbol)
=========================  ======  ===========================================
tip_position               m       x_T, q_Ti: upper end of the stick
tip_velocity               m/s     x_T', q_Ti'
base_position              m       x_M, q_Mi: lower end (cart) of the stick
base_velocity              m/s     x_M', q_Mi'
balancing_error            m       Delta x = x_T - x_M, Delta q_i = q_Ti - q_Mi
balancing_error_velocity   m/s     d/dt of the balancing error
angle                      rad     pendulum angle theta_i (full model only)
=========================  ======  ===========================================

``time`` has shape (samples,), in seconds; sample j is the state *before*
step ``j * decimate``, so ``time[0] = 0`` is the initial state.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .params import ParameterError, check_count

UNITS: dict[str, str] = {
    "tip_position": "m",
    "tip_velocity": "m/s",
    "base_position": "m",
    "base_velocity": "m/s",
    "balancing_error": "m",
    "balancing_error_velocity": "m/s",
    "angle": "rad",
}
#: Fields every engine provides.
COMMON_FIELDS: tuple[str, ...] = tuple(k for k in UNITS if k != "angle")


@dataclass
class Trajectory:
    """Sampled time series of many realisations (see the module docstring).

    Attributes
    ----------
    time : (S,) sample times in s.
    data : field name -> (R, S, C) array.
    attrs : JSON-serialisable settings: model, engine, parameters, seed,
        dt, decimate, and anything the engine adds (largest angle, flags).
    """

    time: np.ndarray
    data: dict[str, np.ndarray]
    attrs: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[name]
        except KeyError:
            raise KeyError(
                f"field {name!r} was not recorded; recorded: {', '.join(self.data)}"
            ) from None

    @property
    def sample_interval(self) -> float:
        """Time between samples in s (dt * decimate)."""
        return float(self.attrs["dt"]) * int(self.attrs.get("decimate", 1))

    @property
    def shape(self) -> tuple[int, int, int]:
        return next(iter(self.data.values())).shape

    def save_npz(self, path: str | Path) -> Path:
        """Write ``time``, each field and ``attrs`` (as JSON) to a ``.npz`` file."""
        from .atomic import atomic_path

        path = Path(path)
        arrays = {"time": self.time, **self.data}
        attrs = np.array(json.dumps(self.attrs, default=_jsonable))
        with atomic_path(path) as tmp, open(tmp, "wb") as f:  # a file object: no ".npz" added
            np.savez(f, **arrays, attrs=attrs)
        return path

    @classmethod
    def load_npz(cls, path: str | Path) -> Trajectory:
        with np.load(path) as f:
            attrs = json.loads(str(f["attrs"]))
            data = {k: f[k] for k in f.files if k not in ("time", "attrs")}
            return cls(time=f["time"], data=data, attrs=attrs)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


#: Memory cap for the recorded arrays; raise it explicitly with ``max_bytes``.
DEFAULT_MAX_BYTES = 2 * 1024**3


def check_amplitude(amplitude: float) -> float:
    a = float(amplitude)
    if not np.isfinite(a):
        raise ParameterError(f"amplitude must be a finite number (m), got {amplitude!r}")
    return a


def recording_bytes(
    n_steps: int, n_realizations: int, nc: int, recording: Any, n_fields: int
) -> int:
    """Bytes that ``n_fields`` fields of ``recording`` (every ``decimate``-th of ``n_steps``
    steps, its ``dtype``) take for ``n_realizations`` realisations of ``nc`` controllers."""
    n_samples = -(-n_steps // recording.decimate)
    return n_samples * n_realizations * nc * n_fields * np.dtype(recording.dtype).itemsize


class RecordingSizeError(ParameterError):
    """A recording beyond its memory cap (:func:`plan_recording`): a command line names its
    own options for the sizes (realisations, duration, decimation)."""


def plan_recording(
    n_steps: int,
    n_realizations: int,
    nc: int,
    recording: Any,
    allowed: tuple[str, ...] = COMMON_FIELDS,
) -> tuple[int, tuple[str, ...]]:
    """Check a recording request; the number of samples and the fields recorded.

    ``recording`` (a :class:`cipcore.scenario.Recording`) keeps every ``decimate``-th
    of ``n_steps`` steps of ``fields`` (default: every name in ``allowed``) for
    ``n_realizations`` realisations of ``nc`` controllers, refused beyond ``max_bytes``.
    """
    decimate = check_count("decimate", recording.decimate)
    fields = allowed if recording.fields is None else tuple(recording.fields)
    max_bytes = recording.max_bytes
    for f in fields:
        if f not in allowed:
            raise ParameterError(f"fields: unknown field {f!r}; allowed: {', '.join(allowed)}")
    n_samples = -(-n_steps // decimate)
    need = recording_bytes(n_steps, n_realizations, nc, recording, len(fields))
    if need > max_bytes:
        raise RecordingSizeError(
            f"recording {len(fields)} field(s) x {n_realizations} realisations x {n_samples} "
            f"samples needs {need / 2**30:.2f} GiB > max_bytes {max_bytes / 2**30:.2f} GiB; "
            "raise decimate, record fewer fields, use dtype=float32 or raise max_bytes"
        )
    return n_samples, fields


def check_duration(duration: float) -> float:
    """``duration`` (s) as a finite float > 0, or a one-line :class:`ParameterError`."""
    try:
        d = float(duration)
    except (TypeError, ValueError):
        raise ParameterError(
            f"duration must be a number of seconds > 0, got {duration!r}"
        ) from None
    if not np.isfinite(d) or d <= 0:
        raise ParameterError(f"duration must be finite and > 0 s, got {duration!r}")
    return d
