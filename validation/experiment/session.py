"""A session: its seats, the countdown and the real-time 50 Hz trial loop.

Seats are humans (a WebSocket each) or bots (:mod:`.bot`).  The countdown
starts when every human seat is taken and ready; then frame k runs at wall
time t0 + k * frame on the server's monotonic clock (the lateness of the
frame is recorded as its jitter), is appended to the recording, and is sent to
every page.  An abort, a closed page or the server stopping end the trial; the
recording is finalised in every case.

One server runs many sessions on one event loop, so nothing a session does may
hold it (``benchmarks/bench_server_load.py`` measures this): a late frame still
yields before it runs (the pages' messages are read and the other sessions' frames
run in turn); mouse messages arriving up to :data:`INPUT_GRACE` s (plus the last
frame's lateness) after the last frame are still recorded; the recording's header
and end record are fsynced on a thread and its ``.npz`` is written in a worker
process (:mod:`.finalize`).

A human seat is bound to the socket that took it for the whole session: when
that socket closes the seat is not free again; only a page holding the
seat's secret (issued when the seat was taken) may take it back, and only
before the countdown.  Bot settings are checked when the session is created
(:func:`make_bots`), so a bad one is an error on the page, never a hung
countdown.  During the countdown every page gets the lines' initial screen
positions to draw.  The client side of each seat (browser, sizes, colours)
goes into the recording's header; every mouse message's arrival time and the
page's report of when it drew each frame are appended as they arrive.
"""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cipcore import ParameterError
from validation.experiment.bot import BotSpec, PseudoNeuralBot
from validation.experiment.finalize import finalize
from validation.experiment.headless import trial_stem
from validation.experiment.recording import Recorder, make_header
from validation.experiment.task import INITIAL_BASES, INITIAL_TIP, TaskSettings, make_task
from validation.experiment.trial import Trial

log = logging.getLogger("cipval.experiment")

#: seconds after a trial's last frame, plus that frame's lateness, in which the pages' mouse
#: messages are still recorded (arrival times past the end): a server running late reads the
#: answers to its last frames late (benchmarks/bench_server_load.py: without this, 1 to 38
#: of a page's last answers were missing from each recording of 16 sessions at once)
INPUT_GRACE = 0.5


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
    secret: str | None = None  # issued when a human takes the seat; needed to take it back
    client: dict | None = None

    @property
    def taken(self) -> bool:
        return self.kind == "bot" or self.ws is not None

    def take(self, ws: Any) -> str:
        """Bind the seat to ``ws``; returns the seat's secret."""
        self.ws = ws
        self.secret = secrets.token_urlsafe(16)
        return self.secret


def make_bots(settings: TaskSettings, seats: list[Seat]) -> list[PseudoNeuralBot | None]:
    """A fresh bot for each bot seat (None for humans); raises ParameterError on bad settings
    (e.g. a delay tau that is not a whole number of time steps dt)."""
    out: list[PseudoNeuralBot | None] = []
    for seat, x0 in zip(seats, INITIAL_BASES[settings.mode], strict=True):
        if seat.kind != "bot":
            out.append(None)
            continue
        sp = seat.spec
        try:
            spec = BotSpec(sp["beta"], sp["tau"], sp["nu"], sp["seed"])
            out.append(PseudoNeuralBot(spec, settings.params, settings.frame, x0))
        except (ParameterError, ValueError) as exc:
            raise ParameterError(f"bot {seat.label}: {exc}") from None
    return out


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
    dropped: dict[str, int] = field(default_factory=dict)
    _task: asyncio.Task | None = None
    _rec: Recorder | None = None
    _t0: float = 0.0

    # ------------------------------------------------------------ seats
    def free_human_seat(self) -> int | None:
        """A human seat nobody has taken yet (a seat once taken stays bound)."""
        for i, s in enumerate(self.seats):
            if s.kind == "human" and s.secret is None:
                return i
        return None

    def count_drop(self, kind: str) -> None:
        self.dropped[kind] = self.dropped.get(kind, 0) + 1

    def clients(self) -> list[Any]:
        return [s.ws for s in self.seats if s.ws is not None] + list(self.spectators)

    async def broadcast(self, msg: dict) -> None:
        text = json.dumps(msg)  # once for every page
        for ws in self.clients():
            if not ws.closed:
                try:
                    await ws.send_str(text)
                except (ConnectionError, RuntimeError) as exc:  # closing socket
                    log.info("session %s: send failed: %s", self.id, exc)

    def describe(self) -> dict:
        return {"type": "session", "phase": self.phase, "mode": self.settings.mode,
                "trial": self.trial_index, "code": self.code,
                "seats": [{"kind": s.kind, "label": s.label, "taken": s.taken,
                           "ready": s.ready or s.kind == "bot"} for s in self.seats],
                "preview": self.preview()}  # fmt: skip

    async def set_ready(self, seat: int | None) -> None:
        if seat is not None:
            self.seats[seat].ready = True
        await self.broadcast(self.describe())
        everyone = all(s.kind == "bot" or (s.ws is not None and s.ready) for s in self.seats)
        if self.phase == "waiting" and everyone and (seat is not None or self.spectators):
            self.phase = "countdown"
            self._task = asyncio.create_task(self.run())

    def mouse(self, seat: int, x: float, t_client: float | None = None) -> None:
        """The seat's latest pixel; while running, its arrival is recorded: seat, arrival
        time (s since frame 0, server clock), the page's event time (s, page clock), x."""
        self.seats[seat].pixel = x
        if self._rec is not None and self.phase == "running":
            now = asyncio.get_running_loop().time() - self._t0
            t = None if t_client is None else t_client / 1000.0
            self._rec.event("mouse", [seat, now, t, x])

    def drawn(self, seat: int | None, ks: list[int], ts: list[float]) -> None:
        """The page of ``seat`` (None: a spectator) drew frames ``ks`` at page times ``ts`` (ms)."""
        if self._rec is not None and self.phase == "running":
            now = asyncio.get_running_loop().time() - self._t0
            for k, t in zip(ks, ts, strict=True):
                self._rec.event("drawn", [seat, k, t / 1000.0, now])

    def preview(self) -> dict:
        """The lines at their initial screen positions (drawn during the countdown)."""
        s = self.settings
        off = s.offsets
        return {"tips": [INITIAL_TIP + o for o in off], "bases": list(INITIAL_BASES[s.mode]),
                "offsets": off.tolist()}  # fmt: skip

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
            await self.broadcast({"type": "countdown", "n": n, **self.preview()})
            await asyncio.sleep(1.0)
            if self.phase == "ended":
                return
        try:
            trial, rec = await self._open()
        except Exception as exc:  # every page must hear why nothing starts
            log.exception("session %s: the trial could not start", self.id)
            self.phase = "ended"
            await self.broadcast({"type": "error", "error": f"the trial could not start: {exc}"})
            return
        self._rec = rec
        self.file = rec.path
        log.info("session %s: trial started, recording %s", self.id, rec.path)
        self.phase = "running"
        s = self.settings
        await self.broadcast({"type": "start", "offsets": s.offsets.tolist(),
                              "frame": s.frame, "duration": s.duration})  # fmt: skip
        try:
            late = await self._frames(trial, rec)
            await asyncio.sleep(INPUT_GRACE + late)  # the pages' answers to the last frames
        except asyncio.CancelledError:
            trial.end("server_stop")
            raise
        finally:
            self._rec = None  # no event is written once the log closes
            end = {"reason": trial.end_reason, "detail": trial.end_detail,
                   "time": trial.end_time, "samples": rec.n_samples,
                   "dropped_messages": sum(self.dropped.values()),
                   "dropped_by_type": dict(self.dropped)}  # fmt: skip
            self.file = await finalize(rec, end)
            self.phase = "ended"
            log.info("session %s: trial ended (%s %s) after %d samples: %s", self.id,
                     trial.end_reason, trial.end_detail, rec.n_samples, self.file)  # fmt: skip
        await self.broadcast({"type": "end", **end, "file": self.file.name})

    async def _open(self) -> tuple[Trial, Recorder]:
        """The trial, its bots and its recording (the header's fsync on a thread)."""
        s = self.settings
        self.trial = trial = Trial(s, make_task(self.engine, s))
        for seat, bot in zip(self.seats, make_bots(s, self.seats), strict=True):
            seat.bot = bot
            if bot is not None:
                seat.pixel = bot.initial_pixel()
        labels = [seat.label for seat in self.seats]
        header = make_header(
            s.as_dict(), self.engine, labels, [seat.spec for seat in self.seats],
            self.trial_index, session=self.id, substeps=s.substeps,
        )  # fmt: skip
        header["client"] = [seat.client for seat in self.seats]
        stem = trial_stem(self.out_dir, s.mode, labels, self.trial_index)
        return trial, await asyncio.to_thread(Recorder, stem, header)

    async def _frames(self, trial: Trial, rec: Recorder) -> float:
        """Frame k at t0 + k * frame (its lateness recorded as jitter) until the trial ends;
        returns the last frame's lateness (s).

        The loop yields to the event loop before every frame, also a late one: a server
        running behind still reads the pages' mouse messages (recorded as they arrive)
        and runs the other sessions' frames in turn, instead of catching up frame after
        frame with neither.
        """
        s = self.settings
        loop = asyncio.get_running_loop()
        t0 = self._t0 = loop.time()
        late = 0.0
        while not trial.ended:
            deadline = t0 + trial.k * s.frame
            await asyncio.sleep(max(0.0, deadline - loop.time()))
            if trial.ended:  # abort or disconnect while waiting
                break
            now = loop.time()
            late = now - deadline
            sample = trial.frame([seat.pixel for seat in self.seats], late, now - t0)
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
        return late
