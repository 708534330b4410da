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
from cipcore.params import check_count, check_positive
from validation.cli.args import add_force_arg, add_no_figures_arg, check_work
from validation.cli.domains import DOMAINS
from validation.cli.main import add_command, add_group, command
from validation.experiment.task import DURATION, ENGINES, TaskSettings

#: the most bot trials per subject and mode (each writes one recording file)
MAX_TRIALS = 10_000
#: an output directory's declared domain: not empty, not an existing file
OUT_DIR = DOMAINS["out dir"].converter()


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise ParameterError(f"--port must be an integer in [0, 65535], got {text!r}") from None
    if not 0 <= v <= 65535:
        raise ParameterError(f"--port must be an integer in [0, 65535], got {v}")
    return v


def _add_engine_arg(p: argparse.ArgumentParser) -> None:
    """--engine: the engine that moves the sticks (:data:`validation.experiment.task.ENGINES`)."""
    p.add_argument("--engine", choices=tuple(ENGINES), default="reduced",
                   help="engine that moves the sticks")  # fmt: skip


def _add_trial_duration_arg(p: argparse.ArgumentParser) -> None:
    """--trial-duration: the length of one trial (s)."""
    p.add_argument("--trial-duration", type=float, default=DURATION,
                   help="length of a trial (s, > 0)")  # fmt: skip


def register(subparsers) -> None:
    """Add ``experiment`` and its subcommands to the ``cip-validate`` parser."""
    sub = add_group(subparsers, "experiment",
                    "The paper's balancing experiment (section 4): serve the tracking task to "
                    "subjects' browsers, run bot-vs-bot trials, and analyse the recordings.",
                    dest="experiment_command", metavar="SUBCOMMAND")  # fmt: skip

    s = add_command(
        sub, "serve", cmd_serve, help="web server of the tracking task (prints the URL)"
    )
    s.add_argument("--host", default="127.0.0.1", help="address to listen on")
    s.add_argument("--port", default="8050",
                   help="TCP port, integer in [0, 65535]; 0 picks a free one")  # fmt: skip
    _add_engine_arg(s)
    s.add_argument("--out", default="experiment-data", metavar="DIR", type=OUT_DIR,
                   help="directory of the recordings (created if absent)")  # fmt: skip
    _add_trial_duration_arg(s)
    s.add_argument("--countdown", type=int, default=3,
                   help="countdown before a trial (s, integer >= 0)")  # fmt: skip
    s.add_argument(
        "--allow-host", action="append", default=argparse.SUPPRESS, metavar="NAME",
        help="a host name under which pages may reach the server (repeatable; IP addresses "
        "and localhost are always allowed)",
    )  # fmt: skip

    a = add_command(sub, "analyze", cmd_analyze, help="Tables 1 and 2, Figs. 12-16")
    a.add_argument("dir", help="directory of recordings")
    a.add_argument("--out", default=argparse.SUPPRESS, metavar="DIR", type=OUT_DIR,
                   help="report directory (default: DIR/analysis)")  # fmt: skip
    add_no_figures_arg(a, "write the tables only")
    a.add_argument(
        "--include-incomplete", action="store_true",
        help="include trials cut short from outside (abort, disconnect, server_stop, "
        "unfinalised) in the averages; without it they are shown but left out",
    )  # fmt: skip

    b = add_command(sub, "bots", cmd_bots, help="bot-vs-bot trials at full speed, no browser")
    b.add_argument("--out", default="experiment-bots", type=OUT_DIR,
                   help="directory of the recordings")  # fmt: skip
    b.add_argument("--mode", choices=("single", "coupled", "both"), default="both",
                   help="task: one stick, two coupled sticks, or both")  # fmt: skip
    b.add_argument("--subjects", default="A,B", help="two labels, e.g. A,B")
    b.add_argument("--trials", type=int, default=5,
                   help=f"trials per subject and mode (count in [1, {MAX_TRIALS}])")  # fmt: skip
    _add_trial_duration_arg(b)
    b.add_argument("--beta", type=float, default=21.0, help="bot gain (1/s^2)")
    b.add_argument("--tau", type=float, default=0.1, help="bot delay (s), >= dt = 1 ms, whole ms")
    b.add_argument("--nu", type=float, default=0.6, help="bot noise (s^1/2); 0: noise-free")
    b.add_argument("--seed", type=int, default=0,
                   help="root seed of every bot's draws (integer >= 0)")  # fmt: skip
    _add_engine_arg(b)
    add_force_arg(b)


@command(
    "Serve the tracking task on HTTP and WebSockets; prints the URL with its access token; each "
    "trial is recorded in --out.",
)
def cmd_serve(a: argparse.Namespace) -> int:
    a.port = _port(a.port)
    check_positive("--trial-duration", a.trial_duration)
    check_count("--countdown", a.countdown, minimum=0)
    try:
        from validation.experiment.server import ServerConfig, start
    except ImportError as exc:
        raise ParameterError(
            f"the experiment server needs aiohttp ({exc}); pip install 'cipval[experiment]'"
        ) from None
    TaskSettings(duration=a.trial_duration)  # validates
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


def _labels(text: str) -> list[str]:
    from validation.experiment.protocol import LABEL

    labels = [x.strip() for x in text.split(",")]
    if len(labels) != 2 or not all(LABEL.fullmatch(x) for x in labels) or labels[0] == labels[1]:
        raise ParameterError(f"--subjects must be two different labels like A,B; got {text!r}")
    return labels


@command(
    "Trials of the task played by delayed random-gain bots (the reduced model's controller) at "
    "full speed, recorded like subjects' trials.",
)
def cmd_bots(a: argparse.Namespace) -> int:
    import numpy as np

    from validation.experiment.bot import BotSpec
    from validation.experiment.headless import run_bot_trial

    labels = _labels(a.subjects)
    trials = check_count("--trials", a.trials)
    if trials > MAX_TRIALS:
        raise ParameterError(
            f"--trials must be an integer in [1, {MAX_TRIALS}] (each trial writes one "
            f"recording per subject), got {trials}"
        )
    check_count("--seed", a.seed, minimum=0)
    modes = MODEL_NAMES if a.mode == "both" else (a.mode,)
    check_positive("--trial-duration", a.trial_duration)
    # every bot steps the tip at the task's dt: one realisation per subject and trial
    dt = TaskSettings().params.dt
    check_work("--trials x --trial-duration", 2 * trials, a.trial_duration, dt,
               runs=len(modes), force=a.force)  # fmt: skip
    # one independent stream per (mode, trial, subject), fixed by --seed
    seeds = iter(np.random.SeedSequence(a.seed).generate_state(2 * trials * 2 * len(modes)))
    out = Path(a.out)
    done = []
    for mode in modes:
        settings = TaskSettings(mode=mode, duration=a.trial_duration)
        for k in range(1, trials + 1):
            groups = [[x] for x in labels] if get_model(mode).n_controllers == 1 else [labels]
            for group in groups:
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
