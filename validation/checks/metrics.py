"""Metrics of balancing time series (paper section 3), over many realisations at once.

Every function takes arrays shaped (realisations, samples) (or (samples,)) and
the sample interval ``dt`` in seconds, and is pure.  Each docstring names the
paper figure or equation it implements.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import numpy as np


# ---------------------------------------------------------------- spectra
def power_spectrum(
    x: np.ndarray, dt: float, segment: float = 20.0
) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density of each realisation (paper Fig. 5).

    Welch's estimator (``scipy.signal.welch``): Hann window, segments of
    ``segment`` seconds (default 20 s: resolution 0.05 Hz), 50 % overlap,
    linear detrending per segment.

    Returns ``f`` (Hz, zero frequency dropped) and ``S`` shaped
    (..., len(f)) in units of x^2 / Hz.
    """
    x = np.asarray(x, dtype=float)
    nperseg = min(x.shape[-1], max(16, round(segment / dt)))
    import scipy.signal

    f, s = scipy.signal.welch(x, fs=1.0 / dt, window="hann", nperseg=nperseg, detrend="linear")
    return f[1:], s[..., 1:]


class _Record:
    """A result dataclass whose :meth:`as_dict` is its fields as plain values."""

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class PowerLawFit(_Record):
    """Two power laws S ~ f^slope_low below f_c and f^slope_high above (Fig. 5).

    Uncertainties are bootstrap standard deviations over realisations.
    """

    slope_low: float
    slope_high: float
    crossover: float  # Hz
    slope_low_se: float
    slope_high_se: float
    crossover_se: float
    fmin: float
    fmax: float


@dataclass
class SeriesMetrics:
    """Per-realisation metrics of one engine's time series (controller 1)."""

    log_rms: np.ndarray
    band_log_power: np.ndarray  # (R, bands)
    band_centres: np.ndarray
    slopes: PowerLawFit
    spectrum: tuple[np.ndarray, np.ndarray]
    tau_hat: np.ndarray  # (R, windows)
    stcc_times: np.ndarray
    tau_hat_median: np.ndarray
    fast_fraction: np.ndarray  # fraction of windows with tau_hat < tau
    log_velocity_sd: np.ndarray


def log_bins(
    f: np.ndarray, s: np.ndarray, fmin: float, fmax: float, n_bins: int
) -> tuple[np.ndarray, np.ndarray]:
    """Average log10 S in ``n_bins`` log-spaced frequency bins over [fmin, fmax] Hz (equal
    weight per decade), the binning of :func:`fit_two_power_laws` and :func:`band_log_power`.

    ``f`` (Hz) and ``s`` (..., len(f)), a PSD in any unit; bins holding no frequency are
    dropped.  Returns (mean log10 f of each bin, mean log10 S: (bins,) for one spectrum,
    (realisations, bins) for ``s`` shaped (realisations, len(f))).
    """
    edges = np.geomspace(fmin, fmax, n_bins + 1)
    idx = np.digitize(f, edges) - 1
    lf, ls = [], []
    logs = np.log10(np.maximum(s, 1e-300))
    for b in range(n_bins):
        sel = idx == b
        if sel.any():
            lf.append(np.log10(f[sel]).mean())
            ls.append(logs[..., sel].mean(axis=-1))
    return np.array(lf), np.array(ls).T if np.ndim(s) > 1 else np.array(ls)


def _broken_line(lf: np.ndarray, ls: np.ndarray, min_points: int = 3) -> tuple[float, float, float]:
    """Least-squares continuous two-segment line through (lf, ls); breakpoint by search."""
    best = (np.inf, np.nan, np.nan, np.nan)
    for k in range(min_points, len(lf) - min_points + 1):
        for xc in np.linspace(lf[k - 1], lf[k], 5):
            a = np.column_stack([np.ones_like(lf), np.minimum(lf - xc, 0), np.maximum(lf - xc, 0)])
            coef, *_ = np.linalg.lstsq(a, ls, rcond=None)
            sse = float(((a @ coef - ls) ** 2).sum())
            if sse < best[0]:
                best = (sse, coef[1], coef[2], xc)
    return best[1], best[2], 10 ** best[3]


def broken_lines(lf: np.ndarray, ls: np.ndarray, min_points: int = 3) -> np.ndarray:
    """The continuous two-segment line of every row of ``ls`` (B, len(lf)) at once through
    (``lf``, row): (B, 3) of (low slope, high slope, crossover 10**breakpoint), the fit of
    :func:`fit_two_power_laws` on :func:`log_bins`' log10 frequencies and log10 PSD (the
    crossover then in Hz).

    The breakpoint is searched at 5 points between each pair of bins with at least
    ``min_points`` bins on either side, the same candidates in the same order as
    :func:`_broken_line`'s, each solved by one least-squares call for all rows (the first
    smallest residual wins, as there); rows agree with it to rounding.
    """
    ys = np.asarray(ls, dtype=float).T  # (points, B)
    best = np.full((ys.shape[1], 4), [np.inf, np.nan, np.nan, np.nan])
    for k in range(min_points, len(lf) - min_points + 1):
        for xc in np.linspace(lf[k - 1], lf[k], 5):
            a = np.column_stack([np.ones_like(lf), np.minimum(lf - xc, 0), np.maximum(lf - xc, 0)])
            coef, *_ = np.linalg.lstsq(a, ys, rcond=None)  # (3, B)
            sse = ((a @ coef - ys) ** 2).sum(axis=0)
            better = sse < best[:, 0]
            best[better] = np.column_stack([sse, coef[1], coef[2], np.full(ys.shape[1], xc)])[
                better
            ]
    return np.column_stack([best[:, 1], best[:, 2], 10 ** best[:, 3]])


def fit_two_power_laws(
    f: np.ndarray,
    s: np.ndarray,
    fmin: float = 0.05,
    fmax: float = 20.0,
    n_bins: int = 24,
    n_bootstrap: int = 200,
    seed: int = 0,
) -> PowerLawFit:
    """Fit two power laws to the realisation-mean spectrum (paper Fig. 5).

    log10 S averaged over realisations and over ``n_bins`` log-spaced bins in
    [fmin, fmax] Hz is fitted by a continuous broken line; the slopes are the
    power-law exponents (on-off intermittency predicts -1/2 at low frequency).
    ``s`` is (realisations, frequencies); bootstrap over realisations gives
    the standard errors.
    """
    s = np.atleast_2d(s)
    keep = (f >= fmin) & (f <= fmax)
    f, s = f[keep], s[:, keep]
    lf, ls = log_bins(f, s, fmin, fmax, n_bins)  # ls: (R, bins)
    lo, hi, fc = _broken_line(lf, ls.mean(axis=0))
    rng = np.random.default_rng(seed)
    boots = []
    if s.shape[0] > 1 and n_bootstrap > 0:
        # the same resamples, drawn in the same order, fitted at once
        picks = [rng.integers(0, s.shape[0], s.shape[0]) for _ in range(n_bootstrap)]
        boots = broken_lines(lf, np.stack([ls[pick].mean(axis=0) for pick in picks]))
    b = np.asarray(boots) if len(boots) else np.full((1, 3), np.nan)
    return PowerLawFit(
        slope_low=float(lo), slope_high=float(hi), crossover=float(fc),
        slope_low_se=float(np.std(b[:, 0], ddof=1)) if len(boots) > 1 else float("nan"),
        slope_high_se=float(np.std(b[:, 1], ddof=1)) if len(boots) > 1 else float("nan"),
        crossover_se=float(np.std(b[:, 2], ddof=1)) if len(boots) > 1 else float("nan"),
        fmin=fmin, fmax=fmax,
    )  # fmt: skip


def band_log_power(f: np.ndarray, s: np.ndarray, fmin: float, fmax: float, n_bins: int = 8):
    """Per-realisation mean log10 S in ``n_bins`` log-spaced bands: (centres Hz, (R, bins))."""
    lf, ls = log_bins(f, np.atleast_2d(s), fmin, fmax, n_bins)
    return 10**lf, ls


# ---------------------------------------------------------- amplitudes
def relative_l2(a: np.ndarray, b: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Trajectory distance ||a - b|| / ||b|| (relative L2; over ``axis``, or all of it).

    The one trajectory distance of the suite: an engine's balancing error ``a``
    against a reference's ``b`` under the same noise (dimensionless).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.linalg.norm(a - b, axis=axis) / np.linalg.norm(b, axis=axis)
    return float(d) if axis is None else d


def rms(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Root mean square over time of each realisation (paper Fig. 6)."""
    x = np.asarray(x, dtype=float)
    return np.sqrt(np.mean(x * x, axis=axis))


def density(v: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Histogram estimate of the probability density of ``v`` on ``edges``, normalised by
    ALL finite samples (samples outside ``edges`` count in the total, so the density on
    the bins is not renormalised to integrate to 1 over the bins)."""
    v = np.asarray(v, dtype=float).ravel()
    v = v[np.isfinite(v)]
    h, _ = np.histogram(v, bins=edges)
    return h / (max(v.size, 1) * np.diff(edges))


def velocity_density_ratio(
    v_coupled: np.ndarray, v_single: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Ratio p(dq1/dt) / p(dx/dt) of velocity-error densities (paper Fig. 7).

    Both densities are histogram estimates on the same ``edges`` (m/s), each
    normalised by all its samples (:func:`density`); returns bin centres and
    the ratio (NaN where the single density is zero).
    """
    pc = density(v_coupled, edges)
    ps = density(v_single, edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ps > 0, pc / ps, np.nan)
    return 0.5 * (edges[1:] + edges[:-1]), ratio


#: Scales for the bins of the velocity density (see :func:`robust_scale`).
SCALES = ("median_std", "mad")


def robust_scale(v: np.ndarray, method: str = "median_std") -> float:
    """A scale of samples ``v`` (realisations, samples) that one runaway realisation cannot set.

    ``"median_std"``: the median over realisations of each realisation's
    standard deviation.  ``"mad"``: 1.4826 x the median absolute deviation
    of all samples from their median (equals sigma for a Gaussian).
    """
    v = np.atleast_2d(np.asarray(v, dtype=float))
    if method == "median_std":
        return float(np.median(np.std(v, axis=-1)))
    if method == "mad":
        flat = v[np.isfinite(v)]
        return float(1.4826 * np.median(np.abs(flat - np.median(flat))))
    raise ValueError(f"scale must be one of {', '.join(SCALES)}, got {method!r}")


def per_realisation_normalised(v: np.ndarray) -> np.ndarray:
    """``v`` (realisations, samples) divided by each realisation's own standard deviation."""
    v = np.atleast_2d(np.asarray(v, dtype=float))
    s = np.std(v, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(s > 0, v / s, np.nan)


@dataclass
class DensityRatio(_Record):
    """p_coupled / p_single on [-h, h] (paper Fig. 7: about 2 near the origin).

    ``h`` = ``half_width`` x ``scale`` (in the units of the velocities, or
    dimensionless when normalised per realisation); ``ci95`` is a percentile
    bootstrap over realisations (each model resampled independently).
    """

    ratio: float
    ci95: tuple[float, float]
    h: float
    scale: float
    scale_method: str
    half_width: float
    normalised: bool
    fraction_coupled: float
    fraction_single: float
    n_bootstrap: int
    seed: int


def density_ratio_near_zero(
    v_coupled: np.ndarray,
    v_single: np.ndarray,
    half_width: float = 0.1,
    scale: str = "median_std",
    normalise: bool = False,
    n_bootstrap: int = 1000,
    seed: int = 0,
) -> DensityRatio:
    """Ratio of velocity-error densities in the bin [-h, h] around 0 (paper Fig. 7).

    Each density is (samples with |v| < h) / (ALL samples x 2h), so the ratio is
    the ratio of the fractions of samples within h of 0.  h = ``half_width``
    times a robust scale (:func:`robust_scale`) of both models' realisations
    pooled, so that neither one runaway realisation nor the smaller model sets
    it.  With ``normalise`` every realisation is first divided by its own
    standard deviation (the ratio then compares shapes, not amplitudes).

    Parameters
    ----------
    v_coupled, v_single : (realisations, samples) velocity errors (m/s).
    """
    return density_ratios_near_zero(v_coupled, v_single, (half_width,), scale, normalise,
                                    n_bootstrap, seed)[0]  # fmt: skip


def density_ratios_near_zero(
    v_coupled: np.ndarray,
    v_single: np.ndarray,
    half_widths: Sequence[float],
    scale: str = "median_std",
    normalise: bool = False,
    n_bootstrap: int = 1000,
    seed: int = 0,
) -> list[DensityRatio]:
    """:func:`density_ratio_near_zero` at each of ``half_widths``, the normalisation and
    the scale computed once (each ratio equals its own call's, bootstrap included)."""
    vc = np.atleast_2d(np.asarray(v_coupled, dtype=float))
    vs = np.atleast_2d(np.asarray(v_single, dtype=float))
    if normalise:
        vc, vs = per_realisation_normalised(vc), per_realisation_normalised(vs)
    if scale == "median_std":
        sc = float(np.median(np.concatenate([np.std(vc, axis=-1), np.std(vs, axis=-1)])))
    else:
        sc = robust_scale(np.concatenate([vc.ravel(), vs.ravel()])[None], scale)
    nc, ns = np.isfinite(vc).sum(axis=-1), np.isfinite(vs).sum(axis=-1)
    ac, as_ = np.abs(vc), np.abs(vs)
    out = []
    for half_width in half_widths:
        h = half_width * sc
        # per-realisation counts within h and sample counts: the bootstrap resamples these
        kc, ks = (ac < h).sum(axis=-1), (as_ < h).sum(axis=-1)

        def ratio(ic, is_, kc=kc, ks=ks):
            with np.errstate(divide="ignore", invalid="ignore"):
                return (kc[ic].sum(-1) / nc[ic].sum(-1)) / (ks[is_].sum(-1) / ns[is_].sum(-1))

        rng = np.random.default_rng(seed)
        ic = rng.integers(0, kc.size, (n_bootstrap, kc.size))
        is_ = rng.integers(0, ks.size, (n_bootstrap, ks.size))
        boot = ratio(ic, is_)
        lo, hi = np.nanpercentile(boot, [2.5, 97.5]) if np.isfinite(boot).any() else (np.nan,) * 2
        out.append(DensityRatio(
            ratio=float(ratio(np.arange(kc.size), np.arange(ks.size))),
            ci95=(float(lo), float(hi)), h=float(h), scale=sc, scale_method=scale,
            half_width=float(half_width), normalised=bool(normalise),
            fraction_coupled=float(kc.sum() / nc.sum()),
            fraction_single=float(ks.sum() / ns.sum()),
            n_bootstrap=int(n_bootstrap), seed=int(seed),
        ))  # fmt: skip
    return out


# ----------------------------------------------------------------- STCC
#: samples (all series of a batch together) per thread of :func:`stcc`: a batch below it
#: runs in the calling thread, where starting a pool costs more than the loop (7 December,
#: 2 cores beside another job: 6 x 20 s 2.1 ms in one thread, 4.4 ms on two; 3 x 100 s
#: 5.7 against 7.5 ms; 16 x 100 s 29.9 against 28.9 ms; 2 x 600 s 25.1 against 21.7 ms)
_STCC_THREADED = 200_000


def _each(task, n: int, threads: int | None = None) -> None:
    """``task(i)`` for i = 0 .. n-1, across up to ``threads`` threads (None: one per core;
    the tasks write disjoint outputs, so the result does not depend on the threads), in
    this thread when that is one."""
    threads = min(threads or os.cpu_count() or 1, n)
    if threads > 1:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(task, range(n)))
    else:
        for i in range(n):
            task(i)


def stcc(
    x: np.ndarray, y: np.ndarray, dt: float, window: float, max_lag: float, stride: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Short-time cross-correlation coefficient R(x, y; tau)(t) (paper eq. (8)).

        R(x, y; tau)(t) = < (x(s) - m_x) (y(s + tau) - m_y) >_[t, t+Dt] / (sigma_x sigma_y)

    with m_x, m_y, sigma_x, sigma_y the mean and deviation of x and y over
    [t, t + Dt] (Dt = ``window``), exactly as the paper defines them.  Because
    <x - m_x>_W = 0 the numerator equals the window covariance of x(s) and the
    lagged y(s + tau); m_y drops out.  Time averages are discrete means over
    the window's samples.  Computed for all window starts t (every ``stride``
    s, up to the last start whose lagged window fits) and all lags
    tau = 0, dt, ..., ``max_lag``.

    Numerics: the series is cut into blocks of g = gcd(window, stride) samples;
    each block's mean and centred sums are formed directly, and a window's
    moments are combined from its blocks by the exact within/between
    decomposition (Chan, Golub & LeVeque 1983), in a compiled loop
    (:mod:`validation.checks._stcc_kernel`).  Nothing is a difference of
    whole-series running sums, so R equals a direct per-window computation to
    rounding (about 1e-14) for signals spanning any dynamic range (tested over
    1e-12 to 1e9).  Cost O(samples x lags + windows x lags x window/g).

    Parameters
    ----------
    x, y : (..., samples) e.g. tip velocity and cart velocity (paper: R(x_T', x_M')).

    Returns
    -------
    t : (windows,) window starts in s;  lags : (lags,) in s;
    R : (..., windows, lags); NaN where a window has zero deviation.
    """
    from validation.checks._stcc_kernel import stcc_lags  # numba: imported when first used

    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = x.shape[-1]
    w = round(window / dt)
    lmax = round(max_lag / dt)
    step = max(1, round(stride / dt))
    if w < 2 or w + lmax > n:
        raise ValueError(
            f"window + max_lag = {(w + lmax) * dt:g} s exceeds the series ({n * dt:g} s)"
        )
    starts = np.arange(0, n - w - lmax + 1, step)
    g = math.gcd(w, step)
    first = (starts // g).astype(np.int64)
    xf = np.ascontiguousarray(x.reshape(-1, n))
    yf = np.ascontiguousarray(y.reshape(-1, n))
    rows = xf.shape[0]
    out = np.empty((rows, starts.size, lmax + 1))
    # tasks of (series, lag range) on a thread per _STCC_THREADED samples, up to one per
    # core (the loop releases the GIL): a series a task, or, with fewer series than
    # threads, each series' lags in one range per thread.  Each lag is computed alone, so
    # R does not depend on the threads or the split; a short batch runs in this thread
    threads = min(os.cpu_count() or 1, 1 + (x.size - 1) // _STCC_THREADED)
    parts = 1 if rows >= threads else -(-threads // rows)
    edges = np.linspace(0, lmax + 1, parts + 1).round().astype(int)

    def lags(i: int) -> None:
        r, p = divmod(i, parts)
        stcc_lags(xf[r], yf[r], first, g, w // g, edges[p], edges[p + 1], out[r])

    _each(lags, rows * parts, threads)
    return starts * dt, np.arange(lmax + 1) * dt, out.reshape(*x.shape[:-1], *out.shape[1:])


@dataclass
class DominantPeaks:
    """First dominant peaks of STCC curves and why a window has none.

    ``tau_hat`` (...): the first dominant peak lag (s), NaN where none;
    ``no_peak`` (...): no interior local maximum qualifies;
    ``boundary_max`` (...): the largest R over the lag range sits at its first or
    last lag (R still rising at max_lag, or decreasing from lag 0).  A
    boundary is never reported as a peak.
    """

    tau_hat: np.ndarray
    no_peak: np.ndarray
    boundary_max: np.ndarray

    def fractions(self) -> dict[str, float]:
        """Fractions of windows with a peak, without one, and with a boundary maximum."""
        n = max(self.tau_hat.size, 1)
        return {
            "with_peak": float(np.isfinite(self.tau_hat).sum() / n),
            "no_peak": float(self.no_peak.sum() / n),
            "boundary_max": float(self.boundary_max.sum() / n),
        }


def dominant_peaks(
    r: np.ndarray,
    lags: np.ndarray,
    dominance: float = 0.8,
    significance: float | np.ndarray = 0.0,
) -> DominantPeaks:
    """First dominant peak tau_hat of STCC curves (paper Figs. 8, 9).

    Rule: a peak is an interior lag (neither the first nor the last) whose R
    exceeds its left neighbour and is not below its right one.  tau_hat is the
    smallest peak lag whose R is at least ``dominance`` times the largest R
    over all lags and above ``significance`` (a scalar or one level per
    window, shape broadcastable to ``r.shape[:-1]``; see
    :func:`stcc_significance_bartlett`).  The paper does not state its rule;
    ``dominance`` is one of the estimator choices of the robustness table.

    ``r`` is (..., lags); every output is (...).
    """
    return dominant_peaks_each(r, lags, (dominance,), significance)[0]


def dominant_peaks_each(
    r: np.ndarray,
    lags: np.ndarray,
    dominances: Sequence[float],
    significance: float | np.ndarray = 0.0,
) -> list[DominantPeaks]:
    """:func:`dominant_peaks` at each of ``dominances``, in order: the peaks, the largest
    R and its lag found once for all of them (the robustness table's dominance choices;
    each result equals :func:`dominant_peaks`' at that dominance alone)."""
    r = np.asarray(r, dtype=float)
    sig = np.asarray(significance, dtype=float)
    if sig.ndim:
        sig = sig[..., None]
    lags = np.asarray(lags)
    with np.errstate(invalid="ignore"):
        ranked = np.where(np.isnan(r), -np.inf, r)  # a NaN lag never the largest
        rmax = ranked.max(axis=-1, keepdims=True)
        peak = np.zeros(r.shape, dtype=bool)
        peak[..., 1:-1] = (r[..., 1:-1] > r[..., :-2]) & (r[..., 1:-1] >= r[..., 2:])
        peak &= (r > sig) & (rmax > 0)
    arg = np.argmax(ranked, axis=-1)
    finite = np.isfinite(r).all(axis=-1)
    boundary = finite & ((arg == 0) | (arg == r.shape[-1] - 1))
    out = []
    for dominance in dominances:
        with np.errstate(invalid="ignore"):
            ok = peak & (r >= dominance * rmax)
        has = ok.any(axis=-1)
        first = np.argmax(ok, axis=-1)
        out.append(DominantPeaks(tau_hat=np.where(has, lags[first], np.nan), no_peak=~has,
                                 boundary_max=boundary))  # fmt: skip
    return out


def first_dominant_peak(
    r: np.ndarray,
    lags: np.ndarray,
    dominance: float = 0.8,
    significance: float | np.ndarray = 0.0,
) -> np.ndarray:
    """tau_hat of :func:`dominant_peaks` alone: (...) in the units of ``lags``, NaN where
    no interior peak qualifies (a boundary is never a peak)."""
    return dominant_peaks(r, lags, dominance, significance).tau_hat


def stcc_significance(window_samples: int, z: float = 3.0) -> float:
    """Correlation level ``z / sqrt(window_samples)``: the white-noise level.

    Valid only when the samples of a window are independent; for correlated
    series (velocities of a balancer are correlated over tens of ms) use
    :func:`stcc_significance_bartlett`, which replaces n by the effective number
    of independent samples.
    """
    return z / np.sqrt(window_samples)


#: windows per FFT call of :func:`_window_acf`: the transforms' working set then stays in
#: the CPU's cache (measured: 1.6x faster than one call over all 2400 windows of a 600 s
#: series, at window lengths of 1000 and 2000 samples; 16 to 128 rows take the same time)
_ACF_ROWS = 64


def _window_acf(x: np.ndarray, starts: np.ndarray, w: int, max_lag: int) -> np.ndarray:
    """Sample autocorrelations r(j), j = 0..max_lag, of the windows x[s:s + w] of one
    series ``x`` (samples,), for each start s in ``starts``: (windows, max_lag + 1).

    The standard (biased) estimator: r(j) = sum_{s<w-j} z'_s z'_{s+j} / sum z'^2,
    z' the window minus its mean; via an FFT zero-padded to at least w + max_lag points
    (the circular correlation then equals the linear one at every lag returned), in
    blocks of :data:`_ACF_ROWS` windows.  Each block's centred windows are written into
    one zero-padded buffer, read from a strided view of ``x`` where the starts are evenly
    spaced (no copy of the overlapping windows): the same numbers as centring a copy and
    letting the FFT pad it, 1.4-2.2x faster (8 December, one series of 600 s at 5 ms,
    windows of 500 to 2000 samples every 50).
    """
    from scipy import fft

    m = min(int(max_lag), w - 1)
    nfft = fft.next_fast_len(w + m, real=True)
    windows = np.lib.stride_tricks.sliding_window_view(x, w)
    step = np.diff(starts)
    even = step.size > 0 and step[0] > 0 and bool((step == step[0]).all())
    out = np.empty((starts.size, m + 1))
    # the padding, columns w.., stays zero: only the first w columns are written, and
    # the transform reads the buffer without overwriting it
    buf = np.zeros((min(_ACF_ROWS, starts.size), nfft))
    for a in range(0, starts.size, _ACF_ROWS):
        k = min(_ACF_ROWS, starts.size - a)
        rows = (windows[starts[a] : starts[a + k - 1] + 1 : step[0]] if even
                else windows[starts[a : a + k]])  # fmt: skip
        block = buf[:k]
        np.subtract(rows, rows.mean(axis=-1, keepdims=True), out=block[:, :w])
        f = fft.rfft(block, axis=-1, overwrite_x=False)
        np.multiply(f, f.conj(), out=f)
        ac = fft.irfft(f, nfft, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            np.divide(ac[:, : m + 1], ac[:, :1], out=out[a : a + k])
    return out


def effective_samples(
    x: np.ndarray, y: np.ndarray, dt: float, t: np.ndarray, window: float,
    max_lag_fraction: float = 0.2,
) -> np.ndarray:  # fmt: skip
    """Effective number of independent samples of each STCC window (Bartlett's formula).

    For two series with no cross-correlation the variance of their sample
    cross-correlation over n samples is (Bartlett 1946; in the form of Pyper &
    Peterman 1998, Can. J. Fish. Aquat. Sci. 55, 2127, eq. 1)::

        1 / n_eff = 1/n + (2/n) sum_{j=1}^{M} (n - j)/n  r_xx(j) r_yy(j),

    with r_xx, r_yy the sample autocorrelations inside the window and
    M = ``max_lag_fraction`` x n (their choice, n/5).  n_eff is clipped to
    [2, n].  ``t`` are window starts (s) as returned by :func:`stcc`.

    Returns (..., windows).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    w = round(window / dt)
    starts = np.round(np.asarray(t) / dt).astype(int)
    m = max(1, int(max_lag_fraction * w))
    j = np.arange(1, m + 1)
    weight = (w - j) / w
    lead = x.shape[:-1]
    xf, yf = x.reshape(-1, x.shape[-1]), y.reshape(-1, y.shape[-1])
    out = np.empty((xf.shape[0], starts.size))

    def row(i: int) -> None:
        rx, ry = _window_acf(xf[i], starts, w, m), _window_acf(yf[i], starts, w, m)
        s = (rx[:, 1:] * ry[:, 1:] * weight).sum(-1)
        inv = 1.0 / w + 2.0 / w * s
        with np.errstate(divide="ignore", invalid="ignore"):
            out[i] = np.clip(1.0 / inv, 2.0, w)

    # one row per task across threads (the FFTs release the GIL); each row is computed
    # alone, so the result does not depend on the number of threads
    _each(row, xf.shape[0])
    return out.reshape(*lead, starts.size)


def stcc_significance_bartlett(
    x: np.ndarray, y: np.ndarray, dt: float, t: np.ndarray, window: float, z: float = 3.0
) -> np.ndarray:
    """Per-window significance level z / sqrt(n_eff) of STCC (n_eff: :func:`effective_samples`).

    Under the null of no cross-correlation R at one lag is approximately
    normal with standard deviation 1/sqrt(n_eff), so a level z = 3 is exceeded
    with probability 0.135 % per lag (one-sided).  A window of L lags then has a
    false significant peak with probability about 1 - (1 - 0.00135)^(L - 2)
    when its lags are independent (white noise: 7.7 % for L = 61), and less
    when they are correlated (0.9 % measured for AR(1) series with a 50 ms
    correlation time, 5 s windows at 5 ms).  Returns (..., windows).
    """
    return z / np.sqrt(effective_samples(x, y, dt, t, window))


def peak_density(tau_hat: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Density of tau_hat over time and realisations (paper Fig. 10).

    Returns the density on ``edges`` (NaNs, i.e. windows without a dominant
    peak, excluded), the height of its maximum (1/s) and its location (s).
    """
    v = np.asarray(tau_hat, dtype=float).ravel()
    v = v[np.isfinite(v)]
    h, _ = np.histogram(v, bins=edges, density=True)
    k = int(np.argmax(h))
    return h, float(h[k]), float(0.5 * (edges[k] + edges[k + 1]))


# ----------------------------------------------------- laminar phases
def laminar_phases(e: np.ndarray, dt: float, threshold: float) -> np.ndarray:
    """Durations (s) of laminar phases: maximal runs with |e| < ``threshold``.

    On-off intermittency predicts a density P(T) ~ T^(-3/2) [Heagy, Platt &
    Hammel 1994].  Runs touching either end of a series are dropped.
    ``e`` is (..., samples); all realisations are pooled.
    """
    e = np.atleast_2d(np.asarray(e, dtype=float))
    e = e.reshape(-1, e.shape[-1])
    out = []
    for row in e:
        lam = np.abs(row) < threshold
        d = np.diff(lam.astype(np.int8))
        starts = np.flatnonzero(d == 1) + 1
        ends = np.flatnonzero(d == -1) + 1
        if lam[0]:
            ends = ends[1:]  # the first run touches the start of the series
        k = min(starts.size, ends.size)
        out.append((ends[:k] - starts[:k]) * dt)
    return np.concatenate(out) if out else np.empty(0)


def power_law_exponent(durations: np.ndarray, tmin: float, tmax: float, n_bins: int = 12):
    """Slope of the log-binned density of ``durations`` in [tmin, tmax] (s).

    Least squares on log10 density vs log10 T over non-empty bins; returns
    (slope, standard error).  -3/2 for the laminar phases of on-off intermittency.
    """
    edges = np.geomspace(tmin, tmax, n_bins + 1)
    h, _ = np.histogram(durations, bins=edges)
    dens = h / np.diff(edges)
    centres = np.sqrt(edges[1:] * edges[:-1])
    sel = h >= 5
    if sel.sum() < 3:
        return float("nan"), float("nan")
    import scipy.stats

    res = scipy.stats.linregress(np.log10(centres[sel]), np.log10(dens[sel]))
    return float(res.slope), float(res.stderr)
