"""Validation of the messages a page sends (JSON over the WebSocket).

Every message is a JSON object of at most :data:`MAX_MESSAGE_BYTES` bytes with a
``type``; anything else is a :class:`BadMessage`, which the server drops and
logs without touching the trial.  Messages from the page::

    {"type": "create", "token": str, "mode": "single"|"coupled", "trial": int,
     "seats": [{"kind": "human", "label": str}
               | {"kind": "bot", "label": str, "beta": float, "tau": float,
                  "nu": float, "seed": int}, ...]}   # 1 seat single, 2 coupled
    {"type": "join", "code": str, "label": str}
    {"type": "ready"}
    {"type": "join", "code": str, "label": str, "secret": str}  # a seat's reconnect
    {"type": "ready"}
    {"type": "mouse", "x": float, "t": float}        # canvas pixel, 1..1200 on screen;
                                                     # t: the page's event time (ms)
    {"type": "drawn", "k": [int, ...], "t": [float, ...]}  # frames drawn, page time (ms)
    {"type": "client", "user_agent": str, "screen": [w, h], "canvas": [w, h],
     "device_pixel_ratio": float, "zoom": float, "colors": [str, ...]}
    {"type": "abort"}

Labels and codes must match their pattern as a whole (``re.fullmatch``: a
trailing newline is refused).  Numbers are checked by type and range before
any conversion, so no value (a 400-digit integer, NaN, 1e999) raises anything
but :class:`BadMessage`.

Every message type is rate limited per connection (:class:`RateLimiter`,
:data:`RATES`): the page sends at most 100 mouse messages per second and a
few others; messages above the limit are dropped and counted.
"""

from __future__ import annotations

import json
import re
from typing import Any

from cipcore.models import get_model
from validation.cli.domains import LABEL  # a subject's label, declared once
from validation.experiment.task import MODES

MAX_MESSAGE_BYTES = 2048
#: mouse messages per second allowed on one connection (the page sends <= 100)
MOUSE_RATE = 200.0
MOUSE_BURST = 50.0
#: (messages per second, burst) allowed on one connection, by message type
RATES = {
    "mouse": (MOUSE_RATE, MOUSE_BURST),
    "drawn": (10.0, 10.0),
    "client": (1.0, 3.0),
    "create": (2.0, 5.0),
    "join": (2.0, 5.0),
    "ready": (2.0, 5.0),
    "abort": (2.0, 5.0),
}
#: client-side timestamps (ms since the page loaded) and sizes (CSS px)
CLIENT_TIME_RANGE = (0.0, 1e10)
SIZE_RANGE = (0.0, 100_000.0)
MAX_DRAWN = 60
COLOR = re.compile(r"#[0-9a-fA-F]{6}")
#: accepted mouse pixels (the canvas is 1..1200; a captured pointer may leave it)
PIXEL_RANGE = (-10_000.0, 10_000.0)
CODE = re.compile(r"[A-Za-z0-9_-]{8,64}")
TRIAL_RANGE = (1, 100_000)
BOT_RANGES = {"beta": (0.0, 2000.0), "tau": (0.001, 1.0), "nu": (0.0, 5.0)}
TYPES = ("create", "join", "ready", "mouse", "abort", "drawn", "client")


class BadMessage(ValueError):
    """A message from a page that is not valid; dropped and logged."""


def _number(msg: dict, key: str, lo: float, hi: float) -> float:
    return _value(msg.get(key), key, lo, hi)


def _value(v: Any, key: str, lo: float, hi: float) -> float:
    # int/float comparisons are exact in Python and never raise (no float(v) before the
    # range check: a huge int would raise OverflowError); NaN fails the range check
    if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= v <= hi:
        raise BadMessage(f"{key} must be a number in [{lo:g}, {hi:g}]")
    return float(v)


def _integer(msg: dict, key: str, lo: int, hi: int) -> int:
    v = msg.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise BadMessage(f"{key} must be a whole number in [{lo}, {hi}]")
    return v


def _label(v: Any, what: str = "label") -> str:
    if not isinstance(v, str) or not LABEL.fullmatch(v):
        raise BadMessage(f"{what} must be 1-32 characters from A-Z a-z 0-9 _ . -")
    return v


def _seat(s: Any) -> dict:
    if not isinstance(s, dict):
        raise BadMessage("a seat must be an object")
    kind = s.get("kind")
    if kind == "human":
        return {"kind": "human", "label": _label(s.get("label"))}
    if kind == "bot":
        out = {"kind": "bot", "label": _label(s.get("label"))}
        for key, (lo, hi) in BOT_RANGES.items():
            out[key] = _number(s, key, lo, hi)
        out["seed"] = _integer(s, "seed", 0, 2**32 - 1)
        return out
    raise BadMessage("seat kind must be 'human' or 'bot'")


def parse(text: str | bytes) -> dict:
    """Parse and validate one message; raises :class:`BadMessage`."""
    if isinstance(text, bytes):
        raise BadMessage("binary messages are not accepted")
    if len(text.encode("utf-8", "replace")) > MAX_MESSAGE_BYTES:
        raise BadMessage(f"message longer than {MAX_MESSAGE_BYTES} bytes")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):  # JSONDecodeError, too many digits
        raise BadMessage("not JSON") from None
    if not isinstance(msg, dict) or msg.get("type") not in TYPES:
        raise BadMessage(f"type must be one of {', '.join(TYPES)}")
    kind = msg["type"]
    if kind == "mouse":
        t = msg.get("t")
        return {"type": "mouse", "x": _number(msg, "x", *PIXEL_RANGE),
                "t": None if t is None else _value(t, "t", *CLIENT_TIME_RANGE)}  # fmt: skip
    if kind in ("ready", "abort"):
        return {"type": kind}
    if kind == "drawn":
        return _drawn(msg)
    if kind == "client":
        return _client(msg)
    if kind == "join":
        code = msg.get("code")
        if not isinstance(code, str) or not CODE.fullmatch(code):
            raise BadMessage("code must be a session code")
        out = {"type": "join", "code": code, "label": _label(msg.get("label"))}
        secret = msg.get("secret")
        if secret is not None:
            if not isinstance(secret, str) or not CODE.fullmatch(secret):
                raise BadMessage("secret must be a seat secret")
            out["secret"] = secret
        return out
    # create
    mode = msg.get("mode")
    if mode not in MODES:
        raise BadMessage(f"mode must be one of {', '.join(MODES)}")
    token = msg.get("token")
    if not isinstance(token, str) or len(token) > 128:
        raise BadMessage("token must be a string")
    seats = msg.get("seats")
    n = get_model(mode).n_controllers
    if not isinstance(seats, list) or len(seats) != n:
        raise BadMessage(f"{mode} needs {n} seat(s)")
    seats = [_seat(s) for s in seats]
    if n == 2 and seats[0]["label"] == seats[1]["label"]:
        raise BadMessage("the two subjects need different labels")
    return {"type": "create", "token": token, "mode": mode,
            "trial": _integer(msg, "trial", *TRIAL_RANGE), "seats": seats}  # fmt: skip


def _drawn(msg: dict) -> dict:
    ks, ts = msg.get("k"), msg.get("t")
    if not (isinstance(ks, list) and isinstance(ts, list) and len(ks) == len(ts) <= MAX_DRAWN):
        raise BadMessage(f"drawn needs lists k and t of equal length <= {MAX_DRAWN}")
    return {"type": "drawn", "k": [_integer({"k": k}, "k", 0, 10**9) for k in ks],
            "t": [_value(t, "t", *CLIENT_TIME_RANGE) for t in ts]}  # fmt: skip


def _text(v: Any, key: str, n: int) -> str:
    if not isinstance(v, str) or len(v) > n or not v.isprintable():
        raise BadMessage(f"{key} must be printable text of at most {n} characters")
    return v


def _client(msg: dict) -> dict:
    out: dict[str, Any] = {"type": "client", "user_agent": _text(msg.get("user_agent"),
                                                                 "user_agent", 512)}  # fmt: skip
    for key in ("screen", "canvas", "window"):
        v = msg.get(key)
        if not isinstance(v, list) or len(v) != 2:
            raise BadMessage(f"{key} must be [width, height] in CSS pixels")
        out[key] = [_value(x, key, *SIZE_RANGE) for x in v]
    out["device_pixel_ratio"] = _number(msg, "device_pixel_ratio", 0.01, 100.0)
    out["zoom"] = _number(msg, "zoom", 0.01, 100.0)
    colors = msg.get("colors")
    if not (isinstance(colors, list) and 1 <= len(colors) <= 2 and
            all(isinstance(c, str) and COLOR.fullmatch(c) for c in colors)):  # fmt: skip
        raise BadMessage("colors must be one or two #rrggbb colours")
    out["colors"] = colors
    return out


class RateLimiter:
    """Token bucket: ``rate`` messages per second with bursts up to ``burst``."""

    def __init__(self, rate: float = MOUSE_RATE, burst: float = MOUSE_BURST) -> None:
        self.rate, self.burst = rate, burst
        self.tokens = burst
        self.last: float | None = None

    def allow(self, now: float) -> bool:
        if self.last is not None:
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
        self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False
