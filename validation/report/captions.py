"""Captions of the report's figures and clips: what each shows, the estimator, the run.

A caption names the quantity drawn, the estimator, the run that made it
(model, engine, realisations x duration, initial balancing error, seed) and
the figure of the paper it redoes by the paper's printed number
(:data:`validation.paper.refs.PAPER_FIGURES`).  Every number comes from the run's settings (the
profile as written to ``results.json``); a stage's noise is drawn from a
stream derived from the profile's seed and a label (``Profile.seed_for``),
so the caption gives the seed and the stream's label.
"""

from __future__ import annotations

from typing import Any

from validation.paper.refs import PAPER_FIGURES
from validation.profiles import PAPER_BETA


def _paper(label: str, what: str) -> str:
    return f"Redoes the paper's Fig. {PAPER_FIGURES[label]} ({what})."


def _beta() -> str:
    return f"beta = {PAPER_BETA['single']} (single) and {PAPER_BETA['coupled']} (coupled)"


def _rod_study(s: dict[str, Any]) -> dict[str, Any]:
    """The rod-length study as the run ran it: the shipped study with the profile's overrides."""
    from validation.sweep import Study, default_studies_dir

    base = Study.from_toml(default_studies_dir() / "rod_length.toml").as_dict()
    base.update(s.get("rod_study") or {})
    return base


def figure_caption(name: str, settings: dict[str, Any], engine: str = "MuJoCo") -> str:
    """The caption of figure file ``name`` of a ``cip-validate run`` with ``settings``.

    Parameters
    ----------
    name : the file name as the run writes it (``fig_rms.png``, ``clip_inside_small_angle.gif``).
    settings : the run's profile (``results["settings"]``).
    engine : the validated engine as the figures name it (its family,
        ``results["engine"]["capabilities"]["family"]``); the clips are MuJoCo's renders
        whatever the engine.

    Returns
    -------
    One paragraph of plain text; a file the suite does not know gets a caption
    saying so (never an empty one).

    The function is long because it is a table of captions, one per figure.
    """
    s = settings
    seed = s["seed"]
    small = (f"{s['series_realizations']} realisations x {s['series_duration']:g} s per "
             f"engine, initial balancing error {s['amplitude']:g} m, {_beta()}, seed {seed} "
             "(stream 'series')")  # fmt: skip
    long = (f"reduced model (eq. (3) single, eq. (5) coupled), {s['peak_realizations']} "
            f"realisations x {s['peak_duration']:g} s, initial balancing error "
            f"{s['rms_amplitude']:g} m, {_beta()}, sampled every {s['decimate']} ms, seed "
            f"{seed} (stream 'series')")  # fmt: skip
    stcc = (f"STCC over windows of Dt = {s['stcc_window']:g} s every {s['stcc_stride']:g} s, "
            f"lags 0-{s['stcc_max_lag']:g} s")  # fmt: skip
    captions = {
        "fig_lLe.png": (
            "Largest Lyapunov exponent lambda1 (1/s) against the feedback gain beta, single "
            "and coupled. Lines: the reduced model, Benettin estimate over the delay history, "
            "mean over realisations with its 95 % confidence band, "
            f"{2 * s['lyapunov_realizations']} realisations x {2 * s['lyapunov_duration']:g} s "
            f"at each of the gains {_seq(s['lyapunov_curve_gains'])}, seed {seed} (stream "
            f"'curve'). Squares: {engine} (rigid-body CIP, the same noise as the reduced model at "
            f"that gain) with 95 % CIs, {s['lyapunov_realizations']} realisations x "
            f"{s['lyapunov_duration']:g} s (stream 'lyapunov'). Dotted: the critical gain beta* "
            f"where lambda1 = 5e-4, bisected on the reduced model ({s['beta_star_realizations']}"
            f" realisations x {s['beta_star_duration']:g} s, stream 'beta_star'). "
            + _paper("lLe", "lambda1 against beta")
        ),
        "fig_Be.png": (
            "Balancing error e(t) (m) of one realisation (realisation 0): Delta x of the single "
            "balancer (top) and Delta q1 of the coupled one (bottom), the reduced model (solid) "
            f"and {engine} (dashed) under the same noise, deep in the small-angle regime. "
            f"Run: {small}. "
            + _paper("Be", "the balancing errors; the paper shows longer, larger runs")
        ),
        "fig_pwsp.png": (
            "Power spectrum S(f) (m^2/Hz) of the balancing error, single (left) and coupled "
            f"(right): Welch estimate with {s['peak_duration'] / 4:g} s segments, mean over "
            f"realisations, of the {long}; the broken line (dashed) is the two-power-law fit "
            "to that mean, whose slopes the panel titles give. The mean is set by the largest "
            "realisations (the RMS spans decades): the grey bands give the realisations' "
            "central 50 % and 90 % and the black line their median at each frequency. The "
            "thin lines are the small-amplitude "
            f"spectra of both engines ({s['spectrum_segment']:g} s segments; {small}), scaled "
            "to the long run's mean power to compare shapes. "
            + _paper("pwsp", "the two power-law regimes")
        ),
        "fig_rms.png": (
            "RMS of the balancing error (m, log axis) of each realisation of the reduced model, "
            f"single and coupled: {s['rms_realizations']} realisations x "
            f"{s['rms_duration']:g} s, initial balancing error {s['rms_amplitude']:g} m, "
            f"{_beta()}, seed {seed} (stream 'rms'). The RMS is heavy-tailed, so each model "
            "is summarised by its median (solid line, and black tick on the bar at the right), "
            "its geometric mean (diamond) and the central 50 % (thick bar) and 90 % (thin bar) "
            "of its realisations; the arithmetic mean, which one realisation can set, is not "
            "drawn. Realisations whose RMS exceeds the pendulum "
            "length L = g/alpha (dash-dot) describe a stick that has fallen: they are drawn "
            "as crosses, counted in the legend and listed as diverged in the run's divergence "
            "list (the linear model itself goes on). "
            + _paper("rms", "log RMS per realisation; the paper's solid lines are the means")
        ),
        "fig_velo.png": (
            "Ratio p(dq1/dt) / p(dx/dt) of the densities of the velocity errors, coupled over "
            "single: histograms with 60 bins over +-3 robust scales (median per-realisation "
            f"SD) of every sample of the {long}. The star is the paper's reading (about 2 "
            "near 0). " + _paper("velo", "the velocity density ratio")
        ),
        "fig_scc.png": (
            "Short-time cross-correlation coefficient R(dq_T/dt, dq_Mi/dt) of the coupled "
            "reduced model against the lag, for both controllers (i = 1, 2), at the window "
            f"nearest t = 36 s: {stcc}; realisation 0 of the {long}. The dotted line is the "
            "controllers' delay tau = 0.1 s. "
            + _paper("scc", "the STCC at t = 36; ours is another draw of the noise")
        ),
        "fig_sccpeak.png": (
            "First peak point tau_hat(t) (s) of the STCC in each window: single (top), the "
            "coupled model's controllers 1 and 2 (middle, bottom). tau_hat is the first "
            "maximum that dominates (>= 0.8 of the window's largest) and exceeds the "
            f"Bartlett significance level; windows without one are left empty. {stcc}; "
            f"realisation 0 of the {long}. " + _paper("sccpeak", "the first peak points over time")
        ),
        "fig_sccpeak_pdf.png": (
            "Probability density (1/s) of the first peak point tau_hat, single (triangles) and "
            "coupled controller 1 (squares), histograms with 0.01 s bins. Solid: the reduced "
            f"model, every window of every realisation of the {long}; dashed: {engine} at small "
            f"amplitude ({small}). " + _paper("sccpeak:pdf", "the densities of tau_hat")
        ),
        "fig_amplitude_scan.png": (
            f"Relative L2 distance between the balancing errors of {engine} and the reduced "
            "model "
            "under the same noise (over the first "
            f"{s['scan_duration']:g} s), against the largest |theta| {engine} reached, for "
            f"initial balancing errors {_seq(s['scan_amplitudes'])} m; "
            f"{s['scan_realizations']} realisations per amplitude, {_beta()}, seed {seed} "
            "(stream 'scan'). The models must agree (below 1 %) inside the small-angle regime "
            "(dotted) and disagree far outside it; the runs beyond |theta| = pi/2 fell on "
            "purpose (the scan looks for the breakdown). No figure of the paper: the "
            "validation's own."
        ),
        "clip_inside_small_angle.gif": _clip(s, 0),
        "clip_outside_small_angle.gif": _clip(s, 1),
    }
    if name in captions:
        return captions[name]
    if name.startswith("fig_rod_length_"):
        metric = name[len("fig_rod_length_") : -len(".png")]
        st = _rod_study(s)
        what = {"max_angle": "largest |theta| (rad) a realisation reached (a pole that fell and "
                             "turned over is drawn at pi)",
                "agreement": "relative L2 distance of the balancing error to the reduced model "
                             "(first 10 s)"}.get(metric, metric)  # fmt: skip
        amps = _seq(st["grid"].get("amplitude", ()))
        return (
            f"Rod-length study: {what}, against the rod length l relative to the pendulum "
            f"length L, one line per initial balancing error ({amps} m). Median over "
            "realisations with the central 50 % and 90 % of them (bands; these quantities are "
            "positive and heavy-tailed); realisations that diverged are counted in the legend "
            f"and the divergence list. Run: {st['model']} model, engine {st['engine']}, "
            f"{st['realizations']} realisations x {st['duration']:g} s per point, beta = "
            f"{st['fixed'].get('beta', PAPER_BETA['coupled'])}, seed {st['seed']}, the same "
            "noise at every point. No figure of the paper: the reduced model has no rod "
            "length (it drops out of eq. (5))."
        )
    return f"{name}: a file of the run without a caption of its own."


def _clip(s: dict[str, Any], k: int) -> str:
    amps = s.get("clip_amplitudes") or (float("nan"), float("nan"))
    where = ("inside the small-angle regime", "leaving the small-angle regime")[k]
    return (
        f"Clip: the coupled rigid-body CIP simulated by MuJoCo {where}: initial balancing "
        f"error {amps[k]:g} m, beta = {PAPER_BETA['coupled']}, {s.get('clip_duration', 0):g} s, "
        f"seed {s['seed']} (realisation 0), 15 frames/s. The overlay gives the time, both "
        "angles theta1, theta2 (rad), the balancing errors Delta q1, Delta q2 (m), the engine "
        "and model, and whether the run is inside the small-angle regime. No figure of the "
        "paper."
    )


def _seq(v: Any) -> str:
    return ", ".join(f"{float(x):g}" for x in v)


def settings_rows(settings: dict[str, Any]) -> list[tuple[str, str]]:
    """The run's settings as (group, ``key = value; ...``) rows, one per stage.

    Keys are grouped by the stage that uses them; units follow the value
    (s, m, Hz); any key not in a known group lands in ``other``.
    """
    groups = [
        ("run", ("name", "seed")),
        ("lambda1, both engines", ("lyapunov_",)),
        ("time series, both engines", ("amplitude", "series_", "decimate", "spectrum_segment",
                                       "spectrum_band", "stcc_")),
        ("amplitude scan", ("scan_",)),
        ("critical gains beta*", ("beta_star_",)),
        ("RMS", ("rms_",)),
        ("STCC peaks and spectra", ("peak_", "spectrum_duration", "spectrum_realizations")),
        ("robustness", ("robustness_", "n_bootstrap")),
        ("nonlinear stick", ("nonlinear_",)),
        ("clips", ("clip_",)),
        ("rod-length study", ("rod_study",)),
    ]  # fmt: skip
    rows, used = [], set()
    for group, prefixes in groups:
        keys = [k for k in settings if k not in used and
                any(k == p or (p.endswith("_") and k.startswith(p)) for p in prefixes)]  # fmt: skip
        used.update(keys)
        if keys:
            rows.append((group, "; ".join(f"{k} = {_compact(settings[k], k)}" for k in keys)))
    rest = [k for k in settings if k not in used]
    if rest:
        rows.append(("other", "; ".join(f"{k} = {_compact(settings[k], k)}" for k in rest)))
    return rows


_UNITS = (("durations", "x the duration"), ("duration", "s"), ("amplitudes", "m"),
          ("amplitude", "m"), ("window", "s"), ("max_lag", "s"), ("stride", "s"),
          ("segment", "s"), ("band", "Hz"), ("decimate", "steps of 1 ms"))  # fmt: skip


def _compact(v: Any, key: str = "") -> str:
    """A setting's value on one line: sequences as ``a, b, c``, mappings as ``k: v``."""
    unit = next((u for suffix, u in _UNITS if key.endswith(suffix)), "")
    if isinstance(v, dict):
        parts = []
        for k, x in v.items():
            # the robustness grid's durations are fractions of the stage's duration
            child = "" if key == "robustness_grid" and k == "duration" else str(k)
            parts.append(f"{k}: {_compact(x, child)}")
        text = "{" + "; ".join(parts) + "}"
        return text if v else "(the shipped study as it is)"
    if isinstance(v, list | tuple):
        text = "(" + ", ".join(_compact(x) for x in v) + ")"
    elif isinstance(v, float):
        text = f"{v:g}"
    else:
        text = str(v)
    return f"{text} {unit}" if unit else text
