"""``cip-validate``: the command line of the suite.

Subcommands are thin: they parse, call the library, and print.  A bad
argument ends with one line ``cip-validate: error: ...`` naming the parameter
and exit status 2; a failing validation check with exit status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from reduced.params import PAPER, BalanceParams, ParameterError

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2


def _model_args(p: argparse.ArgumentParser, *, beta: bool = True) -> None:
    p.add_argument("--model", choices=("single", "coupled"), default="single")
    if beta:
        p.add_argument("--beta", type=float, required=True, help="feedback gain (1/s^2)")
    p.add_argument("--alpha", type=float, default=PAPER["alpha"], help="g/L (1/s^2)")
    p.add_argument("--gamma", type=float, default=PAPER["gamma"], help="damping (1/s)")
    p.add_argument("--nu", type=float, default=PAPER["nu"], help="noise strength (s^1/2)")
    p.add_argument("--tau", type=float, default=PAPER["tau"], help="delay (s)")
    p.add_argument("--dt", type=float, default=PAPER["dt"], help="time step (s)")


def _run_args(p: argparse.ArgumentParser, duration: float, realizations: int) -> None:
    p.add_argument("--duration", type=float, default=duration, help="simulated time (s)")
    p.add_argument("--realizations", type=int, default=realizations)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="default: all cores")


def _params(a: argparse.Namespace, beta: float | None = None) -> BalanceParams:
    return BalanceParams(
        beta=a.beta if beta is None else beta, alpha=a.alpha, gamma=a.gamma, nu=a.nu,
        tau=a.tau, dt=a.dt,
    )  # fmt: skip


def _dump(obj) -> str:
    from validation.report import jsonable

    return json.dumps(jsonable(obj))


# ---------------------------------------------------------------- lyapunov
def cmd_lyapunov(a: argparse.Namespace) -> int:
    if a.engine == "mujoco":
        from cip.lyapunov import lyapunov_full

        res = lyapunov_full(
            a.model, _params(a), a.duration, a.realizations, a.seed,
            threads=a.threads, progress=not a.json,
        )  # fmt: skip
    else:
        from reduced.lyapunov import lyapunov

        res = lyapunov(
            a.model, _params(a), a.duration, a.realizations, a.seed,
            stepper=a.stepper, threads=a.threads, progress=True,
        )  # fmt: skip
    d = res.as_dict()
    d["engine"] = a.engine
    if a.json:
        print(_dump(d))
    else:
        lo, hi = res.ci95
        print(
            f"lambda1 = {res.lambda1:.4e} 1/s  (95% CI [{lo:.4e}, {hi:.4e}], "
            f"{len(res.per_realization)} realisations x {res.duration:g} s, "
            f"{a.engine} {a.model}, beta = {a.beta})"
        )
    return EXIT_OK


# --------------------------------------------------------- critical gain
def cmd_critical_gain(a: argparse.Namespace) -> int:
    from reduced.lyapunov import critical_gain

    lo, hi = a.beta_range
    res = critical_gain(
        a.model, _params(a, beta=lo), (lo, hi), target=a.target, n_gains=a.gains,
        duration=a.duration, n_realizations=a.realizations, seed=a.seed,
        threads=a.threads, progress=True,
    )  # fmt: skip
    if a.json:
        print(_dump(res.as_dict()))
    else:
        print(
            f"beta* = {res.beta_star:.3f} +- {res.std:.3f} (95% CI [{res.ci95[0]:.3f}, "
            f"{res.ci95[1]:.3f}]) for lambda1 = {res.target:g} 1/s ({a.model}, "
            f"{res.n_realizations} realisations x {res.duration:g} s)"
        )
        for b, lam, ci in zip(res.betas, res.lambdas, res.ci95s, strict=True):
            print(f"  beta {b:8.3f}  lambda1 {lam:+.3e}  [{ci[0]:+.3e}, {ci[1]:+.3e}]")
    return EXIT_OK


# -------------------------------------------------------------- stability
def cmd_stability(a: argparse.Namespace) -> int:
    from reduced.stability import characteristic_roots, stability_region

    p = BalanceParams(beta=a.beta, alpha=a.alpha, gamma=a.gamma, nu=0.0, tau=a.tau, dt=a.dt)
    roots = characteristic_roots(a.model, p, n_roots=a.roots)
    out = {
        "model": a.model,
        "params": p.as_dict(),
        "rightmost_root": [roots.rightmost.real, roots.rightmost.imag],
        "abscissa": roots.abscissa,
        "stable": roots.abscissa < 0,
        "roots": [[z.real, z.imag] for z in roots.roots],
    }
    if a.plot:
        from validation.plots import plot_stability_region

        betas = np.linspace(*a.beta_grid)
        taus = np.linspace(*a.tau_grid)
        region = stability_region(a.model, p, betas, taus)
        plot_stability_region(betas, taus, region, a.model, Path(a.plot))
        out["plot"] = str(a.plot)
    if a.json:
        print(_dump(out))
    else:
        word = "stable" if out["stable"] else "unstable"
        print(f"{a.model}, nu = 0, beta = {a.beta}, tau = {a.tau}: {word}")
        print(f"rightmost root s = {roots.rightmost:.6g} 1/s")
        for z in roots.roots[1:]:
            print(f"               s = {z:.6g}")
        if a.plot:
            print(f"stability region plot: {a.plot}")
    return EXIT_OK


def _grid(text: str) -> tuple[float, float, int]:
    try:
        lo, hi, n = text.split(":")
        return float(lo), float(hi), int(n)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW:HIGH:N, got {text!r}") from None


# ------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cip-validate",
        description="Validate a MuJoCo model of coupled inverted pendula against the reduced "
        "linear balancing model of Yoshida, Higeta & Watanabe (2011).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("lyapunov", help="largest Lyapunov exponent lambda1 (mean, 95% CI)")
    _model_args(p)
    _run_args(p, duration=200.0, realizations=8)
    p.add_argument("--engine", choices=("reduced", "mujoco"), default="reduced")
    p.add_argument("--stepper", choices=("semi-implicit", "explicit"), default="semi-implicit")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(func=cmd_lyapunov)

    p = sub.add_parser("critical-gain", help="beta* where lambda1 equals a target (paper: 5e-4)")
    _model_args(p, beta=False)
    _run_args(p, duration=500.0, realizations=16)
    p.add_argument("--beta-range", type=float, nargs=2, metavar=("LOW", "HIGH"), required=True)
    p.add_argument("--target", type=float, default=5e-4)
    p.add_argument("--gains", type=int, default=7)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_critical_gain)

    p = sub.add_parser("stability", help="noise-free characteristic roots and stability region")
    _model_args(p)
    p.add_argument("--roots", type=int, default=5, help="how many rightmost roots to print")
    p.add_argument("--plot", metavar="FILE.png", help="draw the stability region in (beta, tau)")
    p.add_argument("--beta-grid", type=_grid, default=(0.0, 80.0, 81), metavar="LOW:HIGH:N")
    p.add_argument("--tau-grid", type=_grid, default=(0.01, 0.3, 59), metavar="LOW:HIGH:N")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_stability)

    from validation.commands import add_commands
    from validation.experiment.cli import register as register_experiment

    add_commands(sub)
    register_experiment(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ParameterError as exc:
        print(f"cip-validate: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("cip-validate: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
