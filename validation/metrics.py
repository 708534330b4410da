"""Metrics of balancing time series (paper section 3), over many realisations at once.

Every function takes arrays shaped (realisations, samples) (or (samples,)) and
the sample interval ``dt`` in seconds, and is pure.  Each docstring names the
paper figure or equation it implements.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import scipy.signal
import scipy.stats


# ---------------------------------------------------------------- spectra
def power_spectrum(
    x: np.ndarray, dt: float, segment: float = 20.0
) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density of each realisation (paper Fig. pwsp).

    Welch's estimator (``scipy.signal.welch``): Hann window, segments of
    ``segment`` seconds (default 20 s: resolution 0.05 Hz), 50 % overlap,
    linear detrending per segment.

    Returns ``f`` (Hz, zero frequency dropped) and ``S`` shaped
    (..., len(f)) in units of x^2 / Hz.
    """
    x = np.asarray(x, dtype=float)
    nperseg = min(x.shape[-1], max(16, round(segment / dt)))
    f, s = scipy.signal.welch(x, fs=1.0 / dt, window="hann", nperseg=nperseg, detrend="linear")
    return f[1:], s[..., 1:]


@dataclass
class PowerLawFit:
    """Two power laws S ~ f^slope_low below f_c and f^slope_high above (Fig. pwsp).

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

    def as_dict(self) -> dict:
        return asdict(self)


def _log_bins(f: np.ndarray, s: np.ndarray, fmin: float, fmax: float, n_bins: int):
    """Average log10 S in log-spaced frequency bins (equal weight per decade)."""
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


def fit_two_power_laws(
    f: np.ndarray,
    s: np.ndarray,
    fmin: float = 0.05,
    fmax: float = 20.0,
    n_bins: int = 24,
    n_bootstrap: int = 200,
    seed: int = 0,
) -> PowerLawFit:
    """Fit two power laws to the realisation-mean spectrum (paper Fig. pwsp).

    log10 S averaged over realisations and over ``n_bins`` log-spaced bins in
    [fmin, fmax] Hz is fitted by a continuous broken line; the slopes are the
    power-law exponents (on-off intermittency predicts -1/2 at low frequency).
    ``s`` is (realisations, frequencies); bootstrap over realisations gives
    the standard errors.
    """
    s = np.atleast_2d(s)
    keep = (f >= fmin) & (f <= fmax)
    f, s = f[keep], s[:, keep]
    lf, ls = _log_bins(f, s, fmin, fmax, n_bins)  # ls: (R, bins)
    lo, hi, fc = _broken_line(lf, ls.mean(axis=0))
    rng = np.random.default_rng(seed)
    boots = []
    if s.shape[0] > 1:
        for _ in range(n_bootstrap):
            pick = rng.integers(0, s.shape[0], s.shape[0])
            boots.append(_broken_line(lf, ls[pick].mean(axis=0)))
    b = np.array(boots) if boots else np.full((1, 3), np.nan)
    return PowerLawFit(
        slope_low=float(lo), slope_high=float(hi), crossover=float(fc),
        slope_low_se=float(np.std(b[:, 0], ddof=1)) if len(boots) > 1 else float("nan"),
        slope_high_se=float(np.std(b[:, 1], ddof=1)) if len(boots) > 1 else float("nan"),
        crossover_se=float(np.std(b[:, 2], ddof=1)) if len(boots) > 1 else float("nan"),
        fmin=fmin, fmax=fmax,
    )  # fmt: skip


def band_log_power(f: np.ndarray, s: np.ndarray, fmin: float, fmax: float, n_bins: int = 8):
    """Per-realisation mean log10 S in ``n_bins`` log-spaced bands: (centres Hz, (R, bins))."""
    lf, ls = _log_bins(f, np.atleast_2d(s), fmin, fmax, n_bins)
    return 10**lf, ls


# ---------------------------------------------------------- amplitudes
def rms(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Root mean square over time of each realisation (paper Fig. rms)."""
    x = np.asarray(x, dtype=float)
    return np.sqrt(np.mean(x * x, axis=axis))


def density(v: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Histogram estimate of the probability density of all samples of ``v`` on ``edges``."""
    h, _ = np.histogram(np.asarray(v, dtype=float).ravel(), bins=edges, density=True)
    return h


def velocity_density_ratio(
    v_coupled: np.ndarray, v_single: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Ratio p(dq1/dt) / p(dx/dt) of velocity-error densities (paper Fig. velo).

    Both densities are histogram estimates on the same ``edges`` (m/s);
    returns bin centres and the ratio (NaN where the single density is zero).
    """
    pc = density(v_coupled, edges)
    ps = density(v_single, edges)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ps > 0, pc / ps, np.nan)
    return 0.5 * (edges[1:] + edges[:-1]), ratio


# ----------------------------------------------------------------- STCC
#: Largest number of block values gathered at once when combining windows.
_CHUNK_ELEMENTS = 4_000_000


def _block_stats(z: np.ndarray, nblocks: int, g: int) -> tuple[np.ndarray, np.ndarray]:
    """Means (..., nblocks) and centred samples (..., nblocks, g) of consecutive blocks."""
    b = z[..., : nblocks * g].reshape(*z.shape[:-1], nblocks, g)
    m = b.mean(axis=-1)
    return m, b - m[..., None]


def _window_blocks(a: np.ndarray, k: int, first: np.ndarray) -> np.ndarray:
    """(..., windows, k): the k consecutive block values of each window."""
    v = np.lib.stride_tricks.sliding_window_view(a, k, axis=-1)
    return v[..., first, :]


def _window_comoment(
    mx: np.ndarray, my: np.ndarray, cb: np.ndarray, k: int, first: np.ndarray, g: int
) -> np.ndarray:
    """Comoment sum_s (x - m_x)(y - m_y) over windows of k blocks of g samples.

    Exact decomposition into within-block and between-block parts (the
    parallel formula of Chan, Golub & LeVeque 1983 for equal blocks)::

        C_W = sum_b C_b + g sum_b (m_x,b - M_x)(m_y,b - M_y),   M = mean_b m_b,

    every sum taken directly over its window (no differences of running sums),
    so the result keeps full relative precision whatever the dynamic range.
    """
    out = np.empty((*mx.shape[:-1], first.size))
    per = max(1, _CHUNK_ELEMENTS // (k * max(1, mx[..., 0].size)))  # bound the memory
    for a in range(0, first.size, per):
        sel = first[a : a + per]
        bx = _window_blocks(mx, k, sel)
        by = _window_blocks(my, k, sel)
        bx = bx - bx.mean(axis=-1, keepdims=True)
        by = by - by.mean(axis=-1, keepdims=True)
        out[..., a : a + per] = _window_blocks(cb, k, sel).sum(axis=-1) + g * (bx * by).sum(axis=-1)
    return out


def stcc(
    x: np.ndarray, y: np.ndarray, dt: float, window: float, max_lag: float, stride: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Short-time cross-correlation coefficient R(x, y; tau)(t) (paper eq. STCC).

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
    decomposition (Chan, Golub & LeVeque 1983).  Nothing is a difference of
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
    k = w // g
    first = starts // g
    nblocks = int(first[-1]) + k
    mx, cx = _block_stats(x, nblocks, g)
    my0, cy0 = _block_stats(y, nblocks, g)
    sxx = _window_comoment(mx, mx, (cx * cx).sum(axis=-1), k, first, g)
    syy = _window_comoment(my0, my0, (cy0 * cy0).sum(axis=-1), k, first, g)
    norm = np.sqrt(sxx * syy)
    out = np.empty((*x.shape[:-1], starts.size, lmax + 1))
    for lag in range(lmax + 1):
        # every lagged window ends at starts + w + lag <= n - lmax + lag <= n
        my, cy = (my0, cy0) if lag == 0 else _block_stats(y[..., lag:], nblocks, g)
        sxy = _window_comoment(mx, my, (cx * cy).sum(axis=-1), k, first, g)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[..., lag] = sxy / norm
    return starts * dt, np.arange(lmax + 1) * dt, out


def first_dominant_peak(
    r: np.ndarray, lags: np.ndarray, dominance: float = 0.8, significance: float = 0.0
) -> np.ndarray:
    """First dominant peak tau_hat of STCC curves (paper Figs. scc, sccpeak).

    Rule: among the local maxima of R over lags > 0 (a lag whose R exceeds both
    neighbours; the last lag counts if R still rises there), tau_hat is the
    smallest lag whose R is at least ``dominance`` times the largest R over
    all lags and above ``significance``.  NaN where no local maximum qualifies
    (e.g. R decreasing from lag 0, or all correlations insignificant).

    ``r`` is (..., lags); returns (...) in the units of ``lags``.
    """
    r = np.asarray(r, dtype=float)
    rmax = np.nanmax(r, axis=-1, keepdims=True)
    left = r[..., 1:-1] > r[..., :-2]
    right = r[..., 1:-1] >= r[..., 2:]
    peak = np.zeros(r.shape, dtype=bool)
    peak[..., 1:-1] = left & right
    peak[..., -1] = r[..., -1] > r[..., -2]
    ok = peak & (r >= dominance * rmax) & (r > significance) & (rmax > 0)
    first = np.argmax(ok, axis=-1)
    has = ok.any(axis=-1)
    return np.where(has, lags[first], np.nan)


def stcc_significance(window_samples: int, z: float = 3.0) -> float:
    """Correlation level ``z / sqrt(window_samples)``: below it R is indistinguishable
    from that of independent white noise (its standard deviation is 1/sqrt(n))."""
    return z / np.sqrt(window_samples)


def peak_density(tau_hat: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Density of tau_hat over time and realisations (paper Fig. sccpeak:pdf).

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
    res = scipy.stats.linregress(np.log10(centres[sel]), np.log10(dens[sel]))
    return float(res.slope), float(res.stderr)
