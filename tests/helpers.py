"""Helpers shared by the test modules (``from helpers import ...``: pytest puts ``tests/`` on
``sys.path``, the directory having no ``__init__.py``)."""

from __future__ import annotations

import builtins
import fnmatch
import io
import itertools
import json
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from cipcore.registry import availability, get_engine


def engine_or_skip(name: str):
    """The registered engine ``name``; the test is skipped, with the reason, where it is absent."""
    reason = availability(name)
    if reason is not None:
        pytest.skip(f"engine {name!r} unavailable: {reason}")
    return get_engine(name)


def without_refinement(monkeypatch: pytest.MonkeyPatch) -> None:
    """Leave the ``refinement.<model>`` check out of :func:`instrument_checks` (n/a) in a
    test that asserts on the other direct checks (twin, delay): refinement steps the
    engine at dt .. dt/8, most of a slow engine's time there, and its own tests
    (tests/test_refinement.py and each engine's) hold it to the faults."""
    from validation.checks import refinement

    def not_run(model: str, *args: Any, **kwargs: Any):
        return refinement.not_run(model, "left out by the test (tests/helpers.py)")

    monkeypatch.setattr(refinement, "refinement_check", not_run)


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


# ---------------------------------------------------------------- write faults
#: the environment variable carrying a :class:`WriteFault` (JSON) into child processes, where
#: the ``sitecustomize`` of :func:`write_fault_site` installs it at start-up
WRITE_FAULT_ENV = "CIPVAL_TEST_WRITE_FAULT"
#: what a fault can break: opening a file for writing, one ``write()`` of a file object
#: opened for writing (half the data reaches the file first, as on a disk that fills up),
#: ``os.fsync`` of a file, ``os.replace`` / ``os.rename`` onto a name
WRITE_OPS = ("open", "write", "fsync", "replace")


def final_name(path: str | os.PathLike) -> str:
    """The name a temporary file of :mod:`cipcore.atomic` stands for (``.a.json.tmp12`` ->
    ``a.json``, ``.a.tmp12.gif`` -> ``a.gif``); any other name unchanged."""
    name = os.path.basename(os.fspath(path))
    m = re.fullmatch(r"\.(.+?)\.tmp\d+(\.[^.]+)?", name)
    if m is None:
        return name
    stem = m.group(1)
    return stem + m.group(2) if m.group(2) else stem


def final_path(path: str | os.PathLike) -> str:
    """``path`` with its name replaced by :func:`final_name` (absolute)."""
    full = os.path.abspath(os.fspath(path))
    return os.path.join(os.path.dirname(full), final_name(full))


@dataclass
class WriteFault:
    """Make the ``nth`` ``op`` (:data:`WRITE_OPS`; ``nth`` 0: every one) on a file whose
    final path matches the glob ``pattern`` fail with ``OSError(errno)``; each hit is
    appended to ``log``.

    Counted per process.  :meth:`install` patches ``builtins.open``, ``io.open``,
    ``os.open``, ``os.fsync``, ``os.replace`` and ``os.rename`` (pathlib, numpy, PIL,
    matplotlib, scipy's netCDF writer and ElementTree all open their files through them).
    """

    pattern: str
    op: str
    errno: int
    nth: int = 1
    log: str = ""
    seen: int = 0

    def hit(self, op: str, path: str | os.PathLike) -> bool:
        """Count ``op`` on ``path``; True when this one is the one to fail."""
        if op != self.op or not fnmatch.fnmatch(final_path(path), self.pattern):
            return False
        self.seen += 1
        if self.nth and self.seen != self.nth:  # nth 0: every one
            return False
        if self.log:
            with _REAL["open"](self.log, "a") as f:
                f.write(f"{os.getpid()} {op} {final_path(path)}\n")
        return True

    def error(self, path: str | os.PathLike) -> OSError:
        return OSError(self.errno, os.strerror(self.errno), os.fspath(path))

    def to_env(self) -> str:
        return json.dumps({k: getattr(self, k) for k in ("pattern", "op", "errno", "nth", "log")})

    def install(self, setattr_: Callable[[Any, str, Any], None] = setattr) -> None:
        """Patch the write calls (``setattr_``: ``monkeypatch.setattr`` in a test)."""
        real_open, real_os_open = _REAL["open"], _REAL["os.open"]
        real_fsync, real_replace, real_rename = _REAL["fsync"], _REAL["replace"], _REAL["rename"]

        def open_(file, mode="r", *args, **kwargs):
            writing = isinstance(file, str | bytes | os.PathLike) and set(mode) & set("wax+")
            if writing and self.hit("open", file):
                raise self.error(file)
            f = real_open(file, mode, *args, **kwargs)
            return _FaultyFile(f, self, file) if writing and self.op == "write" else f

        def os_open(path, flags, *args, **kwargs):
            if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT) and self.hit("open", path):
                raise self.error(path)
            return real_os_open(path, flags, *args, **kwargs)

        def fsync(fd):
            where = fd if isinstance(fd, int) else fd.fileno()
            try:
                path = os.readlink(f"/proc/self/fd/{where}")
            except OSError:
                path = ""
            if path and self.hit("fsync", path):
                raise self.error(path)
            return real_fsync(fd)

        def replace(src, dst, *args, **kwargs):
            if self.hit("replace", dst):
                raise self.error(dst)
            return real_replace(src, dst, *args, **kwargs)

        def rename(src, dst, *args, **kwargs):
            if self.hit("replace", dst):
                raise self.error(dst)
            return real_rename(src, dst, *args, **kwargs)

        setattr_(builtins, "open", open_)
        setattr_(io, "open", open_)
        setattr_(os, "open", os_open)
        setattr_(os, "fsync", fsync)
        setattr_(os, "replace", replace)
        setattr_(os, "rename", rename)


#: the functions :meth:`WriteFault.install` replaces, as they were at import
_REAL: dict[str, Callable[..., Any]] = {
    "open": io.open, "os.open": os.open, "fsync": os.fsync, "replace": os.replace,
    "rename": os.rename,
}  # fmt: skip


class _FaultyFile:
    """A file opened for writing whose writes count towards a ``"write"`` fault: the
    failing one writes half its data, flushes it (what a filling disk leaves) and raises."""

    def __init__(self, f: Any, fault: WriteFault, path: Any) -> None:
        self._f, self._fault, self._path = f, fault, path

    def write(self, data: Any) -> int:
        if not data:  # nothing to lose; matplotlib probes a file's type with write(b"")
            return self._f.write(data)
        if self._fault.hit("write", self._path):
            self._f.write(data[: len(data) // 2])
            self._f.flush()
            raise self._fault.error(self._path)
        return self._f.write(data)

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def __enter__(self) -> _FaultyFile:
        return self

    def __exit__(self, *exc: Any) -> Any:
        return self._f.__exit__(*exc)

    def __iter__(self) -> Any:
        return iter(self._f)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


def install_write_fault_from_env() -> None:
    """Install the fault in :data:`WRITE_FAULT_ENV`, if set (a child process at start-up)."""
    spec = os.environ.get(WRITE_FAULT_ENV)
    if spec:
        WriteFault(**json.loads(spec)).install()


def write_fault_site(directory: Path) -> Path:
    """A ``sitecustomize.py`` in ``directory`` that installs :data:`WRITE_FAULT_ENV` in every
    Python process started with ``directory`` on its ``PYTHONPATH``; returns ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "sitecustomize.py").write_text(
        "import os, sys\n"
        f"if os.environ.get({WRITE_FAULT_ENV!r}):\n"
        f"    sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "    from helpers import install_write_fault_from_env\n"
        "    install_write_fault_from_env()\n"
    )
    return directory


def forced(model: str, n_realizations: int, n_steps: int, seed: int = 3):
    """The compiled shipped ``model``, its upright state (R, S) with every pendulum tilted
    0.01 rad alike (the rod's length kept; the nonlinear terms take part) and 0.05 x the
    refinement check's band-limited open-loop motor forces (R, n, nu) from ``seed``."""
    import mujoco
    import numpy as np

    from cip.engines.drake_plant import geometry_from_mujoco
    from validation.checks.agreement import model_file
    from validation.checks.refinement import observable, open_loop_forces

    m = model_file(model)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    s = np.empty(mujoco.mj_stateSize(m, full))
    mujoco.mj_getState(m, d, s, full)
    state = np.tile(s, (n_realizations, 1))
    state[:, 1 + np.array(geometry_from_mujoco(m).qpos_theta)] = 0.01
    motors, _ = observable(m)
    ctrl = np.zeros((n_realizations, n_steps, m.nu))
    ctrl[..., motors] = 0.05 * open_loop_forces(
        n_realizations, n_steps, len(motors), m.opt.timestep, seed
    )
    return m, state, ctrl


def roll(backend_cls, m, state, ctrl, chunks: int = 2, n_envs: int | None = None):
    """The states after each step of ``backend_cls`` (a :class:`cip.runner.RolloutBackend`
    class) over ``ctrl`` in ``chunks`` calls, each continuing from the last state of the one
    before; ``n_envs`` realisations a backend (default all).  Asserts no warnings."""
    import numpy as np

    n = ctrl.shape[1]
    out = np.empty((*ctrl.shape[:2], state.shape[1]))
    backend = backend_cls(m, n_envs or state.shape[0], 1)
    edges = [round(k * n / chunks) for k in range(chunks + 1)]
    try:
        for a, b in itertools.pairwise(edges):
            backend(state if a == 0 else out[:, a - 1], ctrl[:, a:b], out[:, a:b])
        assert backend.warnings() == 0
    finally:
        close = getattr(backend, "close", None)
        if close is not None:
            close()
    return out


def tip_stretch(m, out):
    """The rod's stretch (m) of the coupled model's states ``out`` (..., S): the distance of
    the two tips, computed in float64 from the joint coordinates, less the rod's length."""
    import numpy as np

    from cip.engines.drake_plant import geometry_from_mujoco

    g = geometry_from_mujoco(m)
    q = out[..., 1 : 1 + m.nq]
    theta = [q[..., j] for j in g.qpos_theta]
    tx = [g.cart_x0[i] + q[..., g.qpos_x[i]] + g.pendulum_length[i] * np.sin(theta[i])
          for i in range(2)]  # fmt: skip
    tz = [g.pendulum_length[i] * np.cos(theta[i]) for i in range(2)]
    return np.hypot(tx[0] - tx[1], tz[0] - tz[1]) - g.rod_length
