"""The experiment server under load: N concurrent coupled sessions, two WebSocket bots each.

The server (``cip-validate experiment serve``, :mod:`validation.experiment.server`) runs
in a process of its own on a free port of 127.0.0.1; this process plays every seat.
Each session is the coupled task (paper section 4.1, eq. (5)) with two *human* seats,
each taken by a bot that speaks the page's protocol over its own WebSocket: the
pseudo-neural controller of :class:`validation.experiment.bot.PseudoNeuralBot`
(paper eqs. (3), (5); beta 21 s^-2, tau 0.1 s, nu 0.6 s^1/2, seeds from
``cipcore.seeds.purpose_rng(seed, "bot", session)``) sends its initial pixel before
Ready and, on each frame k < n_frames, its pixel for frame k + 1 (``mouse``) -- the
load of two subjects at 50 Hz.  Sessions are created first; their starts are then
spread evenly over ``stagger`` seconds (so that trials end one by one while others
run, as they would on a real server), and every trial runs ``duration`` seconds.

What is measured (all times on CLOCK_MONOTONIC, which the two processes share):

* **frame lateness, server** (ms): for every frame k of every session, the time its
  50 Hz loop started the frame minus its schedule t0 + k * 20 ms (the recording's
  ``frame_jitter``).  p50, p99 and max over all frames of all sessions.
* **frame lateness, at the bots** (ms): the time the frame message reached the bot
  minus t0 + k * 20 ms.  The bot's clock reading of the server's t0 is
  max(send time - server arrival time) over the session's recorded mouse messages: no
  message arrives before it is sent, so this t0 is early by at most the quickest
  bot -> server transit and the lateness is an upper bound by that much.
* **round trip** (ms): the server's arrival time of a bot's answer to frame k minus the
  start of frame k (both from the recording): frame computed and sent, received,
  answered, the answer read by the server.  Beyond 20 ms minus frame k + 1's lateness,
  the answer misses frame k + 1.
* **stale inputs**: seat samples whose recorded pixel is not the bot's pixel for that
  frame (its answer arrived after the frame ran; the server used the older one).
  Not a loss: a late mouse.
* **samples lost** (must be 0): frames the server ran that are not in its recording
  (gaps in k, or fewer rows than the end record's ``samples``), frames a bot did not
  receive or received with tips unlike the recording's, mouse messages a bot sent
  that the recording's ``client_events`` lack (matched in order by value), and
  recorded mouse values no bot sent.
* **server CPU** (s per session-second): user + system CPU of the server process
  (``/proc/<pid>/stat``, all its threads) over the window in which every session
  runs (from the last start to the first end), divided by the trial time served in
  it: the frames the sessions started in the window times 20 ms.  On time, that is
  CPU seconds per session per second of wall time; a server running late serves
  fewer frames in the window, so the number stays the cost of a session, not the
  share of the machine the server was given.  ``1 / server CPU`` sessions fill one
  core.  **bots CPU**: this process's CPU (``os.times``) the same way (two bots a
  session).  The server's ``.npz`` writer (a worker process, busy once trials end)
  falls outside the window.

The server **saturates** at the smallest N whose server-side p99 lateness exceeds one
frame (20 ms) or which loses a sample.  On a machine of few cores the bots compete with
the server for them: the bots' CPU is printed for that reason, and ``uptime``'s load
average is printed beside the table.

Usage:  python benchmarks/bench_server_load.py [--sessions 1,4,16,64] [--duration 10]
            [--stagger 1] [--seed 0] [--out DIR]
Exit status: 0, 1 when a sample was lost at any N, 2 on bad input (one line).
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

import aiohttp
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(ROOT))

from cipcore.seeds import purpose_rng  # noqa: E402
from validation.experiment.bot import BotSpec, PseudoNeuralBot  # noqa: E402
from validation.experiment.recording import load_trial  # noqa: E402
from validation.experiment.task import INITIAL_BASES, TaskSettings  # noqa: E402

#: frame period (s), paper section 4.1
FRAME = 0.02
#: the bots' gain (1/s^2), delay (s) and noise (s^1/2): the paper's balancers
BOT = {"beta": 21.0, "tau": 0.1, "nu": 0.6}
SESSIONS = (1, 4, 16, 64)
#: allowed ranges of the options
MAX_SESSIONS = 256
DURATION_RANGE = (1.0, 600.0)
#: seconds allowed for a session's messages beyond its trial's duration
SLACK = 60.0
#: the benchmark's clock origin (s, CLOCK_MONOTONIC); the bots' page times are relative to it
T_REF = time.monotonic()


def clock() -> float:
    """Seconds since :data:`T_REF` on CLOCK_MONOTONIC (the server's loop clock too)."""
    return time.monotonic() - T_REF


@dataclass
class RemoteBot:
    """One seat played over a WebSocket, and what it sent and received."""

    bot: PseudoNeuralBot
    seat: int
    initial: float
    sent: list[float] = field(default_factory=list)  # pixel for frame k + 1, after frame k
    frames: list[int] = field(default_factory=list)
    tips: list[float] = field(default_factory=list)  # its own thick line, screen units
    arrival: list[float] = field(default_factory=list)  # s, :func:`clock`
    end: dict | None = None


@dataclass
class Result:
    """One trial of the benchmark: N sessions at once (module docstring for each number)."""

    sessions: int
    frames: int
    late_server: np.ndarray  # ms, every frame of every session
    late_bots: np.ndarray  # ms, every frame at every bot
    round_trip: np.ndarray  # ms, every recorded answer of every bot
    stale: int
    lost: int
    server_cpu: float  # s per session-second of trial
    bots_cpu: float  # s per session-second of trial
    load: tuple[float, float, float]
    ends: dict[str, int]

    @property
    def saturated(self) -> bool:
        """p99 of the server's lateness beyond one frame, or a sample lost."""
        return self.lost > 0 or not pct(self.late_server, 99) <= FRAME * 1e3


def pct(x: np.ndarray, q: float) -> float:
    """Percentile ``q`` of ``x`` (NaN when empty)."""
    return float(np.percentile(x, q)) if len(x) else math.nan


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process ``pid``, all its threads (Linux ``/proc``)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def own_cpu() -> float:
    """User + system CPU seconds of this process."""
    t = os.times()
    return t.user + t.system


def count_lost(sent: list[float], recorded: list[float]) -> tuple[int, int]:
    """(sent values missing from ``recorded``, recorded values nobody sent), matching the
    two in order by value (each sent value to its first match after the previous match):
    a message dropped, changed or invented counts."""
    where: dict[float, list[int]] = {}
    for j, x in enumerate(recorded):
        where.setdefault(x, []).append(j)
    matched, i = 0, 0
    for x in sent:
        at = where.get(x, [])
        n = bisect.bisect_left(at, i)
        if n < len(at):
            matched, i = matched + 1, at[n] + 1
    return len(sent) - matched, len(recorded) - matched


# ----------------------------------------------------------------------- the server
def start_server(out: Path, duration: float) -> tuple[subprocess.Popen, str]:
    """``cip-validate experiment serve`` on a free port of 127.0.0.1, no countdown;
    returns the process and its URL (with the access token)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")])}  # fmt: skip
    cmd = [sys.executable, "-m", "validation.cli.main", "experiment", "serve", "--port", "0",
           "--out", str(out), "--trial-duration", repr(duration), "--countdown", "0"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, env=env)  # fmt: skip
    line = proc.stdout.readline()
    if "open " not in line:
        proc.kill()
        proc.wait()
        raise RuntimeError(f"the server did not start (see {out / 'server.log'}): {line!r}")
    return proc, line.split("open ", 1)[1].strip()


def stop_server(proc: subprocess.Popen) -> None:
    """SIGTERM (the server finalises what runs), then wait; SIGKILL after 30 s."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    proc.stdout.close()


# ------------------------------------------------------------------------- the bots
async def _until(ws, kind: str) -> dict:
    """The next message of type ``kind`` (an error message or a closed socket raises)."""
    while True:
        msg = await ws.receive()
        if msg.type != aiohttp.WSMsgType.TEXT:
            raise RuntimeError(f"socket closed waiting for {kind!r}: {msg.type!r}")
        d = json.loads(msg.data)
        if d["type"] == "error":
            raise RuntimeError(f"the server refused: {d['error']}")
        if d["type"] == kind:
            return d


async def _idle(ws, until: float) -> None:
    """Read (and drop) messages until :func:`clock` reaches ``until``: reading is what
    answers the server's pings (every 10 s; a page that does not answer is closed).
    Waits of at most 1 s: aiohttp starts a receive's timeout again after each ping."""
    while (left := until - clock()) > 0:
        try:
            msg = await ws.receive(timeout=min(left, 1.0))
        except TimeoutError:
            continue
        if msg.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSE,
                        aiohttp.WSMsgType.ERROR):  # fmt: skip
            raise RuntimeError(f"socket closed before the trial's start: {msg.type!r}")


async def _send_pixel(ws, x: float) -> None:
    await ws.send_str(json.dumps({"type": "mouse", "x": x, "t": clock() * 1e3}))


async def play(ws, rb: RemoteBot, n_frames: int) -> None:
    """Answer every frame k < ``n_frames`` with the pixel for frame k + 1, until ``end``."""
    async for msg in ws:
        if msg.type != aiohttp.WSMsgType.TEXT:
            break
        d = json.loads(msg.data)
        if d["type"] == "frame":
            k, tip, base = d["k"], d["tips"][rb.seat], d["bases"][rb.seat]
            rb.arrival.append(clock())
            rb.frames.append(k)
            rb.tips.append(tip)
            if k < n_frames:
                x = rb.bot.respond(k, tip - base)
                await _send_pixel(ws, x)
                rb.sent.append(x)
        elif d["type"] == "end":
            rb.end = d
            return
        elif d["type"] == "error":
            raise RuntimeError(f"the server refused: {d['error']}")
    raise RuntimeError(f"seat {rb.seat + 1}: socket closed before the trial's end")


def make_bots(settings: TaskSettings, seed: int, session: int) -> list[RemoteBot]:
    """The session's two bots; their seeds from ``purpose_rng(seed, "bot", session)``."""
    seeds = purpose_rng(seed, "bot", session).integers(0, 2**32, size=2)
    out = []
    for seat, (s, x0) in enumerate(zip(seeds, INITIAL_BASES["coupled"], strict=True)):
        bot = PseudoNeuralBot(BotSpec(**BOT, seed=int(s)), settings.params, FRAME, x0)
        out.append(RemoteBot(bot, seat, bot.initial_pixel()))
    return out


@dataclass
class Plan:
    """What every session of one trial shares."""

    base: str  # the WebSocket URL
    token: str
    settings: TaskSettings
    seed: int
    go: asyncio.Event  # set when every session is created
    started: list[float]  # clock() when each bot saw frame 0
    ended: list[float]  # clock() when each bot saw the end


async def run_session(http, plan: Plan, index: int, start_at: float) -> list[RemoteBot]:
    """Create session ``index`` (seat 1), join it (seat 2), wait for ``plan.go`` and
    ``start_at`` (:func:`clock`), send the initial pixels and Ready, play to the end."""
    bots = make_bots(plan.settings, plan.seed, index)
    a = await http.ws_connect(plan.base)
    b = await http.ws_connect(plan.base)
    try:
        seats = [{"kind": "human", "label": "A"}, {"kind": "human", "label": "B"}]
        await a.send_json({"type": "create", "token": plan.token, "mode": "coupled",
                           "trial": index + 1, "seats": seats})  # fmt: skip
        code = (await _until(a, "created"))["code"]
        await b.send_json({"type": "join", "code": code, "label": "B"})
        await _until(b, "joined")
        await plan.go.wait()
        await asyncio.gather(_idle(a, start_at), _idle(b, start_at))
        for ws, rb in ((a, bots[0]), (b, bots[1])):
            await _send_pixel(ws, rb.initial)  # read before Ready: frame 0 holds it
            await ws.send_json({"type": "ready"})
        n = plan.settings.n_frames
        await asyncio.gather(play(a, bots[0], n), play(b, bots[1], n))
    finally:
        await a.close()
        await b.close()
    return bots


async def drive(url: str, n: int, plan_args: tuple[TaskSettings, int, float]) -> tuple:
    """Run ``n`` sessions against the server at ``url``; returns (bots by session,
    window start, window end) with the window on :func:`clock`."""
    settings, seed, stagger = plan_args
    q = urllib.parse.urlsplit(url)
    token = urllib.parse.parse_qs(q.query)["token"][0]
    plan = Plan(f"ws://{q.netloc}/ws", token, settings, seed, asyncio.Event(), [], [])
    # aiohttp's default connector holds at most 100 connections: 2 per session here
    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as http:
        t_go = clock() + 1.0 + 0.02 * n  # time for every session to be created
        tasks = [asyncio.create_task(run_session(http, plan, i, t_go + stagger * i / n))
                 for i in range(n)]  # fmt: skip
        await asyncio.sleep(max(0.0, t_go - clock()))
        plan.go.set()
        # a saturated server stretches the trials: up to n / 8 times here, at worst
        limit = settings.duration * max(2.0, n / 8) + stagger + SLACK
        try:
            sessions = await asyncio.wait_for(asyncio.gather(*tasks), timeout=limit)
        except TimeoutError:
            raise RuntimeError(f"the sessions had not ended after {limit:.0f} s") from None
    started = max(min(b.arrival[0] for b in s) for s in sessions)
    ended = min(min(b.arrival[-1] for b in s) for s in sessions)
    return sessions, started, ended


# ---------------------------------------------------------------------- the numbers
@dataclass
class SessionNumbers:
    """The numbers of one session (module docstring)."""

    late_server: np.ndarray
    late_bots: np.ndarray
    round_trip: np.ndarray
    ran: np.ndarray  # s, :func:`clock`: when each frame started (t0 + wall)
    stale: int = 0
    lost: int = 0


def frames_lost(rec, bots: list[RemoteBot]) -> int:
    """Frames of the end record's count missing from the recording ``rec`` (or repeated
    in it), and for each bot: recorded frames it did not receive or received with
    another tip, and frames it received that the recording lacks."""
    k = np.rint(rec.time / FRAME).astype(int).tolist()
    expected = set(range(int(rec.attrs["end"]["samples"])))
    row = {f: r for r, f in enumerate(k) if f in expected}
    lost = len(expected) - len(row) + len(k) - len(row)
    offsets = [0.0, rec.attrs["settings"]["rod_length"]]
    for rb in bots:
        tips = rec["tip_position"][0, :, rb.seat] + offsets[rb.seat]
        got = dict(zip(rb.frames, rb.tips, strict=True))
        lost += sum(1 for f, r in row.items() if got.get(f) != tips[r])
        lost += len(got.keys() - row.keys())
    return lost


def session_numbers(rec, bots: list[RemoteBot]) -> SessionNumbers:
    """Compare one session's recording (a :class:`reduced.Trajectory`) with its bots."""
    k = rec.time
    lost = frames_lost(rec, bots)
    wall = rec["wall_time"][0, :, 0]
    ev = rec.attrs["client_events"]["mouse"]
    seat, arrival, page, x = (np.asarray(ev[c], dtype=float) for c in EVENT_COLUMNS)
    t0 = float(np.max(page - arrival)) if len(page) else math.nan  # see the docstring
    trips, lates, stale = [], [], 0
    for rb in bots:
        mine = seat == rb.seat
        missing, invented = count_lost(rb.sent, x[mine].tolist())
        lost += missing + invented
        answers = arrival[mine][: len(wall)]
        trips.append(answers - wall[: len(answers)])
        want = np.array([rb.initial, *rb.sent])[: len(k)]
        stale += int(np.count_nonzero(rec["mouse_pixel"][0, : len(want), rb.seat] != want))
        lates.append(np.asarray(rb.arrival) - (t0 + np.asarray(rb.frames) * FRAME))
    return SessionNumbers(rec["frame_jitter"][0, :, 0] * 1e3, np.concatenate(lates) * 1e3,
                          np.concatenate(trips) * 1e3, t0 + wall, stale, lost)  # fmt: skip


#: the mouse event columns, in :data:`validation.experiment.recording.EVENT_COLUMNS` order
EVENT_COLUMNS = ("seat", "arrival", "page_time", "x")


async def drive_sampled(url: str, n: int, plan_args: tuple, pid: int) -> tuple:
    """:func:`drive`, sampling the CPU of the server (``pid``) and of this process every
    0.25 s: returns (sessions, window start, window end, [(clock, server, own), ...])."""
    samples: list[tuple[float, float, float]] = []

    async def sample() -> None:
        while True:
            samples.append((clock(), cpu_seconds(pid), own_cpu()))
            await asyncio.sleep(0.25)

    sampler = asyncio.create_task(sample())
    try:
        sessions, started, ended = await drive(url, n, plan_args)
    finally:
        sampler.cancel()
    return sessions, started, ended, samples


def window_cpu(samples: list[tuple[float, float, float]], started: float,
               ended: float) -> tuple[float, float, float, float]:  # fmt: skip
    """(server CPU s, own CPU s, from, to) between the first and the last sample inside
    [started, ended] (:func:`clock`); NaN when fewer than two samples fall inside."""
    inside = [s for s in samples if started <= s[0] <= ended]
    if len(inside) < 2:
        return math.nan, math.nan, math.nan, math.nan
    (ta, sa, oa), (tb, sb, ob) = inside[0], inside[-1]
    return sb - sa, ob - oa, ta, tb


def _served(parts: list[SessionNumbers], ta: float, tb: float) -> float:
    """Trial seconds served between ``ta`` and ``tb``: frames started then x 20 ms."""
    return FRAME * sum(int(np.count_nonzero((p.ran >= ta) & (p.ran <= tb))) for p in parts)


@dataclass
class Run:
    """What one trial of the benchmark leaves: every session's bots, the CPU samples and
    the window in which every session ran (:func:`drive_sampled`), the recordings' place."""

    sessions: list[list[RemoteBot]]
    samples: list[tuple[float, float, float]]
    started: float
    ended: float
    out: Path


def run_trial(n: int, duration: float, stagger: float, seed: int, out: Path) -> Run:
    """``n`` sessions of ``duration`` s (starts spread over ``stagger`` s) against a
    server started and stopped here, its recordings under ``out``."""
    settings = TaskSettings(mode="coupled", duration=duration)
    out.mkdir(parents=True, exist_ok=True)
    proc, url = start_server(out, duration)
    try:
        coro = drive_sampled(url, n, (settings, seed, stagger), proc.pid)
        sessions, started, ended, samples = asyncio.run(coro)
    finally:
        stop_server(proc)
    return Run(sessions, samples, started, ended, out)


def summarise(run: Run) -> Result:
    """The numbers of a :class:`Run`, each session's from its recording (read now)."""
    server, own, ta, tb = window_cpu(run.samples, run.started, run.ended)
    parts, ends = [], {}
    for bots in run.sessions:
        rec = load_trial(run.out / bots[0].end["file"])
        parts.append(session_numbers(rec, bots))
        reason = rec.attrs["end"]["reason"]
        ends[reason] = ends.get(reason, 0) + 1
    return Result(
        sessions=len(run.sessions), frames=sum(len(p.late_server) for p in parts),
        late_server=np.concatenate([p.late_server for p in parts]),
        late_bots=np.concatenate([p.late_bots for p in parts]),
        round_trip=np.concatenate([p.round_trip for p in parts]),
        stale=sum(p.stale for p in parts), lost=sum(p.lost for p in parts),
        server_cpu=server / served if (served := _served(parts, ta, tb)) else math.nan,
        bots_cpu=own / served if served else math.nan,
        load=os.getloadavg(), ends=ends,
    )  # fmt: skip


def measure(n: int, duration: float, stagger: float, seed: int, out: Path) -> Result:
    """One trial of the benchmark and its numbers: :func:`run_trial`, :func:`summarise`."""
    return summarise(run_trial(n, duration, stagger, seed, out))


# ------------------------------------------------------------------ command line
def _fail(msg: str) -> None:
    print(f"bench_server_load.py: error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options, each checked against its range (bad input: one line, exit 2)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    lo, hi = DURATION_RANGE
    counts = ",".join(map(str, SESSIONS))
    ap.add_argument(
        "--sessions", default=counts, help=f"session counts, each in [1, {MAX_SESSIONS}]"
    )
    ap.add_argument("--duration", default="10", help=f"seconds per trial, in [{lo:g}, {hi:g}]")
    ap.add_argument(
        "--stagger",
        default="1",
        help="seconds over which the starts are spread, in [0, duration / 2]",
    )
    ap.add_argument("--seed", default="0", help="root seed of the bots, integer >= 0")
    ap.add_argument("--out", default=None, help="keep the recordings in this directory")
    a = ap.parse_args(argv)
    try:
        a.sessions = [int(x) for x in a.sessions.split(",")]
    except ValueError:
        _fail(f"--sessions must be integers in [1, {MAX_SESSIONS}] like 1,4,16, got {a.sessions!r}")
    if not all(1 <= n <= MAX_SESSIONS for n in a.sessions) or len(set(a.sessions)) < len(
        a.sessions
    ):
        _fail(f"--sessions must be distinct integers in [1, {MAX_SESSIONS}], got {a.sessions}")
    a.duration = _number("--duration", a.duration, *DURATION_RANGE)
    a.stagger = _number("--stagger", a.stagger, 0.0, a.duration / 2)
    if not a.seed.isdigit():
        _fail(f"--seed must be an integer >= 0, got {a.seed!r}")
    a.seed = int(a.seed)
    return a


def _number(name: str, text: str, lo: float, hi: float) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not lo <= v <= hi:
        _fail(f"{name} must be a number in [{lo:g}, {hi:g}], got {text!r}")
    return v


HEADER = (
    f"{'N':>4} {'frames':>7}  {'server late p50/p99/max ms':>27}  {'at bots p50/p99 ms':>19}  "
    f"{'round trip p50/p99 ms':>22}  {'stale':>6}  {'lost':>4}  {'CPU s/session-s server':>22}"
    f"  {'bots':>5}  load 1/5/15 min"
)


def row(r: Result) -> str:
    """One line of the table (the numbers of :class:`Result`)."""
    ls, lb, rt = r.late_server, r.late_bots, r.round_trip
    return (
        f"{r.sessions:>4} {r.frames:>7}  "
        f"{f'{pct(ls, 50):.2f} / {pct(ls, 99):.2f} / {np.max(ls):.1f}':>27}  "
        f"{f'{pct(lb, 50):.2f} / {pct(lb, 99):.2f}':>19}  "
        f"{f'{pct(rt, 50):.2f} / {pct(rt, 99):.2f}':>22}  {r.stale:>6}  {r.lost:>4}  "
        f"{r.server_cpu:>22.4f}  {r.bots_cpu:>5.3f}  "
        f"{r.load[0]:.2f} {r.load[1]:.2f} {r.load[2]:.2f}"
    )


def verdict(results: list[Result]) -> str:
    """Where the server saturates (:attr:`Result.saturated`), in one line."""
    hit = [r.sessions for r in results if r.saturated]
    top = max(r.sessions for r in results)
    if not hit:
        return f"no saturation up to N = {top}: p99 server lateness <= 20 ms, 0 samples lost"
    return f"saturates at N = {min(hit)} (p99 server lateness > 20 ms or samples lost)"


def main(argv: list[str] | None = None) -> int:
    """Run the trials of ``--sessions`` in turn and print the table (module docstring);
    returns the exit status."""
    a = parse_args(argv)
    print(f"experiment server under load: coupled sessions of two WebSocket bots at 50 Hz, "
          f"{a.duration:g} s trials, starts spread over {a.stagger:g} s, seed {a.seed}; "
          f"{os.cpu_count()} cores")  # fmt: skip
    print("load average before: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    print(HEADER, flush=True)
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-server-load-") as tmp:
        base = Path(a.out) if a.out else Path(tmp)
        for n in a.sessions:
            try:
                r = measure(n, a.duration, a.stagger, a.seed, base / f"sessions-{n}")
            except RuntimeError as exc:  # the server or a session failed: the cause
                print(f"N = {n}: {exc}", flush=True)
                return 1
            results.append(r)
            print(row(r), flush=True)
            if set(r.ends) != {"time"}:
                print(f"     trials ended: {r.ends}", flush=True)
    print(verdict(results))
    return 1 if any(r.lost for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
