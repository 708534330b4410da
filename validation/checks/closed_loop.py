"""The closed loop by time-step refinement: an engine under the paper's delayed
random-gain feedback against the exact sampled-data solution.

The open-loop refinement (:mod:`validation.checks.refinement`) holds an engine's
rigid body to the exact solution, but with cipval's forces: nothing the engine's
controller does (its gain, its noise, the draws each balancer gets) enters it.  An
engine with an exact twin has that checked by ``twin.trajectory`` under the same
noise; an engine judged by refinement had no such check, so a noise drawn without its
1/sqrt(dt), a noise strength nu 1 % off or two balancers sharing one noise stream went
unseen (the selftests of Pinocchio, DART, Newton, PhysX and the C engine).

This check closes the loop.  cipval's controller, the paper's eq. (5),
F_i = M beta (1 + nu xi_i / sqrt(h)) e_i(t - tau), runs at the model file's time step h
(the control interval) on the engine's states, as every run of the engine applies it
(:class:`cip.runner.CIPRunner`; a selftest's controller faults, injected at the engine
boundary, change its parameters or draws), and the engine steps each interval in 1, 2,
4 and 8 steps with the force held (:func:`substepped`).  The engine is thus held to
the exact solution under forces that follow its own states and change every interval,
and the path from its states through the delay, the gain and the noise to its forces
is checked end to end.  The draws
are the same at every level, so as the engine's step shrinks its trajectory converges
to the exact sampled-data closed loop of the linearised model under the suite's
parameters and draws (:func:`reduced.zoh.zoh_delayed_feedback`): the limit moves when
the controller's gain, noise strength, noise scaling or draws are wrong, and does not
when the stepper is another correct one.  The extrapolation, E0, its interval, the
floor and the order are the open-loop check's (:func:`refinement.extrapolate`,
:func:`refinement.precision_setting`).

The loop is linear in the state (the random gain multiplies e), so the response scales
with the initial tilt: the initial balancing error is chosen so that the largest |e| of
the exact response is the setting's amplitude (1e-5 m in float64).

Measured (MuJoCo's Euler run as a refinement-tier engine, seed 1, 4 realisations, 1 s,
dt = 1 .. 1/8 ms): E0 4.5e-9 (single) and 5.2e-9 (coupled), order 1.004, the
interval's upper end 4e-8, within the float64 floor 1e-6.  Noise faults: nu x1.00001
gives E0 1.7e-6 (single) and 2.8e-6 (coupled), nu x1.01 1.7e-3 and 2.8e-3, the noise
without 1/sqrt(dt) 0.17 and 0.25, the two balancers sharing one noise stream 0.32
(coupled).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from validation.checks import refinement
from validation.checks.refinement import Refinement, RefinementSetting

__all__ = ["EngineLoop", "closed_loop_check", "refine_closed_loop", "substepped"]


@dataclass(frozen=True)
class EngineLoop:
    """The engine's side of the closed loop, as one value.

    ``backend``: its :class:`cip.runner.RolloutBackend` class (a fault's wraps it);
    ``params`` (:class:`cipcore.params.BalanceParams`) the controller it runs (a fault's
    may differ from the suite's); ``xi`` (R, K, C) the draws it gets (None: the seed's);
    ``threads`` the rollout's threads.
    """

    backend: type
    params: object
    xi: np.ndarray | None = None
    threads: int = 1


def substepped(base: type, sub: int) -> type:
    """``base`` (a :class:`cip.runner.RolloutBackend` class) stepping ``sub`` steps of
    h / sub per step of the model it is given (h its time step), the control held.

    The states handed back are those at the model's steps (every ``sub``-th), so the
    closed loop around it runs at h whatever ``sub`` is.
    """
    if sub == 1:
        return base

    class SubStepped(base):
        def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int):
            fine = copy.deepcopy(model)
            fine.opt.timestep = model.opt.timestep / sub
            super().__init__(fine, n_realizations, threads)

        def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
            r, n, _ = ctrl.shape
            buf = np.empty((r, n * sub, out.shape[2]))
            super().__call__(state, np.ascontiguousarray(np.repeat(ctrl, sub, axis=1)), buf)
            out[:] = buf[:, sub - 1 :: sub]

    SubStepped.__name__ = SubStepped.__qualname__ = f"SubStepped{sub}{base.__name__}"
    return SubStepped


def _engine_run(model, m, physical, params, backend, xi, amplitude, obs, threads):
    """The observable (R, K, 2C) after each control interval of the engine's closed loop."""
    from cip.runner import CIPRunner

    r = CIPRunner(model, params, physical, xi.shape[0], amplitude, threads=threads,
                  backend=backend, mj_model=m)  # fmt: skip
    out = []
    try:
        k = 0
        while k < xi.shape[1]:
            n = min(r.d, xi.shape[1] - k)
            out.append(r.advance(np.ascontiguousarray(xi[:, k : k + n])))
            k += n
    finally:
        close = getattr(r.backend, "close", None)
        if close is not None:
            close()
    states = np.concatenate(out, axis=1)
    return (states[..., 1 : 1 + m.nq] - m.qpos0) @ obs.T


def refine_closed_loop(
    model: str,
    m: mujoco.MjModel,
    engine: EngineLoop,
    *,
    params,
    rod: str,
    setting: RefinementSetting,
) -> Refinement:
    """The engine's closed loop at steps h .. h / 2**(levels-1) against the exact one.

    ``params`` (:class:`cipcore.params.BalanceParams`): the suite's controller, the
    reference's; ``engine`` the engine's side (its rollout, controller and draws: a
    fault's may differ).  ``m`` is the compiled model file, its time step h = dt.
    """
    from cip.linearize import rod_jacobians
    from cip.mjcf_params import read_mapping
    from cipcore.noise import GainNoise
    from reduced.zoh import DelayedFeedback, zoh_delayed_feedback, zoh_matrices

    h = float(m.opt.timestep)
    physical = read_mapping(m).physical()
    motors, obs = refinement.observable(m)
    nc = len(motors)
    k_int = round(setting.window / h)
    r_n = setting.n_realizations
    xi = GainNoise(setting.seed, r_n, nc).next_chunk(k_int)
    a, b = rod_jacobians(m, rod)
    ad, bd = zoh_matrices(a, b, h)
    errors = np.zeros((nc, a.shape[0]))
    errors[:, : m.nq] = obs[1::2]
    inputs = np.zeros((m.nu, nc))
    inputs[motors, np.arange(nc)] = 1.0
    length = physical.pendulum_length
    hinge = [int(np.flatnonzero(row)[0]) for row in obs[1::2]]
    loop = DelayedFeedback(
        errors,
        inputs,
        gain=physical.cart_mass * params.beta,
        noise_scale=params.noise_scale,
        delay_steps=params.delay_steps,
    )

    def exact(theta0: float) -> np.ndarray:
        x0 = np.zeros((r_n, a.shape[0]))
        x0[:, hinge] = theta0
        e_before = np.full((r_n, nc), length * np.sin(theta0))
        y = zoh_delayed_feedback(ad, bd, x0, loop, xi=xi, e_before=e_before)
        return y[..., : m.nq] @ obs.T

    # the loop is linear in the state: tilt so that the largest |e| is the amplitude
    unit = 1e-6
    peak = float(np.abs(exact(unit)[..., 1::2]).max())
    theta0 = unit * setting.amplitude / peak
    ref = exact(theta0)
    xi_e = xi if engine.xi is None else engine.xi
    runs, steps = [], []
    for lev in range(setting.levels):
        sub = 2**lev
        steps.append(h / sub)
        runs.append(_engine_run(model, m, physical, engine.params,
                                substepped(engine.backend, sub), xi_e,
                                length * np.sin(theta0), obs, engine.threads))  # fmt: skip
    return refinement.compare(runs, ref, steps)


def closed_loop_check(
    model: str,
    m: mujoco.MjModel,
    engine,
    seed: int,
    *,
    params,
    fault=None,
    threads: int | None = None,
):
    """The ``closed_loop.<model>`` check of ``engine`` on the compiled model file ``m``.

    ``params``: the suite's controller (its dt the file's time step); ``fault`` (a
    :class:`validation.faults.catalogue.Fault`) gives the engine other parameters,
    draws or a rollout that carries it (wrapping the engine's own).  The precision
    setting and floor are the open-loop check's.
    """
    from cipcore.models import get_model
    from validation.checks.stats import FAIL, PASS, Check

    caps = engine.capabilities
    rod = "soft" if caps.rod == "soft" else "rigid"
    ps = refinement.precision_setting(model, caps.precision)
    setting = RefinementSetting(seed, window=ps.window, amplitude=ps.amplitude)
    nc = get_model(model).n_controllers
    k_int = round(ps.window / m.opt.timestep)
    backend, engine_params, xi = engine.rollout(), params, None
    if fault is not None:
        noise = fault.noise(seed, setting.n_realizations, nc, k_int)
        backend, engine_params = fault.backend(backend), fault.engine_params(params)
        xi = None if noise is None else noise.next_chunk(k_int)
    side = EngineLoop(backend, engine_params, xi,
                      threads=max(1, min(threads or 1, setting.n_realizations)))  # fmt: skip
    r = refine_closed_loop(model, m, side, params=params, rod=rod, setting=setting)
    integrator = refinement.m_integrator(m) if len(getattr(engine, "integrators", ())) > 1 else None
    need = refinement.least_order(caps, integrator)
    ok = r.passes(ps.floor, need)
    return Check(
        name=f"closed_loop.{model}",
        status=PASS if ok else FAIL,
        values={
            "e0": r.e0,
            "e0_interval": list(r.e0_interval),
            "floor": ps.floor,
            "order": r.order,
            "least_order": need,
            "steps_s": list(r.steps),
            "errors": list(r.errors),
        },
        tolerance=(
            f"E0, the relative L2 distance of the dt -> 0 limit of the engine's closed loop "
            f"to the exact sampled-data loop of eq. (5) (the suite's gain, noise strength "
            f"and draws), <= {ps.floor:g}, and the observed order >= {need:g}"
        ),
        details=(
            f"delayed random-gain feedback at h = {m.opt.timestep:g} s, tau "
            f"{params.tau:g} s, beta {params.beta:g}, nu {params.nu:g}; the engine steps "
            f"h .. h/{2 ** (setting.levels - 1)}; {setting.n_realizations} realisations x "
            f"{ps.window:g} s, largest |e| {ps.amplitude:g} m, rod {rod}, seed {seed}"
        ),
    )
