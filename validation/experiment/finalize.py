"""Recordings finalised off the server's event loop.

One server runs every session on one event loop; finalising a recording on it held
every other session's frames: the end record's ``fsync`` (a second or more on a busy
disk) and the parse of the whole log into the ``.npz`` (1.2 s for a 10-minute coupled
trial).  On a thread, the parse still held a 50 Hz loop's frames by 60 to 490 ms (the
GIL).  So :func:`finalize` closes the log on a thread and has the ``.npz`` written by
a worker process (:class:`NpzWriter`): one per event loop, started at its first
file, writing one file at a time (the server's ``fsync`` and parse then cost the loop
about 2 ms).  The worker reads the stems on its standard input and exits when that
closes: when the server stops (:func:`close_writer`) or is killed, after the file in
hand, so no process outlives the server for longer than one file.  Should the worker
fail, the ``.npz`` is written on a thread, where an error of the write itself (a full
disk) is raised.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import subprocess
import sys
import weakref
from pathlib import Path
from typing import Any

from validation.experiment.recording import Recorder, write_npz

log = logging.getLogger("cipval.experiment")

#: the worker: a JSON string (a recording's stem) per line in, "ok" or "error ..." out
WORKER = """
import json, sys
from validation.experiment.recording import write_npz
for line in sys.stdin:
    try:
        write_npz(json.loads(line))
        print("ok", flush=True)
    except Exception as exc:
        print(json.dumps(f"error {type(exc).__name__}: {exc}"), flush=True)
"""


class NpzWriter:
    """The worker process of one event loop (module docstring)."""

    def __init__(self) -> None:
        self.proc: asyncio.subprocess.Process | None = None
        self.lock = asyncio.Lock()

    async def _start(self) -> asyncio.subprocess.Process:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        return await asyncio.create_subprocess_exec(
            sys.executable, "-c", WORKER, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL, env=env,
        )  # fmt: skip

    async def write(self, stem: Path) -> str:
        """Have the worker write ``<stem>.npz``; returns "" when it did, else why not."""
        async with self.lock:
            try:
                if self.proc is None or self.proc.returncode is not None:
                    self.proc = await self._start()
                self.proc.stdin.write((json.dumps(str(stem)) + "\n").encode())
                await self.proc.stdin.drain()
                answer = (await self.proc.stdout.readline()).decode("utf-8", "replace").strip()
            except (OSError, ConnectionError) as exc:  # no worker could be started or reached
                self._discard()
                return str(exc)
            if answer == "ok":
                return ""
            if answer.startswith('"'):
                return json.loads(answer)
            self._discard()
            return "the worker process ended"

    def _discard(self) -> None:
        """Forget a worker that failed (killed if it still runs); the next file starts one."""
        if self.proc is not None and self.proc.returncode is None:
            try:
                self.proc.kill()
            except ProcessLookupError:
                pass
        self.proc = None

    async def close(self) -> None:
        """Close the worker's input and wait for it to end."""
        async with self.lock:
            if self.proc is not None and self.proc.returncode is None:
                self.proc.stdin.close()
                await self.proc.wait()


_WRITERS: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, NpzWriter] = (
    weakref.WeakKeyDictionary()
)


def _writer() -> NpzWriter:
    loop = asyncio.get_running_loop()
    if loop not in _WRITERS:
        _WRITERS[loop] = NpzWriter()
    return _WRITERS[loop]


async def finalize(rec: Recorder, end: dict) -> Path:
    """Close ``rec`` with ``end`` on a thread and write its ``.npz`` in the worker
    (module docstring); returns the ``.npz``'s path.  A cancelled wait still waits for
    the file: a recording is always finalised."""
    loop = asyncio.get_running_loop()
    await unless_cancelled(loop.run_in_executor(None, rec.close, end))
    why = await unless_cancelled(asyncio.ensure_future(_writer().write(rec.stem)))
    if not why:
        return rec.stem.with_suffix(".npz")
    log.warning("recording %s: .npz written on a thread (the worker: %s)", rec.stem.name, why)
    return await unless_cancelled(loop.run_in_executor(None, write_npz, rec.stem))


async def close_writer() -> None:
    """End this event loop's worker, if it has one (when the server stops)."""
    writer = _WRITERS.pop(asyncio.get_running_loop(), None)
    if writer is not None:
        await writer.close()


async def unless_cancelled(future: asyncio.Future) -> Any:
    """``await future``; when the waiting task is cancelled, wait for it all the same."""
    try:
        return await asyncio.shield(future)
    except asyncio.CancelledError:
        while not future.done():
            await asyncio.sleep(0.01)
        raise
