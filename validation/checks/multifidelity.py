"""Multifidelity (control-variate) estimation of a mean from a costly and a cheap model.

The agreement checks estimate mu = E[Y], Y = metric(engine) - metric(reduced) per
realisation under the same noise.  The engine's exact linear twin is a cheap model
of the engine: X = metric(twin) - metric(reduced) under the same noise is almost
equal to Y (the twin follows the engine to ~1e-11 at small angles), and the twin
and the reduced model step compiled linear kernels, so X can be sampled on many
more realisations than Y.  The two-model multifidelity Monte Carlo (MFMC)
estimator, a control-variate estimator (Peherstorfer, Willcox & Gunzburger,
"Survey of multifidelity methods in uncertainty propagation, inference, and
optimization", SIAM Review 60(3), 2018, section 3.2 "control variates"; the
two-model case of Peherstorfer, Willcox & Gunzburger, SIAM J. Sci. Comput.
38(5), 2016, MFMC), uses n paired samples (y_i, x_i) and m >= n samples of x
whose first n are the paired ones (nested: realisation i draws the same noise
in every model, :mod:`cipcore.noise`)::

    mu_hat = ybar_n + alpha (xbar_m - xbar_n)
           = mean_n(y - alpha x) + alpha xbar_m.

With alpha = 1 this is [engine - twin] over n plus [twin - reduced] over m.
It is unbiased for any fixed alpha, and its variance is (MFMC, two models)::

    Var(mu_hat) = sigma_y^2 / n + (1/n - 1/m) (alpha^2 sigma_x^2 - 2 alpha rho sigma_y sigma_x),

smallest at alpha* = rho sigma_y / sigma_x, where::

    Var(mu_hat) = sigma_y^2 / n * [1 - (1 - n/m) rho^2]
                = sigma_{y - alpha* x}^2 / n + alpha*^2 sigma_x^2 / m,

the two terms of the last line being the variances of the two (uncorrelated at
alpha*) parts mean_n(y - alpha x) and alpha xbar_m.  With costs w (one y sample)
and 1 (one x sample) and budget p = n w + m, the optimal ratio is::

    r* = m / n = sqrt(w rho^2 / (1 - rho^2)),

and the variance against plain sampling of y at the same budget (n = p / w) is::

    Var_MF / Var_MC = (1 + r / w) [1 - (1 - 1/r) rho^2].

Everything here is a pure function of numpy arrays; nothing is assumed about
rho: it is measured from the paired samples, and where it is low (an engine
outside the twin's regime, the nonlinear stick) :func:`beats_plain` says to
sample y plainly instead.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: The fewest paired samples the estimator accepts: alpha and rho need two, and the
#: residual y - alpha x needs a third for its variance (n - 2 degrees of freedom).
MIN_PAIRED = 3


@dataclass(frozen=True)
class MFEstimate:
    """A two-model MFMC estimate of E[y] with its 95 % interval.

    mean : the estimate mu_hat.  se : its standard error sqrt(v_paired + v_extra).
    half_width : t_{0.975, df} se.  df : Welch-Satterthwaite degrees of freedom.
    alpha, rho : the control-variate coefficient and the correlation of (y, x),
    both from the paired samples.  n, m : paired and cheap sample counts (m
    includes the n).  v_paired, v_extra : the variances of mean_n(y - alpha x)
    and alpha xbar_m.  variance_ratio : Var(mu_hat) / Var(ybar_n) at the same
    sigma_y (:attr:`sigma_y`), i.e. 1 - (1 - n/m) rho^2 at alpha*.
    """

    mean: float
    se: float
    half_width: float
    df: float
    alpha: float
    rho: float
    n: int
    m: int
    v_paired: float
    v_extra: float
    variance_ratio: float

    @property
    def sigma_y(self) -> float:
        """sigma_y estimated from all the samples: sqrt(s^2(y - alpha x) + alpha^2 s_x^2)
        (the regression decomposition; ``v_paired`` n + ``v_extra`` m)."""
        return float(np.sqrt(self.v_paired * self.n + self.v_extra * self.m))

    def plain_half_width(self, n_plain: int) -> float:
        """The 95 % half-width plain sampling of y over ``n_plain`` samples would have at
        this sigma_y: t_{0.975, n_plain - 1} sigma_y / sqrt(n_plain)."""
        if n_plain < 2:
            raise ValueError(f"n_plain must be >= 2, got {n_plain}")
        return float(t975(n_plain - 1) * self.sigma_y / np.sqrt(n_plain))

    @property
    def ci95(self) -> tuple[float, float]:
        """(mean - half_width, mean + half_width)."""
        return self.mean - self.half_width, self.mean + self.half_width

    def as_dict(self) -> dict:
        return asdict(self) | {"ci95": list(self.ci95)}


def t975(df: float) -> float:
    """The Student-t 0.975 quantile with ``df`` (real, > 0) degrees of freedom."""
    from scipy.special import stdtrit

    return float(stdtrit(df, 0.975))


def _check_samples(y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y, x) as float arrays; ValueError naming the parameter when the shapes do not nest."""
    y = np.asarray(y, dtype=float).ravel()
    x = np.asarray(x, dtype=float).ravel()
    if y.size < MIN_PAIRED:
        raise ValueError(f"y must hold at least {MIN_PAIRED} paired samples, got {y.size}")
    if x.size < y.size:
        raise ValueError(f"x must hold at least len(y) = {y.size} samples, got {x.size}")
    if not (np.isfinite(y).all() and np.isfinite(x).all()):
        raise ValueError("y and x must be finite (drop the non-finite pairs first)")
    return y, x


def control_variate(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """(alpha*, rho) of paired samples: alpha* = cov(y, x) / var(x), rho = corr(y, x).

    alpha* = rho sigma_y / sigma_x minimises Var(mu_hat) (module docstring).  A
    constant x gives alpha = 0 and rho = 0 (no control); a constant y with a
    varying x gives rho = 0.
    """
    y = np.asarray(y, dtype=float).ravel()
    x = np.asarray(x, dtype=float).ravel()
    xc, yc = x - x.mean(), y - y.mean()
    vx, vy, c = float(xc @ xc), float(yc @ yc), float(xc @ yc)  # (n - 1) var, var, cov
    if not vx > 0:
        return 0.0, 0.0
    rho = c / np.sqrt(vx * vy) if vy > 0 else 0.0
    return c / vx, float(np.clip(rho, -1.0, 1.0))


def welch_df(v1: float, df1: float, v2: float, df2: float) -> float:
    """Welch-Satterthwaite degrees of freedom of v1 + v2: (v1 + v2)^2 / (v1^2/df1 + v2^2/df2).

    The larger of df1, df2 where both variances vanish.
    """
    den = v1 * v1 / df1 + v2 * v2 / df2
    return float((v1 + v2) ** 2 / den) if den > 0 else float(max(df1, df2))


def mfmc_estimate(
    y: np.ndarray, x: np.ndarray, alpha: float | None = None, x_paired: np.ndarray | None = None
) -> MFEstimate:
    """Two-model MFMC estimate of E[y] from n paired samples and m >= n of x (nested).

    Parameters
    ----------
    y : numpy.ndarray
        (n,) the costly quantity (engine - reduced), n >= :data:`MIN_PAIRED`.
    x : numpy.ndarray
        (m,) the cheap quantity (twin - reduced); x[:n] is paired with y
        (same noise), x[n:] are further independent realisations.
    alpha : float or None
        The control-variate coefficient; None: alpha* estimated from the pairs.
    x_paired : numpy.ndarray or None
        (n,) the cheap quantity paired with y where the pairs ran another setting than
        x (the lambda1 check's engine and its twin's pairs over a shorter duration, x
        over the full one): mu_hat = mean_n(y - alpha x_paired) + alpha xbar_m, an
        estimate of E[y] at x's setting where E[y - alpha x] does not depend on it.
        The pairs' realisations are among x's, run longer, so mean_n(y - alpha x_paired)
        and xbar_m may correlate: the variance then takes the Cauchy-Schwarz bound of
        their covariance, v_paired + v_extra + 2 sqrt(v_paired v_extra n / m).

    Returns
    -------
    MFEstimate
        mu_hat = ybar_n + alpha (xbar_m - xbar_n); its variance estimated as
        s^2(y - alpha x) / n + alpha^2 s_x^2 / m (s_x over all m; s^2(y - alpha x)
        with n - 2 degrees of freedom when alpha is estimated, n - 1 when given), which equals
        the MFMC formula sigma_y^2 / n [1 - (1 - n/m) rho^2] at alpha*; the 95 %
        interval is Student-t with Welch-Satterthwaite degrees of freedom
        (n - 2 for the first part when alpha is estimated, n - 1 when given;
        m - 1 for the second).
    """
    y, x = _check_samples(y, x)
    n, m = y.size, x.size
    xp = x[:n] if x_paired is None else np.asarray(x_paired, dtype=float).ravel()
    if xp.size != n:
        raise ValueError(f"x_paired must hold one value per y ({n}), got {xp.size}")
    if not np.isfinite(xp).all():
        raise ValueError("x_paired must be finite (drop the non-finite pairs first)")
    estimated = alpha is None
    a, rho = control_variate(y, xp)
    if not estimated:
        a = float(alpha)
    mean = float(y.mean() + a * (x.mean() - xp.mean()))
    # the residual of a fitted line (intercept and alpha) has n - 2 degrees of freedom
    v1 = float((y - a * xp).var(ddof=2 if estimated else 1) / n)
    v2 = float(a * a * x.var(ddof=1) / m) if m > 1 else 0.0
    df = welch_df(v1, n - 2 if estimated else n - 1, v2, max(m - 1, 1))
    cross = 0.0 if x_paired is None else 2.0 * np.sqrt(v1 * v2 * n / m)
    se = float(np.sqrt(v1 + v2 + cross))
    vy = (v1 * n + v2 * m) / n  # sigma_y^2 / n, sigma_y from every sample (MFEstimate.sigma_y)
    return MFEstimate(
        mean=mean, se=se, half_width=float(t975(df) * se), df=df, alpha=a,
        rho=rho, n=n, m=m, v_paired=v1, v_extra=v2,
        variance_ratio=(v1 + v2) / vy if vy > 0 else float("nan"),
    )  # fmt: skip


def mfmc_variance(sigma_y: float, sigma_x: float, rho: float, n: int, m: int,
                  alpha: float | None = None) -> float:  # fmt: skip
    """Var(mu_hat) of the two-model MFMC estimator (module docstring).

    sigma_y^2 / n + (1/n - 1/m) (alpha^2 sigma_x^2 - 2 alpha rho sigma_y sigma_x);
    alpha None: alpha* = rho sigma_y / sigma_x, giving sigma_y^2 / n [1 - (1 - n/m) rho^2].
    """
    if not 1 <= n <= m:
        raise ValueError(f"n must be in [1, m = {m}], got {n}")
    if alpha is None:
        return sigma_y**2 / n * (1.0 - (1.0 - n / m) * rho**2)
    cross = alpha**2 * sigma_x**2 - 2.0 * alpha * rho * sigma_y * sigma_x
    return sigma_y**2 / n + (1.0 / n - 1.0 / m) * cross


def optimal_ratio(rho: float, w: float) -> float:
    """MFMC's optimal m / n for two models: r* = sqrt(w rho^2 / (1 - rho^2)).

    ``w`` > 0 is the cost of a costly sample over a cheap one; r* is inf for
    |rho| = 1 and 0 for rho = 0.
    """
    if not w > 0:
        raise ValueError(f"w must be > 0 (cost ratio), got {w}")
    r2 = min(float(rho) ** 2, 1.0)
    return float("inf") if r2 >= 1.0 else float(np.sqrt(w * r2 / (1.0 - r2)))


def budget_variance_ratio(rho: float, w: float, r: float) -> float:
    """Var_MF / Var_MC at the same budget: (1 + r / w) [1 - (1 - 1/r) rho^2], r = m / n >= 1."""
    if not r >= 1:
        raise ValueError(f"r must be >= 1 (m / n), got {r}")
    return (1.0 + r / w) * (1.0 - (1.0 - 1.0 / r) * rho**2)


@dataclass(frozen=True)
class Allocation:
    """Samples of each model: n costly (paired), m cheap (including the n)."""

    n: int
    m: int
    ratio: float  # the MFMC-optimal r* before the caps
    multifidelity: bool  # False: plain sampling of the costly model (m = n)


def allocate(rho: float, w: float, budget: float, n_min: int = MIN_PAIRED,
             m_max: int | None = None) -> Allocation:  # fmt: skip
    """The two-model MFMC allocation of ``budget`` (in cheap-sample units).

    n = budget / (w + r*), m = r* n (r* from :func:`optimal_ratio`), n at least
    ``n_min`` and m at most ``m_max``; plain sampling (n = budget / w, m = n)
    when that is not worse: r* <= 1 or :func:`budget_variance_ratio` >= 1 (low rho).
    """
    if not budget >= w * n_min:
        raise ValueError(f"budget must be >= w * n_min = {w * n_min:g}, got {budget:g}")
    r = optimal_ratio(rho, w)
    plain = max(n_min, int(budget // w))
    if r <= 1.0 or budget_variance_ratio(rho, w, r if np.isfinite(r) else 1e300) >= 1.0:
        return Allocation(n=plain, m=plain, ratio=r, multifidelity=False)
    n = max(n_min, int(budget / (w + r)) if np.isfinite(r) else n_min)
    m = int(budget - n * w) if not np.isfinite(r) else int(np.floor(r * n))
    m = max(n, m if m_max is None else min(m, m_max))
    return Allocation(n=n, m=m, ratio=r, multifidelity=m > n)


def predicted_half_width_ratio(rho: float, n: int, m: int, n_plain: int) -> float:
    """MFMC 95 % half-width at (n, m) over plain sampling's with ``n_plain`` costly samples.

    Both at the same sigma_y: t_{df} sqrt((1 - rho^2)/n + rho^2/m) over
    t_{n_plain - 1} sqrt(1/n_plain), df the Welch-Satterthwaite degrees of freedom
    of the two terms (n - 2 and m - 1).
    """
    if n < MIN_PAIRED or m < n or n_plain < 2:
        raise ValueError(f"need n >= {MIN_PAIRED}, m >= n, n_plain >= 2; got {n}, {m}, {n_plain}")
    r2 = min(float(rho) ** 2, 1.0)
    v1, v2 = (1.0 - r2) / n, r2 / m
    df = welch_df(v1, n - 2, v2, max(m - 1, 1))
    mf = t975(df) * np.sqrt(v1 + v2)
    return float(mf / (t975(n_plain - 1) / np.sqrt(n_plain)))


def beats_plain(rho: float, n: int, m: int, n_plain: int) -> bool:
    """Whether MFMC at (n, m) gives an interval no wider than plain sampling of ``n_plain``."""
    return predicted_half_width_ratio(rho, n, m, n_plain) <= 1.0


def plain_half_width_at(x: np.ndarray, n_plain: int) -> float:
    """The 95 % half-width plain sampling of ``n_plain`` costly samples would have at the
    cheap model's spread: t_{0.975, n_plain - 1} s_x / sqrt(n_plain), s_x over all of
    ``x``.  Where the cheap model follows the costly one, s_x is sigma_y; unlike
    :attr:`MFEstimate.sigma_y` at alpha = 1, it does not count an unrelated control's
    own spread twice (s^2(y - x) + s_x^2 is then 3 sigma^2)."""
    return t975(n_plain - 1) * float(np.std(x, ddof=1)) / np.sqrt(n_plain)


def bootstrap_interval(y: np.ndarray, x: np.ndarray, rng: np.random.Generator,
                       n_bootstrap: int = 1000, alpha: float | None = None
                       ) -> tuple[float, float]:  # fmt: skip
    """95 % percentile bootstrap interval of :func:`mfmc_estimate`'s mean, paired structure kept.

    Each resample draws n of the paired (y_i, x_i) with replacement and, apart,
    m - n of the extra x; alpha is ``alpha`` where given, else alpha* re-estimated in
    each.  A resample whose x pairs are constant (one pair drawn n times: 1 in 9
    resamples for n = 3) keeps the full sample's alpha*.
    """
    y, x = _check_samples(y, x)
    n, m = y.size, x.size
    ip = rng.integers(0, n, (n_bootstrap, n))
    ie = n + rng.integers(0, max(m - n, 1), (n_bootstrap, m - n))
    yb, xb = y[ip], x[ip]
    if alpha is not None:
        a = np.full(n_bootstrap, float(alpha))
    else:
        xc = xb - xb.mean(axis=1, keepdims=True)
        vx = (xc * xc).sum(axis=1)
        cov = (xc * (yb - yb.mean(axis=1, keepdims=True))).sum(axis=1)
        one = (ip.min(axis=1) == ip.max(axis=1)) | ~(vx > 0)
        a = np.where(one, control_variate(y, x[:n])[0], cov / np.where(one, 1.0, vx))
    xall = np.concatenate([xb, x[ie]], axis=1).mean(axis=1)
    est = yb.mean(axis=1) + a * (xall - xb.mean(axis=1))
    lo, hi = np.percentile(est, [2.5, 97.5])
    return float(lo), float(hi)


def finite_nested(y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nested samples with the non-finite ones left out: pairs where y or x[:n]
    is not finite, and extra x that are not finite (an STCC window without a peak)."""
    y = np.asarray(y, dtype=float).ravel()
    x = np.asarray(x, dtype=float).ravel()
    n = y.size
    ok = np.isfinite(y) & np.isfinite(x[:n])
    extra = x[n:]
    return y[ok], np.concatenate([x[:n][ok], extra[np.isfinite(extra)]])
