"""Commands that run or inspect one engine: simulate, linearize."""

from __future__ import annotations

import argparse

import numpy as np

from cipcore.atomic import WriteError
from cipcore.params import ParameterError
from cipcore.registry import get_engine
from cipcore.schema import RecordingSizeError
from validation.checks.divergence import (
    DIVERGED,
    LEFT_SMALL_ANGLE,
    pendulum_length,
    summary,
    trajectory_events,
)
from validation.cli.args import (
    EXIT_OK,
    add_integrator_arg,
    add_json_arg,
    add_model_args,
    add_simulation_args,
    check_out_file,
    dump,
    engine_options,
    params_from_args,
)
from validation.cli.commands.analysis import run_engine
from validation.cli.domains import add_option
from validation.cli.main import add_command, command

#: rod length l (m) and bob / cart mass m/M of the rigid body when not given
DEFAULT_ROD_LENGTH, DEFAULT_MASS_RATIO = 1.0, 1e-3


def physical_from_args(a: argparse.Namespace):
    """The rigid body's :class:`cip.model.CIPParams` from the options (L = g / alpha)."""
    from cip.model import CIPParams

    phys = CIPParams.from_reduced(
        params_from_args(a, beta=0.0), rod_length=a.rod_length, mass_ratio=a.mass_ratio
    )
    if getattr(a, "integrator", None) is not None:  # MuJoCo's names, checked by CIPParams
        from dataclasses import replace

        phys = replace(phys, integrator=a.integrator)
    return phys


def add_physical_args(p: argparse.ArgumentParser, *, note: str = "") -> None:
    add_option(
        p,
        "--rod-length",
        domain="rod length",
        default=DEFAULT_ROD_LENGTH,
        help=f"rod length l (m){note}",
    )
    add_option(
        p,
        "--mass-ratio",
        domain="mass ratio",
        default=DEFAULT_MASS_RATIO,
        help=f"bob / cart mass m/M (dimensionless){note}",
    )
    add_integrator_arg(
        p,
        "MuJoCo integrator of the rigid body (Euler, implicit, implicitfast, RK4; default Euler; "
        f"engines with their own stepper refuse it){note}",
    )


# ---------------------------------------------------------------- simulate
@command(
    "Time series of any registered engine in the shared schema, saved as .npz; reports every "
    "realisation that diverged or left the small-angle regime."
)
def cmd_simulate(a: argparse.Namespace) -> int:
    params = params_from_args(a)
    check_out_file("--out", a.out, (".npz",))
    engine = get_engine(a.engine)
    kw = engine_options(a, engine)
    if engine.capabilities.rigid_body:
        kw["physical"] = physical_from_args(a)
        follows = getattr(engine, "integrators", ())
        if a.integrator is not None and a.integrator not in follows:
            raise ParameterError(
                f"--integrator {a.integrator}: engine {a.engine!r} steps with "
                f"({', '.join(follows) or engine.capabilities.integrator})"
            )
    try:
        traj = run_engine(a, engine.simulate, params, amplitude=a.amplitude,
                          decimate=a.decimate, **kw)  # fmt: skip
    except RecordingSizeError as exc:
        raise ParameterError(
            f"--realizations x --duration / --decimate: {exc} (on the command line: raise "
            "--decimate, or lower --realizations or --duration)"
        ) from None
    try:
        traj.save_npz(a.out)
    except WriteError as exc:
        exc.note = (
            "the simulated run was not kept (rerun with the same --seed for the same numbers)"
        )
        raise
    events = trajectory_events(traj, pendulum_length(params))
    which = {k: [ev.realization for ev in events if ev.kind == k]
             for k in (DIVERGED, LEFT_SMALL_ANGLE)}  # fmt: skip
    e = traj["balancing_error"].astype(float)
    with np.errstate(over="ignore", invalid="ignore"):
        rms = float(np.sqrt(np.mean(e**2)))
    summary_d = {
        "out": str(a.out),
        "engine": a.engine,
        "model": a.model,
        "shape": list(e.shape),
        "rms_balancing_error": rms,
        "max_abs_angle": traj.attrs.get("max_abs_angle"),
        "left_small_angle": which[LEFT_SMALL_ANGLE],  # realisation indices
        "diverged": which[DIVERGED],
        "divergence": [ev.as_dict() for ev in events],
    }
    if a.json:
        print(dump(summary_d))
    else:
        for k, v in summary_d.items():
            if k != "divergence" and v is not None:  # None: not recorded by this engine
                print(f"{k}: {v}")
        line = summary(events, e.shape[0])
        print(f"warning: {line}" if line else "no realisation diverged or left the small angles")
    return EXIT_OK


# --------------------------------------------------------------- linearize
@command(
    "Linearisation of the rigid-body CIP about upright (mjd_transitionFD) beside the reduced "
    "model's matrices."
)
def cmd_linearize(a: argparse.Namespace) -> int:
    from cip.linearize import linearize, transition_check

    phys = physical_from_args(a)
    lin = linearize(a.model, phys)
    out = {
        "model": a.model,
        "coordinates": lin.labels,
        "A_full": lin.A_full,
        "A_reduced": lin.A_reduced,
        "A_difference": lin.A_diff,
        "A_predicted_extra": lin.A_extra,
        "B_full": lin.B_full,
        "B_reduced": lin.B_reduced,
        "residual_after_extra_terms": lin.residual,
        "rod_stiffness": lin.rod_stiffness,
        "rod_damping": lin.rod_damping,
        "implied_reduced": phys.implied_reduced(),
        "mjd_transitionFD_check": transition_check(a.model, phys),
    }
    if a.json:
        print(dump(out))
        return EXIT_OK
    np.set_printoptions(precision=6, suppress=True, linewidth=140)
    print(f"{a.model} CIP linearised about upright; x = ({', '.join(lin.labels)}); u = F/M")
    for key in ("A_full", "A_reduced", "A_difference", "A_predicted_extra", "B_full", "B_reduced"):
        print(f"\n{key}:\n{np.asarray(out[key])}")
    print(f"\nmax |A_full - A_reduced - predicted extra| = {lin.residual:.3g} 1/s^2")
    if lin.rod_stiffness is not None:
        print(
            f"rod constraint on delta: stiffness {lin.rod_stiffness:.4g} 1/s^2, "
            f"damping {lin.rod_damping:.4g} 1/s"
        )
    print(f"mjd_transitionFD vs Euler map of A: {out['mjd_transitionFD_check']:.3g}")
    print("implied reduced parameters:", phys.implied_reduced())
    return EXIT_OK


# ------------------------------------------------------------------ parser
def register(sub: argparse._SubParsersAction) -> None:
    """Add ``linearize`` and ``simulate`` to the parser."""
    p = add_command(sub, "linearize", cmd_linearize)
    add_model_args(p, beta=False)
    add_physical_args(p)
    add_json_arg(p)

    p = add_command(sub, "simulate", cmd_simulate)
    add_simulation_args(p, duration=10.0, realizations=4)
    add_option(
        p, "--amplitude", domain="amplitude", default=0.01, help="initial balancing error (m)"
    )
    add_physical_args(p, note="; rigid-body engines only")
    add_option(
        p, "--decimate", domain="decimate", default=1, help="record every N-th step (count >= 1)"
    )
    add_option(
        p,
        "--out",
        domain="npz out",
        required=True,
        metavar="FILE.npz",
        help="output file (.npz, in a writable directory), required",
    )
    add_json_arg(p)
