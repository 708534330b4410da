"""Bot-only trials at full speed, without a browser or a clock.

The same :class:`.trial.Trial`, :class:`.recording.Recorder` and
:class:`.bot.PseudoNeuralBot` as the server, frame after frame with no
waiting (the frame jitter is recorded as 0 and the wall time as NaN).
"""

from __future__ import annotations

import secrets
from pathlib import Path

from validation.experiment.bot import BotSpec, PseudoNeuralBot
from validation.experiment.recording import Recorder, make_header
from validation.experiment.task import INITIAL_BASES, TaskSettings, make_task
from validation.experiment.trial import Trial


def trial_stem(out_dir: Path, mode: str, subjects: list[str], trial_index: int) -> Path:
    """``<out>/<mode>_<subjects>_trial<index>_<random>``: unique, sortable by name."""
    tag = "-".join(subjects)
    return Path(out_dir) / f"{mode}_{tag}_trial{trial_index:03d}_{secrets.token_hex(4)}"


def run_bot_trial(
    settings: TaskSettings,
    bots: list[BotSpec],
    subjects: list[str],
    trial_index: int,
    out_dir: Path,
    engine: str = "reduced",
) -> Path:
    """Run one trial with a bot in every seat; returns the finalised ``.npz``."""
    if len(bots) != settings.n_sticks or len(subjects) != settings.n_sticks:
        raise ValueError(f"{settings.mode} needs {settings.n_sticks} bots and subject labels")
    trial = Trial(settings, make_task(engine, settings))
    players = [
        PseudoNeuralBot(b, settings.params, settings.frame, x0)
        for b, x0 in zip(bots, INITIAL_BASES[settings.mode], strict=True)
    ]
    header = make_header(
        settings.as_dict(), engine, subjects, [b.as_dict() for b in bots], trial_index,
        session="headless", substeps=settings.substeps,
    )  # fmt: skip
    rec = Recorder(trial_stem(out_dir, settings.mode, subjects, trial_index), header)
    pixels: list[float | None] = [b.initial_pixel() for b in players]
    while True:
        sample = trial.frame(pixels, jitter=0.0)
        rec.append(sample)
        if trial.ended:
            break
        pixels = [
            b.respond(sample.k, tip - base)
            for b, tip, base in zip(players, sample.tip_position, sample.base_position, strict=True)
        ]
    return rec.finalize(
        {"reason": trial.end_reason, "detail": trial.end_detail, "time": trial.end_time,
         "samples": rec.n_samples}
    )  # fmt: skip
