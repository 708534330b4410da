"""Reproduction of the paper's numbers with the reduced model (paper section 3).

Each row: the quantity, the paper's value, ours with its uncertainty, the
settings, and a status: ``reproduced``, ``not reproduced`` or ``qualitative``
(the paper gives a shape, not a number).  Only the critical gains are
verdicts of the run (issue 2's acceptance: within 0.25, shift within 0.15);
the other rows are reported as measured.
"""

from __future__ import annotations

import numpy as np

from reduced import BalanceParams, ParameterError, critical_gain, lyapunov, simulate

from . import metrics
from .profiles import PAPER_BETA, Profile
from .stats import FAIL, PASS, Check

BETA_RANGE = {"single": (19.8, 20.8), "coupled": (20.55, 21.55)}


def _row(quantity, paper, ours, uncertainty, settings, status, note=""):
    return {"quantity": quantity, "paper": paper, "ours": ours, "uncertainty": uncertainty,
            "settings": settings, "status": status, "note": note}  # fmt: skip


def critical_gains(profile: Profile, threads: int | None):
    """beta* for lambda1 = 5e-4, both models (Figs. lLe, Be)."""
    res = {}
    settings = (f"{profile.beta_star_realizations} realisations x {profile.beta_star_duration:g} s"
                f" at {profile.beta_star_gains} gains, dt 1 ms")  # fmt: skip
    failed = []
    for model in ("single", "coupled"):
        try:
            res[model] = critical_gain(
                model, BalanceParams(beta=20.0), BETA_RANGE[model], target=5e-4,
                n_gains=profile.beta_star_gains, duration=profile.beta_star_duration,
                n_realizations=profile.beta_star_realizations,
                seed=profile.seed_for("beta_star", model), threads=threads,
            )  # fmt: skip
        except ParameterError as exc:  # the target was not crossed: a failed check, not a crash
            failed.append(Check(name=f"paper.beta_star.{model}", status=FAIL,
                                values={"paper": PAPER_BETA[model]},
                                tolerance="|beta* - paper| <= 0.25 (issue 2)",
                                details=f"{exc}; {settings}"))  # fmt: skip
    if failed:
        return failed, [], res
    s, c = res["single"], res["coupled"]
    shift = c.beta_star - s.beta_star
    shift_se = float(np.hypot(s.std, c.std))
    checks, rows = [], []
    for model, paper in PAPER_BETA.items():
        r = res[model]
        ok = abs(r.beta_star - paper) <= 0.25
        rows.append(_row(f"beta* {model} (lambda1 = 5e-4)", paper, r.beta_star, r.std, settings,
                         "reproduced" if ok else "not reproduced"))  # fmt: skip
        checks.append(Check(
            name=f"paper.beta_star.{model}", status=PASS if ok else FAIL,
            values={"value": r.beta_star, "se": r.std, "ci95": list(r.ci95), "paper": paper},
            tolerance="|beta* - paper| <= 0.25 (issue 2)", details=settings,
        ))  # fmt: skip
    ok = abs(shift - 0.726) <= 0.15
    rows.append(_row("coupling shift beta*_coupled - beta*_single", 0.726, shift, shift_se,
                     settings, "reproduced" if ok else "not reproduced"))  # fmt: skip
    checks.append(Check(
        name="paper.beta_star.shift", status=PASS if ok else FAIL,
        values={"value": shift, "se": shift_se, "paper": 0.726},
        tolerance="|shift - 0.726| <= 0.15 (issue 2)", details=settings,
    ))  # fmt: skip
    return checks, rows, res


def lyapunov_curve(profile: Profile, threads: int | None) -> dict:
    """lambda1(beta) of the reduced models over the profile's gain grid (Fig. lLe)."""
    out = {}
    for model in ("single", "coupled"):
        vals = []
        for beta in profile.lyapunov_curve_gains:
            r = lyapunov(model, BalanceParams(beta=float(beta)), profile.lyapunov_duration * 2,
                         profile.lyapunov_realizations * 2,
                         seed=profile.seed_for("curve", model), threads=threads)  # fmt: skip
            vals.append((float(beta), r.lambda1, *r.ci95))
        out[model] = np.array(vals)
    return out


def rms_and_velocity(profile: Profile, threads: int | None) -> tuple[list[dict], dict]:
    """RMS of the balancing errors (Fig. rms) and the velocity density ratio (Fig. velo)."""
    data = {}
    for model, beta in PAPER_BETA.items():
        tr = simulate(
            model, BalanceParams(beta=beta), profile.rms_duration, profile.rms_realizations,
            profile.seed_for("rms", model), amplitude=profile.rms_amplitude, decimate=10,
            fields=("balancing_error", "balancing_error_velocity"), dtype=np.float32,
            threads=threads,
        )  # fmt: skip
        data[model] = {
            "rms": metrics.rms(tr["balancing_error"][..., 0]),
            "velocity": tr["balancing_error_velocity"][..., 0],
        }
    rs, rc = data["single"]["rms"], data["coupled"]["rms"]
    n = len(rs)
    settings = (f"{n} realisations x {profile.rms_duration:g} s, initial balancing error "
                f"{profile.rms_amplitude:g} m, beta 20.306 / 21.032")  # fmt: skip
    rows = [
        _row("mean RMS single", 1.5e3, float(rs.mean()), float(rs.std(ddof=1) / np.sqrt(n)),
             settings, "qualitative", "depends on the initial error and duration; heavy tailed"),
        _row("mean RMS coupled", 3.0e-1, float(rc.mean()), float(rc.std(ddof=1) / np.sqrt(n)),
             settings, "qualitative", "depends on the initial error and duration"),
        _row("median RMS coupled / single", None, float(np.median(rc) / np.median(rs)), None,
             settings, "reproduced" if np.median(rc) < np.median(rs) else "not reproduced",
             "paper: coupling suppresses the error (Fig. rms)"),
    ]  # fmt: skip
    # velocity densities near the origin (Fig. velo): bins of 1/20 of the coupled SD
    vs, vc = data["single"]["velocity"], data["coupled"]["velocity"]
    h = float(np.std(vc)) / 20
    edges = np.linspace(-5 * h, 5 * h, 11)
    _centres, ratio = metrics.velocity_density_ratio(vc, vs, edges)
    near = float(np.nanmean(ratio[4:6]))
    rows.append(_row("p(dq1/dt) / p(dx/dt) near 0", 2.0, near, None, settings,
                     "reproduced" if 1.5 <= near <= 2.5 else "not reproduced",
                     f"histogram bins of {h:.2g} m/s"))  # fmt: skip
    wide = np.linspace(-3 * np.std(vs), 3 * np.std(vs), 41)
    data["velo"] = metrics.velocity_density_ratio(vc, vs, wide)
    return rows, data


def peaks_and_spectra(profile: Profile, threads: int | None) -> tuple[list[dict], dict]:
    """STCC example at t = 36 (Fig. scc), tau_hat densities (Fig. sccpeak:pdf), spectral
    slopes (Fig. pwsp) and laminar phases of the reduced models."""
    rows, data = [], {}
    edges = np.arange(0.0, profile.stcc_max_lag + 0.01, 0.01)
    for model, beta in PAPER_BETA.items():
        tr = simulate(
            model, BalanceParams(beta=beta), profile.peak_duration, profile.peak_realizations,
            profile.seed_for("peaks", model), amplitude=profile.rms_amplitude,
            decimate=profile.decimate, fields=("tip_velocity", "base_velocity"),
            dtype=np.float32, threads=threads,
        )  # fmt: skip
        dt = tr.sample_interval
        ths = []
        for i in range(tr.shape[2]):
            t, lags, r = metrics.stcc(
                tr["tip_velocity"][..., i], tr["base_velocity"][..., i], dt,
                profile.stcc_window, profile.stcc_max_lag, profile.stcc_stride,
            )  # fmt: skip
            sig = metrics.stcc_significance(round(profile.stcc_window / dt))
            ths.append(metrics.first_dominant_peak(r, lags, significance=sig))
            if i == 0:
                k36 = int(np.argmin(np.abs(t - 36.0)))
                data[f"scc_{model}"] = {"lags": lags, "R": r[0, k36], "t": t[k36]}
            else:
                data[f"scc_{model}"]["R2"] = r[0, k36]
        dens, hmax, loc = metrics.peak_density(ths[0], edges)
        data[f"peaks_{model}"] = {"t": t, "tau_hat": np.stack(ths, -1), "density": dens,
                                  "edges": edges, "peak_height": hmax, "peak_at": loc}  # fmt: skip
    s, c = data["peaks_single"], data["peaks_coupled"]
    settings = (f"{profile.peak_realizations} realisations x {profile.peak_duration:g} s, "
                f"Dt = {profile.stcc_window:g} s, bins 0.01 s")  # fmt: skip
    h_ratio = c["peak_height"] / s["peak_height"]
    l_ratio = c["peak_at"] / s["peak_at"] if s["peak_at"] > 0 else float("nan")
    th36 = c["tau_hat"][:, np.argmin(np.abs(c["t"] - 36.0))]
    rows += [
        _row("tau_hat at t = 36 (coupled, controllers 1, 2), realisation 0",
             [0.105, 0.035], [float(v) for v in th36[0]], None, settings, "qualitative",
             "one realisation; ours is a different draw"),
        _row("tau_hat density peak height coupled / single", 1.38, float(h_ratio), None,
             settings, "reproduced" if h_ratio > 1.0 else "not reproduced"),
        _row("tau_hat density peak location coupled / single", 0.8, float(l_ratio), None,
             settings, "reproduced" if l_ratio < 1.0 else "not reproduced"),
    ]  # fmt: skip
    for model, beta in PAPER_BETA.items():
        tr = simulate(
            model, BalanceParams(beta=beta), profile.spectrum_duration,
            profile.spectrum_realizations, profile.seed_for("spectrum", model),
            amplitude=profile.rms_amplitude, decimate=10, fields=("balancing_error",),
            dtype=np.float32, threads=threads,
        )  # fmt: skip
        e = tr["balancing_error"][..., 0].astype(float)
        seg = profile.spectrum_duration / 4
        f, sp = metrics.power_spectrum(e, tr.sample_interval, segment=seg)
        fit = metrics.fit_two_power_laws(f, sp, 4.0 / seg, 20.0, n_bootstrap=100)
        data[f"pwsp_{model}"] = {"f": f, "S": sp.mean(axis=0), "fit": fit}
        rows.append(_row(f"low-frequency spectral slope, {model}", -0.5, fit.slope_low,
                         fit.slope_low_se,
                         f"{profile.spectrum_realizations} x {profile.spectrum_duration:g} s, "
                         f"Welch {seg:g} s segments, fit {4 / seg:.3g}-20 Hz",
                         "reproduced" if abs(fit.slope_low + 0.5) <= 3 * fit.slope_low_se
                         else "not reproduced",
                         f"high-frequency slope {fit.slope_high:.2f} +- {fit.slope_high_se:.2f},"
                         f" crossover {fit.crossover:.3g} Hz"))  # fmt: skip
        # laminar phases: |e| below 1 % of its RMS over each realisation
        thr = 0.01 * metrics.rms(e)[:, None]
        durs = np.concatenate([metrics.laminar_phases(row / t, tr.sample_interval, 1.0)
                               for row, t in zip(e, thr, strict=True)])  # fmt: skip
        slope, se = metrics.power_law_exponent(durs, 0.05, 20.0)
        rows.append(
            _row(
                f"laminar-phase density exponent, {model}",
                -1.5,
                slope,
                se,
                "|e| < 1% of its RMS, durations 0.05-20 s",
                "reproduced"
                if np.isfinite(slope) and abs(slope + 1.5) <= 3 * se
                else "not reproduced",
                "on-off intermittency predicts -3/2 (not a number the paper reports)",
            )
        )
    return rows, data
