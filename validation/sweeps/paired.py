"""Paired model comparisons and heavy-tail summaries with bootstrap 95 % intervals.

A ``compare = [A, B]`` study runs models A (the reference) and B at every
grid point with the same seed, so realisation r of each model draws from the
same random stream (common random numbers).  The models consume it
differently (the single balancer one draw per step, the coupled pair two,
interleaved), so the gain noises of a pair are not the same path and pairing
brings little variance reduction; the pairs are still independent and
identically distributed, so the paired bootstrap below is valid.  Per grid
point it stores:

* ``rms_ratio_median``: median RMS of B / median RMS of A (RMS in m);
* ``rms_ratio_geomean``: geometric-mean RMS of B / of A, i.e.
  10^mean(log10 RMS_B - log10 RMS_A) over the paired realisations;
* ``<metric>_diff_median``: median of B minus median of A, for every other
  per-realisation metric (lambda1, tau_hat, ...), in the metric's units;

each with ``_ci_low`` / ``_ci_high``: a paired percentile bootstrap
(:func:`scipy.stats.bootstrap`, ``paired=True``: realisations are resampled
together, keeping each seed's pair) over the realisations that are
finite for both models.  Medians and geometric means are used because the
RMS of the balancing error is heavy-tailed (it spans decades across
realisations): a mean is carried by its largest draw.
"""

from __future__ import annotations

import numpy as np

#: bootstrap resamples of every interval
N_RESAMPLES = 2000
#: per-realisation metrics compared as ratios of RMS (stored as log10 RMS)
LOG_METRICS = ("rms",)
#: per-realisation metrics compared as differences of medians
DIFF_METRICS = ("lambda1", "tau_hat", "tau_hat_fraction", "tau_hat_avg", "agreement",
                "max_angle")  # fmt: skip


def _rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0xB007, index)))


def _ratio_median(a, b, axis=-1):
    return np.median(10.0**b, axis=axis) / np.median(10.0**a, axis=axis)


def _ratio_geomean(a, b, axis=-1):
    return 10.0 ** np.mean(b - a, axis=axis)


def _diff_median(a, b, axis=-1):
    return np.median(b, axis=axis) - np.median(a, axis=axis)


STATISTICS = {"ratio_median": _ratio_median, "ratio_geomean": _ratio_geomean,
              "diff_median": _diff_median}  # fmt: skip


def paired_ci(a: np.ndarray, b: np.ndarray, kind: str, seed: int, index: int = 0):
    """(estimate, low, high) of statistic ``kind`` of paired samples ``a`` (reference), ``b``.

    Pairs with a non-finite member are dropped; fewer than three pairs give NaNs.
    """
    import scipy.stats

    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size < 3:
        return float("nan"), float("nan"), float("nan")
    f = STATISTICS[kind]
    est = float(f(a, b))
    if np.all(a == a[0]) and np.all(b == b[0]):
        return est, est, est
    res = scipy.stats.bootstrap((a, b), f, paired=True, vectorized=True, method="percentile",
                                n_resamples=N_RESAMPLES,
                                random_state=_rng(seed, index))  # fmt: skip
    ci = res.confidence_interval
    return est, float(ci.low), float(ci.high)


def summary_ci(x: np.ndarray, kind: str, seed: int, index: int = 0):
    """(estimate, low, high) of the median or geometric mean (``kind``) of positive samples
    ``x`` (percentile bootstrap, non-finite values dropped)."""
    import scipy.stats

    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size < 3:
        return float("nan"), float("nan"), float("nan")
    if kind == "median":

        def f(v, axis=-1):
            return np.median(v, axis=axis)
    else:

        def f(v, axis=-1):
            return np.exp(np.mean(np.log(v), axis=axis))

    est = float(f(x))
    if np.all(x == x[0]):
        return est, est, est
    res = scipy.stats.bootstrap((x,), f, vectorized=True, method="percentile",
                                n_resamples=N_RESAMPLES,
                                random_state=_rng(seed, index))  # fmt: skip
    return est, float(res.confidence_interval.low), float(res.confidence_interval.high)


def comparison_names(metric: str) -> list[tuple[str, str]]:
    """[(variable name, statistic)] of the paired comparisons of one metric."""
    if metric in LOG_METRICS:
        return [(f"{metric}_ratio_median", "ratio_median"),
                (f"{metric}_ratio_geomean", "ratio_geomean")]  # fmt: skip
    if metric in DIFF_METRICS:
        return [(f"{metric}_diff_median", "diff_median")]
    return []


def paired_variables(ds, compare: list[str], seed: int) -> dict:
    """The paired comparisons of a dataset with a ``model`` dimension (see the module
    docstring): {name: DataArray over the grid dimensions}."""
    import xarray as xr

    a_ds, b_ds = ds.sel(model=compare[0]), ds.sel(model=compare[1])
    out = {}
    for metric in [m for m in ds.data_vars if "realization" in ds[m].dims]:
        for name, kind in comparison_names(metric):
            a = a_ds[metric].transpose(..., "realization")
            b = b_ds[metric].transpose(..., "realization")
            grid_shape = a.shape[:-1]
            est = np.full(grid_shape, np.nan)
            lo, hi = est.copy(), est.copy()
            for i, idx in enumerate(np.ndindex(*grid_shape)):
                est[idx], lo[idx], hi[idx] = paired_ci(a.values[idx], b.values[idx], kind,
                                                       seed, i)  # fmt: skip
            dims = a.dims[:-1]
            for suffix, v in (("", est), ("_ci_low", lo), ("_ci_high", hi)):
                out[name + suffix] = xr.DataArray(v, dims=dims)
    return out
