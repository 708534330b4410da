"""The experiment server's doors, each closed: every test here fails when its door reopens.

Seats bound to their socket (a reconnect needs the seat's secret), labels matched
whole, bot settings checked before the countdown, number parsing that cannot raise,
Host/Origin checks, no secrets in the log, rate limits on every message type counted
in the recording, header and idle timeouts, no missing static file, and the client
side kept in the recording.  All on 127.0.0.1 with in-process servers.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import urllib.parse

import pytest

aiohttp = pytest.importorskip("aiohttp", reason="the experiment server needs aiohttp")

from helpers import until  # noqa: E402

from validation.experiment.protocol import BadMessage, parse  # noqa: E402
from validation.experiment.recording import load_trial  # noqa: E402
from validation.experiment.server import STATIC, ServerConfig, start  # noqa: E402

HUMANS = [{"kind": "human", "label": "A"}, {"kind": "human", "label": "B"}]
BIG = int("9" * 400)


class Server:
    """An in-process server, its token and an HTTP client session."""

    def __init__(self, tmp_path, **config):
        self.config = ServerConfig(tmp_path, **{"duration": 30.0, "countdown": 0, **config})

    async def __aenter__(self):
        self.runner, self.url, self.server = await start(self.config)
        self.token = urllib.parse.parse_qs(urllib.parse.urlparse(self.url).query)["token"][0]
        self.base = self.url.split("?")[0]
        self.http = aiohttp.ClientSession()
        return self

    async def __aexit__(self, *exc):
        await self.http.close()
        await self.runner.cleanup()

    def ws(self, **kw):
        return self.http.ws_connect(self.base + "ws", **kw)

    async def create(self, ws, mode="coupled", seats=HUMANS, trial=1) -> dict:
        await ws.send_json({"type": "create", "token": self.token, "mode": mode,
                            "trial": trial, "seats": seats})  # fmt: skip
        return await until(ws, "created")


def test_a_freed_seat_cannot_be_taken_over_only_its_secret_takes_it_back(tmp_path):
    async def go():
        async with Server(tmp_path) as srv:
            a = await srv.ws()
            created = await srv.create(a)
            code, secret_a = created["code"], created["secret"]
            async with srv.ws() as b:
                await b.send_json({"type": "join", "code": code, "label": "B"})
                assert (await until(b, "joined"))["seat"] == 1
                await a.close()  # A's page closes while waiting: seat 0 stays A's
                await asyncio.sleep(0.1)
                async with srv.ws() as c:
                    for label in ("A", "C"):
                        await c.send_json({"type": "join", "code": code, "label": label})
                        assert "full" in (await until(c, "error"))["error"]
                    await c.send_json({"type": "join", "code": code, "label": "A",
                                       "secret": "x" * 22})  # fmt: skip
                    assert "secret" in (await until(c, "error"))["error"]
                    # B's page cannot take A's seat either: a socket holds one seat
                    await b.send_json({"type": "join", "code": code, "label": "A"})
                    assert "not possible" in (await until(b, "error"))["error"]
                    await c.send_json({"type": "join", "code": code, "label": "A",
                                       "secret": secret_a})  # fmt: skip
                    back = await until(c, "joined")
                    assert back["seat"] == 0 and back["secret"] == secret_a
                    # while A's new page holds the seat, the secret cannot take it again
                    async with srv.ws() as d:
                        await d.send_json({"type": "join", "code": code, "label": "A",
                                           "secret": secret_a})  # fmt: skip
                        assert "in use" in (await until(d, "error"))["error"]

    asyncio.run(go())


@pytest.mark.parametrize("label", ["A\n", "A\r\n", "\nA", "A B", "", "a" * 33])
def test_labels_are_matched_whole(label):
    with pytest.raises(BadMessage, match="label"):
        parse(json.dumps({"type": "join", "code": "c" * 22, "label": label}))
    with pytest.raises(BadMessage):
        parse(json.dumps({"type": "create", "token": "t", "mode": "single", "trial": 1,
                          "seats": [{"kind": "human", "label": label}]}))  # fmt: skip


def test_a_label_ending_in_a_newline_is_refused_on_the_socket(tmp_path):
    async def go():
        async with Server(tmp_path) as srv, srv.ws() as a:
            seats = [{"kind": "human", "label": "A\n"}]
            await a.send_json({"type": "create", "token": srv.token, "mode": "single",
                               "trial": 1, "seats": seats})  # fmt: skip
            return await until(a, "error"), srv.server.sessions

    err, sessions = asyncio.run(go())
    assert "label" in err["error"] and sessions == {}


def test_a_bot_delay_off_the_time_step_is_an_error_before_any_countdown(tmp_path):
    async def go():
        async with Server(tmp_path, countdown=1) as srv, srv.ws() as a:
            bot = {"kind": "bot", "label": "A", "beta": 21.0, "tau": 0.0105, "nu": 0.6,
                   "seed": 1}  # fmt: skip
            await a.send_json({"type": "create", "token": srv.token, "mode": "single",
                               "trial": 1, "seats": [bot]})  # fmt: skip
            return await until(a, "error"), srv.server.sessions

    err, sessions = asyncio.run(go())
    assert "tau" in err["error"] and "whole number" in err["error"] and sessions == {}


@pytest.mark.parametrize(
    "msg",
    [
        {"type": "mouse", "x": BIG},
        {"type": "mouse", "x": -BIG},
        {"type": "mouse", "x": 1.0, "t": BIG},
        {"type": "drawn", "k": [BIG], "t": [1.0]},
        {"type": "create", "token": "t", "mode": "single", "trial": BIG,
         "seats": [{"kind": "human", "label": "A"}]},
        {"type": "create", "token": "t", "mode": "single", "trial": 1,
         "seats": [{"kind": "bot", "label": "A", "beta": BIG, "tau": 0.1, "nu": 0.6,
                    "seed": 1}]},
        {"type": "create", "token": "t", "mode": "single", "trial": 1,
         "seats": [{"kind": "bot", "label": "A", "beta": 21, "tau": 0.1, "nu": 0.6,
                    "seed": BIG}]},
    ],
)  # fmt: skip
def test_huge_integers_are_bad_messages_not_overflow_errors(msg):
    with pytest.raises(BadMessage):
        parse(json.dumps(msg))


def test_a_huge_integer_leaves_the_trial_running(tmp_path):
    async def go():
        async with Server(tmp_path) as srv, srv.ws() as a:
            await srv.create(a, "single", [{"kind": "human", "label": "A"}])
            await a.send_json({"type": "ready"})
            await until(a, "start")
            await a.send_str('{"type": "mouse", "x": ' + "9" * 400 + "}")
            await a.send_json({"type": "mouse", "x": 400.0})
            for _ in range(5):
                await until(a, "frame")
            await a.send_json({"type": "abort"})
            return await until(a, "end")

    end = asyncio.run(go())
    assert end["reason"] == "abort" and end["dropped_by_type"] == {"invalid": 1}


@pytest.mark.parametrize(
    ("headers", "allowed"),
    [
        ({}, True),
        ({"Origin": "http://{host}"}, True),
        ({"Origin": "http://evil.example"}, False),
        ({"Origin": "null"}, False),
        ({"Host": "evil.example:80"}, False),
        ({"Host": "["}, False),
        ({"Host": "localhost:{port}", "Origin": "http://localhost:{port}"}, True),
    ],
)
def test_origin_and_host_are_checked_on_ws(tmp_path, headers, allowed):
    async def go():
        async with Server(tmp_path) as srv:
            u = urllib.parse.urlsplit(srv.base)
            h = {k: v.format(host=u.netloc, port=u.port) for k, v in headers.items()}
            try:
                async with srv.ws(headers=h) as ws:
                    await srv.create(ws, "single", [{"kind": "human", "label": "A"}])
                return True
            except aiohttp.WSServerHandshakeError as exc:
                assert exc.status == 403
                return False

    assert asyncio.run(go()) is allowed


def test_no_token_or_join_code_in_the_log(tmp_path, caplog):
    caplog.set_level(logging.INFO)

    async def go():
        async with Server(tmp_path) as srv:
            async with srv.http.get(srv.url, headers={"Referer": srv.url}) as r:
                assert r.status == 200
            a = await srv.ws()
            code = (await srv.create(a))["code"]
            async with srv.http.get(srv.base + "?code=" + code) as r:
                assert r.status == 200
            async with srv.ws() as b:
                await b.send_json({"type": "join", "code": code, "label": "B"})
                await until(b, "joined")
            await a.close()
            return srv.token, code

    token, code = asyncio.run(go())
    text = caplog.text
    assert "GET / 200" in text and "joined seat 2" in text  # the access log is on
    assert token not in text and code not in text


def test_every_message_type_is_rate_limited_and_counted_in_the_recording(tmp_path):
    async def go():
        async with Server(tmp_path) as srv, srv.ws() as a, srv.ws() as b:
            code = (await srv.create(a))["code"]
            await b.send_json({"type": "join", "code": code, "label": "B"})
            await until(b, "joined")
            await until(a, "session")
            for _ in range(200):  # a flood of ready while waiting: few reach the partner
                await b.send_json({"type": "ready"})
            await asyncio.sleep(0.2)
            seen = 0
            while True:
                try:
                    m = await a.receive(timeout=0.2)
                except TimeoutError:
                    break
                seen += json.loads(m.data)["type"] == "session"
            await a.send_json({"type": "ready"})
            await until(a, "start")
            client = {"type": "client", "user_agent": "x", "screen": [1, 1], "canvas": [1, 1],
                      "window": [1, 1], "device_pixel_ratio": 1, "zoom": 1,
                      "colors": ["#000000"]}  # fmt: skip
            for msg in ({"type": "ready"}, client, {"type": "drawn", "k": [1], "t": [1.0]},
                        {"type": "mouse", "x": 500.0}):  # fmt: skip
                for _ in range(300):
                    await a.send_json(msg)
            await a.send_json({"type": "abort"})
            return seen, await until(a, "end"), srv.server.dropped

    seen, end, dropped = asyncio.run(go())
    assert seen <= 8  # burst 5 plus 2 per second, not 200
    by = end["dropped_by_type"]  # the session's drops, before and during the trial
    assert by["ready"] >= 190 + 290 and by["client"] >= 295 and by["drawn"] >= 285
    assert by["mouse"] >= 200  # 300 in a few ms against a burst of 50
    assert end["dropped_messages"] == sum(by.values()) == dropped


async def _closed_within(reader, seconds: float) -> bool:
    try:
        while await asyncio.wait_for(reader.read(4096), seconds):
            pass
        return True
    except ConnectionError:  # reset by the server
        return True
    except TimeoutError:
        return False


def test_half_open_connections_are_closed_and_websockets_are_not(tmp_path):
    async def go():
        async with Server(tmp_path, idle_timeout=0.4) as srv:
            u = urllib.parse.urlsplit(srv.base)
            silent = await asyncio.open_connection(u.hostname, u.port)
            partial = await asyncio.open_connection(u.hostname, u.port)
            partial[1].write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never ends the header
            trickle = await asyncio.open_connection(u.hostname, u.port)
            idle = await asyncio.open_connection(u.hostname, u.port)
            idle[1].write(b"GET /static/app.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            async with srv.ws() as ws:  # an open WebSocket outlives the idle timeout
                for _ in range(10):  # a header a byte every 0.1 s
                    try:
                        trickle[1].write(b"X")
                        await trickle[1].drain()
                    except ConnectionError:  # closed by the server
                        break
                    await asyncio.sleep(0.1)
                created = await srv.create(ws, "single", [{"kind": "human", "label": "A"}])
            conns = (silent, partial, trickle, idle)
            return [await _closed_within(c[0], 1.5) for c in conns], created

    closed, created = asyncio.run(go())
    assert closed == [True, True, True, True] and created["seat"] == 0


def test_every_static_file_exists_and_the_page_uses_them(tmp_path):
    async def go():
        async with Server(tmp_path) as srv:
            async with srv.http.get(srv.url) as r:
                page = await r.text()
            status = {}
            for name in STATIC:
                async with srv.http.get(srv.base + "static/" + name) as r:
                    status[name] = (r.status, len(await r.read()))
            return page, status

    page, status = asyncio.run(go())
    assert all(s == 200 and n > 100 for s, n in status.values()), status
    assert set(re.findall(r'"/static/([^"]+)"', page)) == set(STATIC)


def test_the_recording_keeps_the_client_side(tmp_path):
    client = {"type": "client", "user_agent": "Mozilla/5.0 test", "screen": [1920, 1080],
              "canvas": [1200, 600], "window": [1260, 820], "device_pixel_ratio": 2,
              "zoom": 1.25, "colors": ["#c0392b"]}  # fmt: skip

    async def go():
        async with Server(tmp_path) as srv, srv.ws() as a:
            await srv.create(a, "single", [{"kind": "human", "label": "A"}])
            await a.send_json(client)
            await a.send_json({"type": "ready"})
            await until(a, "start")
            for i in range(5):
                await a.send_json({"type": "mouse", "x": 400.0 + i, "t": 1000.0 + 10 * i})
                f = await until(a, "frame")
            await a.send_json({"type": "drawn", "k": [f["k"]], "t": [1234.5]})
            await asyncio.sleep(0.1)
            await a.send_json({"type": "abort"})
            return await until(a, "end")

    end = asyncio.run(go())
    tr = load_trial(tmp_path / end["file"])
    info = tr.attrs["client"][0]
    assert info["user_agent"] == "Mozilla/5.0 test" and info["zoom"] == 1.25
    assert info["screen"] == [1920, 1080] and info["colors"] == ["#c0392b"]
    ev = tr.attrs["client_events"]
    assert ev["mouse"]["x"] == [400.0, 401.0, 402.0, 403.0, 404.0]
    assert ev["mouse"]["page_time"] == pytest.approx([1.0, 1.01, 1.02, 1.03, 1.04])
    arrivals = ev["mouse"]["arrival"]
    assert arrivals == sorted(arrivals) and 0 <= arrivals[0] < arrivals[-1] < 5
    assert ev["drawn"]["page_time"] == [1.2345] and ev["drawn"]["seat"] == [0]
