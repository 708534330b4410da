"""Commands on lambda1 and stability: lyapunov, critical-gain, stability."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import get_engine
from validation.checks.divergence import lyapunov_events, summary
from validation.cli.args import (
    EXIT_OK,
    add_force_arg,
    add_json_arg,
    add_model_args,
    add_run_args,
    add_simulation_args,
    check_out_file,
    check_work,
    dump,
    engine_options,
    params_from_args,
    refuse_work,
)
from validation.cli.ci_options import progress_enabled
from validation.cli.domains import add_option
from validation.cli.main import add_command, command

PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def run_engine(
    a: argparse.Namespace, run: Callable[..., Any], params: BalanceParams, **options: Any
) -> Any:
    """``run`` (an engine's ``simulate`` or ``lyapunov``) on the options of
    :func:`validation.cli.args.add_simulation_args`: the model, ``params``, --duration,
    --realizations and --seed on --threads, a progress bar unless --json, and ``options``
    (the method's own), once the work passed :func:`validation.cli.args.check_work`."""
    check_work("--duration", a.realizations, a.duration, params.dt, force=a.force)
    progress = not a.json and progress_enabled()
    args = (a.model, params, a.duration, a.realizations, a.seed)
    return run(*args, threads=a.threads, progress=progress, **options)


# ---------------------------------------------------------------- lyapunov
def check_lyapunov_duration(a: argparse.Namespace, tau: float, dt: float) -> None:
    """--duration must leave one renormalisation interval (tau) after the transient."""
    from cipcore.results import min_lyapunov_duration

    shortest = min_lyapunov_duration(tau, dt)
    if a.duration < shortest:
        raise ParameterError(
            f"--duration must be >= {shortest:g} s for lambda1 (one renormalisation interval "
            f"tau = {tau:g} s after the transient, duration/10), got {a.duration:g}"
        )


@command(
    "lambda1 (1/s) of any registered engine: Benettin's method over the delay history, mean over "
    "realisations and Student-t 95 % CI."
)
def cmd_lyapunov(a: argparse.Namespace) -> int:
    params = params_from_args(a)
    check_lyapunov_duration(a, params.tau, params.dt)
    engine = get_engine(a.engine)
    res = run_engine(a, engine.lyapunov, params, **engine_options(a, engine))
    events = lyapunov_events(res.per_realization, diverged_at=res.diverged_at)
    d = res.as_dict()
    d["engine"] = a.engine
    d["divergence"] = [e.as_dict() for e in events]
    if a.json:
        print(dump(d))
    else:
        lo, hi = res.ci95
        print(
            f"lambda1 = {res.lambda1:.4e} 1/s  (95 % CI [{lo:.4e}, {hi:.4e}], "
            f"{len(res.per_realization)} realisations x {res.duration:g} s, "
            f"{a.engine} {a.model}, beta = {a.beta})"
        )
        line = summary(events, len(res.per_realization))
        if line:
            print(f"warning: {line}")
    return EXIT_OK


# --------------------------------------------------------- critical gain
@command(
    "beta* (1/s^2) where lambda1 of the reduced model crosses the target (paper Fig. 3: 5e-4 1/s)."
)
def cmd_critical_gain(a: argparse.Namespace) -> int:
    from cipcore.scenario import Execution, Scenario
    from reduced.lyapunov import critical_gain, numerical_setting

    lo, hi = a.beta_range  # LOW < HIGH: checked by the parser (the domain's pair)
    params = params_from_args(a, beta=lo, beta_option="--beta-range")
    params_from_args(a, beta=hi, beta_option="--beta-range")
    check_lyapunov_duration(a, params.tau, params.dt)
    check_work("--duration", a.realizations, a.duration, params.dt, runs=a.gains, force=a.force)
    res = critical_gain(
        Scenario(a.model, params, a.duration, a.realizations, a.seed),
        (lo, hi),
        target=a.target,
        n_gains=a.gains,
        execution=Execution(threads=a.threads, progress=progress_enabled()),
    )
    setting = numerical_setting(params, a.duration, a.realizations)
    if a.json:
        print(dump(res.as_dict() | {"setting": setting}))
    else:
        print(
            f"beta* = {res.beta_star:.3f} +- {res.std:.3f} (95 % CI [{res.ci95[0]:.3f}, "
            f"{res.ci95[1]:.3f}]) for lambda1 = {res.target:g} 1/s ({a.model}, "
            f"{res.n_realizations} realisations x {res.duration:g} s)"
        )
        print(
            f"setting: dt {setting['dt_s']:g} s, tau {setting['tau_s']:g} s "
            f"({setting['delay_steps']} steps), {setting['stepper']} stepper, noise "
            f"{setting['noise']}; transient {setting['transient_s']:g} s; estimator "
            f"{setting['estimator']}"
        )
        for b, lam, ci in zip(res.betas, res.lambdas, res.ci95s, strict=True):
            print(f"  beta {b:8.3f}  lambda1 {lam:+.3e}  [{ci[0]:+.3e}, {ci[1]:+.3e}]")
    return EXIT_OK


# -------------------------------------------------------------- stability
#: seconds per point of the stability region (characteristic roots with 32 nodes; 16 ms
#: measured on one core) and the most points a region plot takes without --force
REGION_POINT_S, MAX_REGION_POINTS = 0.016, 100_000


def check_region_work(n_betas: int, n_taus: int, force: bool) -> int:
    """Points of the region plot; a usage error above :data:`MAX_REGION_POINTS` unless forced."""
    points = n_betas * n_taus
    how = (f"{n_betas} x {n_taus}, about {points * REGION_POINT_S / 3600:.2g} h at "
           f"{REGION_POINT_S * 1e3:g} ms a point")  # fmt: skip
    refuse_work("--beta-grid x --tau-grid", points, how, bound=MAX_REGION_POINTS,
                unit="region points", force=force)  # fmt: skip
    return points


@command(
    "Rightmost characteristic roots of the noise-free reduced model (nu = 0) and, with --plot, its "
    "stability region in (beta, tau)."
)
def cmd_stability(a: argparse.Namespace) -> int:
    from reduced.stability import characteristic_roots, stability_region

    p = params_from_args(a).with_(nu=0.0)  # the noise-free model
    if a.plot:
        check_out_file("--plot", a.plot, PLOT_SUFFIXES)
        check_region_work(a.beta_grid[2], a.tau_grid[2], a.force)
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
        from validation.report.plots import plot_stability_region

        betas = np.linspace(*a.beta_grid)
        taus = np.linspace(*a.tau_grid)
        region = stability_region(a.model, p, betas, taus)
        plot_stability_region(betas, taus, region, a.model, Path(a.plot))
        out["plot"] = str(a.plot)
    if a.json:
        print(dump(out))
    else:
        word = "stable" if out["stable"] else "unstable"
        print(f"{a.model}, nu = 0, beta = {a.beta}, tau = {a.tau}: {word}")
        print(f"rightmost root s = {roots.rightmost:.6g} 1/s")
        for z in roots.roots[1:]:
            print(f"               s = {z:.6g}")
        if a.plot:
            print(f"stability region plot: {a.plot}")
    return EXIT_OK


# ------------------------------------------------------------------ parser
def register(sub: argparse._SubParsersAction) -> None:
    """Add ``lyapunov``, ``critical-gain`` and ``stability`` to the parser."""
    p = add_command(sub, "lyapunov", cmd_lyapunov)
    add_simulation_args(p, duration=200.0, realizations=8)
    add_json_arg(p)

    p = add_command(sub, "critical-gain", cmd_critical_gain)
    add_model_args(p, beta=False)
    add_run_args(p, duration=500.0, realizations=16)
    add_option(
        p,
        "--beta-range",
        domain="beta range",
        metavar=("LOW", "HIGH"),
        required=True,
        help="gains searched (1/s^2), LOW < HIGH, required",
    )
    add_option(p, "--target", domain="target", default=5e-4, help="lambda1 target (1/s)")
    add_option(
        p, "--gains", domain="gains", default=7, help="gains evaluated over the range (count >= 2)"
    )
    add_json_arg(p)

    p = add_command(sub, "stability", cmd_stability)
    add_model_args(p)
    add_option(
        p,
        "--roots",
        domain="roots",
        default=5,
        help="how many rightmost roots to print (count >= 1)",
    )
    add_option(
        p,
        "--plot",
        domain="plot out",
        metavar="FILE.png",
        help="draw the stability region in (beta, tau) to this .png, .pdf or .svg",
    )
    # the region plot's axes: option, domain, default, what and unit
    for option, domain, default, what, unit in (
        ("--beta-grid", "beta grid", "0:80:81", "gains", "1/s^2"),
        ("--tau-grid", "tau grid", "0.01:0.3:59", "delays", "s"),
    ):
        add_option(
            p,
            option,
            domain=domain,
            default=default,
            metavar="LOW:HIGH:N",
            help=f"{what} of the region plot ({unit}; N >= 2 points)",
        )
    add_force_arg(p, MAX_REGION_POINTS, "region points")
    add_json_arg(p)
