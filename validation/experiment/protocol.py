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
    {"type": "mouse", "x": float}                    # canvas pixel, 1..1200 on screen
    {"type": "abort"}

Mouse messages are also rate limited per connection (:class:`RateLimiter`):
the page sends at most 100 per second; a burst above :data:`MOUSE_RATE` per
second is dropped.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

from cipcore.models import get_model

from .task import MODES

MAX_MESSAGE_BYTES = 2048
#: mouse messages per second allowed on one connection (the page sends <= 100)
MOUSE_RATE = 200.0
MOUSE_BURST = 50.0
#: accepted mouse pixels (the canvas is 1..1200; a captured pointer may leave it)
PIXEL_RANGE = (-10_000.0, 10_000.0)
LABEL = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")
CODE = re.compile(r"^[A-Za-z0-9_-]{8,64}$")
TRIAL_RANGE = (1, 100_000)
BOT_RANGES = {"beta": (0.0, 2000.0), "tau": (0.001, 1.0), "nu": (0.0, 5.0)}
TYPES = ("create", "join", "ready", "mouse", "abort")


class BadMessage(ValueError):
    """A message from a page that is not valid; dropped and logged."""


def _number(msg: dict, key: str, lo: float, hi: float) -> float:
    v = msg.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise BadMessage(f"{key} must be a finite number")
    if not lo <= v <= hi:
        raise BadMessage(f"{key} must be in [{lo}, {hi}], got {v}")
    return float(v)


def _integer(msg: dict, key: str, lo: int, hi: int) -> int:
    v = msg.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise BadMessage(f"{key} must be an integer in [{lo}, {hi}]")
    return v


def _label(v: Any, what: str = "label") -> str:
    if not isinstance(v, str) or not LABEL.match(v):
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
    except (json.JSONDecodeError, RecursionError):
        raise BadMessage("not JSON") from None
    if not isinstance(msg, dict) or msg.get("type") not in TYPES:
        raise BadMessage(f"type must be one of {', '.join(TYPES)}")
    kind = msg["type"]
    if kind == "mouse":
        return {"type": "mouse", "x": _number(msg, "x", *PIXEL_RANGE)}
    if kind in ("ready", "abort"):
        return {"type": kind}
    if kind == "join":
        code = msg.get("code")
        if not isinstance(code, str) or not CODE.match(code):
            raise BadMessage("code must be a session code")
        return {"type": "join", "code": code, "label": _label(msg.get("label"))}
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
