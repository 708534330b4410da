"""``cip-validate experiment serve | analyze | bots``: the paper's experiment (section 4)."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import signal
import sys
from pathlib import Path

from cipcore import ParameterError
from cipcore.models import MODEL_NAMES, get_model
from cipcore.params import whole_steps
from validation.cli.args import add_force_arg, add_no_figures_arg, refuse_work
from validation.cli.domains import add_option
from validation.cli.main import add_command, add_group, command
from validation.experiment.task import DURATION, FRAME, TaskSettings

#: Bot frames (trials x seats x trial duration / 20 ms, summed over the modes) above which
#: ``experiment bots`` asks for ``--force``: a frame takes about 80 us here (3 x 3600 s of
#: trials, 540,000 frames, in 16.5 s), so 1e7 frames is about 15 minutes.
MAX_BOT_FRAMES = 1e7


def _add_engine_arg(p: argparse.ArgumentParser) -> None:
    """--engine: the engine that moves the sticks (:data:`validation.experiment.task.ENGINES`)."""
    add_option(p, "--engine", domain="task engine", default="reduced",
               help="engine that moves the sticks")  # fmt: skip


def _add_trial_duration_arg(p: argparse.ArgumentParser) -> None:
    """--trial-duration: the length of one trial (s)."""
    add_option(p, "--trial-duration", domain="trial duration", default=DURATION,
               help="length of a trial (s)")  # fmt: skip


def register(subparsers) -> None:
    """Add ``experiment`` and its subcommands to the ``cip-validate`` parser."""
    sub = add_group(subparsers, "experiment",
                    "The paper's balancing experiment (section 4): serve the tracking task to "
                    "subjects' browsers, run bot-vs-bot trials, and analyse the recordings.",
                    dest="experiment_command", metavar="SUBCOMMAND")  # fmt: skip

    s = add_command(
        sub, "serve", cmd_serve, help="web server of the tracking task (prints the URL)"
    )
    add_option(s, "--host", domain="host", default="127.0.0.1", help="address to listen on")
    add_option(s, "--port", domain="port", default=8050, help="TCP port; 0 picks a free one")
    _add_engine_arg(s)
    add_option(s, "--out", domain="out dir", default="experiment-data", metavar="DIR",
               help="directory of the recordings (created if absent)")  # fmt: skip
    _add_trial_duration_arg(s)
    add_option(s, "--countdown", domain="countdown", default=3,
               help="countdown before a trial (s)")  # fmt: skip
    add_option(
        s, "--allow-host", domain="host", action="append", default=argparse.SUPPRESS,
        metavar="NAME",
        help="a host name under which pages may reach the server (repeatable; IP addresses "
        "and localhost are always allowed)",
    )  # fmt: skip

    a = add_command(sub, "analyze", cmd_analyze, help="Tables 1 and 2, Figs. 12-16")
    a.add_argument("dir", help="directory of recordings")
    add_option(a, "--out", domain="out dir", default=argparse.SUPPRESS, metavar="DIR",
               help="report directory (default: DIR/analysis)")  # fmt: skip
    add_no_figures_arg(a, "write the tables only")
    a.add_argument(
        "--include-incomplete", action="store_true",
        help="include trials cut short from outside (abort, disconnect, server_stop, "
        "unfinalised) in the averages; without it they are shown but left out",
    )  # fmt: skip

    b = add_command(sub, "bots", cmd_bots, help="bot-vs-bot trials at full speed, no browser")
    add_option(b, "--out", domain="out dir", default="experiment-bots",
               help="directory of the recordings")  # fmt: skip
    add_option(b, "--mode", domain="task mode", default="both",
               help="task: one stick, two coupled sticks, or both")  # fmt: skip
    add_option(b, "--subjects", domain="subjects", default="A,B", metavar="A,B",
               help="the two subjects' labels")  # fmt: skip
    add_option(b, "--trials", domain="trials", default=5, help="trials per subject and mode")
    _add_trial_duration_arg(b)
    add_option(b, "--beta", domain="beta", default=21.0, help="bot gain (1/s^2)")
    add_option(b, "--tau", domain="bot tau", default=0.1,
               help="bot delay (s), a whole number of the task's 1 ms steps")  # fmt: skip
    add_option(b, "--nu", domain="nu", default=0.6, help="bot noise (s^1/2); 0: noise-free")
    add_option(b, "--seed", domain="seed", default=0, help="root seed of every bot's draws")
    _add_engine_arg(b)
    add_force_arg(b, MAX_BOT_FRAMES, "bot frames")


@command(
    "Serve the tracking task on HTTP and WebSockets; prints the URL with its access token; each "
    "trial is recorded in --out.",
)
def cmd_serve(a: argparse.Namespace) -> int:
    try:
        from validation.experiment.server import ServerConfig, start
    except ImportError as exc:
        raise ParameterError(
            f"the experiment server needs aiohttp ({exc}); pip install 'cipval[experiment]'"
        ) from None
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s",
        handlers=[logging.StreamHandler(sys.stderr), logging.FileHandler(out / "server.log")],
    )  # fmt: skip
    hosts = tuple(getattr(a, "allow_host", ()))
    config = ServerConfig(out_dir=out, engine=a.engine, duration=a.trial_duration,
                          countdown=a.countdown, allowed_hosts=hosts)  # fmt: skip

    async def main() -> None:
        try:
            runner, url, _ = await start(config, a.host, a.port)
        except OSError as exc:
            raise ParameterError(
                f"--host/--port: cannot listen on {a.host}:{a.port}: {exc}"
            ) from None
        print(f"cip-validate experiment: open {url}", flush=True)
        print(f"recordings go to {out.resolve()}; Ctrl-C stops the server", flush=True)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):  # finalise running trials, then exit
            loop.add_signal_handler(sig, stop.set)
        try:
            await stop.wait()
        finally:
            await runner.cleanup()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0


@command(
    "Trials of the task played by delayed random-gain bots (the reduced model's controller) at "
    "full speed, recorded like subjects' trials.",
)
def cmd_bots(a: argparse.Namespace) -> int:
    import numpy as np

    from validation.experiment.bot import BotSpec
    from validation.experiment.headless import run_bot_trial

    labels = list(a.subjects)
    modes = MODEL_NAMES if a.mode == "both" else (a.mode,)
    dt = TaskSettings().params.dt  # every bot steps the tip at the task's 1 ms
    whole_steps("--tau", a.tau, dt)
    # per round, a trial per subject alone (single) or one per pair (coupled), n frames each
    groups = {m: [[x] for x in labels] if get_model(m).n_controllers == 1 else [labels]
              for m in modes}  # fmt: skip
    per_round = sum(len(g) for g in groups.values())
    n = round(a.trial_duration / FRAME)
    refuse_work("--trials x --trial-duration", float(a.trials) * per_round * n,
                f"{a.trials} trials x {per_round} trial(s) per round x {n} frames of {FRAME:g} s",
                bound=MAX_BOT_FRAMES, unit="bot frames", force=a.force)  # fmt: skip
    # one independent stream per (mode, trial, subject), fixed by --seed
    seeds = iter(np.random.SeedSequence(a.seed).generate_state(2 * a.trials * 2 * len(modes)))
    out = Path(a.out)
    done = []
    for mode in modes:
        settings = TaskSettings(mode=mode, duration=a.trial_duration)
        for k in range(1, a.trials + 1):
            for group in groups[mode]:
                specs = [BotSpec(a.beta, a.tau, a.nu, int(next(seeds))) for _ in group]
                path = run_bot_trial(settings, specs, group, k, out, engine=a.engine)
                done.append(path)
                print(f"{path}", flush=True)
    print(json.dumps({"trials": len(done), "out": str(out)}))
    return 0


@command(
    "Analyse a directory of recordings: the paper's STCC and RMS tables and its figures of the "
    "movement, STCC and RMS vs tau.",
)
def cmd_analyze(a: argparse.Namespace) -> int:
    from validation.experiment.recording import find_trials
    from validation.experiment.report import write_report

    d = Path(a.dir)
    if not d.is_dir():
        raise ParameterError(f"DIR must be a directory of recordings, got {a.dir!r}")
    if not find_trials(d):
        raise ParameterError(f"DIR {a.dir!r} holds no recordings (*.jsonl / *.npz)")
    out = Path(a.out) if getattr(a, "out", None) else d / "analysis"
    paths = write_report(d, out, figures=not a.no_figures,
                         include_incomplete=a.include_incomplete)  # fmt: skip
    for p in paths:
        print(p)
    return 0
