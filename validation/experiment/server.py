"""The experiment's web server: one page and one WebSocket (aiohttp).

* ``GET /`` the page (``static/index.html``), ``GET /static/...`` its script.
* ``GET /ws`` the WebSocket.  Creating a session needs the server's access
  token (in the URL printed at start); joining one needs its join code, an
  unguessable ``secrets.token_urlsafe(16)``.  Without them nobody can join,
  watch or send mouse data.  The server listens on 127.0.0.1 unless told
  otherwise.
* ``/ws`` is refused (403) when its ``Host`` is not an IP address,
  ``localhost`` or a name given in :attr:`ServerConfig.allowed_hosts` (no DNS
  rebinding), or when a browser's ``Origin`` is not this server (no
  cross-site WebSocket).
* Every message is validated (:mod:`.protocol`) and rate limited per
  connection and type (:data:`.protocol.RATES`); bad ones are dropped,
  answered with an error the page shows, logged, counted by type in the
  recording's end record, and never touch the trial.
* A seat is bound to the socket that took it (:mod:`.session`); a reconnect
  needs the seat's secret.
* Nothing secret is logged: the access log shows paths without their query
  (the token, the join code), and sessions are named by a short public id.
* An HTTP connection that goes :attr:`ServerConfig.idle_timeout` seconds
  without a complete request (silent after opening, a header trickling in,
  idle after a response) is closed (aiohttp's default would wait an hour); an
  open WebSocket is pinged every 10 s and closed when it stops answering.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import secrets
import socket
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from urllib.parse import urlsplit

from aiohttp import WSCloseCode, WSMsgType, web
from aiohttp.abc import AbstractAccessLogger

from cipcore import ParameterError
from validation.experiment.finalize import close_writer
from validation.experiment.protocol import RATES, BadMessage, RateLimiter, parse
from validation.experiment.session import Seat, Session, make_bots
from validation.experiment.task import TaskSettings

log = logging.getLogger("cipval.experiment")


@dataclass
class ServerConfig:
    """Settings of a server: where recordings go and what every trial uses."""

    out_dir: Path
    engine: str = "reduced"
    duration: float = 600.0
    countdown: int = 3
    token: str = field(default_factory=lambda: secrets.token_urlsafe(16))
    #: host names (besides IP addresses and localhost) under which /ws may be reached
    allowed_hosts: tuple[str, ...] = ()
    #: seconds an HTTP connection may go without a complete request: from its opening, or
    #: since its last response, also while a header trickles in (aiohttp's keep-alive timer)
    idle_timeout: float = 15.0


#: static files and their types (every file here exists under ``static/``)
STATIC = {"app.js": "text/javascript", "style.css": "text/css"}
#: answers to invalid messages per connection (per second, burst)
ERROR_REPLIES = (2.0, 5.0)


class _AccessLog(AbstractAccessLogger):
    """Access log without query strings or headers (they carry the token and codes)."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        self.logger.info("%s %s %s %d %.1f ms", request.remote, request.method, request.path,
                         response.status, time * 1e3)  # fmt: skip


def _static(name: str) -> bytes:
    return resources.files("validation.experiment").joinpath("static", name).read_bytes()


class ExperimentServer:
    """Sessions by join code, and the request handlers."""

    def __init__(self, config: ServerConfig) -> None:
        self.config = config
        self.sessions: dict[str, Session] = {}
        self.sockets: set[web.WebSocketResponse] = set()  # open /ws connections
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
        if name not in STATIC:
            raise web.HTTPNotFound()
        return web.Response(body=_static(name), content_type=STATIC[name])

    def _host_allowed(self, request: web.Request) -> str:
        """Empty when ``request`` may open /ws, else why not (module docstring)."""
        try:
            return self._check_host(request)
        except ValueError:  # a Host or Origin that is not even a URL
            return "malformed Host or Origin"

    def _check_host(self, request: web.Request) -> str:
        name = urlsplit("//" + request.host).hostname or ""
        try:
            ipaddress.ip_address(name)
        except ValueError:
            if name != "localhost" and name not in self.config.allowed_hosts:
                return f"Host {name!r} is not an IP address, localhost or an allowed host"
        origin = request.headers.get("Origin")
        if origin is not None:
            o = urlsplit(origin)
            if o.scheme not in ("http", "https") or o.netloc.lower() != request.host.lower():
                return f"Origin {origin!r} is not this server"
        return ""

    async def shutdown(self, app: web.Application) -> None:
        # end every session first, then wait for them together: one after the other, the
        # later ones ran on while the earlier ones were being finalised
        sessions = list(self.sessions.values())
        for s in sessions:
            s.end("server_stop")
        await asyncio.gather(*(s._task for s in sessions if s._task is not None),
                             return_exceptions=True)  # fmt: skip
        await close_writer()  # the .npz worker, once every recording is finalised
        # then close every page's socket: a page waiting for the close frame otherwise hangs
        # until its own close timeout (10 s in aiohttp's client) while the server stops
        for ws in list(self.sockets):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b"server stopped")

    def _drop(self, session: Session | None, kind: str, why: str, peer: str) -> None:
        """Count (by message type; ``invalid`` when unparsable) and log a dropped message."""
        self.dropped += 1
        if session is not None:
            session.count_drop(kind)
        if self.dropped <= 100 or self.dropped % 1000 == 0:
            log.warning("dropped %s message from %s: %s (%d dropped so far)", kind, peer, why,
                        self.dropped)  # fmt: skip

    async def websocket(self, request: web.Request) -> web.WebSocketResponse:
        peer = request.remote or "?"
        refused = self._host_allowed(request)
        if refused:
            log.warning("refused /ws from %s: %s", peer, refused)
            raise web.HTTPForbidden(text=refused)
        # messages above 2 KiB are dropped by the protocol; above 64 KiB aiohttp closes the socket
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=65536)
        await ws.prepare(request)
        self.sockets.add(ws)
        session: Session | None = None
        seat: int | None = None
        limits = {kind: RateLimiter(*rate) for kind, rate in RATES.items()}
        replies = RateLimiter(*ERROR_REPLIES)

        async def refuse(kind: str, why: str) -> None:
            self._drop(session, kind, why, peer)
            if kind != "mouse" and replies.allow(time.monotonic()):
                await ws.send_json({"type": "error", "error": why})

        try:
            async for raw in ws:
                if raw.type != WSMsgType.TEXT:
                    await refuse("invalid", "not a text message")
                    continue
                try:
                    msg = parse(raw.data)
                except BadMessage as exc:
                    await refuse("invalid", str(exc))
                    continue
                kind = msg["type"]
                if not limits[kind].allow(time.monotonic()):
                    self._drop(session, kind, "above the rate limit", peer)
                elif kind == "mouse":
                    if session is None or seat is None:
                        self._drop(session, kind, "mouse data without a seat", peer)
                    else:
                        session.mouse(seat, msg["x"], msg["t"])
                elif kind == "drawn" and session is not None:
                    session.drawn(seat, msg["k"], msg["t"])
                elif kind == "client" and session is not None and seat is not None:
                    session.seats[seat].client = {k: v for k, v in msg.items() if k != "type"}
                elif kind == "create" and session is None:
                    if not secrets.compare_digest(msg["token"], self.config.token):
                        await refuse(kind, "wrong access token")
                        continue
                    try:
                        session, seat, secret = self._create(msg, ws)
                    except ParameterError as exc:
                        await refuse(kind, str(exc))
                        continue
                    await ws.send_json({**session.describe(), "type": "created", "seat": seat,
                                        "secret": secret})  # fmt: skip
                    await session.broadcast(session.describe())
                elif kind == "join" and session is None:
                    found, at, error = self._join(msg, ws)
                    if error:
                        await refuse(kind, error)
                        continue
                    session, seat = found, at
                    await ws.send_json({**session.describe(), "type": "joined", "seat": seat,
                                        "secret": session.seats[seat].secret})  # fmt: skip
                    await session.broadcast(session.describe())
                elif kind == "ready" and session is not None:
                    await session.set_ready(seat)
                elif kind == "abort" and session is not None and session.phase != "ended":
                    label = session.seats[seat].label if seat is not None else "spectator"
                    log.info("session %s: abort by %s", session.id, label)
                    session.end("abort", label)
                elif kind not in ("drawn", "client"):
                    await refuse(kind, f"{kind} is not possible now")
                else:
                    self._drop(session, kind, f"{kind} not possible now", peer)
        finally:
            self.sockets.discard(ws)
            if session is not None:
                self._leave(session, seat, ws)
        return ws

    def _create(self, msg: dict, ws) -> tuple[Session, int | None, str | None]:
        c = self.config
        settings = TaskSettings(mode=msg["mode"], duration=c.duration)
        seats = [Seat(kind=s["kind"], label=s["label"], spec=s) for s in msg["seats"]]
        make_bots(settings, seats)  # bad bot settings: an error now, not at the countdown
        session = Session(settings, c.engine, msg["trial"], seats, c.out_dir, c.countdown)
        seat = session.free_human_seat()
        secret = None
        if seat is None:
            session.spectators.append(ws)
        else:
            secret = seats[seat].take(ws)
        self.sessions[session.code] = session
        log.info("session %s created: %s, trial %d, seats %s", session.id, settings.mode,
                 msg["trial"], [(s.kind, s.label) for s in seats])  # fmt: skip
        return session, seat, secret

    def _join(self, msg: dict, ws) -> tuple[Session | None, int | None, str]:
        session = None
        for code, s in self.sessions.items():
            if secrets.compare_digest(code, msg["code"]):
                session = s
        if session is None or session.phase != "waiting":
            return None, None, "no open session with this code"
        if "secret" in msg:  # taking one's own seat back after a reload
            for i, s in enumerate(session.seats):
                if s.secret is not None and secrets.compare_digest(s.secret, msg["secret"]):
                    if s.ws is not None:
                        return None, None, "this seat is in use by another page"
                    s.ws = ws
                    log.info("session %s: %s took seat %d back", session.id, s.label, i + 1)
                    return session, i, ""
            return None, None, "wrong seat secret"
        seat = session.free_human_seat()
        if seat is None:
            return None, None, "the session is full"
        others = [s.label for i, s in enumerate(session.seats) if i != seat]
        if msg["label"] in others:
            return None, None, "the two subjects need different labels"
        session.seats[seat].take(ws)
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
    runner = web.AppRunner(server.app(), handle_signals=False, access_log_class=_AccessLog,
                           keepalive_timeout=config.idle_timeout)  # fmt: skip
    await runner.setup()
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    site = web.SockSite(runner, sock)
    await site.start()
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    return runner, f"http://{shown}:{bound}/?token={config.token}", server
