"""beta* under the readings the paper leaves open: estimator, discretisation, duration.

The paper (section 3.1) defines lambda1 = lim (1/t) log ||Delta q(t)|| on the
state q = (q_1, q_1', q_2, q_2') of eq. (3) / (5) and computes it "numerically",
without the method, the time step, the noise's discretisation or the duration;
its beta* (Fig. 4 caption: 20.306 single, 21.032 coupled at lambda1 = 5e-4)
depends on all four.  This module computes lambda1, and from it beta*, under
each reading on common random numbers:

* **noise**: every setting reads one Wiener path per realisation and balancer,
  drawn on a base grid ``base_dt`` (:class:`cipcore.noise.GainNoise`, seed as
  everywhere); a setting with step ``dt = m base_dt`` holding its draw over
  ``hold = k dt`` uses the path's increment over the hold,
  R = 1 + nu (W(t + hold) - W(t)) / hold, i.e. the sum of the k m base draws over
  sqrt(k m), times nu / sqrt(hold).  At ``hold = dt = base_dt`` that is
  :mod:`reduced.lyapunov`'s noise draw for draw;
* **scheme**: semi-implicit Euler (today's), explicit Euler-Maruyama, Heun;
* **initial state**: a random tangent vector over the whole delay state
  (today's, :func:`cipcore.seeds.tangent_rng`) or the paper's kind of initial
  condition, a unit balancing error at rest with a constant history;
* **estimator** (:data:`NORMS`, all from one run: the direction of the state does
  not depend on what is measured): Benettin's sum over the whole delay state
  (today's), the growth of the norm of the state (e_i, e_i') as the paper writes
  it, of the positions e_i alone, or of the first balancer's (e_1, e_1');
  measured from the end of the transient or from t = 0 (:data:`ORIGINS`);
* **duration**: the estimate at every checkpoint t of one run (the estimate at t
  equals a run of duration t: same draws, same transient).

beta* is the root of a quadratic fit of the mean lambda1 over a grid of gains (as
:func:`reduced.lyapunov.critical_gain`), its uncertainty from resampling
realisations, the same resampled indices for every reading (so differences between
readings are paired).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from cipcore.driver import run_blocks
from cipcore.noise import GainNoise
from cipcore.params import BalanceParams, ParameterError, check_choice, check_count, whole_steps
from cipcore.results import check_transient
from cipcore.schema import check_duration
from cipcore.seeds import purpose_rng, tangent_rng

from ._beta_star_kernel import SCHEME_CODES, advance_variant, log_norms
from .lyapunov import _solve_fits
from .simulate import n_controllers

SCHEMES = tuple(SCHEME_CODES)
#: initial states: today's random tangent vector, or a unit error at rest
INITS = ("tangent", "unit-error")
#: what lambda1 measures the growth of (the columns of the kernel's records)
NORMS = ("delay-state", "state", "positions", "balancer-1")
#: where the measured growth starts: the end of the transient (today's), or t = 0
ORIGINS = ("transient", "zero")


@dataclass(frozen=True)
class Discretisation:
    """One discretisation of eq. (3) / (5) for lambda1.

    Attributes
    ----------
    dt : time step (s); tau = 0.1 s must be a whole number of steps.
    hold : time the noise draw is held (s), a whole number of steps; None: dt
        (one draw per step, variance 1/dt: today's).
    scheme : one of :data:`SCHEMES` for the deterministic part.
    init : one of :data:`INITS`.
    """

    dt: float = 1e-3
    hold: float | None = None
    scheme: str = "semi-implicit"
    init: str = "tangent"

    def __post_init__(self) -> None:
        check_choice("scheme", self.scheme, SCHEMES)
        check_choice("init", self.init, INITS)
        if self.hold is not None:
            whole_steps("hold", self.hold, self.dt)

    @property
    def hold_steps(self) -> int:
        """Steps per noise draw (1: a draw per step)."""
        return 1 if self.hold is None else whole_steps("hold", self.hold, self.dt)

    def label(self) -> str:
        """A short name: 'dt 1 ms', 'dt 1 ms, hold 20 ms, heun, unit-error'."""
        parts = [f"dt {self.dt * 1e3:g} ms"]
        if self.hold_steps > 1:
            parts.append(f"hold {self.hold * 1e3:g} ms")
        parts += [s for s in (self.scheme, self.init) if s not in ("semi-implicit", "tangent")]
        return ", ".join(parts)


@dataclass(frozen=True)
class RunPlan:
    """What one pass over the noise simulates: its size and where it looks.

    Attributes
    ----------
    checkpoints : times (s) the estimates are read at, multiples of tau; the
        largest is the duration.
    n_realizations : noise realisations (one lambda1 each per reading and gain).
    seed : the noise seed (:mod:`cipcore.seeds`).
    base_dt : step of the Wiener path's base grid (s); every setting's dt is a
        whole multiple of it.
    transient : s discarded before the "transient" origin, a multiple of tau.
    """

    checkpoints: tuple[float, ...]
    n_realizations: int = 16
    seed: int = 1
    base_dt: float = 1e-3
    transient: float = 10.0

    def __post_init__(self) -> None:
        if not self.checkpoints:
            raise ParameterError("checkpoints must hold at least one time (s)")
        pts = tuple(sorted(check_duration(t) for t in self.checkpoints))
        object.__setattr__(self, "checkpoints", pts)
        check_count("n_realizations", self.n_realizations)
        check_count("seed", self.seed, minimum=0)
        check_transient(self.transient, pts[0])

    @property
    def duration(self) -> float:
        return self.checkpoints[-1]


@dataclass
class Records:
    """The kernel's records of one setting: (gains, realisations, marks, 5) in ``rec``.

    ``marks`` are step counts (0, the end of the transient, the checkpoints);
    ``rec[..., 0]`` the Benettin sum after the transient, ``rec[..., 1:]`` the log
    norms of :data:`NORMS`; ``pre`` (gains, realisations) the sum of the log
    renormalisation factors up to the transient.
    """

    setting: Discretisation
    dt: float
    marks: np.ndarray
    start: int
    rec: np.ndarray
    pre: np.ndarray = field(repr=False)

    def lambdas(self, norm: str, origin: str, checkpoint: int) -> np.ndarray:
        """lambda1 (1/s) per gain and realisation, (G, R), read at mark ``checkpoint``.

        ``norm`` one of :data:`NORMS`, ``origin`` one of :data:`ORIGINS`.  The
        Benettin estimate from the transient is :func:`reduced.lyapunov.lyapunov`'s
        (the sum over the time measured, to the bit); every other is
        (log ||x(t)|| - log ||x(t0)||) / (t - t0) with x the unrenormalised state.
        """
        check_choice("norm", norm, NORMS)
        check_choice("origin", origin, ORIGINS)
        col = 1 + NORMS.index(norm)
        j = int(np.searchsorted(self.marks, checkpoint))
        if j >= self.marks.size or self.marks[j] != checkpoint:
            raise ParameterError(f"checkpoint must be one of the marks {self.marks.tolist()}")
        now = self.rec[:, :, j]
        if origin == "zero":
            t = checkpoint * self.dt
            return (self.pre + now[..., 0] + now[..., col] - self.rec[:, :, 0, col]) / t
        s = int(np.searchsorted(self.marks, self.start))
        t = (checkpoint - self.start) * self.dt
        if norm == "delay-state":  # renormalised to 1 at both ends: the sum alone
            return now[..., 0] / t
        return (now[..., 0] + now[..., col] - self.rec[:, :, s, col]) / t


def initial_state(
    setting: Discretisation, nc: int, d: int, plan: RunPlan
) -> tuple[np.ndarray, np.ndarray]:
    """The start (y (R, 2C), history (R, C, d)) of every realisation.

    ``tangent``: :func:`reduced.lyapunov.lyapunov_gains`' random vector;
    ``unit-error``: e_i = 1, e_i' = 0 and e_i = 1 over the past tau (the paper's kind
    of initial condition, as :func:`reduced.simulate.simulate` starts).
    """
    r_all = plan.n_realizations
    if setting.init == "unit-error":
        y = np.zeros((r_all, 2 * nc))
        y[:, 0::2] = 1.0
        return y, np.ones((r_all, nc, d))
    y = np.empty((r_all, 2 * nc))
    hist = np.empty((r_all, nc, d))
    for r in range(r_all):
        rng = tangent_rng(plan.seed, r)
        y[r] = rng.standard_normal(2 * nc)
        hist[r] = rng.standard_normal((nc, d))
    return y, hist


def _marks(plan: RunPlan, dt: float, every: int) -> tuple[np.ndarray, int]:
    """Step counts of the marks (0, end of transient, checkpoints) and the transient's."""
    transient_steps = whole_steps("transient", plan.transient, dt)
    if transient_steps % every:
        raise ParameterError(f"transient must be a whole number of tau, got {plan.transient}")
    pts = [whole_steps("checkpoint", t, dt) for t in plan.checkpoints]
    if any(n % every for n in pts):
        raise ParameterError(f"checkpoints must be whole numbers of tau, got {plan.checkpoints}")
    return np.unique(np.array([0, transient_steps, *pts], dtype=np.int64)), transient_steps


class _SettingRun:
    """One setting's state over all gains and realisations, advanced a chunk at a time."""

    def __init__(self, model: str, params: Sequence[BalanceParams], setting: Discretisation,
                 plan: RunPlan) -> None:  # fmt: skip
        nc = n_controllers(model)
        self.setting = setting
        self.ratio = whole_steps("dt", setting.dt, plan.base_dt)
        p0 = params[0].with_(dt=setting.dt)
        self.d = p0.delay_steps
        self.marks, self.transient = _marks(plan, setting.dt, self.d)
        k = setting.hold_steps
        scale = (lambda p: p.noise_scale) if k == 1 else (lambda p: p.nu / math.sqrt(k * p.dt))
        self.coefs = [
            np.array([p.alpha, p.beta, p.gamma, scale(p), p.dt])
            for p in (q.with_(dt=setting.dt) for q in params)
        ]
        y, hist = initial_state(setting, nc, self.d, plan)
        g, r = len(params), plan.n_realizations
        self.y = np.repeat(y[None], g, axis=0)
        self.hist = np.repeat(hist[None], g, axis=0)
        self.rec = np.zeros((g, r, self.marks.size, 5))
        for gi in range(g):
            for ri in range(r):
                log_norms(self.y[gi, ri], self.hist[gi, ri], self.rec[gi, ri, 0, 1:])
        self.sums = np.zeros((g, r, 2))
        self.scheme = SCHEME_CODES[setting.scheme]

    @property
    def draws_per_hold(self) -> int:
        return self.ratio * self.setting.hold_steps

    def advance(self, block: slice, z: np.ndarray, n0_base: int) -> None:
        """Advance realisations ``block`` over the base draws ``z`` from base step n0_base."""
        a = self.draws_per_hold
        xi = z if a == 1 else z.reshape(z.shape[0], -1, a, z.shape[2]).sum(axis=2) / math.sqrt(a)
        n0 = n0_base // self.ratio
        steps = np.array([n0, self.d, self.transient], dtype=np.int64)
        for g, coef in enumerate(self.coefs):
            advance_variant(
                xi, self.setting.hold_steps, self.y[g, block], self.hist[g, block], n0 % self.d,
                coef, self.scheme, steps, self.marks, self.rec[g, block], self.sums[g, block],
            )  # fmt: skip

    def records(self) -> Records:
        start = (self.transient // self.d) * self.d
        return Records(self.setting, self.setting.dt, self.marks, start, self.rec,
                       self.sums[..., 1])  # fmt: skip


def run_records(
    model: str,
    base: BalanceParams,
    betas: Sequence[float],
    settings: Sequence[Discretisation],
    plan: RunPlan,
    threads: int | None = None,
) -> list[Records]:
    """Simulate every setting at every gain on one set of Wiener paths; their records.

    Parameters
    ----------
    model : "single" (eq. (3)) or "coupled" (eq. (5)).
    base : alpha, gamma, nu, tau of the model (beta and dt are replaced).
    betas : the gains (1/s^2).
    settings : the discretisations; each dt a whole multiple of ``plan.base_dt``.
    plan : sizes, seed, checkpoints.
    threads : worker threads (results do not depend on it).
    """
    if not settings or not len(betas):
        raise ParameterError("settings and betas must each hold at least one entry")
    params = [base.with_(beta=float(b)) for b in betas]
    runs = [_SettingRun(model, params, s, plan) for s in settings]
    n_base = whole_steps("duration", plan.duration, plan.base_dt)
    chunk = math.lcm(*(r.draws_per_hold for r in runs))
    if n_base % chunk:
        raise ParameterError(
            f"duration {plan.duration} s must be a whole number of every setting's hold"
        )
    noise = GainNoise(plan.seed, plan.n_realizations, n_controllers(model))

    def work(block: slice, z: np.ndarray, n0: int) -> None:
        for run in runs:
            run.advance(block, z, n0)

    run_blocks(noise, n_base, work, threads=threads, chunk_steps=chunk * max(1, 8192 // chunk))
    return [r.records() for r in runs]


def bootstrap_indices(seed: int, n: int, n_boot: int) -> np.ndarray:
    """(n_boot, n) resampled realisation indices, drawn as
    :func:`reduced.lyapunov.critical_gain` draws them (the ``bootstrap`` purpose)."""
    rng = purpose_rng(seed, "bootstrap")
    return np.stack([rng.integers(0, n, n) for _ in range(n_boot)])


def fit_beta_star(
    betas: np.ndarray, lam: np.ndarray, target: float, idx: np.ndarray
) -> tuple[float, np.ndarray]:
    """beta* (1/s^2) where the fit of mean lambda1 over ``betas`` meets ``target`` (1/s).

    ``lam`` (G, R) per gain and realisation; quadratic least squares for four or more
    gains, else linear (:func:`reduced.lyapunov.critical_gain`'s rule).  Returns the
    point estimate (NaN when the fit does not cross the target inside the gains) and
    the estimate on every resample ``idx`` (B, R) (NaN where it does not cross).
    """
    betas = np.asarray(betas, dtype=float)
    deg = 2 if betas.size >= 4 else 1
    point = _solve_fits(betas, lam.mean(axis=1)[:, None], target, deg)[0]
    boots = _solve_fits(betas, lam[:, idx].mean(axis=2), target, deg)
    return float(point), boots


def step_count(records: Records, t: float) -> int:
    """The mark (a step count) of checkpoint time ``t`` (s) in ``records``."""
    return whole_steps("checkpoint", t, records.dt)
