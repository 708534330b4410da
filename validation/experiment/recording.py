"""Recordings that are never lost: append-only JSON lines, then one ``.npz`` per trial.

While a trial runs, :class:`Recorder` appends one JSON line per 20 ms sample to
``<stem>.jsonl`` and flushes it to the operating system at once (a killed
server process loses nothing the OS has; a crash of the machine loses at most
the last second and one ``fsync``'s time, because an ``fsync`` of the file is
started at least once a second).  The ``fsync`` runs on a thread of its own: on
a busy disk one can take a second or more (ext4 commits other files' data with
it), and in the 50 Hz loop it held frames back (a coupled trial's 95th-percentile
frame lateness 76 ms, against 1 to 3 ms, in a test run while packages were still
being written to disk).  Its error (a full disk) is raised by the next sample.
The first line is the metadata header, the last (when the trial ends
normally, by time, out of range, abort or disconnect) the end record.

:meth:`Recorder.finalize` then writes ``<stem>.npz`` in the suite's schema
(:class:`reduced.Trajectory`: fields shaped (1, samples, sticks);
``tip_position``, ``tip_velocity``, ``base_position``, ``base_velocity``,
``balancing_error``, ``balancing_error_velocity``) plus ``mouse_pixel``
(raw pixels), ``frame_jitter`` and ``wall_time`` (s), with the header and
the end record as attributes.  :func:`load_trial` reads either file, so an
unfinalised (killed) trial is still analysable.

The client side: the header's ``client`` holds, per seat, what its page
reported (user agent, screen, window and canvas size in CSS px, device pixel
ratio, zoom, the seat colours); event lines ``{"mouse": [seat, arrival, page
time, x]}`` (arrival: s since frame 0 on the server's clock; page time: s on
the page's clock; x: pixel) and ``{"drawn": [seat, k, page time, arrival]}``
(the page drew frame k) are appended as they arrive and loaded into the
attribute ``client_events`` (column lists; see :data:`EVENT_COLUMNS`).
"""

from __future__ import annotations

import functools
import json
import math
import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from cipcore import Trajectory
from cipcore.atomic import atomic_path
from validation.experiment.trial import Sample

FORMAT = "cipval-experiment-1"
#: an fsync is started at least this often (s)
FSYNC_INTERVAL = 1.0
FIELDS = ("tip_position", "tip_velocity", "base_position", "base_velocity")
#: columns of the event lines (times in s; seat None: a spectator's page)
EVENT_COLUMNS = {"mouse": ("seat", "arrival", "page_time", "x"),
                 "drawn": ("seat", "k", "page_time", "arrival")}  # fmt: skip


def _json(obj: Any) -> str:
    try:  # the common case, in C: finite floats and plain types (a sample, an event)
        return json.dumps(obj, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError):  # NaN or inf (written as null), numpy scalars
        pass

    def fix(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: fix(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [fix(x) for x in v]
        if isinstance(v, np.generic):
            return fix(v.item())
        return v

    return json.dumps(fix(obj), separators=(",", ":"))


class Recorder:
    """Append samples of one trial to ``<stem>.jsonl`` (module docstring)."""

    def __init__(self, stem: Path, header: dict) -> None:
        self.stem = Path(stem)
        self.stem.parent.mkdir(parents=True, exist_ok=True)
        self.path = self.stem.with_suffix(".jsonl")
        self._f = open(self.path, "x", encoding="utf-8")  # kept open for the trial
        self._fsyncs = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recording-fsync")
        self._pending: Future | None = None
        self.header = {"format": FORMAT, **header}
        self._write({"header": self.header})
        self._sync()
        self.n_samples = 0

    def _write(self, obj: dict) -> None:
        self._f.write(_json(obj) + "\n")
        self._f.flush()

    def _wait_pending(self) -> None:
        """Wait for the fsync running on the thread, if any; raise its error."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def _sync(self) -> None:
        """fsync now, in this thread (the header, the end record)."""
        self._wait_pending()
        os.fsync(self._f.fileno())
        self._last_sync = time.monotonic()

    def append(self, sample: Sample) -> None:
        """Write one sample; start an fsync on the thread when the last one started
        FSYNC_INTERVAL ago and has finished (its error, if any, is raised here)."""
        self._write(sample.as_dict())
        self.n_samples += 1
        if self._pending is not None and self._pending.done():
            self._wait_pending()
        if self._pending is None and time.monotonic() - self._last_sync >= FSYNC_INTERVAL:
            self._last_sync = time.monotonic()
            self._pending = self._fsyncs.submit(os.fsync, self._f.fileno())

    def event(self, kind: str, row: list) -> None:
        """Append one client event line (:data:`EVENT_COLUMNS`); flushed with the next sample."""
        self._f.write(_json({kind: row}) + "\n")

    def close(self, end: dict) -> None:
        """Write the end record, fsync and close the log (the first call; later ones
        do nothing)."""
        try:
            if not self._f.closed:
                self._write({"end": end})
                self._sync()
                self._f.close()
        finally:
            self._fsyncs.shutdown(wait=True)

    def finalize(self, end: dict) -> Path:
        """:meth:`close`, then :func:`write_npz`; returns the ``.npz``'s path."""
        self.close(end)
        return write_npz(self.stem)


def write_npz(stem: str | Path) -> Path:
    """Write ``<stem>.npz`` from the closed log ``<stem>.jsonl`` (module docstring);
    returns its path.  A function of the file alone: the server runs it in a process of
    its own (parsing a 10-minute log takes seconds)."""
    stem = Path(stem)
    traj = load_jsonl(stem.with_suffix(".jsonl"))
    out = stem.with_suffix(".npz")
    with atomic_path(out) as tmp, open(tmp, "wb") as f:  # a file object: no ".npz" added
        np.savez(
            f, time=traj.time, **traj.data,
            attrs=np.array(json.dumps(traj.attrs, default=_default)),
        )  # fmt: skip
    return out


def _default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def load_jsonl(path: Path) -> Trajectory:
    """Read a (possibly unfinalised or truncated) ``.jsonl`` recording as a Trajectory.

    A last line cut off by a kill is ignored; without an end record the
    trial's ``end`` attribute is ``{"reason": "unfinalised"}``.
    """
    header: dict | None = None
    end: dict | None = None
    rows: list[dict] = []
    events: dict[str, dict[str, list]] = {
        kind: {c: [] for c in cols} for kind, cols in EVENT_COLUMNS.items()
    }
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                obj = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut off by a kill
            if "header" in obj:
                header = obj["header"]
            elif "end" in obj:
                end = obj["end"]
            elif obj.keys() & events.keys():
                ((kind, row),) = obj.items()
                for c, v in zip(EVENT_COLUMNS[kind], row, strict=True):
                    events[kind][c].append(v)
            else:
                rows.append(obj)
    if header is None:
        raise ValueError(f"{path}: no header line; not a cipval experiment recording")
    n = len(header["subjects"])
    data = {
        name: np.array([[r[name] for r in rows]], dtype=float).reshape(1, len(rows), n)
        for name in FIELDS
    }
    data["balancing_error"] = data["tip_position"] - data["base_position"]
    data["balancing_error_velocity"] = data["tip_velocity"] - data["base_velocity"]
    data["mouse_pixel"] = np.array(
        [[[math.nan if p is None else p for p in r["pixel"]] for r in rows]], dtype=float
    ).reshape(1, len(rows), n)
    for name, key in (("frame_jitter", "jitter"), ("wall_time", "wall")):
        data[name] = np.array(
            [[math.nan if r[key] is None else r[key] for r in rows]], dtype=float
        ).reshape(1, len(rows), 1)
    time_ = np.array([r["t"] for r in rows], dtype=float)
    frames = np.array([r["k"] for r in rows], dtype=int)
    attrs = {
        **header,
        "end": end if end is not None else {"reason": "unfinalised"},
        "first_frame": int(frames[0]) if len(frames) else 0,
        "missing_frames": int(np.count_nonzero(np.diff(frames) != 1)) if len(frames) else 0,
        "source": str(path),
        "client_events": events,
    }
    return Trajectory(time=time_, data=data, attrs=attrs)


def load_trial(path: str | Path) -> Trajectory:
    """Load one trial: its ``.npz`` when finalised, else its ``.jsonl`` log."""
    path = Path(path)
    npz = path.with_suffix(".npz")
    if path.suffix in (".npz", ".jsonl") and npz.exists():
        return Trajectory.load_npz(npz)
    return load_jsonl(path.with_suffix(".jsonl"))


def find_trials(directory: str | Path) -> list[Path]:
    """Every trial under ``directory`` (one path per stem, .npz preferred), sorted."""
    d = Path(directory)
    stems = sorted({p.with_suffix("") for p in d.rglob("*.jsonl")} |
                   {p.with_suffix("") for p in d.rglob("*.npz")})  # fmt: skip
    out = []
    for s in stems:
        npz = s.with_suffix(".npz")
        out.append(npz if npz.exists() else s.with_suffix(".jsonl"))
    return out


def versions() -> dict[str, str]:
    """Versions of the software that produced a recording."""
    return dict(_versions())


@functools.cache
def _versions() -> dict[str, str]:
    # read once per process: the package metadata took 40 ms per trial's start, on the
    # server's loop, holding every other session's frames
    import importlib.metadata as md
    import platform

    out = {"python": platform.python_version()}
    for pkg in ("cipval", "numpy", "aiohttp", "mujoco"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


def make_header(
    settings_dict: dict,
    engine: str,
    subjects: list[str],
    seats: list[dict],
    trial_index: int,
    session: str,
    substeps: int,
) -> dict:
    """The metadata header of a recording.

    ``seats`` describes each seat (``{"kind": "human"}`` or a bot's settings);
    ``dt`` and ``decimate`` give the sample interval dt * decimate (s) as in
    :class:`reduced.Trajectory`.
    """
    return {
        "mode": settings_dict["mode"],
        "engine": engine,
        "subjects": list(subjects),
        "pair": list(subjects) if len(subjects) == 2 else None,
        "seats": seats,
        "trial_index": int(trial_index),
        "session": session,
        "settings": settings_dict,
        "dt": settings_dict["params"]["dt"],
        "decimate": int(substeps),
        "start_time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "versions": versions(),
    }
