"""The experiment server over real WebSockets on 127.0.0.1, and a SIGKILL mid-trial."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import urllib.parse
from pathlib import Path

import numpy as np
import pytest

aiohttp = pytest.importorskip("aiohttp", reason="the experiment server needs aiohttp")

from helpers import until  # noqa: E402

from validation.experiment.recording import find_trials, load_trial  # noqa: E402
from validation.experiment.server import ServerConfig, start  # noqa: E402

BOT = {"kind": "bot", "beta": 21.0, "tau": 0.1, "nu": 0.6}


def _bot(label: str, seed: int) -> dict:
    return {**BOT, "label": label, "seed": seed}


async def _frames_until_end(ws) -> tuple[list[dict], dict]:
    frames = []
    while True:
        msg = await ws.receive(timeout=30)
        d = json.loads(msg.data)
        if d["type"] == "frame":
            frames.append(d)
        elif d["type"] == "end":
            return frames, d


def _run(coro):
    return asyncio.run(coro)


def test_bot_session_runs_at_50_hz_and_is_recorded(tmp_path):
    async def go():
        runner, url, _ = await start(ServerConfig(tmp_path, duration=2.0, countdown=1))
        token = urllib.parse.parse_qs(urllib.parse.urlparse(url).query)["token"][0]
        try:
            async with aiohttp.ClientSession() as s, s.ws_connect(url.split("?")[0] + "ws") as ws:
                await ws.send_json({"type": "create", "token": token, "mode": "coupled",
                                    "trial": 2, "seats": [_bot("A", 1), _bot("B", 2)]})  # fmt: skip
                created = await until(ws, "created")
                assert created["seat"] is None  # a spectator: both seats are bots
                await ws.send_json({"type": "ready"})
                return await _frames_until_end(ws)
        finally:
            await runner.cleanup()

    frames, end = _run(go())
    assert end["reason"] == "time" and end["samples"] == 101
    assert [f["k"] for f in frames] == list(range(101))
    tr = load_trial(tmp_path / end["file"])
    assert tr.attrs["end"]["reason"] == "time" and tr.attrs["trial_index"] == 2
    np.testing.assert_allclose(tr["tip_position"][0, :, 0] + 1.0, [f["tips"][1] for f in frames])
    wall = tr["wall_time"][0, :, 0]
    jitter = tr["frame_jitter"][0, :, 0]
    # frame k starts at k * 20 ms plus its recorded lateness
    np.testing.assert_allclose(wall, np.arange(101) * 0.02 + jitter, atol=1e-9)
    assert np.median(jitter) < 0.01


async def _human_pair(tmp_path, duration=30.0):
    runner, url, server = await start(ServerConfig(tmp_path, duration=duration, countdown=1))
    token = urllib.parse.parse_qs(urllib.parse.urlparse(url).query)["token"][0]
    base = url.split("?")[0] + "ws"
    s = aiohttp.ClientSession()
    a = await s.ws_connect(base)
    b = await s.ws_connect(base)
    await a.send_json({"type": "create", "token": token, "mode": "coupled", "trial": 1,
                       "seats": [{"kind": "human", "label": "A"},
                                 {"kind": "human", "label": "B"}]})  # fmt: skip
    code = (await until(a, "created"))["code"]
    await b.send_json({"type": "join", "code": code, "label": "B"})
    await until(b, "joined")
    for ws in (a, b):
        await ws.send_json({"type": "ready"})
    await until(a, "start")
    return runner, server, s, a, b


def test_bad_messages_are_dropped_and_abort_ends_the_trial(tmp_path):
    async def go():
        runner, _server, s, a, b = await _human_pair(tmp_path)
        try:
            await a.send_json({"type": "mouse", "x": 300.0})
            await b.send_json({"type": "mouse", "x": 900.0})
            for bad in ("nonsense", '{"type": "mouse", "x": NaN}', '{"type": "mouse", "x": 1e12}',
                        '{"type": "teleport"}', "x" * 5000):  # fmt: skip
                await a.send_str(bad)
            await a.send_bytes(b"\x00\x01")
            for i in range(20):
                await b.send_json({"type": "mouse", "x": 900.0 + i})
                await asyncio.sleep(0.02)
            await b.send_json({"type": "abort"})
            frames, end = await _frames_until_end(a)
            return frames, end
        finally:
            await s.close()
            await runner.cleanup()

    frames, end = _run(go())
    assert end["reason"] == "abort" and end["detail"] == "B"
    assert end["dropped_messages"] == 6
    tr = load_trial(tmp_path / end["file"])
    px = tr["mouse_pixel"][0]
    assert np.nanmax(px[:, 1]) == 919.0 and px[-1, 0] == 300.0
    # the first pixel anchors each lower end at its initial screen position
    np.testing.assert_allclose(tr["base_position"][0, 0] + [0, 1], [-0.6, 0.6])
    assert tr.time.size == len(frames) == end["samples"]


def test_closed_page_ends_the_trial_as_disconnect(tmp_path):
    async def go():
        runner, _server, s, a, b = await _human_pair(tmp_path)
        try:
            await asyncio.sleep(0.3)
            await b.close()
            return await _frames_until_end(a)
        finally:
            await s.close()
            await runner.cleanup()

    _frames, end = _run(go())
    assert end["reason"] == "disconnect" and end["detail"] == "B"
    assert load_trial(tmp_path / end["file"]).time.size == end["samples"] >= 10


def test_wrong_token_and_wrong_code_are_refused(tmp_path):
    async def go():
        runner, url, server = await start(ServerConfig(tmp_path, duration=1.0))
        base = url.split("?")[0] + "ws"
        try:
            async with aiohttp.ClientSession() as s, s.ws_connect(base) as ws:
                await ws.send_json({"type": "create", "token": "guess", "mode": "single",
                                    "trial": 1, "seats": [_bot("A", 1)]})  # fmt: skip
                e1 = await until(ws, "error")
                await ws.send_json({"type": "join", "code": "A" * 22, "label": "Z"})
                e2 = await until(ws, "error")
                await ws.send_json({"type": "mouse", "x": 10.0})  # no seat: dropped
                await ws.send_json({"type": "ready"})  # no session: dropped
                await asyncio.sleep(0.1)
                return e1, e2, server.dropped, server.sessions
        finally:
            await runner.cleanup()

    e1, e2, dropped, sessions = _run(go())
    assert "token" in e1["error"] and "code" in e2["error"]
    assert dropped == 4 and sessions == {}


def test_page_is_served(tmp_path):
    async def go():
        runner, url, _ = await start(ServerConfig(tmp_path))
        try:
            async with aiohttp.ClientSession() as s:
                async with s.get(url) as r:
                    page = await r.text()
                async with s.get(url.split("?")[0] + "static/app.js") as r:
                    js = await r.text()
                async with s.get(url.split("?")[0] + "static/../server.py") as r:
                    status = r.status
            return page, js, status
        finally:
            await runner.cleanup()

    page, js, status = _run(go())
    assert 'width="1200" height="600"' in page and "WebSocket" in js and status == 404


@contextlib.contextmanager
def _server_process(tmp_path, *options: str):
    """``experiment serve`` in a process of its own (port 0, countdown 0, ``options``):
    yields the process and the address it prints; killed at the end if still running."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(
        [sys.executable, "-m", "validation.cli.main", "experiment", "serve", "--port", "0",
         "--out", str(tmp_path), "--countdown", "0", *options],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env,
    )  # fmt: skip
    try:
        yield proc, proc.stdout.readline().split("open ")[1].strip()
    finally:
        if proc.poll() is None:
            proc.kill()


async def _start_trial(s, url: str, mode: str, seats: list):
    """Connect to the server at ``url``, create a trial of ``mode`` with ``seats`` and start
    it; the websocket."""
    token = urllib.parse.parse_qs(urllib.parse.urlparse(url).query)["token"][0]
    ws = await s.ws_connect(url.split("?")[0] + "ws")
    await ws.send_json({"type": "create", "token": token, "mode": mode, "trial": 1,
                        "seats": seats})  # fmt: skip
    await ws.send_json({"type": "ready"})
    return ws


def test_sigkill_mid_trial_loses_at_most_the_last_second(tmp_path):
    """Issue 13: a killed server keeps all but (at most) the last second of samples."""
    with _server_process(tmp_path, "--trial-duration", "600") as (proc, url):

        async def go():
            async with aiohttp.ClientSession() as s:
                ws = await _start_trial(s, url, "coupled", [_bot("A", 1), _bot("B", 2)])
                last = -1
                t_end = time.monotonic() + 3.0
                while time.monotonic() < t_end:
                    d = await until(ws, "frame")
                    last = d["k"]
                os.kill(proc.pid, signal.SIGKILL)
                await ws.close()
                return last

        last_seen = _run(go())
        proc.wait(timeout=10)
    (path,) = find_trials(tmp_path)
    assert path.suffix == ".jsonl"  # never finalised
    tr = load_trial(path)
    k = np.rint(tr.time / 0.02).astype(int)
    assert tr.attrs["end"] == {"reason": "unfinalised"}
    np.testing.assert_array_equal(k, np.arange(k.size))  # no gap
    lost = last_seen - int(k[-1])
    assert lost <= 50, f"lost {lost} frames"
    print(f"SIGKILL: last frame seen by the page {last_seen}, last on disk {k[-1]}")


def test_sigterm_finalises_the_running_trial(tmp_path):
    with _server_process(tmp_path) as (proc, url):

        async def go():
            async with aiohttp.ClientSession() as s:
                ws = await _start_trial(s, url, "single", [_bot("A", 1)])
                for _ in range(25):
                    await until(ws, "frame")
                proc.send_signal(signal.SIGTERM)
                end = await until(ws, "end")
                await ws.close()
                return end

        end = _run(go())
        assert proc.wait(timeout=20) == 0
    assert end["reason"] == "server_stop"
    tr = load_trial(tmp_path / end["file"])
    assert tr.attrs["end"]["reason"] == "server_stop" and tr.time.size == end["samples"] >= 25
