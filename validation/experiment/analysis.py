"""Per-trial tau_hat and RMS, per subject; the paper's Tables STCC and RMS (section 4.3).

For every trial and every stick i:

* tau_hat: the first dominant peak (:func:`validation.checks.metrics.first_dominant_peak`)
  of the STCC R(x_T', x_M'; tau) (paper eq. (8); R(q_T', q_Mi') coupled),
  averaged over the trial's windows (window Dt = 5 s as in paper section 3.3,
  lags 0 .. 0.5 s, a window every 1 s; windows whose R is not finite at some
  lag, e.g. a motionless stretch, are left out of the average).  A peak must
  exceed the white-noise level of the average, 3/sqrt(samples of the trial)
  (:func:`validation.checks.metrics.stcc_significance`).  At 50 Hz tau_hat is a
  multiple of 0.02 s, as the paper's values are.
* RMS of the balancing error Dx or Dq_i over the trial (:func:`validation.checks.metrics.rms`),
  in model units and in pixels (1 unit = 1199/6 px).  The paper does not state
  the unit of its RMS values (2.0 .. 6.1); their size is that of screen
  pixels (ours are ~0.1 in model units, ~20 px), so the report sets them
  beside our pixels, never beside model units.

Every recording is kept: two recordings of the same (mode, subject, trial
index) are both shown and listed as duplicates (:func:`duplicates`).  Trials
that did not end by themselves (by time or a line out of range) -- aborted,
disconnected, stopped with the server, or never finalised (:data:`INCOMPLETE`)
-- are shown but left out of averages and ellipses unless asked for.

The velocities are the recorded ones: the tip's from the model, the lower
end's the backward difference of the mouse over one frame.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from cipcore import Trajectory
from cipcore.models import MODEL_NAMES
from validation.checks import metrics
from validation.experiment.recording import find_trials, load_trial
from validation.experiment.screen import UNIT_PER_PX

#: end reasons of trials cut short from outside; left out of averages unless asked for
INCOMPLETE = ("abort", "disconnect", "server_stop", "unfinalised")
#: units of the per-trial quantities
UNITS = {"tau_hat": "s", "rms": "model units", "rms_px": "px"}
#: which of the paper's Tables a quantity is compared with (same unit only)
PAPER_QUANTITY = {"tau_hat": "tau_hat", "rms_px": "rms"}

STCC_WINDOW = 5.0
STCC_MAX_LAG = 0.5
STCC_STRIDE = 1.0
#: windows where a velocity's standard deviation is below this (units/s, i.e. 2e-4 px/s,
#: far below any mouse motion) are motionless: their R is rounding noise and is left out
MOTION_FLOOR = 1e-6

#: Paper Tables STCC and RMS, pair (A, B), trials 1..5.
PAPER_AB = {
    "tau_hat": {
        ("single", "A"): [0.12, 0.14, 0.14, 0.12, 0.14],
        ("single", "B"): [0.14, 0.12, 0.14, 0.14, 0.14],
        ("coupled", "A"): [0.12, 0.12, 0.12, 0.12, 0.16],
        ("coupled", "B"): [0.18, 0.16, 0.16, 0.18, 0.16],
    },
    "rms": {
        ("single", "A"): [2.4, 2.9, 3.8, 5.5, 3.5],
        ("single", "B"): [4.9, 4.9, 5.8, 5.0, 6.1],
        ("coupled", "A"): [2.9, 3.5, 2.4, 3.9, 2.4],
        ("coupled", "B"): [2.4, 2.8, 2.6, 2.7, 2.0],
    },
}
PAPER_AB_AVERAGE = {
    "tau_hat": {("single", "A"): 0.132, ("single", "B"): 0.136,
                ("coupled", "A"): 0.128, ("coupled", "B"): 0.168},
    "rms": {("single", "A"): 3.62, ("single", "B"): 5.34,
            ("coupled", "A"): 3.02, ("coupled", "B"): 2.50},
}  # fmt: skip


@dataclass
class StickResult:
    """One subject in one trial."""

    file: str
    mode: str
    subject: str
    stick: int
    trial_index: int
    pair: str
    end: str
    duration: float
    tau_hat: float
    rms: float
    rms_px: float
    stcc_peak: float

    @property
    def complete(self) -> bool:
        """Ended by itself (time, or a line out of range), not cut short from outside."""
        return self.end not in INCOMPLETE

    def as_dict(self) -> dict:
        return {**asdict(self), "complete": self.complete}


def mean_stcc(
    tip_velocity: np.ndarray,
    base_velocity: np.ndarray,
    dt: float,
    window: float = STCC_WINDOW,
    max_lag: float = STCC_MAX_LAG,
    stride: float = STCC_STRIDE,
) -> tuple[np.ndarray, np.ndarray, int]:
    """R(x_T', x_M'; lag) averaged over the windows where it is finite.

    Each window is computed on its own stretch of the series (window + max_lag)
    with :func:`validation.checks.metrics.stcc`, so that the running sums of one
    window never mix with the amplitudes of another (a trial whose motion
    grows or decays by orders of magnitude keeps every window exact).
    Windows in which either velocity stands still (standard deviation below
    :data:`MOTION_FLOOR`) are left out with the non-finite ones.
    Returns lags (s), the mean R (NaN if no window qualifies) and the number
    of windows averaged.
    """  # fmt: skip
    x = np.asarray(tip_velocity, dtype=float)
    y = np.asarray(base_velocity, dtype=float)
    w, lmax, step = round(window / dt), round(max_lag / dt), max(1, round(stride / dt))
    curves = []
    lags = np.arange(lmax + 1) * dt
    for start in range(0, x.size - w - lmax + 1, step):
        seg = slice(start, start + w + lmax)
        if min(x[seg].std(), y[seg].std()) < MOTION_FLOOR:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            _, lags, r = metrics.stcc(x[seg], y[seg], dt, window, max_lag, window)
        if np.all(np.isfinite(r[0])):
            curves.append(r[0])
    if not curves:
        return lags, np.full(lags.shape, np.nan), 0
    return lags, np.mean(curves, axis=0), len(curves)


def trial_tau_hat(lags: np.ndarray, r_mean: np.ndarray, n_samples: int) -> float:
    """First dominant peak of the window-averaged STCC (s), NaN when none is significant.

    The average over a trial of ``n_samples`` samples is significant above
    3/sqrt(n_samples), the white-noise level of a correlation over the whole trial.
    """
    if not np.isfinite(r_mean).any():
        return float("nan")
    sig = metrics.stcc_significance(n_samples)
    return float(metrics.first_dominant_peak(r_mean, lags, significance=sig))


def analyse_trial(traj: Trajectory, name: str = "") -> list[StickResult]:
    """tau_hat and RMS of every stick of one trial (module docstring)."""
    dt = traj.sample_interval
    a = traj.attrs
    out = []
    subjects = a["subjects"]
    for i, subject in enumerate(subjects):
        vt = traj["tip_velocity"][0, :, i]
        vm = traj["base_velocity"][0, :, i]
        e = traj["balancing_error"][0, :, i]
        if vt.size * dt >= STCC_WINDOW + STCC_MAX_LAG:
            lags, r, _ = mean_stcc(vt, vm, dt)
            th = trial_tau_hat(lags, r, vt.size)
            peak = float(np.nanmax(r)) if np.isfinite(r).any() else float("nan")
        else:
            th = peak = float("nan")
        rm = float(metrics.rms(e))
        out.append(StickResult(
            file=name, mode=a["mode"], subject=subject, stick=i + 1,
            trial_index=int(a["trial_index"]), pair="-".join(a["pair"]) if a.get("pair") else "",
            end=a["end"]["reason"], duration=float(traj.time[-1]) if traj.time.size else 0.0,
            tau_hat=th, rms=rm, rms_px=rm / UNIT_PER_PX, stcc_peak=peak,
        ))  # fmt: skip
    return out


def analyse_directory(directory: str | Path) -> tuple[list[StickResult], dict[str, Trajectory]]:
    """Every trial in ``directory``: per-stick results and the trajectories by file name."""
    results, trajs = [], {}
    for path in find_trials(directory):
        traj = load_trial(path)
        trajs[path.name] = traj
        results.extend(analyse_trial(traj, path.name))
    return results, trajs


def table(results: list[StickResult], quantity: str, include_incomplete: bool = False) -> dict:
    """Table STCC (``quantity="tau_hat"``) or RMS (``"rms"``/``"rms_px"``).

    Returns {(mode, subject): {"trials": {index: [value, ...]}, "ends": {index:
    [end reason, ...]}, "used": {index: [in the average?, ...]}, "average":
    mean over the finite values used, "std": sample standard deviation, "n":
    values used, "excluded": incomplete trials left out}}; every recording
    keeps its value (duplicates of an index are a list of several), in file
    order; rows ordered single then coupled, subjects by label.
    """
    rows: dict[tuple[str, str], dict] = {}
    for r in sorted(results, key=lambda r: (r.mode != "single", r.subject, r.trial_index)):
        row = rows.setdefault((r.mode, r.subject), {"trials": {}, "ends": {}, "used": {}})
        use = include_incomplete or r.complete
        for key, v in (("trials", getattr(r, quantity)), ("ends", r.end), ("used", use)):
            row[key].setdefault(r.trial_index, []).append(v)
    for row in rows.values():
        pairs = [(x, u) for k in row["trials"] for x, u in zip(row["trials"][k], row["used"][k],
                                                               strict=True)]  # fmt: skip
        v = np.array([x for x, u in pairs if u and np.isfinite(x)])
        row["n"] = int(v.size)
        row["excluded"] = sum(not u for _, u in pairs)
        row["average"] = float(v.mean()) if v.size else float("nan")
        row["std"] = float(v.std(ddof=1)) if v.size > 1 else float("nan")
    return rows


def duplicates(results: list[StickResult]) -> list[dict]:
    """Recordings sharing (mode, subject, trial index): each group with its files."""
    groups: dict[tuple[str, str, int], list[str]] = {}
    for r in results:
        groups.setdefault((r.mode, r.subject, r.trial_index), []).append(r.file)
    return [{"mode": m, "subject": s, "trial_index": k, "files": files}
            for (m, s, k), files in sorted(groups.items()) if len(files) > 1]  # fmt: skip


def condition_ellipses(
    results: list[StickResult], include_incomplete: bool = False
) -> dict[str, dict]:
    """Mean and standard deviation of (tau_hat, RMS in model units) per condition
    (Fig. 16); incomplete trials left out unless ``include_incomplete``."""
    out = {}
    for mode in MODEL_NAMES:
        pts = np.array([(r.tau_hat, r.rms) for r in results
                        if r.mode == mode and (include_incomplete or r.complete)])  # fmt: skip
        pts = pts[np.all(np.isfinite(pts), axis=1)] if pts.size else pts
        if len(pts) == 0:
            continue
        sd = pts.std(axis=0, ddof=1) if len(pts) > 1 else np.full(2, np.nan)
        out[mode] = {"n": len(pts), "mean_tau_hat": float(pts[:, 0].mean()),
                     "mean_rms": float(pts[:, 1].mean()), "sd_tau_hat": float(sd[0]),
                     "sd_rms": float(sd[1])}  # fmt: skip
    return out
