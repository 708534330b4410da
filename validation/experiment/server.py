"""The experiment's web server: one page and one WebSocket (aiohttp).

* ``GET /`` the page (``static/index.html``), ``GET /static/...`` its script.
* ``GET /ws`` the WebSocket.  Creating a session needs the server's access
  token (in the URL printed at start); joining one needs its join code, an
  unguessable ``secrets.token_urlsafe(16)``.  Without them nobody can join,
  watch or send mouse data.  The server listens on 127.0.0.1 unless told
  otherwise.
* Every message is validated (:mod:`.protocol`); bad ones are dropped and
  logged, counted in the recording's end record, and never touch the trial.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import socket
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from aiohttp import WSMsgType, web

from .protocol import BadMessage, RateLimiter, parse
from .session import Seat, Session
from .task import TaskSettings

log = logging.getLogger("cipval.experiment")


@dataclass
class ServerConfig:
    """Settings of a server: where recordings go and what every trial uses."""

    out_dir: Path
    engine: str = "reduced"
    duration: float = 600.0
    countdown: int = 3
    token: str = field(default_factory=lambda: secrets.token_urlsafe(16))


def _static(name: str) -> bytes:
    return resources.files("validation.experiment").joinpath("static", name).read_bytes()


class ExperimentServer:
    """Sessions by join code, and the request handlers."""

    def __init__(self, config: ServerConfig) -> None:
        self.config = config
        self.sessions: dict[str, Session] = {}
        self.dropped = 0

    def app(self) -> web.Application:
        app = web.Application(client_max_size=4096)
        app.router.add_get("/", self.index)
        app.router.add_get("/static/{name}", self.static)
        app.router.add_get("/ws", self.websocket)
        app.on_shutdown.append(self.shutdown)
        return app

    async def index(self, request: web.Request) -> web.Response:
        return web.Response(body=_static("index.html"), content_type="text/html")

    async def static(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        types = {"app.js": "text/javascript", "style.css": "text/css"}
        if name not in types:
            raise web.HTTPNotFound()
        return web.Response(body=_static(name), content_type=types[name])

    async def shutdown(self, app: web.Application) -> None:
        for s in list(self.sessions.values()):
            s.end("server_stop")
            if s._task is not None:
                await asyncio.gather(s._task, return_exceptions=True)

    def _drop(self, session: Session | None, why: str, peer: str) -> None:
        self.dropped += 1
        if session is not None:
            session.dropped += 1
        if self.dropped <= 100 or self.dropped % 1000 == 0:
            log.warning("dropped message from %s: %s (%d dropped so far)", peer, why, self.dropped)

    async def websocket(self, request: web.Request) -> web.WebSocketResponse:
        # messages above 2 KiB are dropped by the protocol; above 64 KiB aiohttp closes the socket
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=65536)
        await ws.prepare(request)
        peer = request.remote or "?"
        session: Session | None = None
        seat: int | None = None
        limiter = RateLimiter()
        try:
            async for raw in ws:
                if raw.type != WSMsgType.TEXT:
                    self._drop(session, "not a text message", peer)
                    continue
                try:
                    msg = parse(raw.data)
                except BadMessage as exc:
                    self._drop(session, str(exc), peer)
                    continue
                kind = msg["type"]
                if kind == "mouse":
                    if session is None or seat is None:
                        self._drop(session, "mouse data without a seat", peer)
                    elif not limiter.allow(time.monotonic()):
                        self._drop(session, "mouse messages above the rate limit", peer)
                    else:
                        session.mouse(seat, msg["x"])
                elif kind == "create" and session is None:
                    if not secrets.compare_digest(msg["token"], self.config.token):
                        self._drop(None, "create with a wrong access token", peer)
                        await ws.send_json({"type": "error", "error": "wrong access token"})
                        continue
                    session, seat = self._create(msg, ws)
                    await ws.send_json({**session.describe(), "type": "created", "seat": seat})
                    await session.broadcast(session.describe())
                elif kind == "join" and session is None:
                    session, seat, error = self._join(msg, ws)
                    if error:
                        self._drop(None, error, peer)
                        await ws.send_json({"type": "error", "error": error})
                        session = None
                        continue
                    await ws.send_json({"type": "joined", "seat": seat})
                    await session.broadcast(session.describe())
                elif kind == "ready" and session is not None:
                    await session.set_ready(seat)
                elif kind == "abort" and session is not None:
                    label = session.seats[seat].label if seat is not None else "spectator"
                    log.info("session %s: abort by %s", session.id, label)
                    session.end("abort", label)
                else:
                    self._drop(session, f"{kind} not allowed now", peer)
        finally:
            if session is not None:
                self._leave(session, seat, ws)
        return ws

    def _create(self, msg: dict, ws) -> tuple[Session, int | None]:
        c = self.config
        settings = TaskSettings(mode=msg["mode"], duration=c.duration)
        seats = [Seat(kind=s["kind"], label=s["label"], spec=s) for s in msg["seats"]]
        session = Session(settings, c.engine, msg["trial"], seats, c.out_dir, c.countdown)
        seat = session.free_human_seat()
        if seat is None:
            session.spectators.append(ws)
        else:
            seats[seat].ws = ws
        self.sessions[session.code] = session
        log.info("session %s created: %s, trial %d, seats %s", session.id, settings.mode,
                 msg["trial"], [(s.kind, s.label) for s in seats])  # fmt: skip
        return session, seat

    def _join(self, msg: dict, ws) -> tuple[Session | None, int | None, str]:
        session = None
        for code, s in self.sessions.items():
            if secrets.compare_digest(code, msg["code"]):
                session = s
        if session is None or session.phase != "waiting":
            return None, None, "no open session with this code"
        seat = session.free_human_seat()
        if seat is None:
            return None, None, "the session is full"
        others = [s.label for i, s in enumerate(session.seats) if i != seat]
        if msg["label"] in others:
            return None, None, "the two subjects need different labels"
        session.seats[seat].ws = ws
        session.seats[seat].label = msg["label"]
        session.seats[seat].spec = {"kind": "human", "label": msg["label"]}
        log.info("session %s: %s joined seat %d", session.id, msg["label"], seat + 1)
        return session, seat, ""

    def _leave(self, session: Session, seat: int | None, ws) -> None:
        if seat is None:
            if ws in session.spectators:
                session.spectators.remove(ws)
            if session.phase == "ended" or any(s.kind == "human" for s in session.seats):
                return
            label = "spectator"
        else:
            label = session.seats[seat].label
            session.seats[seat].ws = None
        if session.phase in ("countdown", "running"):
            log.info("session %s: %s disconnected", session.id, label)
            session.end("disconnect", label)
        elif session.phase == "waiting" and seat is not None:
            session.seats[seat].ready = False
        if session.phase == "ended" or not any(s.ws for s in session.seats):
            self.sessions.pop(session.code, None)


async def start(
    config: ServerConfig, host: str = "127.0.0.1", port: int = 0
) -> tuple[web.AppRunner, str, ExperimentServer]:
    """Start serving; returns the runner (``await runner.cleanup()`` stops it), the URL
    with the access token, and the server object."""
    server = ExperimentServer(config)
    runner = web.AppRunner(server.app(), handle_signals=False)
    await runner.setup()
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    site = web.SockSite(runner, sock)
    await site.start()
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    return runner, f"http://{shown}:{bound}/?token={config.token}", server
