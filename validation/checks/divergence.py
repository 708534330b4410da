"""Which realisations of a run diverged or left the small-angle regime, when, and how far.

Read from the recorded data and attributes alone (no engine names):

* **diverged** (the result past that time means nothing):
  - a non-finite sample of any recorded field;
  - an engine's own stop (``attrs["diverged"]``: a non-finite state or engine
    warnings in a rigid-body engine);
  - a pole that fell: |theta| > pi/2 where the run records pendulum angles, or
    a balancing error |e| > L where it does not (the reduced model: e = L sin
    theta cannot exceed the pendulum length L = g / alpha, so beyond it the
    linear model describes no stick).
* **left the small-angle regime**: |theta| above the small-angle limit
  theta_s (:func:`cip.model.small_angle_limit`, sin theta = theta to 0.1 %),
  or |e| > L sin theta_s for the reduced model.

The data up to that time are kept as computed; these functions only report.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass

import numpy as np

from cipcore.params import BalanceParams
from cipcore.schema import Trajectory

DIVERGED, LEFT_SMALL_ANGLE = "diverged", "left the small-angle regime"


@dataclass(frozen=True)
class Event:
    """One realisation's first divergence or departure from the small-angle regime.

    Attributes
    ----------
    realization : realisation index (as in the run's seed streams).
    kind : :data:`DIVERGED` or :data:`LEFT_SMALL_ANGLE`.
    reason : what was seen (non-finite sample, engine stop, |theta| or |e| bound).
    time : first time (s) it was seen, or None when only a summary was recorded.
    extent : how far: the largest finite |theta| (rad) or |e| (m) of the realisation.
    unit : "rad" or "m".
    """

    realization: int
    kind: str
    reason: str
    time: float | None
    extent: float
    unit: str

    def as_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        when = "" if self.time is None else f" at t = {self.time:.4g} s"
        return (
            f"realisation {self.realization} {self.kind}{when} ({self.reason}; "
            f"largest |{'theta' if self.unit == 'rad' else 'e'}| {self.extent:.3g} {self.unit})"
        )


def pendulum_length(params: BalanceParams) -> float:
    """L = g / alpha (m), the pendulum length the reduced gain alpha implies."""
    from cip.model import CIPParams

    return CIPParams.from_reduced(params).pendulum_length


def small_angle_limit() -> float:
    """theta_s (rad), see :func:`cip.model.small_angle_limit`."""
    from cip.model import small_angle_limit as limit

    return limit()


def _first(mask: np.ndarray) -> np.ndarray:
    """Index of the first True along axis 1 of (R, S), -1 where none."""
    hit = mask.any(axis=1)
    return np.where(hit, mask.argmax(axis=1), -1)


def trajectory_events(tr: Trajectory, length: float) -> list[Event]:
    """Every realisation's first divergence, else its first exit from the small angles.

    ``length`` is the pendulum length L (m) (:func:`pendulum_length`).
    """
    first_r = int(tr.attrs.get("first_realization", 0) or 0)
    limit = small_angle_limit()
    if "angle" in tr.data:
        x = np.abs(np.asarray(tr["angle"], dtype=float)).max(axis=2)
        unit, fall, small, name = "rad", math.pi / 2, limit, "theta"
    elif "balancing_error" in tr.data:
        x = np.abs(np.asarray(tr["balancing_error"], dtype=float)).max(axis=2)
        unit, fall, small, name = "m", length, length * math.sin(limit), "e"
    else:
        x = None
    nonfinite = np.zeros((tr.shape[0], tr.time.size), dtype=bool)
    for arr in tr.data.values():
        nonfinite |= ~np.isfinite(np.asarray(arr, dtype=float)).all(axis=2)
    events: list[Event] = []
    n_real = tr.shape[0]
    engine_stop = tr.attrs.get("diverged")
    max_angle = tr.attrs.get("max_abs_angle")
    for r in range(n_real):
        ext = float("nan")
        t_nf = t_fall = t_small = None
        if x is not None:
            xr = x[r]
            fin = xr[np.isfinite(xr)]
            ext = float(fin.max()) if fin.size else float("nan")
            i = _first(np.asarray([xr > fall]))[0]
            t_fall = float(tr.time[i]) if i >= 0 else None
            i = _first(np.asarray([xr > small]))[0]
            t_small = float(tr.time[i]) if i >= 0 else None
        elif max_angle is not None:
            unit, name, ext = "rad", "theta", float(max_angle[r])
        i = _first(nonfinite[r : r + 1])[0]
        t_nf = float(tr.time[i]) if i >= 0 else None
        rr = r + first_r
        if t_nf is not None:
            events.append(Event(rr, DIVERGED, "non-finite sample", t_nf, ext, unit))
        elif isinstance(engine_stop, dict) and engine_stop.get("realization") == rr:
            t0 = engine_stop.get("time_window", [None])[0]
            events.append(Event(rr, DIVERGED, f"engine stopped: {engine_stop.get('reason')}",
                                t0, ext, unit))  # fmt: skip
        elif t_fall is not None:
            events.append(Event(rr, DIVERGED, f"|{name}| > {fall:.4g} {unit}", t_fall, ext, unit))
        elif t_small is not None:
            events.append(Event(rr, LEFT_SMALL_ANGLE, f"|{name}| > {small:.3g} {unit}",
                                t_small, ext, unit))  # fmt: skip
        elif x is None and max_angle is not None and ext > limit:
            kind = DIVERGED if ext > math.pi / 2 else LEFT_SMALL_ANGLE
            events.append(Event(rr, kind, f"|theta| > {limit:.3g} rad", None, ext, unit))
    return events


def lyapunov_events(
    per_realization: np.ndarray, first_realization: int = 0, diverged_at: np.ndarray | None = None
) -> list[Event]:
    """Realisations whose lambda1 came out non-finite (their run overflowed); with
    ``diverged_at`` (s per realisation, NaN where finite: an engine's
    :class:`cipcore.results.LyapunovResult`) the time its state went non-finite."""
    lam = np.asarray(per_realization, dtype=float)
    at = np.full(lam.shape, np.nan) if diverged_at is None else np.asarray(diverged_at, float)
    return [
        Event(int(r) + first_realization, DIVERGED,
              "non-finite lambda1" if np.isnan(at[r]) else "non-finite state (Benettin run)",
              None if np.isnan(at[r]) else float(at[r]), float("nan"), "")
        for r in np.flatnonzero(~np.isfinite(lam))
    ]  # fmt: skip


def summary(events: list[Event], n_realizations: int, limit: int = 5) -> str | None:
    """One line: how many diverged / left the small angles, the first few of each; None if none."""
    if not events:
        return None
    parts = []
    for kind in (DIVERGED, LEFT_SMALL_ANGLE):
        ev = [e for e in events if e.kind == kind]
        if ev:
            shown = "; ".join(str(e) for e in ev[:limit])
            more = f"; and {len(ev) - limit} more" if len(ev) > limit else ""
            parts.append(f"{len(ev)} of {n_realizations} realisations {kind}: {shown}{more}")
    return " | ".join(parts)


def divergence_times(events: list[Event], n_realizations: int, first: int = 0) -> list:
    """Per realisation: the time (s) it diverged, NaN where it did not (or time unknown)."""
    out = [float("nan")] * n_realizations
    for e in events:
        if e.kind == DIVERGED and e.time is not None:
            out[e.realization - first] = e.time
    return out


def rms_divergence(rms: dict, length: float, limit: int = 10) -> list[dict]:
    """The realisations whose RMS balancing error exceeds the pendulum length L.

    ``rms`` maps a model name to ``{"rms": array (R,)}`` (m); ``length`` is
    L = g / alpha (m).  A linear model's error can grow without bound, but a
    stick whose balancing error e = L sin(theta) is beyond L on average (RMS)
    has fallen: those realisations are listed as diverged (non-finite RMS
    too).  Returns entries of the run's divergence list (stage, run, summary,
    realizations), one per model with any.
    """
    out = []
    for model, d in rms.items():
        if not isinstance(d, dict) or "rms" not in d:
            continue
        r = np.asarray(d["rms"], dtype=float)
        bad = np.flatnonzero(~(r <= length))
        if not bad.size:
            continue
        shown = ", ".join(str(i) for i in bad[:limit]) + (", ..." if bad.size > limit else "")
        fin = r[np.isfinite(r)]
        largest = f"; largest RMS {fin.max():.3g} m" if fin.size else ""
        out.append({"stage": "RMS and velocity", "run": f"{model} reduced",
                    "summary": f"{bad.size} of {r.size} realisations {DIVERGED}: RMS of the "
                    f"balancing error beyond L = {length:.3g} m (the stick would have fallen; "
                    f"the linear model goes on): realisations {shown}{largest}",
                    "realizations": bad.tolist()})  # fmt: skip
    return out


def group_lines(entries: list[dict]) -> list[str]:
    """The run's divergence list as one line per stage.

    Entries marked ``"intended": True`` (runs that leave the small-angle regime on
    purpose, such as the amplitude scan looking for the breakdown) share one
    line per stage, which says so; the others are listed per stage, each run
    with its summary.
    """
    by: dict[tuple[str, bool], list[dict]] = {}
    for e in entries:
        by.setdefault((e["stage"], bool(e.get("intended"))), []).append(e)
    lines = []
    for (stage, intended), ev in by.items():
        if intended:
            why = re.search(r"\(intended: ([^)]*)\)", ev[0]["summary"])
            parts = [f"{e['run']} {re.sub(r' ?[(]intended:[^)]*[)]', '', e['summary'])}"
                     for e in ev]  # fmt: skip
            lines.append(f"{stage}, intended ({why.group(1) if why else 'on purpose'}), "
                         f"{len(ev)} runs: " + "; ".join(parts))  # fmt: skip
        elif len(ev) == 1:
            lines.append(f"{stage}, {ev[0]['run']}: {ev[0]['summary']}")
        else:
            lines.append(f"{stage}, {len(ev)} runs: "
                         + "; ".join(f"{e['run']}: {e['summary']}" for e in ev))  # fmt: skip
    return lines
