"""Exactness by time-step refinement: any engine against the exact zero-order-hold solution.

The exact twins (:mod:`reduced.twin`) hold an engine to 1e-9, but only when cipval
re-implements the engine's discretisation.  An engine whose stepper cipval does not
know (its own integrator, sub-steps, a rigid rod) is judged here instead, by what any
correct stepper must satisfy: cipval computes every control and hands the engine
forces held constant over each control interval h (the model file's time step), so as
the engine's own step shrinks, dt = h, h/2, h/4, h/8, its trajectories must converge
to the exact solution of the linearised rigid body under those piecewise-constant
forces, x_{k+1} = exp(A h) x_k + int_0^h exp(A s) ds B u_k (:mod:`reduced.zoh`; no
discretisation of cipval's enters).  A wrong mass, length, gravity or damping moves
that limit; a different correct stepper does not.

The test (open loop, no noise, no feedback):

* excitation: per realisation a band-limited force, a sum of :data:`N_MODES`
  sinusoids with random frequencies in [:data:`F_MIN`, :data:`F_MAX`] Hz and random
  phases (stream ``refinement`` of the seed), held over each control interval; smooth
  forces keep the rod's stiff constraint modes (eigenvalues near -500 1/s) unexcited,
  so that the positions converge at the stepper's order (a new random force every
  interval stalls every extrapolation near 3e-4);
* observable: the positions, cart x (m) and the balancing error e = L theta (m) of
  each balancer, at the control boundaries, starting upright at rest and scaled so the
  largest |e| is :data:`AMPLITUDE` (the angles' second-order terms are then below
  1e-12 relative);
* reference: A and B from central differences of MuJoCo's ``qacc`` at upright
  (:func:`cip.linearize.rod_jacobians`), with the rod as the engine declares it
  (``soft``: the file's solref/solimp spring-damper; ``rigid``: an exact distance
  constraint, the dynamics projected on J q'' = 0);
* extrapolation: the observed order p = log2(|y_{h/2} - y_{h/4}| / |y_{h/4} - y_{h/8}|)
  (norms over every realisation, time and coordinate; levels whose change is below
  :data:`ROUNDOFF` of the trajectory are rounding and left out, so a fourth-order
  stepper's order comes from h, h/2, h/4), taken as the nearest whole
  number when within :data:`WHOLE_ORDER` of one (steppers have whole orders; the
  next terms bend the observed p, 1.002 for Euler at h = 1 ms, and one Richardson step
  at 1.002 would leave 3e-6 of the limit), one Richardson step of that order on the
  trajectories themselves, then one of order + 1 (the next term of the error's
  expansion in powers of dt): y_0 = the limit dt -> 0.  E0 is the relative
  L2 distance of y_0 to the exact solution; its interval is E0 +- the change the last
  extrapolation made (the extrapolation's own error estimate), widened by the spread
  of E0 over realisations (Student-t 95 %).

Verdict: pass when the interval's upper end is within the floor (:data:`FLOOR`) and p
is at least the declared order less :data:`ORDER_SLACK` (or :data:`UNDECLARED_ORDER`
when the engine declares none).  The floor, measured (``benchmarks/refinement_power.py``,
seeds 1-20, 4 force sequences each): MuJoCo's Euler and implicitfast E0 median 1e-8, at
most 3.4e-8, the interval's upper end at most 3.1e-7 (0 false failures in 20 seeds per
model and integrator); RK4 3e-10, the reference's own floor (central differences of
``qacc``).  A relative error of 1e-5 in the tip mass, gravity or tip damping, or 1e-6
in the cart damping or pendulum length, is flagged (E0 1e-6 to 9e-6).

Float32 engines (``capabilities.precision == "float32"``) are judged at a setting of
their own (:data:`FLOAT32_SETTINGS`, :func:`precision_setting`; the float64 setting
above is unchanged).  Float32 rounds the state by about 6e-8 of itself every step: over
the 8000 steps at h/8 the trajectories carry a rounding noise of about 1e-6 of
themselves, which the two Richardson steps amplify about threefold, so that E0 is noise,
3.1e-6 to 1.4e-5 at 1e-5 m and 1 s (PhysX through SAPIEN; MuJoCo's Euler with its
state rounded to float32 after every step, :func:`float32_stand_in`: 2.9e-6 to 7.9e-6),
its interval up to 4.5e-5, and a 1e-4 error of the tip mass (E0 1e-5 to 2e-5) is inside it.  A
float32 engine whose rod is computed from world positions (PhysX's distance joint near
x = +-0.5 m, resolution 6e-8 m) adds an absolute noise: the coupled model's E0 is 4e-3
to 8e-3 at 1e-5 m, falling as 1 / amplitude (6e-4 at 1e-4 m, 7e-5 at 1e-3 m).  The
linearisation's own error (the exact solution is of the linearised model) grows as
amplitude^2: float64 MuJoCo's median E0 at 1 s is 1e-8 at 1e-5 and 1e-4 m, 9e-7 (single) and
7e-7 (coupled) at 1e-3 m, 8e-6 and 6e-6 at 3e-3 m, 9e-5 and 7e-5 at 1e-2 m.  The
float32 setting trades these three (measured with ``benchmarks/refinement_power.py
--float32``, seeds 1-20, 4 force sequences each):

* window 4 s instead of 1 s: a model error's share of the trajectory grows with the time
  the unstable pendulum amplifies it, faster than the rounding noise (a 1e-4 tip-mass
  error: E0 1e-5 to 2e-5 at 1 s, 6e-5 to 1.4e-4 at 4 s; the correct engines' E0 median
  5e-6 at 1 s, 1.4e-5 at 4 s); the linearisation's error at 4 s is 2 to 4 times that
  at 1 s (float64 MuJoCo at 1e-3 m: E0 at most 6.7e-6 single, 2.7e-6 coupled);
* single model: amplitude 1e-3 m, where float32 rounding is relative (the same E0 at
  1e-5 to 1e-3 m) and the linearisation's error a sixth of it, and an engine's absolute
  rounding a hundredth of its size at 1e-5 m; floor 1.2e-4: the correct engines' upper
  end at most 8.2e-5 (PhysX: E0 median 1.4e-5, at most 2.6e-5, order 0.995-1.004;
  the stand-in 7.7e-5), 0 false failures in 20 seeds each;
* coupled model: amplitude 3e-3 m, where the rod's float32 noise (falling as
  1 / amplitude) and the linearisation's error (growing as amplitude^2) are least
  together (PhysX's upper end at most 2.9e-4 at 1e-3 m, 1.1e-4 at 3e-3 m, 6.3e-4 at
  1e-2 m); floor 1.6e-4: the correct engines' upper end at most 1.1e-4 (PhysX: E0 median
  3.2e-5, at most 3.8e-5, order 1.000-1.002; the stand-in 7.0e-5), 0 false failures in
  20 seeds each.

By E0 alone, flagged at every one of 20 seeds at the float32 setting (sizes 1e-3, 3e-4,
1e-4 tried): single model, PhysX and the stand-in, a relative error of 1e-4 in the tip
mass, the pendulum length, gravity or the tip damping (the tip damping's least upper end
1.3e-4, at the floor's edge) and 3e-4 in the cart damping (whose E0 is 0.9 of its size,
float32 or not: 1e-4 is flagged at 14 and 15 of 20 seeds); coupled model, PhysX: 1e-4 in
the tip mass, the length or gravity, 3e-4 in the tip and the cart damping (1e-4 flagged
at 14 and 9 of 20 seeds); the stand-in: 1e-4 in the length, 3e-4 in the tip mass,
gravity, the tip and the cart damping (1e-4 flagged at 15, 15, 2 and 0 of 20 seeds).

So a float32 engine is also held to the projection of its limit's deviation on each
parameter's direction (:func:`parameter_projections`).  A relative error d_k of
parameter k (tip mass, pendulum length, gravity, tip or cart damping; :mod:`cip.edits`)
moves the limit by d_k s_k, along the exact solution's sensitivity s_k to it
(:func:`sensitivities`), while rounding spreads over every direction, so

    c_k = <y_0 - x - n, s_k> / <s_k, s_k>,

the relative error of parameter k that alone best explains the deviation, sees a wrong
parameter that E0 cannot.  n is the linearisation's own error at the setting's amplitude
(:func:`reference_limit`: the file's nonlinear response, MuJoCo's RK4 in float64
extrapolated, less its linear response), the same for every correct engine: without it
the coupled model's c along the tip damping, mass and gravity sits at -1.5e-5 on average
(float64 MuJoCo at 3e-3 m: -1.7e-5), with it float64 MuJoCo's c falls below 1e-8.  The
check passes only when every |c_k| <= :attr:`PrecisionSetting.projection_bound`, 5e-5,
half a 1e-4 error.  Measured (``benchmarks/refinement_projection.py``, seeds 1-20, 4
force sequences each): the correct float32 engines' largest |c_k| is 2.0e-5 (PhysX
single), 1.5e-5 (PhysX coupled), 1.9e-5 (Newton single) and 2.5e-5 (Newton coupled),
with a standard deviation over seeds of 7.5e-6 at most (so the bound is 3 of them above
the largest seen, 6.7 above zero); a 1e-4 error of any of the five parameters gives c_k
of 8.5e-5 or more along its own direction at every seed, PhysX and the stand-in on both
models at seeds 1-20, Newton at seeds 1-5.  The tip mass, gravity and tip damping move
the limit along nearly one direction (:data:`ALIKE`): the check names them together.

A one-step delay of the engine's control is itself a consistent first-order
discretisation of the held force (it converges to the same limit), so this check does
not see it: the ``delay`` check, which counts the steps between a step in the
balancing error and the force, does, at the model file's step.
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, field
from typing import NamedTuple

import mujoco
import numpy as np

from cipcore.seeds import purpose_rng

__all__ = [
    "ALIKE",
    "AMPLITUDE",
    "FLOAT32_SETTINGS",
    "FLOAT64_SETTING",
    "FLOOR",
    "F_MAX",
    "F_MIN",
    "LEVELS",
    "N_MODES",
    "ORDER_SLACK",
    "PROJECTED",
    "PROJECTION_BOUND",
    "UNDECLARED_ORDER",
    "WINDOW",
    "PrecisionSetting",
    "Projection",
    "Refinement",
    "alike_directions",
    "compare",
    "excitation",
    "extrapolate",
    "float32_stand_in",
    "float32_state",
    "linear_response",
    "open_loop_forces",
    "parameter_projections",
    "precision_setting",
    "projections",
    "reference_limit",
    "refine",
    "run_levels",
    "sensitivities",
]

#: refinement levels: the engine steps at h, h/2, ..., h / 2**(LEVELS - 1)
LEVELS = 4
#: the test window (s): 1000 control intervals at h = 1 ms
WINDOW = 1.0
#: sinusoids per force and their band (Hz): smooth at the control interval
N_MODES, F_MIN, F_MAX = 4, 0.2, 5.0
#: the largest balancing error of the response (m): linear to 1e-12 relative
AMPLITUDE = 1e-5
#: the largest E0 (relative L2) a correct engine may show (module docstring)
FLOOR = 1e-6
#: a level's change below this fraction of the trajectory is rounding (float64, 8000
#: steps; MuJoCo's RK4 on the coupled file: changes of 1.5e-11 to 2.5e-11 at h/8 whose
#: ratio to the one before falls from 16 to 6.6): the levels after it are left out of
#: the order and the extrapolation
ROUNDOFF = 3e-11
#: an observed order this close to a whole number is taken as that number
WHOLE_ORDER = 0.15
#: force sequences (realisations) per test, and the longest stretch handed to an engine
#: at once (s: the delay tau, the chunk protocol's bound)
REALIZATIONS, CHUNK_TIME = 4, 0.1
#: how far the observed order may fall below the declared one
ORDER_SLACK = 0.3
#: the least observed order of an engine that declares none
UNDECLARED_ORDER = 0.8


@dataclass(frozen=True)
class Refinement:
    """What one refinement test measured (module docstring).

    ``errors``: relative L2 distance to the exact solution at each level's step
    (``steps``, s); ``order`` the observed p (finest three levels) and
    ``order_coarse`` the same from the coarsest three; ``e0`` the extrapolated
    limit's distance and ``e0_interval`` its interval; ``per_realization`` E0 of each
    force sequence.
    """

    steps: tuple[float, ...]
    errors: tuple[float, ...]
    order: float
    order_coarse: float
    e0: float
    e0_interval: tuple[float, float]
    per_realization: tuple[float, ...] = field(default_factory=tuple)

    def passes(self, floor: float, least_order: float) -> bool:
        ok = np.isfinite(self.e0_interval[1]) and self.e0_interval[1] <= floor
        return bool(ok and np.isfinite(self.order) and self.order >= least_order)


def open_loop_forces(
    n_realizations: int, n_intervals: int, n_controllers: int, h: float, seed: int
) -> np.ndarray:
    """Band-limited forces (R, K, C), unit scale, each held over an interval of ``h`` s.

    Realisation r's force is drawn from the seed's stream ``refinement``, key r
    (:func:`cipcore.seeds.purpose_rng`): the same for any batch split.
    Force k is the sum of the sinusoids at the interval's midpoint.
    """
    t = (np.arange(n_intervals) + 0.5) * h
    out = np.empty((n_realizations, n_intervals, n_controllers))
    for r in range(n_realizations):
        rng = purpose_rng(seed, "refinement", r)
        freq = rng.uniform(F_MIN, F_MAX, (N_MODES, n_controllers))
        phase = rng.uniform(0.0, 2 * np.pi, (N_MODES, n_controllers))
        weight = rng.standard_normal((N_MODES, n_controllers))
        out[r] = np.einsum(
            "mc,kmc->kc", weight, np.sin(2 * np.pi * freq * t[:, None, None] + phase)
        )
    return out


def extrapolate(
    levels: list[np.ndarray], roundoff: float = 0.0
) -> tuple[np.ndarray, float, float, float]:
    """The dt -> 0 limit of trajectories at steps h, h/2, ... (at least 3 levels).

    Returns (y0, p, p_coarse, change): the limit, the observed order from the finest
    three levels used and from the coarsest three, and the norm of the last
    extrapolation step's change (its error estimate, in the trajectories' unit).  One
    Richardson step of order p, then (with four or more levels) one of order p + 1.

    ``roundoff`` (relative): a level whose change from the one before is below
    ``roundoff`` times the trajectory's norm has converged to rounding (a fourth-order
    stepper at h/8: 1e-12 of the trajectory, the rounding of 8000 steps): the levels
    after it carry no information about the order, and are left out.
    """
    if len(levels) < 3:
        raise ValueError("extrapolation needs at least three refinement levels")
    diffs = [float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(levels)]
    scale = float(np.linalg.norm(levels[-1]))
    used = len(levels)
    for j, d in enumerate(diffs):
        if d <= roundoff * scale:  # level j + 1 adds only rounding to level j
            used = j + 1
            break
    if used < 3:  # converged within two levels: the finest of them is the limit
        return levels[used - 1], float("inf"), float("inf"), diffs[0] if used == 2 else 0.0
    levels, diffs = levels[:used], diffs[: used - 1]

    def order(d1: float, d2: float) -> float:
        return float(np.log2(d1 / d2)) if d1 > 0 and d2 > 0 else float("inf")

    p, p_coarse = order(diffs[-2], diffs[-1]), order(diffs[0], diffs[1])
    if not np.isfinite(p):  # the levels agree exactly: the finest is the limit
        return levels[-1], p, p_coarse, 0.0
    # steppers have whole orders: the observed p carries the next terms' trace (1.002 for
    # Euler at h = 1 ms), which one Richardson step would amplify to 3e-6 of the limit
    k = round(p) if abs(p - round(p)) <= WHOLE_ORDER and round(p) >= 1 else p
    r1 = [b + (b - a) / (2**k - 1) for a, b in itertools.pairwise(levels)]
    if len(r1) < 3:
        return r1[-1], p, p_coarse, float(np.linalg.norm(r1[-1] - r1[-2]))
    q = k + 1
    r2 = [b + (b - a) / (2**q - 1) for a, b in itertools.pairwise(r1)]
    return r2[-1], p, p_coarse, float(np.linalg.norm(r2[-1] - r2[-2]))


def _run_backend(backend, model: mujoco.MjModel, state0: np.ndarray, ctrl: np.ndarray, chunk: int,
                 threads: int) -> np.ndarray:  # fmt: skip
    """The states (R, n, nstate) after each of the n steps of ``ctrl`` (R, n, nu)."""
    r, n, _ = ctrl.shape
    nstate = state0.shape[1]
    rollout = backend(model, r, threads)
    out = np.empty((r, n, nstate))
    state = np.array(state0)
    try:
        for k0 in range(0, n, chunk):
            k1 = min(n, k0 + chunk)
            buf = np.empty((r, k1 - k0, nstate))
            rollout(state, np.ascontiguousarray(ctrl[:, k0:k1]), buf)
            out[:, k0:k1] = buf
            state = buf[:, -1]
    finally:
        close = getattr(rollout, "close", None)
        if close is not None:
            close()
    return out


def observable(model: mujoco.MjModel) -> tuple[list[int], np.ndarray]:
    """The motors' actuator ids and the map from qpos - qpos0 to the observable: cart x and
    e = L theta (m) of each balancer, L the hinge-to-tip distance at upright (the model's
    element names, :mod:`cip.names`)."""
    from cip.names import cart_joint, hinge_joint, motor, tip_site

    obj = mujoco.mjtObj
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    motors, rows = [], []
    i = 1
    while mujoco.mj_name2id(model, obj.mjOBJ_JOINT, cart_joint(i)) >= 0:
        jx = mujoco.mj_name2id(model, obj.mjOBJ_JOINT, cart_joint(i))
        jt = mujoco.mj_name2id(model, obj.mjOBJ_JOINT, hinge_joint(i))
        tip = data.site_xpos[mujoco.mj_name2id(model, obj.mjOBJ_SITE, tip_site(i))]
        length = float(np.linalg.norm(tip - data.xanchor[jt]))
        motors.append(mujoco.mj_name2id(model, obj.mjOBJ_ACTUATOR, motor(i)))
        rx, rt = np.zeros(model.nq), np.zeros(model.nq)
        rx[model.jnt_qposadr[jx]] = 1.0
        rt[model.jnt_qposadr[jt]] = length
        rows += [rx, rt]
        i += 1
    return motors, np.array(rows)


@dataclass(frozen=True)
class RefinementSetting:
    """The numerical setting of one refinement.

    Attributes
    ----------
    seed : root seed of the open-loop forces (the ``refinement`` stream).
    n_realizations : independent force histories.
    chunk_time : the longest stretch handed to the engine at once, s (the delay tau:
        the chunk protocol's bound).
    levels : time steps dt, dt/2, ..., dt/2^(levels-1).
    window : simulated time, s.
    amplitude : the largest balancing error |e| of the response, m.
    """

    seed: int
    n_realizations: int = REALIZATIONS
    chunk_time: float = CHUNK_TIME
    levels: int = LEVELS
    window: float = WINDOW
    amplitude: float = AMPLITUDE


def excitation(
    model: mujoco.MjModel, rod: str, setting: RefinementSetting
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The test's forces and the exact solution they give (module docstring).

    Returns (ctrl, exact, x0): the controls (R, K, nu) held per control interval h (the
    model file's time step: forces on the motors, scaled so that the largest |e| of the
    response is ``setting.amplitude``), the exact zero-order-hold response's observable
    (R, K, 2 x balancers: cart x and e, m) of the file's linearisation with the rod as
    ``rod`` declares it, and the initial state (R, nq + nv: upright, at rest).
    """
    from cip.linearize import rod_jacobians

    h = float(model.opt.timestep)
    k_int = round(setting.window / h)
    motors, _ = observable(model)
    # forces on the motors only (the damping actuators take no control)
    f = open_loop_forces(setting.n_realizations, k_int, len(motors), h, setting.seed)
    ctrl = np.zeros((setting.n_realizations, k_int, model.nu))
    for i, motor in enumerate(motors):
        ctrl[..., motor] = f[..., i]
    x0 = np.zeros((setting.n_realizations, model.nq + model.nv))
    exact = linear_response(model, rod_jacobians(model, rod), x0, ctrl)
    scale = setting.amplitude / np.abs(exact[..., 1::2]).max(axis=(1, 2), keepdims=True)
    return ctrl * scale, exact * scale, x0


def linear_response(
    model: mujoco.MjModel, ab: tuple[np.ndarray, np.ndarray], x0: np.ndarray, ctrl: np.ndarray
) -> np.ndarray:
    """The observable (:func:`observable`, m) of the exact zero-order-hold response of the
    linear system ``ab`` = (A, B) from ``x0`` under ``ctrl`` held per control interval h
    (:func:`reduced.zoh.zoh_response`: x_{k+1} = exp(A h) x_k + int_0^h exp(A s) ds B u_k)."""
    from reduced.zoh import zoh_response

    _, obs = observable(model)
    return zoh_response(*ab, x0, ctrl, float(model.opt.timestep))[..., : model.nq] @ obs.T


def refine(
    model: mujoco.MjModel,
    backend,
    *,
    rod: str,
    setting: RefinementSetting,
    threads: int = 1,
) -> Refinement:
    """Run ``backend`` (a :class:`cip.runner.RolloutBackend` class, faults included) on
    ``model`` with its time step halved ``setting.levels - 1`` times; compare with the
    exact solution of the file's linearisation with the rod as ``rod`` declares it.

    ``model`` is the compiled model file (its time step is the control interval h).
    """
    ctrl, exact, _ = excitation(model, rod, setting)
    h = float(model.opt.timestep)
    steps = [h / 2**lev for lev in range(setting.levels)]
    return compare(run_levels(model, backend, ctrl, setting, threads), exact, steps)


def run_levels(
    model: mujoco.MjModel, backend, ctrl: np.ndarray, setting: RefinementSetting, threads: int = 1
) -> list[np.ndarray]:
    """The engine's observable (:func:`observable`: cart x and balancing error e per
    balancer, m) at the control boundaries, from rest, under ``ctrl`` (R, K, nu) held per
    control interval h (the model file's time step), at each time step h / 2^level of
    ``setting.levels``: a list of (R, K, .) arrays, finest last."""
    h = float(model.opt.timestep)
    _, obs = observable(model)
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    s0 = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, s0, spec)
    state0 = np.tile(s0, (ctrl.shape[0], 1))
    runs = []
    for lev in range(setting.levels):
        sub = 2**lev
        mk = copy.deepcopy(model)
        mk.opt.timestep = h / sub
        states = _run_backend(backend, mk, state0, np.repeat(ctrl, sub, axis=1),
                              max(1, round(setting.chunk_time / (h / sub))), threads)  # fmt: skip
        q = states[:, sub - 1 :: sub, 1 : 1 + model.nq] - model.qpos0
        runs.append(q @ obs.T)
    return runs


def compare(runs: list[np.ndarray], exact: np.ndarray, steps: list[float]) -> Refinement:
    """The :class:`Refinement` of trajectories ``runs`` (R, K, .) at ``steps`` (s, each
    half the one before) against the ``exact`` solution: extrapolation, E0 and its
    interval (module docstring)."""
    norm = float(np.linalg.norm(exact))
    errors = tuple(float(np.linalg.norm(y - exact)) / norm for y in runs)
    y0, p, p_coarse, change = extrapolate(runs, ROUNDOFF)
    e0 = float(np.linalg.norm(y0 - exact)) / norm
    per = np.array([np.linalg.norm(y0[r] - exact[r]) / np.linalg.norm(exact[r])
                    for r in range(exact.shape[0])])  # fmt: skip
    from validation.checks.stats import t_half_width

    spread = t_half_width(per) if exact.shape[0] > 1 else 0.0
    width = change / norm + (spread if np.isfinite(spread) else 0.0)
    return Refinement(
        steps=tuple(steps), errors=errors, order=p, order_coarse=p_coarse, e0=e0,
        e0_interval=(max(0.0, e0 - width), e0 + width),
        per_realization=tuple(float(x) for x in per),
    )  # fmt: skip


# ------------------------------------------------------------ the projection (float32)
#: the parameters whose directions the projection tests (:data:`cip.edits.PARAMETER_EDITS`)
PROJECTED = ("mass_ratio", "pendulum_length", "gravity", "tip_damping", "cart_damping")
#: the relative change of a parameter that defines its direction
SENSITIVITY_STEP = 1e-3


def sensitivities(
    model: mujoco.MjModel, rod: str, x0: np.ndarray, ctrl: np.ndarray, exact: np.ndarray
) -> dict[str, np.ndarray]:
    """s_k = (x(p_k (1 + d)) - x(p_k)) / d for each parameter k of :data:`PROJECTED`.

    x is the exact response's observable (:func:`linear_response`, the model file's
    observable map) to ``ctrl`` from ``x0`` of the model file ``model`` with parameter k
    scaled by 1 + d (d = :data:`SENSITIVITY_STEP`, :mod:`cip.edits`), the rod as ``rod``
    declares it; ``exact`` the unscaled model's.  Linear in d to O(d): a relative error
    d_k of parameter k moves the limit by d_k s_k.
    """
    from cip.edits import PARAMETER_EDITS
    from cip.linearize import rod_jacobians

    out = {}
    for kind in PROJECTED:
        fm = copy.deepcopy(model)
        PARAMETER_EDITS[kind](fm, 1.0 + SENSITIVITY_STEP)
        mujoco.mj_setConst(fm, mujoco.MjData(fm))
        out[kind] = (linear_response(model, rod_jacobians(fm, rod), x0, ctrl) - exact) / (
            SENSITIVITY_STEP
        )
    return out


def projections(deviation: np.ndarray, sens: dict[str, np.ndarray]) -> dict[str, float]:
    """c_k = <deviation, s_k> / <s_k, s_k>: the relative error of parameter k that alone
    best explains ``deviation`` (least squares along s_k, :func:`sensitivities`)."""
    e = deviation.ravel()
    return {k: float(e @ v.ravel() / (v.ravel() @ v.ravel())) for k, v in sens.items()}


def reference_limit(
    model: mujoco.MjModel, ctrl: np.ndarray, setting: RefinementSetting, threads: int = 1
) -> np.ndarray:
    """The model file's nonlinear response to ``ctrl`` (:func:`run_levels`' observable):
    MuJoCo's RK4 in float64 at the setting's levels, extrapolated (its finest levels reach
    1e-10 of the trajectory, the rounding of the central differences).  Its distance to
    the file's linear response (soft rod) is the linearisation's own error at the
    setting's amplitude, the same for every correct engine; MuJoCo's integration of the
    file is itself held to its exact twins at 1e-9 by the twin checks."""
    from cip.runner import MujocoRollout

    mr = copy.deepcopy(model)
    mr.opt.integrator = int(mujoco.mjtIntegrator.mjINT_RK4)
    return extrapolate(run_levels(mr, MujocoRollout, ctrl, setting, threads), ROUNDOFF)[0]


#: 1 - |cos| below which two parameters' directions are reported as alike: the data
#: cannot tell them apart (:func:`alike_directions`).  Measured (seeds 1, 2, both
#: models): the tip mass and the tip damping 2e-7 to 2e-6 apart (with the damper's
#: coefficient gamma m held, a heavier bob is a smaller gamma), gravity 5e-6 to 7e-6
#: from both over the float32 setting's 4 s (3e-4 to 5e-4 over 1 s); every other pair
#: 2e-2 or more
ALIKE = 1e-4


def alike_directions(sens: dict[str, np.ndarray], alike: float = ALIKE) -> dict[str, tuple]:
    """For each parameter k, the parameters whose direction s_j (:func:`sensitivities`)
    is within 1 - |cos(s_k, s_j)| < ``alike`` of its own, k included, in
    :data:`PROJECTED`'s order: a deviation along one of them projects on all of them
    alike, so the largest c_k names the group, not one parameter."""
    unit = {k: v.ravel() / np.linalg.norm(v) for k, v in sens.items()}
    return {k: tuple(j for j in sens if 1.0 - abs(float(unit[k] @ unit[j])) < alike)
            for k in sens}  # fmt: skip


class Projection(NamedTuple):
    """Each parameter's projection of an engine's dt -> 0 limit's deviation
    (:func:`parameter_projections`)."""

    #: c_k from the nonlinear reference (the linearisation's own error removed)
    c: dict[str, float]
    #: c_k from the exact linear solution alone
    c_linear: dict[str, float]
    #: the parameters whose directions are alike (:func:`alike_directions`)
    alike: dict[str, tuple]

    @property
    def largest_key(self) -> str:
        """The parameter k of the largest |c_k| (the first in :data:`PROJECTED`'s order on
        a tie)."""
        return max(self.c, key=lambda j: abs(self.c[j]))

    def largest(self) -> str:
        """The parameter of the largest |c_k|, with those alike: ``"a ~ b"``."""
        return " ~ ".join(self.alike[self.largest_key])


#: the parts of the projection that depend on the model file, the rod and the setting
#: only (the forces, the exact solution, the sensitivities, the nonlinear reference's
#: offset, the alike directions), per (file digest, rod, setting): a float32 engine's
#: selftest runs one check per fault on the same file and forces
_BASES: dict[tuple, tuple] = {}
_BASES_KEPT = 8


def _projection_basis(model: mujoco.MjModel, rod: str, setting: RefinementSetting,
                      threads: int) -> tuple:  # fmt: skip
    import hashlib
    import pickle

    from cip.linearize import rod_jacobians

    key = (hashlib.sha256(pickle.dumps(model)).hexdigest(), rod, setting)
    if key not in _BASES:
        ctrl, exact, x0 = excitation(model, rod, setting)
        sens = sensitivities(model, rod, x0, ctrl, exact)
        soft = linear_response(model, rod_jacobians(model, "soft"), x0, ctrl)
        nonlinear = reference_limit(model, ctrl, setting, threads) - soft
        while len(_BASES) >= _BASES_KEPT:
            del _BASES[next(iter(_BASES))]
        _BASES[key] = (exact, sens, nonlinear, alike_directions(sens))
    return _BASES[key]


def parameter_projections(
    model: mujoco.MjModel,
    rod: str,
    setting: RefinementSetting,
    runs: list[np.ndarray],
    threads: int = 1,
) -> Projection:
    """Each parameter's projection (:func:`projections`) of the engine's dt -> 0 limit's
    deviation, from the nonlinear reference (:func:`reference_limit`: the exact solution
    with the linearisation's own error added) and from the exact linear solution alone,
    with the parameters whose directions are alike.  ``runs``: the engine's levels
    (:func:`run_levels`) under the forces of :func:`excitation` at ``setting``.  What
    does not depend on ``runs`` is computed once per model file, rod and setting."""
    exact, sens, nonlinear, alike = _projection_basis(model, rod, setting, threads)
    y0 = extrapolate(runs, ROUNDOFF)[0]
    return Projection(projections(y0 - exact - nonlinear, sens), projections(y0 - exact, sens),
                      alike)  # fmt: skip


def float32_state(base: type) -> type:
    """``base`` (a :class:`cip.runner.RolloutBackend` class) with its state rounded to
    float32 after every step: a float32 engine's rounding on a float64 stepper.

    Each step is one call of ``base`` (one step of every realisation), then the whole
    ``mjSTATE_FULLPHYSICS`` vector (time, positions, velocities, ...) is rounded to the
    nearest float32 and handed back as float64, the state the next step starts from and
    the one recorded.  MuJoCo's ``Euler`` so wrapped is the float32 stand-in of the
    module docstring (:func:`float32_stand_in`): it is a correct engine, held in float32.
    """

    class Float32State(base):
        def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
            s = np.asarray(state, dtype=np.float32).astype(np.float64)
            one = np.empty((ctrl.shape[0], 1, out.shape[2]))
            for k in range(ctrl.shape[1]):
                super().__call__(s, np.ascontiguousarray(ctrl[:, k : k + 1]), one)
                s = one[:, 0].astype(np.float32).astype(np.float64)
                out[:, k] = s

    Float32State.__name__ = Float32State.__qualname__ = f"Float32{base.__name__}"
    return Float32State


def float32_stand_in():
    """MuJoCo's ``Euler`` with its state rounded to float32 after every step
    (:func:`float32_state`), as an engine of the refinement tier: float32, no exact twin,
    its own stepper (the file's ``Euler``: order 1), the file's soft rod.  Not in the
    registry: the engine the float32 setting is measured and tested with."""
    from dataclasses import replace

    from cip.engines.rigid_body import MUJOCO
    from cip.runner import MujocoRollout

    backend = float32_state(MujocoRollout)
    caps = replace(MUJOCO.capabilities, precision="float32", twin=None, linearize=False)
    return replace(MUJOCO, name="mujoco-float32", capabilities=caps, backend=lambda: backend,
                   integrators=(), linearizer=None,
                   notes="MuJoCo Euler, state rounded to float32 after every step")  # fmt: skip


# ------------------------------------------------------------ the tier and the check
#: the exact-twin tier and the refinement tier (module docstring)
TWIN, REFINEMENT = "exact twin", "refinement"

#: orders of the steppers cipval knows, as the engines run them (forces and dampers held
#: over a step).  Measured with :func:`refine` (seed 1, 4 realisations, dt = 1 .. 1/8 ms):
#: MuJoCo Euler and implicitfast, Drake's SAP and Bullet 1.00, Exudyn's Newmark with
#: gamma = 1 1.00, MuJoCo's RK4 3.9-4.0 (its finest levels reach the reference's own
#: floor, 1e-10 to 3e-10).
KNOWN_ORDERS: dict[str, float] = {
    "Euler": 1.0,
    "implicit": 1.0,
    "implicitfast": 1.0,
    "RK4": 4.0,
    "SAP": 1.0,
    "Newmark(beta=1/2, gamma=1)": 1.0,
}


def declared_order(capabilities, integrator: str | None = None) -> float | None:
    """The order the engine declares (``capabilities.order``), else the known order of
    the stepper it runs (``integrator``: the model file's where the engine follows it,
    else ``capabilities.integrator``), else None."""
    if capabilities.order is not None:
        return float(capabilities.order)
    return KNOWN_ORDERS.get(integrator or capabilities.integrator)


def least_order(capabilities, integrator: str | None = None) -> float:
    """The least observed order that passes: the declared order less :data:`ORDER_SLACK`,
    or :data:`UNDECLARED_ORDER`."""
    p = declared_order(capabilities, integrator)
    return UNDECLARED_ORDER if p is None else p - ORDER_SLACK


def tier(capabilities) -> tuple[str, str]:
    """(tier, why) from what the engine declares, before anything is measured.

    An engine with an exact twin (``capabilities.twin``) is judged by it; one without
    is judged by refinement; one that declared nothing (``declared`` False) is held to
    the model file's twin, and moved to refinement by :func:`undeclared_tier` when its
    distance to that twin shows it steps another way.
    """
    if capabilities.twin is None:
        return REFINEMENT, (
            f"no exact twin of its discretisation (stepper {capabilities.integrator}, rod "
            f"{capabilities.rod}): judged against the exact solution by time-step refinement"
        )
    if not capabilities.declared:
        return TWIN, "it declared no discretisation and matches the model file's exact twin"
    return TWIN, f"its declared discretisation has an exact twin: {capabilities.twin}"


def undeclared_tier(distance: float, tolerance: float) -> tuple[str, str]:
    """The tier of an engine that declared no discretisation, from its twin distance."""
    if distance <= tolerance:
        return TWIN, (
            f"it declared no discretisation and matches the model file's exact twin "
            f"(distance {distance:.2g} <= {tolerance:g})"
        )
    return REFINEMENT, (
        f"it declared no discretisation and does not step as the model file's integrator "
        f"(twin distance {distance:.2g} > {tolerance:g}): judged against the exact solution "
        "by time-step refinement"
    )


@dataclass(frozen=True)
class PrecisionSetting:
    """What the refinement check of an engine of one precision runs and is held to.

    Attributes
    ----------
    amplitude : the largest balancing error |e| of the response, m.
    window : simulated time, s.
    floor : the largest upper end of E0's interval that passes (relative L2).
    why : one sentence: the measured floor it leaves margin over (module docstring).
    projection_bound : the largest |c_k| that passes, for every parameter k of
        :data:`PROJECTED` (:func:`parameter_projections`); None: not tested.
    """

    amplitude: float
    window: float
    floor: float
    why: str
    projection_bound: float | None = None


#: the float64 setting, every model (module docstring): the response at 1e-5 m, the
#: floor 1e-6
FLOAT64_SETTING = PrecisionSetting(
    AMPLITUDE, WINDOW, FLOOR, "float64: the correct engines' E0 with margin"
)

#: the largest |c_k| of a float32 engine that passes (module docstring, "Float32
#: engines"): half a 1e-4 error; the correct float32 engines' largest |c_k| over seeds
#: 1-20 is 2.5e-5 (Newton coupled), a 1e-4 error's least c_k along its own direction 8.5e-5
PROJECTION_BOUND = 5e-5

#: the float32 setting per model (module docstring, "Float32 engines"): the amplitude
#: where float32 rounding and the linearisation's own error are least, the floor above
#: the largest upper end of E0's interval of the correct float32 engines at 20 seeds
FLOAT32_SETTINGS: dict[str, PrecisionSetting] = {
    "single": PrecisionSetting(
        1e-3, 4.0, 1.2e-4,
        "at 1e-3 m float32 rounding is relative and the linearisation's error a sixth of "
        "it; 4 s lets a model error grow beyond the rounding; correct float32 engines' upper "
        "end at most 8.2e-5 over 20 seeds",
        PROJECTION_BOUND,
    ),
    "coupled": PrecisionSetting(
        3e-3, 4.0, 1.6e-4,
        "at 3e-3 m the rod's float32 noise (as 1 / amplitude) and the linearisation's "
        "error (as amplitude^2) are least together; 4 s lets a model error grow beyond "
        "them; correct float32 engines' upper end at most 1.1e-4 over 20 seeds",
        PROJECTION_BOUND,
    ),
}  # fmt: skip


def precision_setting(model: str, precision: str) -> PrecisionSetting:
    """The setting the refinement check of ``model`` judges an engine of ``precision``
    ("float64" or "float32", :attr:`cipcore.engine.Capabilities.precision`) at."""
    if precision != "float32":
        return FLOAT64_SETTING
    if model not in FLOAT32_SETTINGS:
        raise ValueError(f"no float32 refinement setting for model {model!r}")
    return FLOAT32_SETTINGS[model]


def refinement_check(
    model: str, m: mujoco.MjModel, engine, seed: int, *, backend=None, threads: int | None = None
):
    """The ``refinement.<model>`` check of ``engine`` on the compiled model file ``m``.

    ``backend``: the engine's :class:`cip.runner.RolloutBackend` class to run (a fault
    wraps it; default the engine's own).  Forces from ``seed``'s ``refinement`` stream.
    The engine's precision picks the setting (:func:`precision_setting`): a float64
    engine's check is the module's :data:`AMPLITUDE` and :data:`FLOOR`; a float32
    engine's says in its values (``setting``, ``amplitude_m``, ``window_s``), tolerance
    and details that the float32 setting judged it, and why.
    """
    from validation.checks.stats import FAIL, PASS, Check

    caps = engine.capabilities
    integrator = m_integrator(m) if len(getattr(engine, "integrators", ())) > 1 else None
    rod = "soft" if caps.rod == "soft" else "rigid"
    ps = precision_setting(model, caps.precision)
    float32 = ps is not FLOAT64_SETTING
    setting = RefinementSetting(seed, window=ps.window, amplitude=ps.amplitude)
    threads = max(1, min(threads or 1, REALIZATIONS))
    ctrl, exact, _ = excitation(m, rod, setting)
    runs = run_levels(m, backend or engine.rollout(), ctrl, setting, threads)
    h = float(m.opt.timestep)
    r = compare(runs, exact, [h / 2**lev for lev in range(setting.levels)])
    need = least_order(caps, integrator)
    p_decl = declared_order(caps, integrator)
    ok = r.passes(ps.floor, need)
    values = {
        "e0": r.e0,
        "e0_interval": list(r.e0_interval),
        "floor": ps.floor,
        "order": r.order,
        "order_coarse": r.order_coarse,
        "least_order": need,
        "declared_order": p_decl,
        "steps_s": list(r.steps),
        "errors": list(r.errors),
    }
    projection = ""
    if ps.projection_bound is not None:
        proj = parameter_projections(m, rod, setting, runs, threads)
        c = proj.c
        ok = ok and all(abs(v) <= ps.projection_bound for v in c.values())
        values.update(projection=c, projection_bound=ps.projection_bound)
        projection = (
            f"; and every parameter's projection |c_k| <= {ps.projection_bound:g} (the relative "
            f"error of m, L, g or a damper that alone best explains the limit's deviation from "
            f"the nonlinear reference; largest here: {proj.largest()} {c[proj.largest_key]:+.2g})"
        )
    why = "(the correct engines' E0 with margin)"
    details = (
        f"open loop, {REALIZATIONS} band-limited forces ({N_MODES} sinusoids in "
        f"{F_MIN:g}-{F_MAX:g} Hz) held per {m.opt.timestep:g} s, {ps.window:g} s, largest "
        f"|e| {ps.amplitude:g} m, rod {rod}, seed {seed}"
    )
    if float32:
        values.update(setting="float32", amplitude_m=ps.amplitude, window_s=ps.window)
        why = f"(the float32 setting of the {model} model: {ps.why})"
        details += (
            f"; float32 setting (the engine's precision is float32), not the float64 one "
            f"(floor {FLOOR:g} at {AMPLITUDE:g} m, {WINDOW:g} s)"
        )
    return Check(
        name=f"refinement.{model}",
        status=PASS if ok else FAIL,
        values=values,
        tolerance=(
            f"E0, the relative L2 distance of the dt -> 0 limit (Richardson on the "
            f"trajectories at dt = h .. h/{2 ** (len(r.steps) - 1)}) to the exact "
            f"zero-order-hold solution, <= {ps.floor:g} {why}, "
            f"and the observed order >= {need:g} "
            + ("(declared order less 0.3)" if p_decl is not None else "(no order declared)")
            + projection
        ),
        details=details,
    )


#: why a float32 engine with an exact twin is not judged by refinement
FLOAT32_RULE = (
    "not run for a float32 engine judged by its exact twin: float32 rounds the 1e-5 m "
    "trajectory to about 6e-8 a step, so the differences between levels at h/4 and h/8 are "
    "rounding (MuJoCo Warp on the coupled file: E0 1.2e-3, seed 1); its twin, at its "
    "float32 floor, is the exactness check"
)


def not_run(model: str, why: str):
    """The ``refinement.<model>`` check of an engine it does not judge: n/a, with why."""
    from validation.checks.stats import NOT_APPLICABLE, Check

    return Check(name=f"refinement.{model}", status=NOT_APPLICABLE, values={}, tolerance="",
                 details=why)  # fmt: skip


def m_integrator(m: mujoco.MjModel) -> str:
    """The model file's integrator in MuJoCo's names (Euler, implicit, implicitfast, RK4)."""
    from cip.mjcf_params import INTEGRATOR_NAMES

    return INTEGRATOR_NAMES[mujoco.mjtIntegrator(m.opt.integrator).name]
