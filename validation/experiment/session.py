"""A session: its seats, the countdown and the real-time 50 Hz trial loop.

Seats are humans (a WebSocket each) or bots (:mod:`.bot`).  The countdown
starts when every human seat is taken and ready; then frame k runs at wall
time t0 + k * frame on the server's monotonic clock (the lateness of the
frame is recorded as its jitter), is appended to the recording, and is sent to
every page.  An abort, a closed page or the server stopping end the trial; the
recording is finalised in every case.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .bot import BotSpec, PseudoNeuralBot
from .headless import trial_stem
from .recording import Recorder, make_header
from .task import INITIAL_BASES, TaskSettings, make_task
from .trial import Trial

log = logging.getLogger("cipval.experiment")


@dataclass
class Seat:
    """One subject's place in a session."""

    kind: str  # "human" or "bot"
    label: str
    spec: dict
    ws: Any = None
    ready: bool = False
    pixel: float | None = None
    bot: PseudoNeuralBot | None = None

    @property
    def taken(self) -> bool:
        return self.kind == "bot" or self.ws is not None


@dataclass
class Session:
    """A single or coupled session (module docstring)."""

    settings: TaskSettings
    engine: str
    trial_index: int
    seats: list[Seat]
    out_dir: Path
    countdown: int = 3
    code: str = field(default_factory=lambda: secrets.token_urlsafe(16))
    id: str = field(default_factory=lambda: secrets.token_hex(4))
    phase: str = "waiting"  # waiting, countdown, running, ended
    spectators: list[Any] = field(default_factory=list)
    trial: Trial | None = None
    file: Path | None = None
    dropped: int = 0
    _task: asyncio.Task | None = None

    # ------------------------------------------------------------ seats
    def free_human_seat(self) -> int | None:
        for i, s in enumerate(self.seats):
            if s.kind == "human" and s.ws is None:
                return i
        return None

    def clients(self) -> list[Any]:
        return [s.ws for s in self.seats if s.ws is not None] + list(self.spectators)

    async def broadcast(self, msg: dict) -> None:
        for ws in self.clients():
            if not ws.closed:
                try:
                    await ws.send_json(msg)
                except (ConnectionError, RuntimeError) as exc:  # closing socket
                    log.info("session %s: send failed: %s", self.id, exc)

    def describe(self) -> dict:
        return {"type": "session", "phase": self.phase, "mode": self.settings.mode,
                "trial": self.trial_index, "code": self.code,
                "seats": [{"kind": s.kind, "label": s.label, "taken": s.taken,
                           "ready": s.ready or s.kind == "bot"} for s in self.seats]}  # fmt: skip

    async def set_ready(self, seat: int | None) -> None:
        if seat is not None:
            self.seats[seat].ready = True
        await self.broadcast(self.describe())
        everyone = all(s.kind == "bot" or (s.ws is not None and s.ready) for s in self.seats)
        if self.phase == "waiting" and everyone and (seat is not None or self.spectators):
            self.phase = "countdown"
            self._task = asyncio.create_task(self.run())

    def mouse(self, seat: int, x: float) -> None:
        self.seats[seat].pixel = x

    def end(self, reason: str, detail: str = "") -> None:
        """End the running trial (or cancel a session that has not started)."""
        if self.trial is not None:
            self.trial.end(reason, detail)
        elif self.phase in ("waiting", "countdown"):
            self.phase = "ended"
            if self._task is not None:
                self._task.cancel()

    # ------------------------------------------------------------- loop
    async def run(self) -> None:
        """Countdown, then the trial at 50 Hz until an end rule fires."""
        for n in range(self.countdown, 0, -1):
            await self.broadcast({"type": "countdown", "n": n})
            await asyncio.sleep(1.0)
            if self.phase == "ended":
                return
        s = self.settings
        self.trial = trial = Trial(s, make_task(self.engine, s))
        for seat, x0 in zip(self.seats, INITIAL_BASES[s.mode], strict=True):
            if seat.kind == "bot":
                spec = BotSpec(seat.spec["beta"], seat.spec["tau"], seat.spec["nu"],
                               seat.spec["seed"])  # fmt: skip
                seat.bot = PseudoNeuralBot(spec, s.params, s.frame, x0)
                seat.pixel = seat.bot.initial_pixel()
        labels = [seat.label for seat in self.seats]
        header = make_header(
            s.as_dict(), self.engine, labels, [seat.spec for seat in self.seats],
            self.trial_index, session=self.id, substeps=s.substeps,
        )  # fmt: skip
        rec = Recorder(trial_stem(self.out_dir, s.mode, labels, self.trial_index), header)
        self.file = rec.path
        log.info("session %s: trial started, recording %s", self.id, rec.path)
        self.phase = "running"
        await self.broadcast({"type": "start", "offsets": s.offsets.tolist(),
                              "frame": s.frame, "duration": s.duration})  # fmt: skip
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        try:
            while not trial.ended:
                deadline = t0 + trial.k * s.frame
                delay = deadline - loop.time()
                if delay > 0:
                    await asyncio.sleep(delay)
                if trial.ended:  # abort or disconnect while waiting
                    break
                now = loop.time()
                sample = trial.frame([seat.pixel for seat in self.seats], now - deadline, now - t0)
                rec.append(sample)
                off = s.offsets
                await self.broadcast({
                    "type": "frame", "k": sample.k, "t": sample.t,
                    "tips": [p + o for p, o in zip(sample.tip_position, off, strict=True)],
                    "bases": [p + o for p, o in zip(sample.base_position, off, strict=True)],
                })  # fmt: skip
                for seat, tip, base in zip(self.seats, sample.tip_position, sample.base_position,
                                           strict=True):  # fmt: skip
                    if seat.bot is not None and not trial.ended:
                        seat.pixel = seat.bot.respond(sample.k, tip - base)
        except asyncio.CancelledError:
            trial.end("server_stop")
            raise
        finally:
            end = {"reason": trial.end_reason, "detail": trial.end_detail,
                   "time": trial.end_time, "samples": rec.n_samples,
                   "dropped_messages": self.dropped}  # fmt: skip
            self.file = rec.finalize(end)
            self.phase = "ended"
            log.info("session %s: trial ended (%s %s) after %d samples: %s", self.id,
                     trial.end_reason, trial.end_detail, rec.n_samples, self.file)  # fmt: skip
        await self.broadcast({"type": "end", **end, "file": self.file.name})
