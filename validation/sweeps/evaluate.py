"""Metric evaluation: the study's metrics at one grid point (pure; runs in a worker)."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from cipcore.registry import REFERENCE, get_engine
from validation.checks import metrics as mt
from validation.checks.divergence import divergence_times, pendulum_length, trajectory_events
from validation.profiles import TRAJECTORY_WINDOW
from validation.sweeps.mapping import point_params
from validation.sweeps.study import Study, point_seed

SERIES_FIELDS = ("balancing_error", "tip_velocity", "base_velocity")


def evaluate_point(
    study_dict: dict, point: dict[str, Any], threads: int = 1, gain: dict | None = None
) -> dict[str, Any]:
    """Compute the study's metrics at one grid point.

    Besides the metrics, every point records ``diverged`` (1 when a realisation
    diverged: non-finite, an engine stop, a fallen pole; see
    :mod:`validation.checks.divergence`) and ``divergence_time`` (s, per realisation,
    NaN where none).  ``gain`` is the point's target gain
    (:func:`validation.sweeps.gains.point_gains`: ``beta_star`` and its 95 %
    interval, 1/s^2), recorded with the point and used as its beta.
    """
    study = Study(**study_dict)
    engine = get_engine(study.engine)
    rigid = engine.capabilities.rigid_body
    model = study.model_of(point)
    params, phys, amplitude = point_params(study, point, gain["beta_star"] if gain else None)
    seed = point_seed(study, point)
    n, dur = study.realizations, study.duration
    out: dict[str, Any] = {"seed": seed, **(gain or {})}
    need_series = set(study.metrics) & {"rms", "max_angle", "agreement", "tau_hat", "slopes"}
    if need_series:
        kw: dict[str, Any] = {"amplitude": amplitude, "decimate": study.decimate,
                              "threads": threads}  # fmt: skip
        fields = SERIES_FIELDS
        if rigid:
            kw["physical"] = phys
            fields = (*fields, "angle")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # recorded below, per realisation
            tr = engine.simulate(model, params, dur, n, seed, fields=fields, **kw)
        out.update(trajectory_metrics(study, params, amplitude, seed, tr, threads, model=model))
    if "lambda1" in study.metrics:
        kw = {"physical": phys} if rigid else {}
        res = engine.lyapunov(model, params, dur, n, seed, threads=threads, **kw)
        out["lambda1"] = res.per_realization.tolist()
    return {k: nan_to_none(v) for k, v in out.items()}


def trajectory_metrics(
    study: Study,
    params,
    amplitude: float,
    seed: int,
    tr,
    threads: int = 1,
    model: str | None = None,
) -> dict[str, Any]:
    """The study's time-series metrics of one point's trajectory ``tr`` (any engine).

    ``diverged`` / ``divergence_time`` (see :func:`evaluate_point`), and those of
    ``rms`` (log10 of the RMS balancing error in m), ``max_angle`` (rad),
    ``agreement`` (relative L2 distance to the reduced reference under the same
    noise over the trajectory window), ``slope_low`` / ``slope_high`` (two power
    laws of the spectrum, with bootstrap SEs ``slope_low_se`` /
    ``slope_high_se``) that the study asks for, and for ``tau_hat`` three
    numbers per realisation from the STCC R(x_T', x_M'; tau)(t) of the tip and
    cart velocities (paper eq. (8), Figs. 8, 9), with the study's ``[stcc]``
    window, lags, dominance and significance:

    * ``tau_hat``: the median over windows of the first dominant significant
      peak lag (s), over the windows that have one.  It estimates the typical
      reaction lag *when the velocities are clearly coupled*; windows without a
      peak do not count, so read it beside
    * ``tau_hat_fraction``: the fraction of windows with such a peak;
    * ``tau_hat_avg``: the lag (s) of the largest value of the STCC averaged
      over all windows: the lag of the strongest average coupling, every window
      counting (it follows the delay tau where the median peak may not).

    An engine run that stopped early (a non-finite state) is measured over what it
    recorded: ``agreement`` over the span it shares with the reference, ``tau_hat`` and
    the slopes NaN where it holds no STCC window (window + largest lag) or no Welch
    segment (a quarter of the duration).
    """
    model = model or study.model
    n, dur = study.realizations, study.duration
    out: dict[str, Any] = {}
    events = trajectory_events(tr, pendulum_length(params))
    out["diverged"] = any(e.kind == "diverged" for e in events)
    out["divergence_time"] = divergence_times(events, n, int(tr.attrs.get(
        "first_realization", 0) or 0))  # fmt: skip
    e = tr["balancing_error"][..., 0].astype(float)
    dt = tr.sample_interval
    if "rms" in study.metrics:
        with np.errstate(over="ignore", invalid="ignore"):
            out["rms"] = np.log10(mt.rms(e)).tolist()
    if "max_angle" in study.metrics:
        out["max_angle"] = list(tr.attrs["max_abs_angle"])
    if "agreement" in study.metrics:
        ref = get_engine(REFERENCE).simulate(
            model, params, min(dur, TRAJECTORY_WINDOW), n, seed, amplitude=amplitude,
            decimate=study.decimate, fields=("balancing_error",), threads=threads,
        )  # fmt: skip
        k = min(ref.time.size, tr.time.size)  # an engine run that stopped: its span
        ef = tr["balancing_error"][:, :k, 0].astype(float)
        er = ref["balancing_error"][:, :k, 0]
        out["agreement"] = mt.relative_l2(ef, er, axis=1).tolist()
    held = tr.time.size * dt  # s recorded: less than the duration where an engine run stopped
    if "tau_hat" in study.metrics:
        out.update(stcc_lag_metrics(tr, study.stcc, n, held))
    if "slopes" in study.metrics and held < dur / 4:  # not one Welch segment
        for name in ("slope_low", "slope_high", "slope_low_se", "slope_high_se"):
            out[name] = float("nan")
    elif "slopes" in study.metrics:
        f, sp = mt.power_spectrum(e, dt, segment=dur / 4)
        fit = mt.fit_two_power_laws(f, sp, 8.0 / dur, 20.0, n_bins=16, n_bootstrap=50)
        out["slope_low"] = fit.slope_low
        out["slope_high"] = fit.slope_high
        out["slope_low_se"] = fit.slope_low_se
        out["slope_high_se"] = fit.slope_high_se
    return out


def stcc_lag_metrics(tr, st: dict[str, Any], n: int, held: float) -> dict[str, list]:
    """``tau_hat``, ``tau_hat_fraction`` and ``tau_hat_avg`` per realisation
    (:func:`trajectory_metrics`) with the study's ``[stcc]`` table ``st``; NaN where the
    ``held`` s of the run hold no window (window + largest lag: an engine run that
    stopped)."""
    if held < st["window"] + st["max_lag"]:
        return {name: [float("nan")] * n for name in ("tau_hat", "tau_hat_fraction", "tau_hat_avg")}
    dt = tr.sample_interval
    vt, vb = tr["tip_velocity"][..., 0], tr["base_velocity"][..., 0]
    t, lags, r = mt.stcc(vt, vb, dt, st["window"], st["max_lag"], st["stride"])
    # per-window level from the effective number of independent samples (Bartlett)
    sig = (mt.stcc_significance_bartlett(vt, vb, dt, t, st["window"], st["significance_z"])
           if st["significance_z"] > 0 else 0.0)  # fmt: skip
    th = mt.first_dominant_peak(r, lags, st["dominance"], sig)
    out: dict[str, list] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN: no dominant peak
        out["tau_hat"] = np.nanmedian(th, axis=-1).tolist()
        out["tau_hat_fraction"] = np.isfinite(th).mean(axis=-1).tolist()
        avg = np.nanmean(r, axis=-2)  # (realisations, lags)
    out["tau_hat_avg"] = [float(lags[np.nanargmax(a)]) if np.isfinite(a).any()
                          else float("nan") for a in avg]  # fmt: skip
    return out


def nan_to_none(v):
    """NaN and infinities (alone or in a list) as None, for JSON point files."""
    if isinstance(v, list):
        return [None if isinstance(x, float) and not np.isfinite(x) else x for x in v]
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v
