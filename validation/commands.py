"""Subcommands beyond the reduced model's own: simulate, linearize, run, baseline."""

from __future__ import annotations

import argparse

import numpy as np

from reduced.params import ParameterError
from validation.cli import EXIT_OK, _dump, _model_args, _params, _run_args


def cmd_simulate(a: argparse.Namespace) -> int:
    params = _params(a)
    if a.engine == "mujoco":
        from cip.model import CIPParams
        from cip.simulate import simulate_full

        phys = CIPParams.from_reduced(params, rod_length=a.rod_length, mass_ratio=a.mass_ratio)
        traj = simulate_full(
            a.model, params, a.duration, a.realizations, a.seed, amplitude=a.amplitude,
            physical=phys, decimate=a.decimate, threads=a.threads, progress=True,
        )  # fmt: skip
    else:
        from reduced.simulate import simulate

        traj = simulate(
            a.model, params, a.duration, a.realizations, a.seed, amplitude=a.amplitude,
            stepper=a.stepper, decimate=a.decimate, threads=a.threads, progress=True,
        )  # fmt: skip
    if not a.out.endswith(".npz"):
        raise ParameterError(f"--out must name a .npz file, got {a.out!r}")
    traj.save_npz(a.out)
    e = traj["balancing_error"]
    summary = {
        "out": a.out,
        "engine": a.engine,
        "model": a.model,
        "shape": list(e.shape),
        "rms_balancing_error": float(np.sqrt(np.mean(e.astype(float) ** 2))),
        "max_abs_angle": traj.attrs.get("max_abs_angle"),
        "left_small_angle": traj.attrs.get("left_small_angle"),
    }
    print(_dump(summary) if a.json else "\n".join(f"{k}: {v}" for k, v in summary.items()))
    return EXIT_OK


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="time series of either engine to a .npz file")
    _model_args(p)
    _run_args(p, duration=10.0, realizations=4)
    p.add_argument("--engine", choices=("reduced", "mujoco"), default="reduced")
    p.add_argument("--stepper", choices=("semi-implicit", "explicit"), default="semi-implicit",
                   help="reduced engine only")  # fmt: skip
    p.add_argument("--amplitude", type=float, default=0.01, help="initial balancing error (m)")
    p.add_argument("--rod-length", type=float, default=1.0, help="rod length l (m), mujoco only")
    p.add_argument("--mass-ratio", type=float, default=1e-3, help="bob / cart mass m/M, mujoco")
    p.add_argument("--decimate", type=int, default=1, help="record every N-th step")
    p.add_argument("--out", required=True, metavar="FILE.npz")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_simulate)
