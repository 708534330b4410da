"""Helpers shared by the test modules (``from helpers import ...``: pytest puts ``tests/`` on
``sys.path``, the directory having no ``__init__.py``)."""

from __future__ import annotations

import json

import pytest

from cipcore.registry import availability, get_engine


def engine_or_skip(name: str):
    """The registered engine ``name``; the test is skipped, with the reason, where it is absent."""
    reason = availability(name)
    if reason is not None:
        pytest.skip(f"engine {name!r} unavailable: {reason}")
    return get_engine(name)


def running(pid: int) -> bool:
    """True while process ``pid`` exists and is not a zombie (Linux ``/proc``)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


async def until(ws, kind: str, timeout: float = 20.0) -> dict:
    """Next JSON message of type ``kind`` on an aiohttp websocket (others are skipped).

    ``timeout`` (s) bounds the wait for each message; a closed socket fails the test.
    """
    import aiohttp

    while True:
        msg = await ws.receive(timeout=timeout)
        if msg.type != aiohttp.WSMsgType.TEXT:
            raise AssertionError(f"socket closed waiting for {kind}: {msg}")
        d = json.loads(msg.data)
        if d["type"] == kind:
            return d
