"""The paper's claims, one row each, tested with the reduced models (paper sections 3, 4).

Every row names the system the paper makes the claim about (the linear model
of section 3, or the human experiment of section 4), the section and the
equation / figure / table label, the paper's value, ours with a 95 % interval,
the estimator, and a status by the rules :data:`VERDICT_RULE` and
:data:`ROBUSTNESS_RULE` state (a ratio claim: "direction and magnitude
reproduced", "direction reproduced; magnitude not", "not reproduced",
"direction inconclusive; magnitude not" or "inconclusive"), or ``not a
check`` (with the reason: a claim about the human experiment, one noise
draw, or a number that depends on an unstated initial condition).  Only the
critical gains are verdicts of the run (within their confidence tolerance plus
the paper's printed precision, :func:`beta_star_tolerance`); the other rows are
reported as measured.

All statistics read float64 series: the balancing error of the linear models
at the paper's operating point is a random walk in log |e| spanning more
than twenty decades over 1200 s, which float32 flushes to zero.
Simulations are made once per model and re-estimated for every estimator
choice (:func:`robustness`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cipcore.models import MODEL_NAMES, get_model
from cipcore.scenario import Execution, Recording, Scenario
from reduced import (
    BalanceParams,
    CriticalGain,
    GainNoise,
    ParameterError,
    critical_gain,
    lyapunov_gains,
    simulate,
)
from reduced.nonlinear import simulate_nonlinear
from validation.checks import metrics
from validation.checks.stats import FAIL, PASS, Check, bootstrap_ratio_ci, heavy_tailed_summary
from validation.profiles import PAPER_BETA, Profile

BETA_RANGE = {"single": (19.8, 20.8), "coupled": (20.55, 21.55)}
#: Two-sided false-failure rate of each beta* check for a correct model.
BETA_STAR_FALSE_FAILURE = 1e-3
#: The paper prints beta* to three decimals (Fig. 4 caption: 20.306, 21.032), so
#: each is known to +-5e-4 and their difference 0.726 to +-1e-3.
PAPER_PRECISION = {"single": 5e-4, "coupled": 5e-4, "shift": 1e-3}


#: cipval's beta* at the paper's printed parameters minus the paper's value, at the
#: long-duration limit: (offset, its standard error).  Measured by
#: ``benchmarks/beta_star_duration.py --nu 0.6`` at seeds 7 and 8 (512 realisations x
#: 4000 s each, every checkpoint from 100 s fitted by b_inf + c / (t - 10 s), the two
#: seeds pooled by inverse variance; docs/paper.md, "The offset and the checks"): single
#: 20.385 +- 0.008, coupled 21.100 +- 0.006.  The printed parameters' precision explains
#: it (nu printed 0.6: 0.617 and 0.624 reproduce the paper's single and coupled values),
#: the duration does not (c = +1.5 +- 3.3 s and -2.8 +- 2.6 s; the quick size's estimate
#: lies +0.010 +- 0.009 and -0.005 +- 0.009 from the limit).  The shift's offset is the
#: difference (the models run on independent noise).
PRINTED_PARAMETER_OFFSET = {"single": (0.079, 0.0079), "coupled": (0.068, 0.0061),
                            "shift": (-0.011, 0.0100)}  # fmt: skip


def beta_star_tolerance(se: float, n: int, precision: float, offset: float = 0.0) -> float:
    """Largest |ours - paper| a correct model reaches with probability 1 - 1e-3.

    ``se`` is the bootstrap standard error of beta* over ``n`` realisations; the
    bootstrap's sqrt((n - 1)/n) shrinkage is undone and the two-sided Student t
    quantile with n - 1 degrees of freedom at ``BETA_STAR_FALSE_FAILURE`` taken
    (small runs get wide tolerances: 5.4 standard errors at 8 realisations, 4.1 at
    16), plus the paper's printed precision, plus ``offset``: the bound on the explained
    offset of the model's beta* from the paper's (:data:`PRINTED_PARAMETER_OFFSET`, the
    upper end of its 95 % interval: :func:`offset_bound`).
    """
    from scipy.stats import t as student_t

    q = student_t.ppf(1.0 - BETA_STAR_FALSE_FAILURE / 2, max(n - 1, 1))
    return float(q * se * np.sqrt(n / max(n - 1, 1)) + precision + abs(offset))


def offset_bound(quantity: str) -> float:
    """|offset| + 1.96 SE of :data:`PRINTED_PARAMETER_OFFSET` for ``quantity`` ("single",
    "coupled" or "shift")."""
    offset, se = PRINTED_PARAMETER_OFFSET[quantity]
    return abs(offset) + 1.96 * se


def _row(quantity, paper, ours, uncertainty, settings, status, note="", *, system="model",
         where="section 3.1, Fig. Be"):  # fmt: skip
    return {"quantity": quantity, "system": system, "where": where, "paper": paper,
            "ours": ours, "uncertainty": uncertainty, "settings": settings, "status": status,
            "note": note}  # fmt: skip


#: What the study of the numerical setting found (docs/paper.md, "Where beta* comes from"
#: and "The offset and the checks"), in the checks' details.
BETA_STAR_OFFSET = (
    "no numerical setting tried reproduces the paper's beta* (estimator, dt 0.1-10 ms, "
    "noise held 10-20 ms, Euler-Maruyama or Heun, target 5e-5 or 5e-4, 100-10,000 s); at "
    "the printed parameters cipval's long-duration beta* is 20.385 +- 0.008 and 21.100 +- "
    "0.006 (2 x 512 x 4000 s, seeds 7 and 8), +0.079 and +0.068 above the paper's, within "
    "the printed parameters' precision (nu = 0.617 and 0.624, printed 0.6, reproduce them); "
    "the tolerance adds that offset's 95 % bound (docs/paper.md)"
)


def bracketed_gain(scenario: Scenario, n_gains: int, threads: int | None) -> CriticalGain:
    """beta* of ``scenario``'s model over its :data:`BETA_RANGE`; where lambda1 does not
    cross the target there, over the range widened by its width on each side (the
    bracket expanded once, as a root finder would; the result's ``betas`` show which); a
    :class:`ParameterError` when it does not cross there either.

    The range holds the correct model's beta* at every profile but the smallest: the smoke
    profile's single-model estimate (per-run SD 0.16 about 20.38) fell above 20.8 at one
    seed of 120 (``benchmarks/beta_star_seeds.py``), a false failure without the retry.
    """
    lo, hi = BETA_RANGE[scenario.model]
    run = Execution(threads=threads)
    try:
        return critical_gain(scenario, (lo, hi), target=5e-4, n_gains=n_gains, execution=run)
    except ParameterError:
        wide = (max(lo - (hi - lo), 0.0), hi + (hi - lo))
    return critical_gain(scenario, wide, target=5e-4, n_gains=n_gains, execution=run)


def critical_gains(profile: Profile, threads: int | None):
    """beta* for lambda1 = 5e-4, both models (Figs. lLe, Be)."""
    res = {}
    settings = (f"{profile.beta_star_realizations} realisations x {profile.beta_star_duration:g} s"
                f" at {profile.beta_star_gains} gains, dt 1 ms")  # fmt: skip
    failed = []
    for model in MODEL_NAMES:
        try:
            scenario = Scenario(model, BalanceParams(beta=20.0), profile.beta_star_duration,
                                profile.beta_star_realizations,
                                profile.seed_for("beta_star", model))  # fmt: skip
            res[model] = bracketed_gain(scenario, profile.beta_star_gains, threads)
        except ParameterError as exc:  # the target was not crossed: a failed check, not a crash
            failed.append(Check(name=f"paper.beta_star.{model}", status=FAIL,
                                values={"paper": PAPER_BETA[model]},
                                tolerance="|beta* - paper| <= 0.25",
                                details=f"{exc}; {settings}"))  # fmt: skip
    if failed:
        return failed, [], res
    s, c = res["single"], res["coupled"]
    shift = c.beta_star - s.beta_star
    shift_se = float(np.hypot(s.std, c.std))
    checks, rows = [], []
    details = f"{settings}; {BETA_STAR_OFFSET}"  # the checks' details; the rows keep settings
    rule = ("|ours - paper| <= t_(1-5e-4, n-1) x SE (bootstrap, n/(n-1) corrected) + the "
            "paper's printed precision + the 95 % bound of the offset explained by the "
            "printed parameters: false-failure rate at most 1e-3 per check")  # fmt: skip
    for model, paper in PAPER_BETA.items():
        r = res[model]
        tol = beta_star_tolerance(r.std, r.n_realizations, PAPER_PRECISION[model],
                                  offset_bound(model))  # fmt: skip
        ok = abs(r.beta_star - paper) <= tol
        rows.append(_row(f"beta* {model} (lambda1 = 5e-4)", paper, r.beta_star, r.std, settings,
                         "reproduced" if ok else "not reproduced"))  # fmt: skip
        span = [round(float(r.betas[0]), 6), round(float(r.betas[-1]), 6)]
        wide = (
            f"; lambda1 did not cross the target in {list(BETA_RANGE[model])}: the gains "
            f"span {span}"
            if span != list(BETA_RANGE[model])
            else ""
        )
        checks.append(Check(
            name=f"paper.beta_star.{model}", status=PASS if ok else FAIL,
            values={"value": r.beta_star, "se": r.std, "ci95": list(r.ci95), "paper": paper,
                    "tolerance": tol, "offset_bound": offset_bound(model)},
            tolerance=rule, details=details + wide,
        ))  # fmt: skip
    n = min(s.n_realizations, c.n_realizations)
    tol = beta_star_tolerance(shift_se, n, PAPER_PRECISION["shift"], offset_bound("shift"))
    ok = abs(shift - 0.726) <= tol
    rows.append(_row("coupling shift beta*_coupled - beta*_single", 0.726, shift, shift_se,
                     settings, "reproduced" if ok else "not reproduced"))  # fmt: skip
    checks.append(Check(
        name="paper.beta_star.shift", status=PASS if ok else FAIL,
        values={"value": shift, "se": shift_se, "paper": 0.726, "tolerance": tol,
                "offset_bound": offset_bound("shift")},
        tolerance=rule, details=details,
    ))  # fmt: skip
    return checks, rows, res


def lyapunov_curve(profile: Profile, threads: int | None) -> dict:
    """lambda1(beta) of the reduced models over the profile's gain grid (Fig. lLe)."""
    out = {}
    for model in MODEL_NAMES:
        vals = []
        gains = [BalanceParams(beta=float(beta)) for beta in profile.lyapunov_curve_gains]
        # one seed for every gain: each realisation's draws are made once for all of them
        scenario = Scenario(
            model,
            gains[0],
            profile.lyapunov_duration * 2,
            profile.lyapunov_realizations * 2,
            profile.seed_for("curve", model),
        )
        found = lyapunov_gains(scenario, gains, execution=Execution(threads=threads))
        for p, r in zip(gains, found, strict=True):
            vals.append((float(p.beta), r.lambda1, *r.ci95))
        out[model] = np.array(vals)
    return out


# ------------------------------------------------------------------ simulations
#: Simulations shared by every estimator of one run: (model, R, T, amplitude, dt, seed) -> arrays
_SERIES: dict[tuple, dict[str, np.ndarray]] = {}
#: Estimates the paper stages share with the robustness stage (same simulations, same
#: seeds, so the same numbers): RMS samples, the STCC of the paper's window, spectra
_RMS: dict[tuple, dict] = {}
_STCC: dict[tuple, tuple] = {}
_SPECTRA: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def clear_cache() -> None:
    """Forget the shared simulations (they hold a few hundred MB in the paper profile)."""
    for cache in (_SERIES, _RMS, _STCC, _SPECTRA):
        cache.clear()


def _batches(n: int, size: int):
    for a in range(0, n, size):
        yield a, min(size, n - a)


def _series_key(profile: Profile, model: str, amplitude: float | None = None) -> tuple:
    """What fixes :func:`series_set`'s simulations (the key of every estimate on them)."""
    amp = profile.rms_amplitude if amplitude is None else amplitude
    return (model, profile.peak_realizations, profile.peak_duration, amp, profile.decimate,
            profile.seed_for("series", model))  # fmt: skip


def series_set(
    profile: Profile, model: str, threads: int | None, amplitude: float | None = None
) -> dict[str, np.ndarray]:
    """float64 series of one model at the paper's gain, simulated once and cached.

    ``peak_realizations`` x ``peak_duration`` s sampled every ``decimate`` ms:
    balancing error ``e`` and its velocity ``ev`` (controller 1), tip and base
    velocities ``vt``, ``vb`` (controller 1), and for the coupled model the
    base velocity of controller 2 in realisation 0 (``vb2``, for Fig. scc).
    """
    amp = profile.rms_amplitude if amplitude is None else amplitude
    seed = profile.seed_for("series", model)
    key = _series_key(profile, model, amp)
    if key in _SERIES:
        return _SERIES[key]
    nc = get_model(model).n_controllers
    n = profile.peak_realizations
    parts: dict[str, list] = {"e": [], "ev": [], "vt": [], "vb": []}
    vb2 = None
    for r0, nb in _batches(n, 16):
        scn = Scenario(model, BalanceParams(beta=PAPER_BETA[model]), profile.peak_duration,
                       amplitude=amp)  # fmt: skip
        fields = ("balancing_error", "balancing_error_velocity", "tip_velocity", "base_velocity")
        tr = simulate(scn, noise=GainNoise(seed, nb, nc, first_realization=r0),
                      recording=Recording(decimate=profile.decimate, fields=fields),
                      execution=Execution(threads=threads))  # fmt: skip
        for k, f in (("e", "balancing_error"), ("ev", "balancing_error_velocity"),
                     ("vt", "tip_velocity"), ("vb", "base_velocity")):  # fmt: skip
            parts[k].append(tr[f][..., 0].copy())
        if r0 == 0 and nc == 2:
            vb2 = tr["base_velocity"][0, :, 1].copy()
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["dt"] = np.float64(profile.decimate * BalanceParams(beta=1.0).dt)
    if vb2 is not None:
        out["vb2"] = vb2
    _SERIES[key] = out
    return out


def rms_samples(profile: Profile, model: str, threads: int | None) -> dict[str, np.ndarray]:
    """Per-realisation RMS and largest |e| over [0, f T] for each duration fraction f (Fig. rms).

    ``rms_realizations`` x ``rms_duration`` s, batches of 32 realisations
    (same draws as one run), float64, sampled every 10 ms.
    """
    nc = get_model(model).n_controllers
    seed = profile.seed_for("rms", model)
    fracs = profile.robustness_durations
    key = (model, profile.rms_realizations, profile.rms_duration, profile.rms_amplitude,
           tuple(fracs), seed)  # fmt: skip
    if key in _RMS:  # simulated by the RMS stage: the robustness stage re-estimates on them
        return dict(_RMS[key])
    rms = {f: [] for f in fracs}
    peak = []
    for r0, nb in _batches(profile.rms_realizations, 32):
        tr = simulate(
            Scenario(
                model,
                BalanceParams(beta=PAPER_BETA[model]),
                profile.rms_duration,
                amplitude=profile.rms_amplitude,
            ),
            noise=GainNoise(seed, nb, nc, first_realization=r0),
            recording=Recording(decimate=10, fields=("balancing_error",)),
            execution=Execution(threads=threads),
        )
        e = tr["balancing_error"][..., 0]
        for f in fracs:
            rms[f].append(metrics.rms(e[:, : max(2, round(f * e.shape[1]))]))
        peak.append(np.max(np.abs(e), axis=-1))
    _RMS[key] = {"rms": {f: np.concatenate(v) for f, v in rms.items()},
                 "max": np.concatenate(peak)}  # fmt: skip
    return dict(_RMS[key])


# ------------------------------------------------------------------ estimators
def _tau_hat_density(th: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Per-realisation counts of tau_hat in ``edges``: (R, bins)."""
    th = th.reshape(th.shape[0], -1)
    return np.stack([np.histogram(row[np.isfinite(row)], bins=edges)[0] for row in th])


def _peak_of(counts: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height (1/s) and location (s) of the density's maximum; counts (..., bins)."""
    tot = counts.sum(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        dens = counts / (tot * np.diff(edges))
    k = np.argmax(dens, axis=-1)
    centres = 0.5 * (edges[1:] + edges[:-1])
    return np.take_along_axis(dens, k[..., None], -1)[..., 0], centres[k]


def _density_peak_ratios(cs: np.ndarray, cc: np.ndarray, edges, n_boot: int, seed: int):
    """Coupled / single ratios of the tau_hat density's peak height and location, with a
    percentile bootstrap over realisations (each model resampled independently)."""
    hs, ls = _peak_of(cs.sum(0), edges)
    hc, lc = _peak_of(cc.sum(0), edges)
    rng = np.random.default_rng(seed)
    bs = cs[rng.integers(0, cs.shape[0], (n_boot, cs.shape[0]))].sum(1)
    bc = cc[rng.integers(0, cc.shape[0], (n_boot, cc.shape[0]))].sum(1)
    hbs, lbs = _peak_of(bs, edges)
    hbc, lbc = _peak_of(bc, edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        hr, lr = hbc / hbs, lbc / lbs
    return {
        "height": (float(hc / hs), *map(float, np.nanpercentile(hr, [2.5, 97.5]))),
        "location": (float(lc / ls), *map(float, np.nanpercentile(lr, [2.5, 97.5]))),
        "single": (float(hs), float(ls)), "coupled": (float(hc), float(lc)),
    }  # fmt: skip


#: the rule of the paper table's status of a claim with a direction (a ratio below or above
#: 1) and a paper value
VERDICT_RULE = (
    "direction and magnitude reproduced: the 95 % interval lies on the claimed side of 1 and "
    "contains the paper's value; direction reproduced; magnitude not: on the claimed side, the "
    "paper's value outside; not reproduced: the interval lies on the other side of 1; "
    "direction inconclusive; magnitude not: the interval contains 1 but not the paper's value; "
    "inconclusive: the interval contains 1 and the paper's value"
)
#: the rule of the robustness table's verdict over the estimator choices
ROBUSTNESS_RULE = (
    "robust: every choice supports the claim (then: magnitude reproduced when the paper's value "
    "is inside every interval, not when inside none, else in how many); estimator-dependent: "
    "some choices support it, some do not; not reproduced: none supports it and at least one "
    "contradicts it; inconclusive: every choice is inconclusive"
)


def ratio_status(lo: float, hi: float, paper: float, side: str) -> str:
    """Paper-table status of a ratio claimed ``side`` ('below' / 'above') of 1 whose paper
    value is ``paper``, from its 95 % interval [lo, hi] (:data:`VERDICT_RULE`)."""
    d = _direction(lo, hi, side)
    if d == "supports":
        if lo <= paper <= hi:
            return "direction and magnitude reproduced"
        return "direction reproduced; magnitude not"
    if d == "contradicts":
        return "not reproduced"
    if np.isfinite(lo) and np.isfinite(hi) and not lo <= paper <= hi:
        return "direction inconclusive; magnitude not"
    return "inconclusive"


def _direction(lo: float, hi: float, side: str) -> str:
    """'supports' when the 95 % interval lies on the claimed side of 1, 'contradicts' when
    on the other, else 'inconclusive'."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "inconclusive"
    below, above = hi < 1.0, lo > 1.0
    if (side == "below" and below) or (side == "above" and above):
        return "supports"
    if (side == "below" and above) or (side == "above" and below):
        return "contradicts"
    return "inconclusive"


def _slope_agreement(a: float, sa: float, b: float, sb: float) -> str:
    s = float(np.hypot(sa, sb))
    if not np.isfinite(s) or s == 0:
        return "inconclusive"
    z = abs(a - b) / s
    return "supports" if z <= 2 else ("contradicts" if z > 3 else "inconclusive")


def _verdict(outcomes: list[str], in_ci: list[bool] | None = None) -> str:
    """Verdict over the estimator choices (:data:`ROBUSTNESS_RULE`); ``in_ci``: per choice,
    whether the paper's value lies inside its interval (None: no single paper number)."""
    if outcomes and all(o == "supports" for o in outcomes):
        if not in_ci:
            return "robust: reproduced"
        k = sum(in_ci)
        mag = ("magnitude reproduced" if k == len(in_ci) else "magnitude not" if k == 0
               else f"magnitude in {k}/{len(in_ci)} choices")  # fmt: skip
        return f"robust: direction reproduced; {mag}"
    if any(o == "supports" for o in outcomes):
        return "estimator-dependent"
    if any(o == "contradicts" for o in outcomes):
        return "not reproduced"
    return "inconclusive"


def _series_sets(profile: Profile, threads: int | None) -> tuple[dict[str, dict], float]:
    """Both models' :func:`series_set` (in :data:`MODEL_NAMES` order) and their sample
    interval (s)."""
    sets = {m: series_set(profile, m, threads) for m in MODEL_NAMES}
    return sets, float(sets["single"]["dt"])


def _duration_prefixes(profile: Profile, grid: dict, dt: float) -> list[tuple[float, int]]:
    """Each duration choice of ``grid`` (a fraction of ``peak_duration``) with the samples
    of the prefix of every series it keeps, at the sample interval ``dt`` (s)."""
    return [(frac, round(frac * profile.peak_duration / dt)) for frac in grid["duration"]]


def peak_grid(profile: Profile, threads: int | None, grid: dict) -> list[dict]:
    """tau_hat density claims (Fig. sccpeak:pdf) for every estimator choice in ``grid``.

    One STCC per model and window (computed up to the largest lag, every
    smaller lag range is a slice of it), re-estimated for each lag range,
    dominance, significance rule, bin width and duration prefix.
    """
    rows = []
    sets, dt = _series_sets(profile, threads)
    lmax = max(grid["max_lag"])
    seed = profile.seed_for("robustness", "peaks")
    for window in grid["window"]:
        stc = {m: _stcc_of(profile, m, d, window, lmax) for m, d in sets.items()}
        for max_lag in grid["max_lag"]:
            nl = round(max_lag / dt) + 1
            for frac in grid["duration"]:
                for sig_rule in grid["significance"]:
                    peaks = {}
                    for m, (t, lags, r, lev) in stc.items():
                        keep = t + window + max_lag <= frac * profile.peak_duration + 1e-9
                        sig = lev[:, keep] if sig_rule == "bartlett" else 0.0
                        each = metrics.dominant_peaks_each(r[:, keep, :nl], lags[:nl],
                                                           grid["dominance"], sig)  # fmt: skip
                        peaks[m] = dict(zip(grid["dominance"], each, strict=True))
                    for dom in grid["dominance"]:
                        ps, pc = peaks["single"][dom], peaks["coupled"][dom]
                        for width in grid["bins"]:
                            edges = np.arange(0.0, max_lag + width / 2, width)
                            cs = _tau_hat_density(ps.tau_hat, edges)
                            cc = _tau_hat_density(pc.tau_hat, edges)
                            res = _density_peak_ratios(cs, cc, edges, profile.n_bootstrap, seed)
                            res["densities"] = {
                                m: c.sum(0) / max(c.sum(), 1) / np.diff(edges)
                                for m, c in (("single", cs), ("coupled", cc))
                            }
                            rows.append({
                                "window": window, "max_lag": max_lag, "duration": frac
                                * profile.peak_duration, "significance": sig_rule,
                                "dominance": dom, "bin": width, **res,
                                "fractions_single": ps.fractions(),
                                "fractions_coupled": pc.fractions(),
                            })  # fmt: skip
    return rows


def _stcc_of(profile: Profile, model: str, d: dict, window: float, max_lag: float) -> tuple:
    """STCC (t, lags, R) and Bartlett level of one model's series set, all realisations.

    The paper's window (``profile.stcc_window``) is kept for the robustness stage,
    which re-estimates on it; other windows are computed and dropped.
    """
    dt = float(d["dt"])
    key = (*_series_key(profile, model), window, max_lag, profile.stcc_stride)
    if key in _STCC:
        return _STCC[key]
    t, lags, r = metrics.stcc(d["vt"], d["vb"], dt, window, max_lag, profile.stcc_stride)
    lev = metrics.stcc_significance_bartlett(d["vt"], d["vb"], dt, t, window)
    if window == profile.stcc_window:
        _STCC[key] = (t, lags, r, lev)
    return t, lags, r, lev


def velocity_grid(profile: Profile, threads: int | None, grid: dict) -> list[dict]:
    """Velocity density ratio near 0 (Fig. velo) for every estimator choice in ``grid``."""
    sets, _ = _series_sets(profile, threads)
    rows = []
    n = sets["single"]["ev"].shape[1]
    for frac in grid["duration"]:
        k = max(2, round(frac * n))
        for scale in grid["scale"]:
            for norm in grid["normalise"]:
                for res in metrics.density_ratios_near_zero(
                    sets["coupled"]["ev"][:, :k], sets["single"]["ev"][:, :k],
                    grid["half_width"], scale, norm, profile.n_bootstrap,
                    profile.seed_for("robustness", "velocity"),
                ):  # fmt: skip
                    rows.append({"duration": frac * profile.peak_duration, **res.as_dict()})
    return rows


def spectrum_grid(profile: Profile, threads: int | None, grid: dict) -> list[dict]:
    """Two power-law regimes of the error spectra, single vs coupled (Fig. pwsp)."""
    sets, dt = _series_sets(profile, threads)
    rows = []
    for frac, k in _duration_prefixes(profile, grid, dt):
        for seg in grid["segment"]:
            if seg > frac * profile.peak_duration / 2:
                continue
            for fmax in grid["fmax"]:
                fits = {}
                for m, d in sets.items():
                    f, s = _spectrum_of(profile, m, d, k, seg)
                    fits[m] = metrics.fit_two_power_laws(
                        f, s, max(0.05, 4.0 / seg), fmax, n_bootstrap=100,
                        seed=profile.seed_for("robustness", "spectrum"),
                    )  # fmt: skip
                rows.append(
                    {
                        "duration": frac * profile.peak_duration,
                        "segment": seg,
                        "fmax": fmax,
                        **{m: fit.as_dict() for m, fit in fits.items()},
                    }
                )
    return rows


def _spectrum_of(profile: Profile, model: str, d: dict, k: int, segment: float) -> tuple:
    """Welch spectrum (f, S) of the first ``k`` samples of one model's balancing errors,
    computed once per run (the paper table, its figure and the robustness grid share it)."""
    key = (*_series_key(profile, model), k, segment)
    if key not in _SPECTRA:
        _SPECTRA[key] = metrics.power_spectrum(d["e"][:, :k], float(d["dt"]), segment=segment)
    return _SPECTRA[key]


def laminar_grid(profile: Profile, threads: int | None, grid: dict) -> list[dict]:
    """Laminar-phase density exponent (on-off intermittency predicts -3/2)."""
    sets, dt = _series_sets(profile, threads)
    rows = []
    for frac, k in _duration_prefixes(profile, grid, dt):
        for ref in grid["threshold_reference"]:
            for thr in grid["threshold"]:
                out = {}
                for m, d in sets.items():
                    e = d["e"][:, :k]
                    scale = metrics.rms(e) if ref == "rms" else np.median(np.abs(e), -1)
                    durs = np.concatenate([
                        metrics.laminar_phases(row / (thr * s), dt, 1.0)
                        for row, s in zip(e, scale, strict=True)
                    ])  # fmt: skip
                    slope, se = metrics.power_law_exponent(durs, 10 * dt, 20.0)
                    out[m] = {"slope": slope, "se": se, "n_phases": int(durs.size)}
                rows.append({"duration": frac * profile.peak_duration, "reference": ref,
                             "threshold": thr, **out})  # fmt: skip
    return rows


def rms_grid(profile: Profile, threads: int | None, grid: dict) -> list[dict]:
    """Coupled / single RMS ratios (Fig. rms) by statistic and duration, bootstrap CIs."""
    s, c = rms_samples(profile, "single", threads), rms_samples(profile, "coupled", threads)
    rows = []
    for frac in profile.robustness_durations:
        for stat in grid["statistic"]:
            v, lo, hi = bootstrap_ratio_ci(c["rms"][frac], s["rms"][frac], stat,
                                           profile.n_bootstrap,
                                           profile.seed_for("robustness", "rms"))  # fmt: skip
            rows.append({"duration": frac * profile.rms_duration, "statistic": stat,
                         "ratio": v, "ci95": [lo, hi]})  # fmt: skip
    return rows, {"single": s, "coupled": c}


# ------------------------------------------------------------------ the paper table
DEFAULT_GRID = {
    "window": (5.0,), "max_lag": None, "dominance": (0.8,), "significance": ("bartlett",),
    "bins": (0.01,), "duration": (1.0,), "scale": ("median_std",), "normalise": (False, True),
    "half_width": (0.1,), "segment": None, "fmax": (20.0,), "threshold": (0.01,),
    "threshold_reference": ("rms",), "statistic": ("median", "geometric_mean", "mean"),
}  # fmt: skip


def _default_grid(profile: Profile) -> dict:
    g = dict(DEFAULT_GRID)
    g["max_lag"] = (profile.stcc_max_lag,)
    g["segment"] = (profile.peak_duration / 4,)
    return g


def _ci(v: float, lo: float, hi: float) -> str:
    return f"{v:.3g} [{lo:.3g}, {hi:.3g}]"


def rms_and_velocity(profile: Profile, threads: int | None) -> tuple[list[dict], dict]:
    """Coupling-induced stability (section 3.2): RMS (Fig. rms) and velocity density (Fig. velo)."""
    g = _default_grid(profile)
    rms_rows, samples = rms_grid(profile, threads, g)
    s_rms = samples["single"]["rms"][1.0]
    c_rms = samples["coupled"]["rms"][1.0]
    n = s_rms.size
    settings = (f"{n} realisations x {profile.rms_duration:g} s, initial balancing error "
                f"{profile.rms_amplitude:g} m, beta 20.306 / 21.032, float64")  # fmt: skip
    where = "section 3.2, Figs. Be, rms"
    full = {r["statistic"]: r for r in rms_rows if r["duration"] == profile.rms_duration}
    rows = []
    for stat, label in (("median", "median"), ("geometric_mean", "geometric mean")):
        r = full[stat]
        rows.append(_row(
            f"RMS coupled / single, {label} over realisations", 1e-2, r["ratio"], r["ci95"],
            settings, ratio_status(*r["ci95"], 1e-2, "below"),
            "paper: 'as low as 1 %' in RMS and maximum (text); a ratio below 1 is the claim"
            " (coupling suppresses the error)", where=where,
        ))  # fmt: skip
    pk = bootstrap_ratio_ci(samples["coupled"]["max"], samples["single"]["max"], "median",
                            profile.n_bootstrap, profile.seed_for("rms", "max"))  # fmt: skip
    rows.append(
        _row(
            "largest abs error coupled / single, median over realisations",
            1e-2,
            pk[0],
            list(pk[1:]),
            settings,
            ratio_status(pk[1], pk[2], 1e-2, "below"),
            "paper: 'as low as 1 %' of the maximal values (text)",
            where=where,
        )
    )
    for model, paper_mean in (("single", 1.5e3), ("coupled", 3.0e-1)):
        h = heavy_tailed_summary(
            samples[model]["rms"][1.0],
            (1e-2, 1.0, 1e2),
            profile.n_bootstrap,
            profile.seed_for("rms", "summary", model),
        )
        samples[model]["summary"] = h
        rows.append(_row(
            f"mean RMS, {model}", paper_mean, h["mean"]["value"], h["mean"]["ci95"], settings,
            "not a check",
            f"the mean of a heavy-tailed sample: the largest realisation carries "
            f"{100 * h['mean']['largest_share']:.0f} % of the sum and the RMS spans "
            f"{h['log10_spread']:.1f} decades; it also scales with the unstated initial error "
            f"(the model is linear). Median {h['median']['value']:.3g} "
            f"[{h['median']['ci95'][0]:.3g}, {h['median']['ci95'][1]:.3g}], geometric mean "
            f"{h['geometric_mean']['value']:.3g}; fraction above 1e-2 / 1 / 1e2 m: "
            + " / ".join(f"{v:.2f}" for v in h["fraction_above"].values()),
            where="section 3.2, Fig. rms (500 realisations)",
        ))  # fmt: skip
    r = full["mean"]
    rows.append(_row("ratio of mean RMS coupled / single", 2e-4, r["ratio"], r["ci95"], settings,
                     "not a check", "paper: 0.02 % (text); a ratio of unstable means",
                     where="section 3.2, Fig. rms"))  # fmt: skip
    # velocity density near 0 (Fig. velo)
    vel = velocity_grid(profile, threads, g)
    vs_ = series_set(profile, "single", threads)["ev"]
    vc_ = series_set(profile, "coupled", threads)["ev"]
    vset = (f"{vs_.shape[0]} realisations x {profile.peak_duration:g} s at "
            f"{profile.decimate} ms, bin |v| < 0.1 x median per-realisation SD")  # fmt: skip
    for v in vel:
        label = "velocities normalised per realisation" if v["normalised"] else "velocities"
        status = ratio_status(v["ci95"][0], v["ci95"][1], 2.0, "above")
        rows.append(_row(f"p(dq1/dt) / p(dx/dt) near 0, {label}", 2.0, v["ratio"], v["ci95"],
                         vset, status, f"h = {v['h']:.3g}; fractions within h: coupled "
                         f"{v['fraction_coupled']:.3g}, single {v['fraction_single']:.3g}",
                         where="section 3.2, Fig. velo"))  # fmt: skip
    sc = metrics.robust_scale(np.concatenate([vs_, vc_]), "median_std")
    edges = np.linspace(-3 * sc, 3 * sc, 61)
    return rows, {"single": {**samples["single"], "rms_by_duration": samples["single"]["rms"],
                             "rms": s_rms},
                  "coupled": {**samples["coupled"], "rms_by_duration": samples["coupled"]["rms"],
                              "rms": c_rms},
                  "velo": metrics.velocity_density_ratio(vc_, vs_, edges)}  # fmt: skip


def peaks_and_spectra(profile: Profile, threads: int | None) -> tuple[list[dict], dict]:
    """Coupling-induced sensitivity (section 3.3), spectra (section 3.1) and the experiment's
    claims (section 4), one row each.

    The function is long because the STCC peaks and the spectra share the simulations of one
    batch loop.
    """
    g = _default_grid(profile)
    rows, data = [], {}
    sets, dt = _series_sets(profile, threads)
    edges = np.arange(0.0, profile.stcc_max_lag + 0.005, 0.01)  # as peak_grid's 0.01 s bins
    for model, d in sets.items():
        vbs = [d["vb"][:1]] + ([d["vb2"][None]] if "vb2" in d else [])
        ths = []
        for i, vb in enumerate(vbs):
            t, lags, r = metrics.stcc(d["vt"][:1], vb, dt, profile.stcc_window,
                                      profile.stcc_max_lag, profile.stcc_stride)  # fmt: skip
            lev = metrics.stcc_significance_bartlett(d["vt"][:1], vb, dt, t, profile.stcc_window)
            ths.append(metrics.dominant_peaks(r, lags, 0.8, lev).tau_hat)
            k36 = int(np.argmin(np.abs(t - 36.0)))
            data.setdefault(f"scc_{model}", {"lags": lags, "t": t[k36]})
            data[f"scc_{model}"]["R" if i == 0 else "R2"] = r[0, k36]
        data[f"peaks_{model}"] = {"t": t, "tau_hat": np.stack(ths, -1), "edges": edges}
    if "R2" not in data["scc_single"]:
        data["scc_single"]["R2"] = data["scc_single"]["R"]
    th36 = data["peaks_coupled"]["tau_hat"][0, int(np.argmin(np.abs(t - 36.0)))]
    pset = (f"{profile.peak_realizations} realisations x {profile.peak_duration:g} s, "
            f"Dt = {profile.stcc_window:g} s, lags 0-{profile.stcc_max_lag:g} s, dominance 0.8, "
            f"Bartlett level z = 3, bins 0.01 s")  # fmt: skip
    rows.append(_row("tau_hat at t = 36 s, coupled, controllers 1 and 2 (one realisation)",
                     [0.105, 0.035], [float(v) for v in th36], "n/a (one realisation)", pset,
                     "not a check", "one draw of the noise; ours is another draw",
                     where="section 3.3, Fig. scc"))  # fmt: skip
    pk = peak_grid(profile, threads, g)[0]
    for m in MODEL_NAMES:
        data[f"peaks_{m}"]["peak_height"], data[f"peaks_{m}"]["peak_at"] = pk[m]
        data[f"peaks_{m}"]["density"] = pk["densities"][m]
    for key, paper_v, side, text in (
        ("height", 1.38, "above", "density peak height coupled / single ('38 % higher')"),
        ("location", 0.8, "below", "density peak location coupled / single ('20 % shorter')"),
    ):
        v, lo, hi = pk[key]
        status = ratio_status(lo, hi, paper_v, side)
        rows.append(_row(
            f"tau_hat {text}", paper_v, v, [lo, hi], pset, status,
            f"paper value inside the 95 % interval: {'yes' if lo <= paper_v <= hi else 'no'}; "
            f"windows without a peak: single {pk['fractions_single']['no_peak']:.2f}, coupled "
            f"{pk['fractions_coupled']['no_peak']:.2f}; boundary maxima: single "
            f"{pk['fractions_single']['boundary_max']:.2f}, coupled "
            f"{pk['fractions_coupled']['boundary_max']:.2f}",
            where="section 3.3, Fig. sccpeak:pdf (100 realisations, [0, 1200] s)",
        ))  # fmt: skip
    # spectra: the model's claim is two regimes unchanged by coupling (Fig. pwsp)
    sp = spectrum_grid(profile, threads, g)[0]
    fs, fc = sp["single"], sp["coupled"]
    for m in MODEL_NAMES:
        f, s = _spectrum_of(profile, m, sets[m], sets[m]["e"].shape[1],
                            profile.peak_duration / 4)  # fmt: skip
        data[f"pwsp_{m}"] = {"f": f, "S": s.mean(axis=0),
                             "fit": metrics.PowerLawFit(**sp[m])}  # fmt: skip
        # the realisations' spread (the mean is set by the largest ones): for the figure
        data[f"pwsp_{m}"]["S_quantiles"] = np.quantile(s, (0.05, 0.25, 0.5, 0.75, 0.95), axis=0)
    sset = (f"{profile.peak_realizations} x {profile.peak_duration:g} s, Welch "
            f"{profile.peak_duration / 4:g} s segments, broken-line fit "
            f"{max(0.05, 16 / profile.peak_duration):.3g}-20 Hz")  # fmt: skip
    two_oc = [
        _slope_agreement(f["slope_low"], f["slope_low_se"], f["slope_high"], f["slope_high_se"])
        for f in (fs, fc)
    ]
    # two regimes: the slopes differ (beyond 3 SE) in both models; one model with equal slopes
    # (within 2 SE) contradicts it; anything else is inconclusive
    two_status = (
        "reproduced"
        if all(t == "contradicts" for t in two_oc)
        else "not reproduced"
        if "supports" in two_oc
        else "inconclusive"
    )
    rows.append(_row(
        "two power-law regimes in the error spectrum (single, coupled)", "two slopes",
        [fs["slope_low"], fs["slope_high"], fc["slope_low"], fc["slope_high"]],
        [fs["slope_low_se"], fs["slope_high_se"], fc["slope_low_se"], fc["slope_high_se"]],
        sset, two_status,
        f"slopes low, high (single) and low, high (coupled) with bootstrap SEs; crossovers "
        f"{fs['crossover']:.3g} / {fc['crossover']:.3g} Hz; the paper gives no slope values",
        where="section 3.1, Fig. pwsp",
    ))  # fmt: skip
    same = [_slope_agreement(fs[k], fs[k + "_se"], fc[k], fc[k + "_se"])
            for k in ("slope_low", "slope_high")]  # fmt: skip
    rows.append(_row(
        "coupling does not change the scaling law (slopes single = coupled)", "unchanged",
        [fc["slope_low"] - fs["slope_low"], fc["slope_high"] - fs["slope_high"]],
        [float(np.hypot(fs[k + "_se"], fc[k + "_se"])) for k in ("slope_low", "slope_high")],
        sset, {"supports": "reproduced", "contradicts": "not reproduced"}.get(
            min(same, key=["contradicts", "inconclusive", "supports"].index),
            "inconclusive"),
        "differences coupled - single of the low and high slopes; equal within 2 SE",
        where="section 3.1, Fig. pwsp",
    ))  # fmt: skip
    lam = laminar_grid(profile, threads, g)[0]
    for m in MODEL_NAMES:
        sl, se = lam[m]["slope"], lam[m]["se"]
        lam_status = (
            "inconclusive"
            if not (np.isfinite(sl) and np.isfinite(se))
            else "reproduced"
            if abs(sl + 1.5) <= 2 * se
            else "not reproduced"
            if abs(sl + 1.5) > 3 * se
            else "inconclusive"
        )
        rows.append(_row(
            f"laminar-phase density exponent, {m}", -1.5, sl, se,
            f"|e| < 1 % of its RMS per realisation, durations {10 * dt:g}-20 s",
            lam_status,
            "the paper asserts on-off intermittency (section 3.1) and cites its -3/2 law; it "
            f"reports no exponent. {lam[m]['n_phases']} phases",
            where="section 3.1 (on-off intermittency, with Fig. pwsp)",
        ))  # fmt: skip
    rows += experiment_rows(fs, fc)
    return rows, data


def experiment_rows(fs: dict, fc: dict) -> list[dict]:
    """Claims about the human experiment (section 4) and the paper's own inconsistencies:
    reported beside the table, not checks (no human data here)."""
    exp = "human experiment"
    why = "not a check: a claim about the human experiment (no human data here)"
    return [
        _row("low-frequency spectral exponent of the balancing error, single and coupled",
             -0.5, [fs["slope_low"], fc["slope_low"]], [fs["slope_low_se"], fc["slope_low_se"]],
             "ours: the linear model's low slope (single, coupled), for information",
             "not a check", why + "; the paper claims -1/2 for the subjects, not the model",
             system=exp, where="section 4.2, Figs. move_s, move_c"),
        _row("mean correlation time: single A, B; coupled A, B (s)",
             [0.132, 0.136, 0.128, 0.168], "n/a (human data)", "n/a (human data)",
             "5 trials per subject, pair (A, B)", "not a check", why, system=exp,
             where="section 4.3, Tab. STCC, Figs. stcc_s, stcc_c"),
        _row("mean RMS of the balancing error: single A, B; coupled A, B",
             [3.62, 5.34, 3.02, 2.50], "n/a (human data)", "n/a (human data)",
             "5 trials per subject, pair (A, B)", "not a check", why, system=exp,
             where="section 4.3, Tab. RMS"),
        _row("coupling decreases the individual differences in correlation time and increases "
             "those in RMS (six subjects)", "qualitative", "n/a (human data)",
             "n/a (human data)", "pairs (A,B), (C,D), (F,D)", "not a check",
             why + "; it states the opposite of the text on Tabs. STCC and RMS",
             system=exp, where="section 4.3, Fig. rmstau"),
        _row("lambda1 chosen for on-off intermittency", 5e-4, "n/a (a setting)",
             "n/a (a setting)", "gains 20.306 / 21.032 of the captions", "not a check",
             "the text says 5e-5, the captions of Figs. Be and pwsp 5e-4 with these gains; "
             "we use the captions", where="section 3.1, Figs. lLe, Be, pwsp"),
    ]  # fmt: skip


# ------------------------------------------------------------------ robustness table
CLAIMS = {
    "suppression": "coupling suppresses the error (RMS coupled / single < 1; paper: 1 %)",
    "velocity": "velocity density near 0 about 2x higher with coupling",
    "peak_height": "tau_hat density peak 38 % higher with coupling",
    "peak_location": "tau_hat density peak 20 % shorter with coupling",
    "two_regimes": "two spectral power-law regimes",
    "unchanged": "spectral slopes unchanged by coupling",
    "laminar": "on-off intermittency: laminar phases ~ T^-3/2",
}
WHERE = {"suppression": "section 3.2, Figs. Be, rms", "velocity": "section 3.2, Fig. velo",
         "peak_height": "section 3.3, Fig. sccpeak:pdf",
         "peak_location": "section 3.3, Fig. sccpeak:pdf", "two_regimes": "section 3.1, Fig. pwsp",
         "unchanged": "section 3.1, Fig. pwsp", "laminar": "section 3.1"}  # fmt: skip


#: claims about the direction of a ratio (below / above 1) that also have a paper value
RATIO_CLAIMS = ("suppression", "velocity", "peak_height", "peak_location")


def _outcomes(grids: dict) -> dict[str, list[dict]]:
    """Per claim: one entry per estimator choice with its estimate, interval and outcome."""
    out: dict[str, list[dict]] = {k: [] for k in CLAIMS}
    for r in grids["rms"]:
        out["suppression"].append({"choice": {"statistic": r["statistic"],
                                              "duration": r["duration"]},
                                   "estimate": r["ratio"], "ci95": r["ci95"], "paper": 1e-2,
                                   "outcome": _direction(*r["ci95"], "below")})  # fmt: skip
    for r in grids["velocity"]:
        out["velocity"].append({"choice": {k: r[k] for k in ("duration", "scale_method",
                                                            "normalised", "half_width")},
                                "estimate": r["ratio"], "ci95": list(r["ci95"]), "paper": 2.0,
                                "outcome": _direction(*r["ci95"], "above")})  # fmt: skip
    for r in grids["peaks"]:
        ch = {k: r[k] for k in ("window", "max_lag", "duration", "significance", "dominance",
                                "bin")}  # fmt: skip
        for key, claim, side, pv in (
            ("height", "peak_height", "above", 1.38),
            ("location", "peak_location", "below", 0.8),
        ):
            v, lo, hi = r[key]
            out[claim].append({"choice": ch, "estimate": v, "ci95": [lo, hi], "paper": pv,
                               "outcome": _direction(lo, hi, side)})  # fmt: skip
    for r in grids["spectra"]:
        ch = {k: r[k] for k in ("duration", "segment", "fmax")}
        s, c = r["single"], r["coupled"]
        two = [_slope_agreement(f["slope_low"], f["slope_low_se"], f["slope_high"],
                                f["slope_high_se"]) for f in (s, c)]  # fmt: skip
        oc = (
            "supports"
            if all(t == "contradicts" for t in two)
            else "contradicts"
            if all(t == "supports" for t in two)
            else "inconclusive"
        )
        out["two_regimes"].append({"choice": ch, "estimate": [s["slope_low"], s["slope_high"],
                                   c["slope_low"], c["slope_high"]], "ci95": None,
                                   "paper": "two slopes", "outcome": oc})  # fmt: skip
        same = [_slope_agreement(s[k], s[k + "_se"], c[k], c[k + "_se"])
                for k in ("slope_low", "slope_high")]  # fmt: skip
        out["unchanged"].append({"choice": ch, "estimate": [c["slope_low"] - s["slope_low"],
                                 c["slope_high"] - s["slope_high"]], "ci95": None,
                                 "paper": "unchanged",
                                 "outcome": min(same, key=["contradicts", "inconclusive",
                                                           "supports"].index)})  # fmt: skip
    for r in grids["laminar"]:
        ch = {k: r[k] for k in ("duration", "reference", "threshold")}
        for m in MODEL_NAMES:
            sl, se = r[m]["slope"], r[m]["se"]
            oc = (
                "inconclusive"
                if not np.isfinite(sl)
                else "supports"
                if abs(sl + 1.5) <= 2 * se
                else "contradicts"
                if abs(sl + 1.5) > 3 * se
                else "inconclusive"
            )
            out["laminar"].append({"choice": {**ch, "model": m}, "estimate": sl,
                                   "ci95": [sl - 1.96 * se, sl + 1.96 * se], "paper": -1.5,
                                   "outcome": oc})  # fmt: skip
    return out


def _summary(outcomes: dict[str, list[dict]]) -> list[dict]:
    rows = []
    for claim, entries in outcomes.items():
        oc = [e["outcome"] for e in entries]
        est = [
            e["estimate"]
            for e in entries
            if np.isscalar(e["estimate"]) and np.isfinite(e["estimate"])
        ]
        dims: dict[str, list] = {}
        for e in entries:
            for k, v in e["choice"].items():
                dims.setdefault(k, [])
                if v not in dims[k]:
                    dims[k].append(v)
        by_dim = {}
        for k, values in dims.items():
            if len(values) < 2:
                continue
            by_dim[k] = {str(v): f"{sum(e['outcome'] == 'supports' for e in entries if e['choice'][k] == v)}/{sum(e['choice'][k] == v for e in entries)}" for v in values}  # noqa: E501  # fmt: skip
        in_ci = [e for e in entries if e["ci95"] is not None and np.isscalar(e["paper"])]
        rows.append({
            "claim": CLAIMS[claim], "key": claim, "system": "model", "where": WHERE[claim],
            "n_choices": len(entries), "supports": oc.count("supports"),
            "contradicts": oc.count("contradicts"), "inconclusive": oc.count("inconclusive"),
            "estimate_range": [float(np.nanmin(est)), float(np.nanmax(est))] if est else None,
            "paper_in_ci": (f"{sum(e['ci95'][0] <= e['paper'] <= e['ci95'][1] for e in in_ci)}"
                            f"/{len(in_ci)}") if in_ci else "n/a (no single paper number)",
            "supports_by_choice": by_dim,
            "verdict": _verdict(oc, [e["ci95"][0] <= e["paper"] <= e["ci95"][1]
                                     for e in in_ci] if in_ci and claim in RATIO_CLAIMS
                                else None),
        })  # fmt: skip
    return rows


def robustness(profile: Profile, threads: int | None) -> dict:
    """The robustness table: each quantitative model claim across the estimator choices the
    paper leaves unstated (``profile.robustness_grid``), re-estimated on one set of
    simulations per model.  Verdict: :data:`ROBUSTNESS_RULE`."""
    g = {**_default_grid(profile), **profile.robustness_grid}
    grids = {"rms": rms_grid(profile, threads, g)[0],
             "velocity": velocity_grid(profile, threads, g),
             "peaks": peak_grid(profile, threads, g),
             "spectra": spectrum_grid(profile, threads, g),
             "laminar": laminar_grid(profile, threads, g)}  # fmt: skip
    outcomes = _outcomes(grids)
    amp = amplitude_invariance(profile, threads)
    return {"summary": _summary(outcomes), "outcomes": outcomes, "grid": g,
            "amplitude": amp}  # fmt: skip


def amplitude_invariance(profile: Profile, threads: int | None) -> dict:
    """Initial amplitude: the linear models scale exactly with it under the same noise, so every
    ratio and slope above is invariant.  Checked on 2 realisations x 20 s per model."""
    out = {}
    for model in MODEL_NAMES:
        scn = Scenario(model, BalanceParams(beta=PAPER_BETA[model]), 20.0, 2,
                       profile.seed_for("series", model))  # fmt: skip
        rec = Recording(decimate=5, fields=("balancing_error",))
        a = [simulate(replace(scn, amplitude=amp), recording=rec,
                      execution=Execution(threads=threads))["balancing_error"]
             for amp in (1e-8, 1e-2)]  # fmt: skip
        out[model] = float(np.max(np.abs(a[1] * 1e-6 - a[0])) / np.max(np.abs(a[0])))
    return {
        "max_relative_difference_of_scaled_errors": out,
        "amplitudes": [1e-8, 1e-2],
        "invariant": all(v < 1e-9 for v in out.values()),
    }


# ------------------------------------------------------------------ nonlinear stick
def nonlinear_comparison(profile: Profile, threads: int | None) -> list[dict]:
    """Spectral slopes and laminar exponent of the nonlinear stick (eq. (1)) beside the
    linear single model (eq. (2)) at beta = 20.306, same seed, each noise floor."""
    n, T = profile.nonlinear_realizations, profile.nonlinear_duration
    seed = profile.seed_for("nonlinear")
    p = BalanceParams(beta=PAPER_BETA["single"])
    runs = {
        "linear single": simulate(
            Scenario("single", p, T, n, seed, amplitude=profile.rms_amplitude),
            recording=Recording(decimate=profile.decimate, fields=("balancing_error",)),
            execution=Execution(threads=threads),
        )["balancing_error"][..., 0]
    }
    for floor in profile.nonlinear_floors:
        runs[f"nonlinear, floor {floor:g}"] = simulate_nonlinear(
            Scenario("single", p, T, n, seed, amplitude=profile.rms_amplitude),
            noise_floor=floor,
            recording=Recording(decimate=profile.decimate, fields=("angle",)),
            execution=Execution(threads=threads),
        )["angle"][..., 0]
    dt = profile.decimate * p.dt
    rows = []
    for name, e in runs.items():
        angle = name.startswith("nonlinear")
        seg = T / 4
        f, s = metrics.power_spectrum(e, dt, segment=seg)
        fit = metrics.fit_two_power_laws(f, s, max(0.05, 4 / seg), 20.0, n_bootstrap=100,
                                         seed=seed)  # fmt: skip
        thr = 0.01 * metrics.rms(e)
        durs = np.concatenate([metrics.laminar_phases(row / t, dt, 1.0)
                               for row, t in zip(e, thr, strict=True)])  # fmt: skip
        sl, se = metrics.power_law_exponent(durs, 10 * dt, 20.0)
        rows.append(
            {
                "model": name,
                "realizations": n,
                "duration": T,
                "seed": seed,
                "slope_low": fit.slope_low,
                "slope_low_se": fit.slope_low_se,
                "slope_high": fit.slope_high,
                "crossover": fit.crossover,
                "low_is_minus_half": bool(abs(fit.slope_low + 0.5) <= 2 * fit.slope_low_se),
                "laminar_slope": sl,
                "laminar_se": se,
                "laminar_is_minus_three_halves": bool(np.isfinite(sl) and abs(sl + 1.5) <= 2 * se),
                "max_abs": float(np.nanmax(np.abs(e))),
                "fallen_fraction": (
                    float(np.mean(np.nanmax(np.abs(e), -1) > np.pi / 2)) if angle else None
                ),
            }
        )
    return rows
