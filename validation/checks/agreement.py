"""Full (a rigid-body engine) vs reduced model under the same noise draws: metrics and verdicts.

Each function runs the engine under validation (any rigid-body engine of
:mod:`cipcore.registry`, ``engine=``, MuJoCo by default) and the reduced model
with one seed, computes a metric per realisation and returns
:class:`validation.checks.stats.Check` objects whose tolerances follow the rules in
:mod:`validation.checks.stats`.
"""

from __future__ import annotations

import warnings
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TypedDict, Unpack

import numpy as np

from cip.model import small_angle_limit
from cip.simulate import DivergenceWarning
from cipcore.models import MODEL_NAMES, get_model
from cipcore.noise import GainNoise, StackedNoise
from cipcore.params import ParameterError
from cipcore.registry import get_engine
from cipcore.results import min_lyapunov_duration
from cipcore.scenario import EngineTarget, Execution, Recording, Scenario
from cipcore.schema import Trajectory
from reduced import BalanceParams, lyapunov, simulate
from validation.checks import metrics, refinement
from validation.checks.closed_loop import closed_loop_check
from validation.checks.metrics import SeriesMetrics
from validation.checks.rod import rod_check
from validation.checks.stats import (
    FAIL,
    INCONCLUSIVE,
    NOT_APPLICABLE,
    PASS,
    Check,
    ci_overlap,
    paired_equivalence,
    paired_shift,
    se_agreement,
    t_half_width,
    tost_status,
    worst,
)
from validation.profiles import PAPER_BETA, TRAJECTORY_WINDOW, Profile

SERIES_FIELDS = ("balancing_error", "balancing_error_velocity", "tip_velocity", "base_velocity")


class TargetKeywords(TypedDict, total=False):
    """The engine under validation as the run's stages (:func:`lyapunov_checks`,
    :func:`series_checks`, :func:`amplitude_scan`) take it: the fields of
    :class:`cipcore.scenario.EngineTarget` (:meth:`~cipcore.scenario.EngineTarget.as_kwargs`),
    each defaulting as there (MuJoCo on the shipped files with their integrators).

    engine : a registered rigid-body engine.  integrator : MuJoCo's integrator name run
    instead of the files'.  files : model name -> a user's MJCF file.
    """

    files: Mapping[str, str] | None
    engine: str
    integrator: str | None


def lyapunov_checks(
    profile: Profile, threads: int | None, **target: Unpack[TargetKeywords]
) -> tuple[list[Check], dict]:
    """lambda1 of both engines at each gain of the profile (CI-overlap rule).

    Where the profile switches the multifidelity allocation on
    (``Profile.mf_engine_realizations``), the engine's lambda1 is estimated from that
    many engine realisations with its exact twin's lambda1
    (:func:`reduced.twin_lyapunov.lyapunov_twin`, the same noise and initial deviation)
    over ``mf_twin_realizations`` as the control variate, and the reduced model runs
    those too (:func:`lambda1_multifidelity`); plain sampling where that interval would
    be wider than plain sampling's.
    """
    from cip.mjcf_params import read_mapping

    t = EngineTarget(**target)
    checks, rows = [], []
    precision = rigid_engine(t.engine).capabilities.precision
    epsilon = profile.lyapunov_epsilon(precision)
    note = lyapunov_epsilon_note(profile, precision)
    for model, gains in profile.lyapunov_gains.items():
        m = model_file(model, t.files, t.integrator)
        mapping = read_mapping(m)
        body = {"physical": mapping.physical(), "mj_model": m, "epsilon": epsilon,
                "threads": threads}  # fmt: skip
        scenarios = [Scenario(model, BalanceParams(beta=beta), profile.lyapunov_duration,
                              profile.lyapunov_realizations,
                              profile.seed_for("lyapunov", model, beta))
                     for beta in gains]  # fmt: skip
        mf = (lambda1_multifidelity(scenarios, t.engine, mapping, profile, body, note)
              if profile.mf_engine_realizations else [""] * len(scenarios))  # fmt: skip
        for scn, got in zip(scenarios, mf, strict=True):
            if not isinstance(got, str):
                checks.append(got[0])
                rows.append(got[1])
                continue
            fallback = f"; {got}" if got else ""
            p, seed = scn.params, scn.seed
            red = lyapunov(scn, execution=Execution(threads=threads))
            full = rigid_engine(t.engine).lyapunov(model, p, scn.duration, scn.realizations,
                                                   seed, **body)  # fmt: skip
            rows.append(
                {"model": model, "beta": p.beta, "full": full.as_dict(), "reduced": red.as_dict()}
            )
            details = (f"{profile.lyapunov_realizations} realisations x "
                       f"{profile.lyapunov_duration:g} s, seed {seed}, same noise in both "
                       f"engines, Benettin deviation {epsilon:g} m{note}{fallback}")  # fmt: skip
            checks.append(lambda1_check(model, p.beta, full.lambda1, full.ci95, full.sem, red,
                                        details))  # fmt: skip
            checks[-1] = diverged_lambda1(checks[-1], full.divergence())
    return checks, {"lyapunov": rows}


def lambda1_check(model: str, beta: float, value: float, ci95, se: float, red,
                  details: str, **extra) -> Check:  # fmt: skip
    """``agreement.lambda1.<model>.beta=<beta>``: the engine's lambda1 (``value``, its 95 %
    interval ``ci95`` and standard error ``se``, 1/s) against the reduced model's ``red``
    (a :class:`cipcore.results.LyapunovResult`) by the CI-overlap rule
    (:func:`validation.checks.stats.ci_overlap`); ``extra`` joins the engine's values."""
    status, v = ci_overlap(value, ci95, red.lambda1, red.ci95)
    return Check(
        name=f"agreement.lambda1.{model}.beta={beta:g}", status=status,
        values={"full": {"value": value, "ci95": list(ci95), "se": se, **extra},
                "reduced": {"value": red.lambda1, "ci95": list(red.ci95), "se": red.sem}, **v},
        tolerance="95% CIs overlap: pass if |difference| <= larger half-width, "
        "fail if the intervals are disjoint", details=details,
    )  # fmt: skip


def diverged_lambda1(check: Check, divergence: str | None) -> Check:
    """``check`` failed where the engine's Benettin run went non-finite (``divergence``,
    :meth:`cipcore.results.LyapunovResult.divergence`; None: ``check`` as it is).

    A deviation renormalised to epsilon every tau stays in the linear regime, where a
    correct engine's state is finite at every step: a non-finite one is the engine's
    fault, not an exponent to compare (its lambda1 is +inf, and the CI-overlap rule
    would call a non-finite mean inconclusive).
    """
    if divergence is None:
        return check
    return replace(check, status=FAIL, details=f"{check.details}; {divergence}: the exponent "
                   "is +inf, a correct engine's state stays finite at this deviation")  # fmt: skip


def engine_duration(profile: Profile, params: BalanceParams) -> float:
    """The lambda1 check's engine duration (s) under the multifidelity allocation:
    ``profile.mf_engine_duration`` (0: ``lyapunov_duration``); a one-line ParameterError
    outside [the shortest Benettin run at tau, ``lyapunov_duration``]."""
    full = profile.lyapunov_duration
    short = profile.mf_engine_duration or full
    shortest = min_lyapunov_duration(params.tau, params.dt)
    if not shortest <= short <= full:
        raise ParameterError(f"mf_engine_duration must be 0 or in [{shortest:g}, "
                             f"lyapunov_duration = {full:g}] s, got {short:g}")  # fmt: skip
    return float(short)


def lambda1_multifidelity(
    scenarios: list[Scenario], engine: str, mapping, profile: Profile, body: dict, note: str
) -> list[tuple[Check, dict] | str]:
    """Each gain's lambda1 check of one model with the engine on
    ``profile.mf_engine_realizations``.

    The engine's per-realisation exponents y (n of them) and its twin's x (m =
    max(mf_twin_realizations, lyapunov_realizations), the first n paired: same noise,
    same initial deviation, same norm) give the two-model MFMC estimate of the
    engine's lambda1 with alpha = 1, mean_n(y - x) + mean_m(x)
    (:func:`validation.checks.multifidelity.mfmc_estimate`); the
    reduced model runs the m realisations.  ``scenarios`` hold the model's gains in the
    plain allocation (lyapunov_realizations each, their own seeds); the engine runs the n
    realisations of every gain in one call (a :class:`cipcore.noise.StackedNoise` with a
    gain per realisation: each realisation's exponent is the one it has alone), so a
    batched engine steps once for all gains and the threads share G x n realisations.
    The engine and the twin's n pairs run :func:`engine_duration` (``mf_engine_duration``,
    shorter than ``lyapunov_duration``): the paired difference engine - twin is the same
    over 50 s as over 200 s to 1e-4 1/s while the check's interval is about 1e-2
    (docs/performance.md), and the estimate is mean_n(engine - twin over it) + mean_m(twin
    over the whole duration) (:func:`validation.checks.multifidelity.mfmc_estimate`'s
    ``x_paired``).  ``mapping`` is the model file's
    (:func:`cip.mjcf_params.read_mapping`), ``body`` the engine's keywords.  Returns per
    gain either why, a line for the plain check's details, where the estimate's interval
    is wider than plain sampling's would be at the same spread (the twin does not follow
    the engine), or (the check, the stage's row).

    The function is long because one engine call serves every gain, and each gain's check
    is then built from its part of the batch, its twin's two runs and the reduced model's.
    """
    import time

    from reduced.twin import TwinParams
    from reduced.twin_lyapunov import lyapunov_twin
    from validation.checks import multifidelity as mfe

    first = scenarios[0]
    model, duration, n_plain = first.model, first.duration, first.realizations
    n, m = profile.mf_engine_realizations, max(profile.mf_twin_realizations, n_plain)
    if not mfe.MIN_PAIRED <= n < n_plain:
        raise ParameterError(f"mf_engine_realizations must be 0 or in [{mfe.MIN_PAIRED}, "
                             f"lyapunov_realizations = {n_plain}), got {n}")  # fmt: skip
    short = engine_duration(profile, first.params)
    execution = Execution(threads=body["threads"])
    twin = TwinParams(**rigid_engine(engine).twin_terms(mapping))
    nc = get_model(model).n_controllers
    noise = StackedNoise([GainNoise(s.seed, n, nc) for s in scenarios])
    betas = np.repeat([s.params.beta for s in scenarios], n)
    t0 = time.perf_counter()
    batch = rigid_engine(engine).lyapunov(model, first.params, short, len(betas), first.seed,
                                          noise=noise, betas=betas, **body)  # fmt: skip
    engine_s = (time.perf_counter() - t0) / len(betas)  # per engine realisation
    out: list[tuple[Check, dict] | str] = []
    for g, scenario in enumerate(scenarios):
        p, seed = scenario.params, scenario.seed
        full = batch.part(slice(g * n, (g + 1) * n), p.beta, seed)
        t1 = time.perf_counter()
        cheap = replace(scenario, realizations=m)
        red = lyapunov(cheap, execution=execution)
        if full.diverged_at is not None:  # no estimate to make: the engine failed
            details = (f"multifidelity: engine {n} x {short:g} s, seed {seed}, Benettin "
                       f"deviation {body['epsilon']:g} m{note}; reduced model {m} x "
                       f"{duration:g} s")  # fmt: skip
            check = lambda1_check(model, p.beta, full.lambda1, full.ci95, full.sem, red, details)
            out.append((diverged_lambda1(check, full.divergence()),
                        {"model": model, "beta": p.beta, "full": full.as_dict(),
                         "reduced": red.as_dict()}))  # fmt: skip
            continue
        tw = lyapunov_twin(cheap, twin, epsilon=body["epsilon"], execution=execution)
        w = engine_s * duration / short / max((time.perf_counter() - t1) / m, 1e-9)
        # the twin's pairs over the engine's duration (the first n of its m, shorter)
        pairs = tw if short == duration else lyapunov_twin(
            replace(scenario, realizations=n, duration=short), twin, epsilon=body["epsilon"],
            execution=execution)  # fmt: skip
        # alpha fixed at 1 (engine - twin over n, plus the twin over m): the twin models
        # the engine itself, alpha* = 1 where it follows it, and 3 pairs cannot estimate
        # alpha (an unrelated control reached rho = -0.9995 at 3 pairs); with alpha given,
        # the residual's variance is unbiased with n - 1 degrees of freedom
        paired = None if pairs is tw else pairs.per_realization
        est = mfe.mfmc_estimate(full.per_realization, tw.per_realization, alpha=1.0,
                                x_paired=paired)  # fmt: skip
        plain = mfe.plain_half_width_at(tw.per_realization, n_plain)
        if not est.half_width <= plain:
            out.append(f"multifidelity not used: with the engine on {n} and its twin on {m} "
                       f"realisations the interval would be {est.half_width / plain:.3g} times "
                       f"plain sampling's (rho {est.rho:.6g}), so the engine ran "
                       f"{n_plain}")  # fmt: skip
            continue
        same = "" if short == duration else f", paired with its twin over the same {short:g} s"
        details = (
            f"multifidelity: engine {n} x {short:g} s, its {twin.integrator} twin and the "
            f"reduced model {m} x {duration:g} s (same noise, nested; plain sampling: {n_plain} "
            f"x {duration:g} s; the engine ran the {len(scenarios)} gains' realisations in one "
            f"batch{same}), seed {seed}, Benettin deviation {body['epsilon']:g} m{note}, 1 - rho "
            f"{1 - est.rho:.2g}, half-width {est.half_width / plain:.3g} x plain sampling's, "
            f"cost ratio engine : twin + reduced w = {w:.3g} (measured)"
        )
        mf = {"multifidelity": est.as_dict(), "n": n, "n_twin": m,
              "twin": {"value": tw.lambda1, "ci95": list(tw.ci95), "se": tw.sem}}  # fmt: skip
        check = lambda1_check(model, p.beta, est.mean, est.ci95, est.se, red, details, **mf)
        engine_row = {**full.as_dict(), "lambda1": est.mean, "ci95": list(est.ci95),
                      "multifidelity": est.as_dict()}  # fmt: skip
        out.append((check, {"model": model, "beta": p.beta, "full": engine_row,
                            "reduced": red.as_dict(), "twin": tw.as_dict()}))  # fmt: skip
    return out


def planned_samples(tr: Trajectory) -> int:
    """The samples ``tr`` was planned to record (attrs ``duration``, ``dt``, ``decimate``);
    an engine run that stopped at a non-finite state holds fewer."""
    a = tr.attrs
    return -(-round(float(a["duration"]) / float(a["dt"])) // int(a.get("decimate", 1)))


def stop_note(tr: Trajectory) -> str:
    """``""``, or where an engine run stopped early (``attrs["diverged"]``) a clause for a
    check's details: when, why, and that its metrics have no estimate."""
    d = tr.attrs.get("diverged")
    if not d:
        return ""
    a, b = d["time_window"]
    return (f"; the engine's run stopped between t = {a:.4g} and {b:.4g} s ({d['reason']} in "
            f"realisation {d['realization']}): its metrics have no estimate")  # fmt: skip


def no_estimate(m: SeriesMetrics) -> SeriesMetrics:
    """``m`` with every estimate NaN, its coordinates (band centres, frequencies, STCC
    window times, the fit's frequency range) kept: the shapes of a whole run's metrics."""
    from dataclasses import fields

    def nan(a):
        return np.full(np.shape(a), np.nan)

    fit = m.slopes
    return replace(
        m, log_rms=nan(m.log_rms), band_log_power=nan(m.band_log_power),
        slopes=replace(fit, **{f.name: float("nan") for f in fields(fit)
                               if f.name not in ("fmin", "fmax")}),
        spectrum=(m.spectrum[0], nan(m.spectrum[1])), tau_hat=nan(m.tau_hat),
        tau_hat_median=nan(m.tau_hat_median), fast_fraction=nan(m.fast_fraction),
        log_velocity_sd=nan(m.log_velocity_sd),
    )  # fmt: skip


def series_metrics(tr: Trajectory, profile: Profile, tau: float, segment: float) -> SeriesMetrics:
    """Metrics of controller 1's balancing error and velocities (paper section 3).

    An engine run that stopped early (a non-finite state: ``attrs["diverged"]``, fewer
    samples than planned) has no estimate: every metric NaN (:func:`no_estimate`), with
    the shapes of a whole run's, so that each comparison with it is inconclusive and says
    so, and its own checks (the trajectory, the divergence summary) say why.
    """
    n = planned_samples(tr) if tr.attrs.get("diverged") else tr.time.size
    if tr.time.size < n:  # the shapes from the run padded with zeros, every value NaN
        pad = {k: np.concatenate([v, np.zeros((v.shape[0], n - v.shape[1], *v.shape[2:]),
                                              v.dtype)], axis=1)
               for k, v in tr.data.items()}  # fmt: skip
        whole = Trajectory(time=np.arange(n) * tr.sample_interval, data=pad, attrs=tr.attrs)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return no_estimate(series_metrics(whole, profile, tau, segment))
    dt = tr.sample_interval
    e = tr["balancing_error"][..., 0].astype(float)
    f, s = metrics.power_spectrum(e, dt, segment=segment)
    lo, hi = profile.spectrum_band
    lo = max(lo, 2.0 / segment)
    centres, bands = metrics.band_log_power(f, s, lo, hi, n_bins=8)
    fit = metrics.fit_two_power_laws(f, s, lo, hi, n_bins=16, n_bootstrap=100, seed=profile.seed)
    vt, vb = tr["tip_velocity"][..., 0], tr["base_velocity"][..., 0]
    t, lags, r = metrics.stcc(
        vt, vb, dt, profile.stcc_window, profile.stcc_max_lag, profile.stcc_stride
    )
    # per-window level from the effective number of independent samples (Bartlett)
    sig = metrics.stcc_significance_bartlett(vt, vb, dt, t, profile.stcc_window)
    th = metrics.first_dominant_peak(r, lags, significance=sig)
    with np.errstate(invalid="ignore"):
        fast = np.nanmean(np.where(np.isfinite(th), th < tau, np.nan), axis=-1)
    return SeriesMetrics(
        log_rms=np.log10(metrics.rms(e)),
        band_log_power=bands,
        band_centres=centres,
        slopes=fit,
        spectrum=(f, s),
        tau_hat=th,
        stcc_times=t,
        tau_hat_median=np.nanmedian(th, axis=-1),
        fast_fraction=fast,
        log_velocity_sd=np.log10(np.std(tr["balancing_error_velocity"][..., 0], axis=-1)),
    )


def trajectory_distance(
    full: Trajectory, red: Trajectory, window: float = TRAJECTORY_WINDOW
) -> float:
    """Relative L2 distance of the balancing errors over [0, window) s, all realisations."""
    k = int(np.searchsorted(full.time, window))
    return metrics.relative_l2(full["balancing_error"][:, :k], red["balancing_error"][:, :k])


def run_pair(
    scenario: Scenario, target: EngineTarget, *, decimate: int, threads: int | None
) -> tuple[Trajectory, Trajectory]:
    """Both engines, same scenario (same parameters and seed): (full, reduced).

    The full model is the model file (``target.files[model]``, a user's ``--mjcf``,
    or the shipped ``models/cip_<model>.xml``, stepped with ``target.integrator``
    where given), its physical parameters read from it, run by ``target.engine``;
    every ``decimate``-th step is recorded.
    """
    run = {"decimate": decimate, "threads": threads}
    return run_full(scenario, target, **run), run_reduced(scenario, **run)


def run_full(
    scenario: Scenario, target: EngineTarget, *, decimate: int, threads: int | None
) -> Trajectory:
    """The engine's half of :func:`run_pair` (the model file run by ``target.engine``)."""
    from cip.mjcf_params import read_mapping

    model = scenario.model
    m = model_file(model, target.files, target.integrator)
    kw = {"amplitude": scenario.amplitude, "decimate": decimate, "threads": threads}
    return rigid_engine(target.engine).simulate(
        model, scenario.params, scenario.duration, scenario.realizations, scenario.seed,
        fields=(*SERIES_FIELDS, "angle"), physical=read_mapping(m).physical(), mj_model=m,
        **kw,
    )  # fmt: skip


def run_reduced(scenario: Scenario, *, decimate: int, threads: int | None) -> Trajectory:
    """The reduced model's half of :func:`run_pair` (the same noise streams)."""
    rec = Recording(decimate=decimate, fields=SERIES_FIELDS)
    return simulate(scenario, recording=rec, execution=Execution(threads=threads))


#: Floor of the full-vs-twin metric differences (log10 units, seconds or fractions):
#: measured at most 2.2e-8 (coupled spectrum bands; 7.7e-12 single) for the quick
#: profile's series (1e-8 m, 8 x 100 s); 1e-6 leaves a factor 45.
TWIN_METRIC_FLOOR = 1e-6

PAIRED_RULE = (
    "paired TOST: 95% CI of the per-realisation full - reduced difference within +- margin, "
    "margin = |twin - reduced| (the known terms, paired mean + 95% half-width) + the paired "
    "95% half-width; inconclusive states the realisations needed"
)


def run_twin(
    scenario: Scenario, target: EngineTarget, *, decimate: int, threads: int | None
) -> Trajectory:
    """The engine's exact twin of the model file under the same noise as :func:`run_pair`."""
    from cip.mjcf_params import read_mapping
    from reduced.twin import TwinParams, simulate_twin

    mapping = read_mapping(model_file(scenario.model, target.files, target.integrator))
    tw = TwinParams(**rigid_engine(target.engine).twin_terms(mapping))
    rec = Recording(decimate=decimate, fields=SERIES_FIELDS)
    return simulate_twin(scenario, tw, recording=rec, execution=Execution(threads=threads))


def bands_check(name: str, bands: list[dict], tolerance: str, details: str) -> Check:
    """``agreement.spectrum_bands.<name>``: one verdict per log-spaced band of the log10 PSD
    (``bands``: each band's ``centre_hz``, ``status`` and values), the worst band decides."""
    return Check(
        name=f"agreement.spectrum_bands.{name}",
        status=worst([b["status"] for b in bands]),
        values={"bands": bands},
        tolerance=tolerance,
        details=f"Welch PSD of the balancing error (Fig. pwsp); {details}",
    )


def compare_series(
    model: str,
    mf: SeriesMetrics,
    mr: SeriesMetrics,
    label: str,
    details: str,
    mt: SeriesMetrics | None = None,
    me: SeriesMetrics | None = None,
) -> list[Check]:
    """Verdicts for RMS, spectrum (bands and slopes), STCC peaks and velocity spread.

    ``mt`` are the exact twin's metrics under the same noise: they set the
    full-vs-reduced margins (the known terms' difference) and each metric is
    also checked against the twin (:func:`validation.checks.stats.paired_shift`).
    ``me`` are the envelope twin's (:func:`validation.checks.conformance.envelope_twin_terms`):
    the known terms enter a margin only up to theirs.

    The function is long because it is the table of the series checks, one entry per metric,
    each with its rule said in place.
    """
    from validation.checks.conformance import BOUNDED_RULE, bounded_margin

    checks = []
    shifts: dict[str, dict] = {}

    def twin_shift(metric: str, a, t) -> None:
        if mt is not None:
            st, v = paired_shift(a, t, TWIN_METRIC_FLOOR)
            shifts[metric] = {"status": st, **v}

    def paired(metric: str, a, b, what: str, t=None, env=None) -> None:
        if t is not None and env is not None:
            status, v = paired_equivalence(a, b, bounded_margin(a, b, t - b, env - b))
        else:
            status, v = paired_equivalence(a, b, expected=None if t is None else t - b)
        twin_shift(metric, a, t)
        checks.append(
            Check(
                name=f"agreement.{metric}.{model}{label}",
                status=status,
                values=v,
                tolerance=PAIRED_RULE if env is None else BOUNDED_RULE,
                details=f"{what}; {details}",
            )
        )

    def tw(name: str):
        return None if mt is None else getattr(mt, name)

    def ev(name: str):
        return None if me is None else getattr(me, name)

    paired("log10_rms", mf.log_rms, mr.log_rms, "log10 RMS of the balancing error (Fig. rms)",
           tw("log_rms"), ev("log_rms"))  # fmt: skip
    bands = []
    for k, fc in enumerate(mr.band_centres):
        tb = None if mt is None else mt.band_log_power[:, k]
        exp = None if tb is None else tb - mr.band_log_power[:, k]
        if exp is not None and me is not None:
            eb = me.band_log_power[:, k] - mr.band_log_power[:, k]
            mg = bounded_margin(mf.band_log_power[:, k], mr.band_log_power[:, k], exp, eb)
            st, v = paired_equivalence(mf.band_log_power[:, k], mr.band_log_power[:, k], mg)
        else:
            st, v = paired_equivalence(
                mf.band_log_power[:, k], mr.band_log_power[:, k], expected=exp
            )
        if tb is not None:
            twin_shift(f"spectrum_band_{k}", mf.band_log_power[:, k], tb)
        bands.append({"centre_hz": float(fc), "status": st, **v})
    checks.append(
        bands_check(
            f"{model}{label}",
            bands,
            "paired TOST per log-spaced band of log10 PSD (margin as for the RMS); worst band "
            "decides",
            details,
        )
    )
    slope_status = []
    sv = {}
    for which in ("slope_low", "slope_high"):
        st, v = se_agreement(
            getattr(mf.slopes, which),
            getattr(mf.slopes, which + "_se"),
            getattr(mr.slopes, which),
            getattr(mr.slopes, which + "_se"),
        )
        slope_status.append(st)
        sv[which] = {
            "full": {"value": getattr(mf.slopes, which), "se": getattr(mf.slopes, which + "_se")},
            "reduced": {
                "value": getattr(mr.slopes, which),
                "se": getattr(mr.slopes, which + "_se"),
            },
            **v,
        }
    checks.append(
        Check(
            name=f"agreement.spectral_slopes.{model}{label}",
            status=worst(slope_status),
            values=sv,
            tolerance="bootstrap standard errors: pass within 2 sigma, fail beyond 3 sigma",
            details=f"two power laws fitted to the mean spectrum (Fig. pwsp); {details}",
        )
    )
    paired(
        "stcc_peak_median",
        mf.tau_hat_median,
        mr.tau_hat_median,
        "median first dominant STCC peak tau_hat of R(x_T', x_M') (Fig. sccpeak)",
        tw("tau_hat_median"),
        ev("tau_hat_median"),
    )
    paired(
        "stcc_fast_fraction",
        mf.fast_fraction,
        mr.fast_fraction,
        "fraction of windows with tau_hat < tau (Fig. sccpeak:pdf)",
        tw("fast_fraction"),
        ev("fast_fraction"),
    )
    paired(
        "log10_velocity_sd",
        mf.log_velocity_sd,
        mr.log_velocity_sd,
        "log10 SD of the velocity error (Fig. velo)",
        tw("log_velocity_sd"),
        ev("log_velocity_sd"),
    )
    if mt is not None:
        for which in ("slope_low", "slope_high"):
            diff = getattr(mf.slopes, which) - getattr(mt.slopes, which)
            ok = abs(diff) <= TWIN_METRIC_FLOOR
            shifts[which] = {"status": PASS if ok else FAIL, "difference": diff}
        checks.append(
            Check(
                name=f"twin.metrics.{model}{label}",
                status=worst([v["status"] for v in shifts.values()]),
                values=shifts,
                tolerance="every metric of the full model equals the exact twin's under the same "
                f"noise: paired mean difference within its 95% CI + {TWIN_METRIC_FLOOR:g} "
                "(agreement.TWIN_METRIC_FLOOR)",
                details=details,
            )
        )
    return checks


#: Why a float32 engine's series runs at Profile.amplitude_float32 (the checks' details say it).
FLOAT32_AMPLITUDE_RULE = (
    "float32 resolves the coupled rod to about l * 6e-8 m, an error against the series that "
    "falls as 1/amplitude, and the rigid body's nonlinear residual grows as amplitude^2: the "
    "largest amplitude on a 1-3-10 grid at which float64 MuJoCo's twin metrics stay within "
    "their floor over the profile's series (quick, 8 x 100 s: 1e-5 m, its spectral slopes "
    "1.5e-6 to 4.6e-6 off at 3e-5 m; paper, 16 x 200 s: 3e-7 m; smoke, 3 x 45 s: 1e-4 m)"
)


def series_amplitude_note(profile: Profile, precision: str) -> str:
    """Why the series runs at its amplitude, where the engine's precision sets it
    (:meth:`validation.profiles.Profile.series_amplitude`); '' at the profile's own."""
    if profile.series_amplitude(precision) == profile.amplitude:
        return ""
    rule = FLOAT32_AMPLITUDE_RULE
    return f" ({precision}'s series amplitude; {profile.amplitude:g} m in float64: {rule})"


#: Why a float32 engine's lambda1 runs at Profile.benettin_epsilon_float32 (the checks say it).
FLOAT32_EPSILON_RULE = (
    "float32 resolves the coupled rod's length (a tendon between tips about 1 m apart) to "
    "about ulp(1 m) = 1.2e-7 m, as large as float64's deviation 1e-7 m: MuJoCo Warp's "
    "lambda1 (coupled, beta 20.5, 3 x 20 s) is -0.45 1/s at 1e-7 m, 0.096 at 1e-6, 0.044 "
    "at 1e-5, 3.3e-3 at 1e-4 and 9.7e-4 at 5e-4 m against float64 MuJoCo's 9.0e-4 (the same "
    "to 3e-9 1/s from 1e-7 to 5e-4 m: linear); at 5e-4 m the angles stay below "
    "epsilon / L = 1.1e-3 rad, sin theta = theta to theta^2 / 6 = 2e-7"
)


def lyapunov_epsilon_note(profile: Profile, precision: str) -> str:
    """Why lambda1 runs at its Benettin deviation, where the engine's precision sets it
    (:meth:`validation.profiles.Profile.lyapunov_epsilon`); '' at the float64 one."""
    if profile.lyapunov_epsilon(precision) == profile.benettin_epsilon:
        return ""
    return (
        f" ({precision}'s deviation; {profile.benettin_epsilon:g} m in float64: "
        f"{FLOAT32_EPSILON_RULE})"
    )


def judged_by_refinement(checks: list[Check]) -> set[str]:
    """The models on which the engine has no exact twin, judged by refinement instead
    (:mod:`validation.checks.refinement`): those whose ``twin.trajectory.<model>`` check
    (:func:`instrument_checks`) is not applicable."""
    return {
        c.name.rsplit(".", 1)[1]
        for c in checks
        if c.name.startswith("twin.trajectory.") and c.status == NOT_APPLICABLE
    }


def series_checks(
    profile: Profile, threads: int | None, **target: Unpack[TargetKeywords]
) -> tuple[list[Check], dict]:
    """Time-series agreement at the paper's gains, small amplitude, and the direct checks.

    Full vs reduced (the paper's model, margins from the known terms) and full vs
    the exact twin (every metric), then :func:`instrument_checks` (twin trajectory
    at 1e-6 m, rod, measured delay, declared model).
    """
    t = EngineTarget(**target)
    checks, data = [], {}
    precision = rigid_engine(t.engine).capabilities.precision
    # the direct checks first (their own seed): they decide each model's tier, which says
    # whether the twin's metrics judge the engine (listed after the series checks)
    direct = instrument_checks(
        profile.seed_for("twin"), profile.series_realizations, threads, target=t
    )
    by_refinement = judged_by_refinement(direct)
    # an engine judged by refinement is compared with the reduced model through the
    # known stepper nearest its observed order (like with like: MuJoCo's RK4 for an order
    # of 2 or more, else Euler), both for the twin under the same noise and the envelope
    nearest = {
        c.name.rsplit(".", 1)[1]: "RK4" if c.values["order"] >= 2 else "Euler"
        for c in direct
        if c.name.startswith("refinement.")
    }
    amplitude = profile.series_amplitude(precision)
    for model, beta in PAPER_BETA.items():
        seed = profile.seed_for("series", model)
        scn = Scenario(model, BalanceParams(beta=beta), profile.series_duration,
                       profile.series_realizations, seed, amplitude)  # fmt: skip
        got = series_model_checks(
            scn, t, profile, threads=threads,
            nearest=nearest.get(model) if model in by_refinement else None, precision=precision,
        )  # fmt: skip
        checks += got[0]
        data[model] = got[1]
    return checks + direct, data


class SeriesOptions(TypedDict):
    """How :func:`series_model_checks` and :func:`multifidelity_series` run one model's series.

    threads : worker threads (None: all cores).  nearest : the MuJoCo integrator of the
    nearest twin for an engine judged by refinement (None: the engine's own exact twin).
    precision : the engine's floating-point type (``capabilities.precision``), which sets
    the series amplitude (:meth:`validation.profiles.Profile.series_amplitude`).
    """

    threads: int | None
    nearest: str | None
    precision: str


def twin_of(model: str, target: EngineTarget, nearest: str | None) -> tuple[EngineTarget, str]:
    """The twin that judges ``target`` on ``model`` and the envelope twin's stepper: MuJoCo
    with the integrator ``nearest`` for an engine judged by refinement, else the engine's
    own exact twin and its stepper (:func:`twin_integrator`)."""
    if nearest:
        return EngineTarget("mujoco", nearest, target.files), nearest
    return target, twin_integrator(model, target.files, target.engine, target.integrator)


def series_model_checks(
    scenario: Scenario, target: EngineTarget, profile: Profile, **options: Unpack[SeriesOptions]
) -> tuple[list[Check], dict]:
    """One model's time-series checks (:func:`series_checks`): full vs reduced and full vs
    its twin, by the multifidelity estimator where the profile switches it on and it pays
    (:func:`multifidelity_series`), else plainly.

    ``scenario`` and ``target`` as :func:`run_pair`'s, every ``profile.decimate``-th
    step recorded on ``options["threads"]`` (:class:`SeriesOptions`).  Returns
    (checks, the stage's data for the model).
    """
    from validation.checks.conformance import run_envelope_twin

    threads, nearest, precision = options["threads"], options["nearest"], options["precision"]
    model, beta, amplitude = scenario.model, scenario.params.beta, scenario.amplitude
    fallback, ran = "", None
    if profile.mf_engine_realizations:  # PlainFallback: the twin does not pay, plain sampling
        got = multifidelity_series(scenario, target, profile, **options)
        if not isinstance(got, PlainFallback):
            return got
        fallback, ran = f"; {got.why}", got.full
    run = {"decimate": profile.decimate, "threads": threads}
    full = ran if ran is not None else run_full(scenario, target, **run)
    red = run_reduced(scenario, **run)
    twin_target, env_integrator = twin_of(model, target, nearest)
    twin = run_twin(scenario, twin_target, **run)
    rec = Recording(decimate=profile.decimate, fields=SERIES_FIELDS)
    env = run_envelope_twin(scenario, recording=rec, threads=threads, integrator=env_integrator)
    mf = series_metrics(full, profile, 0.1, profile.spectrum_segment)
    mr = series_metrics(red, profile, 0.1, profile.spectrum_segment)
    mt = series_metrics(twin, profile, 0.1, profile.spectrum_segment)
    me = series_metrics(env, profile, 0.1, profile.spectrum_segment)
    max_angle = float(np.max(full.attrs["max_abs_angle"]))
    details = (
        f"beta {beta}, amplitude {amplitude:g} m{series_amplitude_note(profile, precision)}, "
        f"{profile.series_realizations} x {profile.series_duration:g} s, seed {scenario.seed}, "
        f"largest |theta| {max_angle:.2g} rad{fallback}{stop_note(full)}"
    )
    series = compare_series(model, mf, mr, "", details, mt, me)
    if nearest:  # the twin's metrics do not judge another discretisation
        series = [not_applicable(c) if c.name.startswith("twin.") else c for c in series]
    data = {"full": full, "reduced": red, "metrics_full": mf, "metrics_reduced": mr}
    return [*series, trajectory_check(model, full, red, details)], data


def trajectory_check(model: str, full: Trajectory, red: Trajectory, details: str) -> Check:
    """``agreement.trajectory.<model>``: the balancing errors within 1 % (relative L2) over
    the first :data:`TRAJECTORY_WINDOW` s, every angle inside the small-angle regime."""
    rel = trajectory_distance(full, red)
    max_angle = float(np.max(full.attrs["max_abs_angle"]))
    return Check(
        name=f"agreement.trajectory.{model}",
        status=PASS if rel < 0.01 and max_angle < small_angle_limit() else FAIL,
        values={"relative_l2": rel, "max_abs_angle": max_angle},
        tolerance="relative L2 distance of the balancing errors < 1% over the first 10 s, "
        "in the small-angle regime",
        details=details,
    )


# ------------------------------------------------------------ multifidelity agreement
#: The multifidelity agreement rule (Profile.mf_engine_realizations > 0).
MF_RULE = (
    "multifidelity paired TOST (validation.checks.multifidelity, two-model MFMC): the full - "
    "reduced difference estimated as [full - twin] over the engine's n realisations + "
    "[twin - reduced] over the twin's m (same noise, nested; alpha = 1: the twin models the "
    "engine); its 95% t-interval (MFMC variance, Welch-Satterthwaite df) within +- margin, "
    "margin = min(|twin - reduced|, |envelope twin - reduced|) over the m (paired mean + 95% "
    "half-width) + the multifidelity half-width"
)
MF_SLOPE_RULE = (
    "the engine's realisation-mean log spectrum by the twin as control variate (per bin, n "
    "engine and m twin realisations, alpha = 1), two power laws fitted to it; standard error "
    "by the paired bootstrap (n pairs and the m - n further twins resampled apart); against "
    "the reduced model's over m: pass within 2 sigma, fail beyond 3 sigma"
)


#: a trajectory's attributes with one entry per realisation (the engines' and the reduced
#: model's final state, :func:`reduced.simulate.final_state`)
PER_REALISATION_ATTRS = ("max_abs_angle", "left_small_angle", "final_state")


def head(tr: Trajectory, n: int) -> Trajectory:
    """The first ``n`` realisations of ``tr``: the same noise streams as an n-realisation run
    (its per-realisation attributes, :data:`PER_REALISATION_ATTRS`, cut to them too)."""
    attrs = dict(tr.attrs)
    for key in PER_REALISATION_ATTRS:
        if isinstance(attrs.get(key), list):
            attrs[key] = attrs[key][:n]
    return Trajectory(time=tr.time, data={k: v[:n] for k, v in tr.data.items()}, attrs=attrs)


def _known(x: np.ndarray) -> float:
    """|mean| + 95 % half-width of the finite values (the known terms of a margin)."""
    x = x[np.isfinite(x)]
    return abs(float(x.mean())) + t_half_width(x) if x.size > 1 else float("inf")


def _mf_rng(profile: Profile, model: str, metric: str) -> np.random.Generator:
    """The bootstrap stream of one multifidelity check (:mod:`cipcore.seeds`)."""
    from cipcore.seeds import purpose_rng

    key = zlib.crc32(f"multifidelity/{model}/{metric}".encode())
    return purpose_rng(profile.seed, "bootstrap", key)


def mf_equivalence(
    full: np.ndarray,
    red: np.ndarray,
    twin: np.ndarray,
    env: np.ndarray,
    n_plain: int,
    rng: np.random.Generator,
) -> tuple[str, dict, float]:
    """Multifidelity paired TOST (:data:`MF_RULE`) of one per-realisation metric.

    ``full``: (n,) the engine's values; ``red``, ``twin``, ``env``: (m,) the reduced
    model's, the twin's and the envelope twin's, the first n under the engine's noise.
    Returns (status, values, the half-width over the one plain sampling of ``n_plain``
    engine realisations would have at the twin's spread over the m, sigma_y where the twin
    follows the engine; 0 where both vanish).

    alpha is 1, not estimated: the twin models the engine itself (alpha* = 1 where it
    follows it), and an alpha fitted to 3 pairs can be anything (PhysX's coupled 15 Hz
    band fitted alpha = -0.50 at rho = -0.9997 from 3 pairs and failed, 7 December).
    """
    from validation.checks import multifidelity as mfe

    a = np.asarray(full, dtype=float).ravel()
    r = np.asarray(red, dtype=float).ravel()
    y, x = mfe.finite_nested(a - r[: a.size], np.asarray(twin, dtype=float).ravel() - r)
    if y.size < mfe.MIN_PAIRED:
        return INCONCLUSIVE, {"n": int(y.size), "reason": "too few finite pairs"}, float("inf")
    est = mfe.mfmc_estimate(y, x, alpha=1.0)
    margin = min(_known(x), _known(np.asarray(env, dtype=float).ravel() - r)) + est.half_width
    lo, hi = est.ci95
    status = tost_status(lo, hi, margin)
    plain = mfe.plain_half_width_at(x, n_plain)
    ratio = est.half_width / plain if plain > 0 else (0.0 if est.half_width == 0 else np.inf)
    rf = r[np.isfinite(r)]
    ref, ref_se = float(rf.mean()), float(rf.std(ddof=1) / np.sqrt(rf.size))
    boot = mfe.bootstrap_interval(y, x, rng, 500, alpha=1.0)
    return (
        status,
        {
            "n": est.n,
            "n_twin": est.m,
            "full": {"value": ref + est.mean, "se": float(np.hypot(est.se, ref_se))},
            "reduced": {"value": ref, "se": ref_se},
            "difference": {"value": est.mean, "se": est.se},
            "difference_mean": est.mean,
            "difference_ci95": [lo, hi],
            "margin": float(margin),
            "margin_rule": "known terms' difference over the twin's realisations + the "
            "multifidelity half-width",
            "multifidelity": {
                "rho": est.rho,
                "alpha": est.alpha,
                "df": est.df,
                "variance_ratio": est.variance_ratio,
                "bootstrap_ci95": list(boot),
                "half_width_vs_plain": ratio,
            },
        },
        ratio,
    )


def _log_spectra(m: SeriesMetrics, profile: Profile) -> tuple[np.ndarray, np.ndarray]:
    """(log10 bin frequencies, (R, 16) per-realisation binned log10 PSD) as the slope fit
    of :func:`series_metrics` bins them (:func:`validation.checks.metrics.fit_two_power_laws`)."""
    f, s = m.spectrum
    lo = max(profile.spectrum_band[0], 2.0 / profile.spectrum_segment)
    hi = profile.spectrum_band[1]
    keep = (f >= lo) & (f <= hi)
    return metrics.log_bins(f[keep], np.atleast_2d(s)[:, keep], lo, hi, 16)


def mf_slopes(full: SeriesMetrics, twin: SeriesMetrics, red: SeriesMetrics, profile: Profile,
              n_plain: int, rng: np.random.Generator) -> tuple[str, dict, float]:  # fmt: skip
    """The spectral slopes by the twin as control variate (:data:`MF_SLOPE_RULE`).

    Returns (worst status of both slopes, values, the largest standard error over
    the one plain sampling with ``n_plain`` engine realisations would have, predicted
    from the twin's own bootstrap SE over its m realisations times sqrt(m / n_plain)).
    """
    lf, le = _log_spectra(full, profile)
    _, lt = _log_spectra(twin, profile)
    n, m, nb = le.shape[0], lt.shape[0], 100
    ip = np.vstack([np.arange(n), rng.integers(0, n, (nb, n))])
    ix = np.vstack([np.arange(n, m), n + rng.integers(0, m - n, (nb, m - n))])
    ye, xp = le[ip], lt[ip]  # (1 + nb, n, bins)
    xall = np.concatenate([xp, lt[ix]], axis=1).mean(axis=1)
    est = ye.mean(axis=1) + (xall - xp.mean(axis=1))  # (1 + nb, bins); alpha = 1
    fits = metrics.broken_lines(lf, est)
    # the twin's own slopes over its m: plain sampling's SE at n_plain, scaled from them
    twin_se = np.std(metrics.broken_lines(lf, xall[1:]), axis=0, ddof=1) * np.sqrt(m / n_plain)
    statuses, values, ratio = [], {}, 0.0
    for k, which in enumerate(("slope_low", "slope_high")):
        v, se = float(fits[0, k]), float(np.std(fits[1:, k], ddof=1))
        ref, ref_se = getattr(red.slopes, which), getattr(red.slopes, which + "_se")
        st, z = se_agreement(v, se, ref, ref_se)
        plain = float(twin_se[k])
        ratio = max(ratio, se / plain if plain > 0 else float("inf"))
        statuses.append(st)
        values[which] = {"full": {"value": v, "se": se}, "reduced": {"value": ref, "se": ref_se},
                         **z, "multifidelity": {"n": n, "n_twin": m, "se_vs_plain": se / plain
                                                if plain > 0 else None}}  # fmt: skip
    return worst(statuses), values, ratio


def compare_series_mf(
    model: str, ms: dict[str, SeriesMetrics], profile: Profile, n_plain: int, details: str
) -> tuple[list[Check], float]:
    """:func:`compare_series`'s agreement checks by the multifidelity estimator.

    ``ms``: the metrics of "full" (n realisations), "reduced", "twin", "envelope"
    (m each, the first n under the engine's noise).  Returns the checks and the
    largest predicted interval width over plain sampling's with ``n_plain``
    engine realisations (above 1: the twin does not pay, sample plainly).
    """
    full, red, twin, env = ms["full"], ms["reduced"], ms["twin"], ms["envelope"]
    checks, ratios = [], []

    def paired(metric: str, attr: str, what: str) -> None:
        st, v, ratio = mf_equivalence(getattr(full, attr), getattr(red, attr),
                                      getattr(twin, attr), getattr(env, attr), n_plain,
                                      _mf_rng(profile, model, metric))  # fmt: skip
        ratios.append(ratio)
        checks.append(Check(name=f"agreement.{metric}.{model}", status=st, values=v,
                            tolerance=MF_RULE, details=f"{what}; {details}"))  # fmt: skip

    paired("log10_rms", "log_rms", "log10 RMS of the balancing error (Fig. rms)")
    bands = []
    for k, fc in enumerate(red.band_centres):
        st, v, ratio = mf_equivalence(
            full.band_log_power[:, k], red.band_log_power[:, k], twin.band_log_power[:, k],
            env.band_log_power[:, k], n_plain, _mf_rng(profile, model, f"band{k}"),
        )  # fmt: skip
        ratios.append(ratio)
        bands.append({"centre_hz": float(fc), "status": st, **v})
    tolerance = MF_RULE + "; per log-spaced band of log10 PSD, worst band decides"
    checks.append(bands_check(model, bands, tolerance, details))
    st, v, ratio = mf_slopes(full, twin, red, profile, n_plain, _mf_rng(profile, model, "slopes"))
    ratios.append(ratio)
    checks.append(Check(name=f"agreement.spectral_slopes.{model}", status=st, values=v,
                        tolerance=MF_SLOPE_RULE, details="two power laws fitted to the mean "
                        f"spectrum (Fig. pwsp); {details}"))  # fmt: skip
    paired(
        "stcc_peak_median",
        "tau_hat_median",
        "median first dominant STCC peak tau_hat of R(x_T', x_M') (Fig. sccpeak)",
    )
    paired(
        "stcc_fast_fraction",
        "fast_fraction",
        "fraction of windows with tau_hat < tau (Fig. sccpeak:pdf)",
    )
    paired("log10_velocity_sd", "log_velocity_sd", "log10 SD of the velocity error (Fig. velo)")
    return checks, max(ratios)


@dataclass(frozen=True)
class PlainFallback:
    """:func:`multifidelity_series` declined: ``why``, a line for the plain checks' details,
    and ``full``, the engine's plain allocation where it already ran (a ``batch`` engine,
    :class:`cipcore.engine.Capabilities`), else None."""

    why: str
    full: Trajectory | None = None


def multifidelity_series(
    scenario: Scenario, target: EngineTarget, profile: Profile, **options: Unpack[SeriesOptions]
) -> tuple[list[Check], dict] | PlainFallback:
    """One model's series checks with the engine on ``profile.mf_engine_realizations``.

    ``scenario``, ``target``, ``options``: :func:`series_model_checks`' (the scenario's
    realisations = the plain allocation, series_realizations).  The twin, the reduced model and
    the envelope twin run ``profile.mf_twin_realizations`` under the same noise (the
    first n are the engine's).  Returns a :class:`PlainFallback` (the caller samples
    plainly) when at the correlations measured some check's interval would be wider than
    plain sampling's (the engine outside the twin's regime); else (checks, the stage's
    data).  A ``batch`` engine runs the plain allocation in its one call, for about the
    cost of n, and every realisation of it is paired (n = the plain allocation: the
    estimator's variance only falls with n); a fall back then reuses that call.  Where
    a realisation stopped that call early (a divergence), the profile's n run alone,
    as for any engine.
    """
    import time

    from validation.checks import multifidelity as mfe
    from validation.checks.conformance import run_envelope_twin

    threads, nearest, precision = options["threads"], options["nearest"], options["precision"]
    model, beta, amplitude = scenario.model, scenario.params.beta, scenario.amplitude
    duration, n_plain, seed = scenario.duration, scenario.realizations, scenario.seed
    n, m = profile.mf_engine_realizations, max(profile.mf_twin_realizations, n_plain)
    if not mfe.MIN_PAIRED <= n < n_plain:
        raise ParameterError(f"mf_engine_realizations must be 0 or in [{mfe.MIN_PAIRED}, "
                             f"series_realizations = {n_plain}), got {n}")  # fmt: skip
    cheap = replace(scenario, realizations=m)
    run = {"decimate": profile.decimate, "threads": threads}
    twin_target, stepper = twin_of(model, target, nearest)
    t0 = time.perf_counter()
    ran = None  # the plain allocation, where the engine ran it (a batch engine)
    if rigid_engine(target.engine).capabilities.batch:
        ran = run_full(scenario, target, **run)
    paired_from_ran = ran is not None and ran.attrs.get("diverged") is None
    if paired_from_ran:  # all of the call paired
        n, full, engine_runs = n_plain, ran, n_plain
    else:  # the profile's n alone (also after a batch call a divergence stopped early)
        full = run_full(replace(scenario, realizations=n), target, **run)
        engine_runs = n + (n_plain if ran is not None else 0)
    t1 = time.perf_counter()
    red = run_reduced(cheap, **run)
    twin = run_twin(cheap, twin_target, **run)
    # the engine's cost per realisation it ran, against the cheap models' per realisation
    w = (t1 - t0) / engine_runs / max((time.perf_counter() - t1) / m, 1e-9)
    batch = " (a batch engine: every realisation of its one call paired)" if paired_from_ran else ""
    rec = Recording(decimate=profile.decimate, fields=SERIES_FIELDS)
    env = run_envelope_twin(cheap, recording=rec, threads=threads, integrator=stepper)
    runs = {"full": full, "reduced": red, "twin": twin, "envelope": env,
            "reduced_n": head(red, n), "twin_n": head(twin, n)}  # fmt: skip
    ms = {k: series_metrics(tr, profile, 0.1, profile.spectrum_segment) for k, tr in runs.items()}
    y = ms["full"].log_rms - ms["reduced_n"].log_rms
    rho = abs(mfe.control_variate(y, ms["twin_n"].log_rms - ms["reduced_n"].log_rms)[1])
    details = (
        f"beta {beta}, amplitude {amplitude:g} m{series_amplitude_note(profile, precision)}, "
        f"multifidelity: engine {n} x {duration:g} s{batch}, twin and reduced {m} x "
        f"{duration:g} s "
        f"(same noise, nested; plain sampling: {n_plain} x {duration:g} s), seed {seed}, "
        f"largest |theta| {float(np.max(full.attrs['max_abs_angle'])):.2g} rad, cost ratio "
        f"engine : twin + reduced w = {w:.3g} (measured), MFMC-optimal m/n for the RMS's "
        f"rho: {mfe.optimal_ratio(rho, max(w, 1e-9)):.3g}{stop_note(full)}"
    )
    checks, ratio = compare_series_mf(model, ms, profile, n_plain, details)
    # an engine run that stopped (a non-finite state) has no estimate at any allocation:
    # running the plain one as well would only stop again
    if not ratio <= 1.0 and not full.attrs.get("diverged"):
        return PlainFallback(f"multifidelity not used: with the engine on {n} and the twin "
                             f"on {m} realisations an interval would be {ratio:.3g} times "
                             f"plain sampling's (log10 RMS rho {rho:.6g}), so the engine "
                             f"ran {n_plain}", ran)  # fmt: skip
    own = compare_series(model, ms["full"], ms["reduced_n"], "", details, ms["twin_n"])
    own = [c for c in own if c.name.startswith("twin.")]
    checks += [not_applicable(c) for c in own] if nearest else own
    checks.append(trajectory_check(model, full, runs["reduced_n"], details))
    return checks, {"full": full, "reduced": red, "metrics_full": ms["full"],
                    "metrics_reduced": ms["reduced"]}  # fmt: skip


#: How far (relative) the engine's largest |theta| may go past the reference's, scaled
#: by the engine's linear excess (:func:`mark_engine_left`), inside the small-angle
#: regime: the regime's 1 % trajectory tolerance, applied to the angle
ENGINE_LEFT_TOLERANCE = 0.01


def mark_engine_left(rows: list[dict], limit: float) -> None:
    """Set each scan row's ``engine_left_regime``: did the engine leave the small-angle
    regime while the reference stayed inside it?

    ``rows`` are one model's amplitude-scan rows, each with the engine's largest |theta|
    (``max_abs_angle``, rad, at every step) and the reference's (``reference_max_abs_angle``,
    arcsin(|e| / L) over its recorded samples and every stick).  Under the same noise both
    linear models scale with the amplitude, so at the smallest amplitude whose reference
    stays inside the regime the ratio r_lin = engine / reference is the engine's linear
    excess: its rigid body against the m/M -> 0 reference, and every step against the
    recorded samples (1.0007 to 1.0075 over seeds 1 to 40 of the quick profile, the same at
    1e-5, 1e-4 and 1e-3 m).  A row whose reference is inside the regime (``limit``, rad)
    has its engine leave it where

        max_abs_angle > max(limit, (1 + ENGINE_LEFT_TOLERANCE) r_lin reference_max_abs_angle).

    What is left inside the regime after the scaling is the angles' nonlinear terms: at most
    0.45 % over the same seeds (0.89 % without the scaling, against the 1 % tolerance: the
    coupled model failed at 4 of 20 seeds while the reference read one stick only).  An
    engine that hits a joint limit or a contact goes past it by far (0.41 against 0.041 rad
    for a cart slide range of 0.02 m).  Without a row inside the regime, or where the
    engine's angle there is not finite, r_lin = 1.
    """
    inside = sorted((r for r in rows if r["reference_max_abs_angle"] <= limit),
                    key=lambda r: r["amplitude"])  # fmt: skip
    first = inside[0] if inside else None
    r_lin = 1.0
    if first is not None and first["reference_max_abs_angle"] > 0:
        r_lin = first["max_abs_angle"] / first["reference_max_abs_angle"]
        r_lin = r_lin if np.isfinite(r_lin) else 1.0  # an engine that fell there: unscaled
    for r in rows:
        expected = (1.0 + ENGINE_LEFT_TOLERANCE) * r_lin * r["reference_max_abs_angle"]
        r["engine_left_regime"] = bool(
            r["reference_max_abs_angle"] <= limit and r["max_abs_angle"] > max(limit, expected)
        )


#: The departure the small-angle regime allows (cip.model.small_angle_limit: sin theta =
#: theta to 0.1 %), in log10 units: added to the scan's paired margins, which resolve
#: the angles' second-order terms (1e-4 in log10 RMS at 0.04 rad) well inside it.
SMALL_ANGLE_FLOOR = float(np.log10(1.001))


def amplitude_scan(
    profile: Profile, threads: int | None, **target: Unpack[TargetKeywords]
) -> tuple[list[Check], list[dict]]:
    """Agreement of RMS, spectrum bands and trajectory vs initial amplitude.

    Locates, per model and metric, the largest |theta| at which the models
    still agree, and checks that they agree everywhere inside the small-angle
    regime and disagree far outside it.  Whether a run is inside the regime is
    judged by the reference (the reduced model under the same noise: |theta| =
    arcsin(|e| / L)), never by the engine under test: a run whose engine leaves
    the regime while the reference stays inside (a joint limit, a contact) is
    listed and fails ``agreement.small_angle_regime``.  The margins' known terms
    are bounded by the envelope twin (:mod:`validation.checks.conformance`).

    The function is long because each amplitude's row and its verdicts are built from the
    same four runs.
    """
    from validation.checks.conformance import bounded_margin, run_envelope_twin
    from validation.checks.divergence import pendulum_length

    t = EngineTarget(**target)
    rows, checks = [], []
    limit = small_angle_limit()
    seg = profile.scan_duration / 4
    for model, beta in PAPER_BETA.items():
        seed = profile.seed_for("scan", model)
        stepper = twin_integrator(model, t.files, t.engine, t.integrator)
        for amp in profile.scan_amplitudes:
            scn = Scenario(model, BalanceParams(beta=beta), profile.scan_duration,
                           profile.scan_realizations, seed, amp)  # fmt: skip
            run = {"decimate": profile.decimate, "threads": threads}
            full, red = run_pair(scn, t, **run)
            twin = run_twin(scn, t, **run)
            rec = Recording(decimate=profile.decimate, fields=("balancing_error",))
            env = run_envelope_twin(scn, recording=rec, threads=threads, integrator=stepper)
            ef, er = full["balancing_error"].astype(float), red["balancing_error"].astype(float)
            et, ee = twin["balancing_error"], env["balancing_error"]
            # an engine run stopped where its state went non-finite (the breakdown the
            # scan looks for) holds fewer samples: every series over their common span
            span = min(x.shape[1] for x in (ef, er, et, ee))
            ef, er, et, ee = (x[:, :span] for x in (ef, er, et, ee))
            rel = trajectory_distance(full, red)
            dt = full.sample_interval
            log_rms = [np.log10(metrics.rms(x[..., 0])) for x in (ef, er, et, ee)]
            st_rms, v_rms = paired_equivalence(
                log_rms[0], log_rms[1], bounded_margin(
                    log_rms[0], log_rms[1], log_rms[2] - log_rms[1], log_rms[3] - log_rms[1],
                    floor=SMALL_ANGLE_FLOOR,
                ),
            )  # fmt: skip
            f, sf = metrics.power_spectrum(ef[..., 0], dt, segment=seg)
            _, sr = metrics.power_spectrum(er[..., 0], dt, segment=seg)
            _, st_ = metrics.power_spectrum(et[..., 0], dt, segment=seg)
            _, se_ = metrics.power_spectrum(ee[..., 0], dt, segment=seg)
            _, bf = metrics.band_log_power(f, sf, 2.0 / seg, profile.spectrum_band[1], 6)
            _, br = metrics.band_log_power(f, sr, 2.0 / seg, profile.spectrum_band[1], 6)
            _, bt = metrics.band_log_power(f, st_, 2.0 / seg, profile.spectrum_band[1], 6)
            _, be = metrics.band_log_power(f, se_, 2.0 / seg, profile.spectrum_band[1], 6)
            st_band = worst([
                paired_equivalence(bf[:, k], br[:, k], bounded_margin(
                    bf[:, k], br[:, k], bt[:, k] - br[:, k], be[:, k] - br[:, k],
                    floor=SMALL_ANGLE_FLOOR,
                ))[0]
                for k in range(bf.shape[1])
            ])  # fmt: skip
            max_angle = float(np.max(full.attrs["max_abs_angle"]))
            # the regime as the reference sees it: theta = arcsin(|e| / L), L = g / alpha,
            # over every stick, as the engine's largest |theta| is (the coupled model's
            # second stick went past the first's by 12 % at 1e-4 m, seed 7)
            L_ref = pendulum_length(BalanceParams(beta=beta))
            with np.errstate(invalid="ignore"):
                e_max = float(np.nanmax(np.abs(er)))
            ref_angle = float(np.arcsin(min(1.0, e_max / L_ref)))
            rows.append(
                {
                    "model": model,
                    "amplitude": amp,
                    "max_abs_angle": max_angle,
                    "reference_max_abs_angle": ref_angle,
                    "small_angle": ref_angle <= limit,
                    "relative_l2": rel,
                    "trajectory": PASS if rel < 0.01 else FAIL,
                    "log10_rms": st_rms,
                    "spectrum_bands": st_band,
                    "rms_difference_ci95": v_rms.get("difference_ci95"),
                    "twin_relative_l2": _relative_l2(ef, et),
                    "fell": max_angle > np.pi / 2,
                }
            )
    for model in PAPER_BETA:
        mine = [r for r in rows if r["model"] == model]
        mark_engine_left(mine, limit)
        inside = [r for r in mine if r["small_angle"]]
        outside = [r for r in mine if not r["small_angle"]]
        largest = {}
        for metric in ("trajectory", "log10_rms", "spectrum_bands"):
            # up to the first amplitude at which the metric stops agreeing
            largest[metric] = None
            for r in sorted(mine, key=lambda r: r["amplitude"]):
                if r[metric] != PASS:
                    break
                largest[metric] = r["max_abs_angle"]
        inside_ok = all(r[m] == PASS for r in inside for m in ("trajectory", "log10_rms"))
        left = [r["amplitude"] for r in inside if r["engine_left_regime"]]
        checks.append(
            Check(
                name=f"agreement.small_angle_regime.{model}",
                status=PASS if inside and inside_ok and not left else FAIL,
                values={
                    "amplitudes": [r["amplitude"] for r in inside],
                    "largest_agreeing_angle": largest,
                    "engine_left_while_reference_inside": left,
                },
                tolerance=f"trajectory (rel. L2 < 1%) and RMS (paired equivalence) agree at every "
                f"amplitude whose largest |theta| stays below {limit:.3f} rad in the reference "
                "(the reduced model, same noise), and the engine stays inside there too",
                details=f"beta {PAPER_BETA[model]}, {profile.scan_realizations} x "
                f"{profile.scan_duration:g} s per amplitude",
            )
        )
        far = [r for r in outside if r["reference_max_abs_angle"] > 3 * limit]
        breaks = [r for r in far if r["trajectory"] == FAIL or r["log10_rms"] == FAIL]
        checks.append(
            Check(
                name=f"agreement.breakdown_detected.{model}",
                status=PASS if far and len(breaks) == len(far) else FAIL,
                values={
                    "far_amplitudes": [r["amplitude"] for r in far],
                    "disagreeing": [r["amplitude"] for r in breaks],
                },
                tolerance=f"every amplitude reaching |theta| > {3 * limit:.2f} rad must disagree "
                "(trajectory or RMS fails): the suite detects the end of the linear regime",
                details="a suite that found agreement there would be blind",
            )
        )
    return checks, rows


def rod_length_study(
    profile: Profile,
    out_dir,
    workers: int | None,
    engine: str = "mujoco",
    integrator: str | None = None,
) -> tuple[list[Check], list[dict], object]:
    """The shipped rod-length study at the profile's size.

    Check: in the linear regime (smallest amplitude) the rod length must not
    matter (it drops out of the reduced model): with common random numbers,
    each length's per-realisation trajectory distance, largest angle and RMS
    are compared with those at l = L by the paired-equivalence rule.  The rows
    report every metric per (l/L, amplitude); beyond the linear regime the
    rigid rod's geometry is free to matter, and the rows show where it does.

    The function is long because it maps the study's result onto the checks and the figure's
    data in one place.
    """
    import json
    import os
    import shutil
    from pathlib import Path

    import xarray as xr

    from validation.sweep import Study, SweepPool, default_studies_dir, mean_ci, run_sweep

    base = Study.from_toml(default_studies_dir() / "rod_length.toml").as_dict()
    base.update(profile.rod_study)
    base["engine"] = engine
    if integrator is not None:
        base["fixed"] = {**base.get("fixed", {}), "integrator": integrator}
    study = Study(**base)
    where = Path(out_dir) / "rod_length"
    meta = where / "study.json"
    if meta.exists() and json.loads(meta.read_text()).get("fingerprint") != study.fingerprint():
        shutil.rmtree(where)  # another study or other package versions: never reuse
    # in this process, its realisations on the run's threads: a point takes well under a
    # second at the quick profile, less than a worker process's start-up (measured: the
    # stage's wall time was 2.3x its CPU time with two worker processes)
    rep = run_sweep(
        study, where, pool=SweepPool(workers=1, point_threads=workers or os.cpu_count() or 1)
    )
    with xr.open_dataset(rep.dataset_path, engine="scipy") as f:
        ds = f.load()
    lengths = ds["rod_length_ratio"].values
    ref = lengths[np.argmin(np.abs(lengths - 1.0))]
    small = float(ds["amplitude"].min())
    statuses, detail = [], {}
    for metric in ("agreement", "max_angle", "rms"):
        a = ds[metric].sel(amplitude=small)
        for l_over_L in lengths:
            st, v = paired_equivalence(
                a.sel(rod_length_ratio=l_over_L).values, a.sel(rod_length_ratio=ref).values
            )
            statuses.append(st)
            detail[f"{metric}.l/L={l_over_L:g}"] = {"status": st, **v}
    checks = [
        Check(
            name="rod_length.independent_in_linear_regime",
            status=worst(statuses),
            values=detail,
            tolerance=f"paired equivalence of each length against l/L = {ref:g} at amplitude "
            f"{small:g} m (same noise at every point)",
            details=f"{study.realizations} realisations x {study.duration:g} s per point, "
            f"seed {study.seed}",
        )
    ]
    rows = []
    for point in study.points():
        sel = {k: float(v) for k, v in point.items()}
        row = dict(point)
        for metric in ("agreement", "max_angle", "rms", "tau_hat"):
            if metric in ds:
                m, h = mean_ci(ds, metric)
                row[metric] = float(m.sel(sel))
                row[metric + "_ci95"] = float(h.sel(sel))
                v = ds[metric].sel(sel).values.astype(float)  # heavy-tailed: also quantiles
                v = v[np.isfinite(v)]
                row[metric + "_q05_50_95"] = (
                    np.quantile(v, (0.05, 0.5, 0.95)).tolist() if v.size else None
                )
        rows.append(row)
    return checks, rows, ds


# ------------------------------------------------------------------ the exact twin
#: Initial balancing error (m) of the twin comparison: small enough that the
#: terms the twin leaves out (second order in the angles) stay below 1e-10, large
#: enough that the rod's absolute round-off (~1e-17 m) stays below it too.
TWIN_AMPLITUDE = 1e-6
TWIN_WINDOW = 10.0  # s
# The twin and rod tolerances are the engine's own (cip.engines.rigid_body.RigidBodyEngine:
# twin_tolerance, rod_tolerance), set from its measured floor.


def rigid_engine(name: str):
    """The registered rigid-body engine ``name`` (one line naming the reason if it is not one)."""
    engine = get_engine(name)
    if not engine.capabilities.rigid_body or not hasattr(engine, "twin_terms"):
        raise ParameterError(
            f"engine {name!r} is not a rigid-body engine: `run` validates a rigid-body engine "
            "against the reduced model (`cip-validate engines` compares the others)"
        )
    return engine


def model_file(model: str, files: dict[str, str] | None = None, integrator: str | None = None):
    """The compiled model file of ``model`` (a user's ``--mjcf`` or the shipped one).

    ``integrator`` (MuJoCo's names: Euler, implicit, implicitfast, RK4) replaces the
    file's ``<option integrator>`` where given.
    """
    import mujoco

    from cip.mjcf_params import INTEGRATOR_NAMES, load_model_file, shipped_model_path

    m = load_model_file((files or {}).get(model) or shipped_model_path(model))
    if integrator is not None:
        enum = {v: k for k, v in INTEGRATOR_NAMES.items()}
        if integrator not in enum:
            raise ParameterError(f"integrator must be one of {', '.join(enum)}, got {integrator!r}")
        m.opt.integrator = int(getattr(mujoco.mjtIntegrator, enum[integrator]))
    return m


def not_applicable(check: Check) -> Check:
    """``check`` (an exact-twin check) of an engine judged by refinement: its numbers kept,
    its status n/a (its details say why: the tier)."""
    return replace(check, status=NOT_APPLICABLE)


def _relative_l2(a: np.ndarray, b: np.ndarray) -> float:
    k = min(a.shape[1], b.shape[1])
    return metrics.relative_l2(a[:, :k], b[:, :k])


def measured_delay(model: str, params: BalanceParams, physical, mj_model, backend=None) -> int:
    """The engine's delay in steps, read from its response (no noise).

    The balancing error's history is zero before t = 0 and ``TWIN_AMPLITUDE`` at
    t = 0: a step.  The run with the controller and one without it (beta = 0)
    start from the same state; the first step after which the carts' velocities
    differ is the first step whose control force is non-zero, the delay.  Any
    one-step integrator that holds the control over a step (semi-implicit Euler,
    implicit, RK4, SAP) first moves the velocity after the step whose control
    changed, so the count assumes no stepper.  ``backend`` is the engine's
    :class:`cip.runner.RolloutBackend` class.  Returns -1 if no force appears
    within three delays.
    """
    from cip.runner import CIPRunner

    vels = []
    for beta in (params.beta, 0.0):
        p = replace(params, beta=beta, nu=0.0)
        r = CIPRunner(
            model, p, physical, 1, TWIN_AMPLITUDE, threads=1, backend=backend, mj_model=mj_model
        )
        r.e_hist[:] = 0.0
        r.edot_hist[:] = 0.0
        chunks = [r.advance(np.zeros((1, r.d, r.nc)))[0][:, r.i_vx] for _ in range(3)]
        vels.append(np.concatenate(chunks))
    moved = np.flatnonzero(np.abs(vels[0] - vels[1]).max(axis=1) > 0)
    return int(moved[0]) if moved.size else -1


def twin_integrator(
    model: str, files: dict[str, str] | None, engine: str, integrator: str | None
) -> str:
    """The stepper of ``engine``'s exact twin for ``model`` run with ``integrator``.

    The specification's envelope twin steps with it, so that the agreement margins
    admit the rigid body's known terms and not the integrator's own difference from
    the reduced model's semi-implicit Euler step.
    """
    from cip.mjcf_params import read_mapping

    mapping = read_mapping(model_file(model, files, integrator))
    return rigid_engine(engine).twin_terms(mapping)["integrator"]


def instrument_checks(
    seed: int,
    n_realizations: int,
    threads: int | None = None,
    *,
    target: EngineTarget = EngineTarget(),
    fault=None,
    models: tuple[str, ...] = MODEL_NAMES,
) -> list[Check]:
    """Full model vs the engine's exact twin, the delay, the rod, the declared model.

    ``target`` names the rigid-body engine (its twin, tolerances and rollout
    backend), the MuJoCo integrator run instead of the file's and the user's model
    files (default: the shipped files); ``fault`` a
    :class:`validation.faults.catalogue.Fault` injected into the engine only.

    The function is long because the direct checks share one run per model (the engine, its
    twin, the delay probe) and are built together.
    """
    from cip.mjcf_params import read_mapping
    from reduced.twin import TwinParams, simulate_twin

    files, engine, integrator = target.files, target.engine, target.integrator

    eng = rigid_engine(engine)
    caps = eng.capabilities
    checks = []
    for model in models:
        m = model_file(model, files, integrator)
        mp = read_mapping(m)
        if mp.model != model:
            raise ParameterError(f"--mjcf: the file for {model!r} describes a {mp.model} model")
        p = BalanceParams(beta=PAPER_BETA[model])
        declared = {
            "timestep": (mp.timestep, p.dt),
            "alpha": (mp.alpha, p.alpha),
            "gamma_tip": (mp.tip_damping, p.gamma),
            "gamma_cart": (mp.cart_damping, p.gamma),
        }
        ok = all(abs(a - b) <= 1e-12 * abs(b) for a, b in declared.values())
        # an engine that follows the file's integrator must support it; one with its
        # own stepper (no integrators listed) runs what its capabilities declare
        ok = ok and (not eng.integrators or mp.integrator in eng.integrators)
        runs = mp.integrator if eng.integrators else caps.integrator
        checks.append(
            Check(
                name=f"model.declared.{model}",
                status=PASS if ok else FAIL,
                values={k: {"model": a, "controller": b} for k, (a, b) in declared.items()}
                | {"integrator": runs, "engine": engine, "twin": caps.twin},
                tolerance="time step, g/L and dampings of the model file equal the "
                "controller's dt, alpha, gamma to 1e-12 relative; the file's integrator is one "
                "the engine steps and its twin follows "
                f"({', '.join(eng.integrators) or 'the engine has its own: ' + caps.integrator})",
                details=f"mapping read from the model file ({mp.model}, m/M = {mp.mass_ratio:g})",
            )
        )
        if not ok:
            continue  # the engine would run another model than the controller assumes
        phys = mp.physical()
        twin_p = TwinParams(**eng.twin_terms(mp))
        pe, backend = p, eng.rollout()
        noise = None
        n_steps = round(TWIN_WINDOW / p.dt)
        if fault is not None:
            pe, backend = fault.engine_params(p), fault.backend(backend)
            noise = fault.noise(seed, n_realizations, get_model(model).n_controllers, n_steps)
        kw = {"amplitude": TWIN_AMPLITUDE, "threads": threads}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DivergenceWarning)
            full = eng.simulate(
                model,
                pe,
                TWIN_WINDOW,
                n_realizations,
                seed,
                physical=phys,
                mj_model=m,
                backend=backend,
                noise=noise,
                fields=("balancing_error", "tip_position"),
                **kw,
            )
        twin = simulate_twin(
            Scenario(model, p, TWIN_WINDOW, n_realizations, seed, TWIN_AMPLITUDE),
            twin_p,
            recording=Recording(fields=("balancing_error", "tip_position")),
            execution=Execution(threads=threads),
        )
        ef, et = full["balancing_error"], twin["balancing_error"]
        complete = bool(ef.shape[1] == et.shape[1] and np.isfinite(ef).all())
        rel = _relative_l2(ef, et)
        judged, why = refinement.tier(caps)
        if not caps.declared:
            judged, why = refinement.undeclared_tier(rel, eng.twin_tolerance_for(model))
        details = (
            f"engine {engine} ({twin_p.integrator}), amplitude {TWIN_AMPLITUDE:g} m, "
            f"{n_realizations} x {TWIN_WINDOW:g} s, seed {seed}, same noise; "
            f"tier: {judged} ({why})"
        )
        ok = complete and rel <= eng.twin_tolerance_for(model)
        checks.append(
            Check(
                name=f"twin.trajectory.{model}",
                status=(PASS if ok else FAIL) if judged == refinement.TWIN else NOT_APPLICABLE,
                values={"relative_l2": rel, "complete": complete},
                tolerance=f"relative L2 distance of the balancing errors to the engine's exact "
                f"linear twin <= {eng.twin_tolerance_for(model):g} (the engine's twin_tolerance, "
                "from its "
                "measured floor)",
                details=details,
            )
        )
        if mp.n_controllers == 2:
            sf = full["tip_position"][..., 0] - full["tip_position"][..., 1]
            st = twin["tip_position"][..., 0] - twin["tip_position"][..., 1]
            rod = rod_check(model, sf, st, ef, twin_p, (caps.rod, eng.rod_tolerance), details)
            checks.append(rod if judged == refinement.TWIN else not_applicable(rod))
        if caps.precision == "float32" and judged == refinement.TWIN:
            checks.append(refinement.not_run(model, refinement.FLOAT32_RULE))
        else:
            checks.append(
                refinement.refinement_check(model, m, eng, seed, backend=backend, threads=threads)
            )
        if judged == refinement.REFINEMENT:  # the controller's path, which no twin checks
            checks.append(
                closed_loop_check(model, m, eng, seed, params=p, fault=fault, threads=threads)
            )
        expected = round(p.tau / m.opt.timestep)
        got = measured_delay(model, pe, phys, m, backend)
        checks.append(
            Check(
                name=f"delay.{model}",
                status=PASS if got == expected else FAIL,
                values={"measured_steps": got, "expected_steps": expected},
                tolerance="a step in the balancing error reaches the control force exactly "
                "tau / timestep steps later (timestep read from the model file)",
                details=f"tau {p.tau:g} s, model timestep {m.opt.timestep:g} s, no noise",
            )
        )
    return checks
