"""An engine in another program: the chunk exchange protocol over stdin/stdout.

An engine written in any language runs as a child process (``--engine-cmd
"CMD ARGS"``); :class:`ProcessRollout` is the :class:`cip.runner.RolloutBackend`
that drives it, so the delayed random-gain control (eq. (3)), the noise
draws, the recording and every check stay in cipval, and the engine only
advances the CIP's states over one delay chunk at a time under controls it is
given (the controls of a chunk of d = tau/dt steps depend only on states a
delay old, so they are known before the chunk starts).

Wire format, version 1 (all numbers little-endian IEEE-754 float64 or int64):

1. cipval writes one line of UTF-8 JSON, the **header**, ending in ``\\n``::

       {"protocol": "cipval-chunk", "version": 1, "n_realizations": R,
        "nstate": S, "nu": U, "timestep": dt, "integrator": "Euler",
        "state_layout": "mjSTATE_FULLPHYSICS",
        "joints": {"x_M1": {"qpos": i, "qvel": j}, "theta_1": {...}, ...},
        "actuators": {"u_1": k, ...},
        "parameters": {...},            # the CIP's physical quantities (SI units)
        "mjb_base64": "..."}            # the same model as a MuJoCo binary (MJB)

   ``parameters`` are :class:`cip.engines.drake_plant.CIPGeometry`'s fields: cart and
   bob masses (kg), the carts' reference x (m), pendulum lengths L (m, hinge to
   bob), the bobs' central principal inertias (kg m^2, about x, y, z; the hinge
   axis is y), the viscous damping coefficients (N s/m: a force -c_tip v_x at
   the tip along x, the tip's world x velocity, and -c_cart x' on the cart),
   gravity (m/s^2, a vector), the motors' actuator indices and gears (cart force
   = gear x control; the damping actuators take no control), the rod length
   between the tips (m; null for the single model), the qpos / qvel indices of
   each joint (a cart slides along world +x; a hinge turns about +y, theta > 0
   tilting the tip to +x).  ``timestep`` at the top level is the step the engine
   takes (``parameters.timestep`` is the same number).  A state
   vector (S values) is MuJoCo's ``mjSTATE_FULLPHYSICS``: time (s), then qpos
   (nq: cart x in m, pendulum angle in rad, per controller), qvel (nv), then
   the remaining physics state, which an engine without it passes through.
   The header also carries ``"versions": [1, 2]`` (the versions cipval speaks),
   ``"nq"`` and ``"nv"`` (the sizes of qpos and qvel),
   ``"rod"`` (coupled model: ``length`` m, MuJoCo's ``solref`` [time constant s,
   damping ratio] and ``solimp`` [dmin, dmax, width m, midpoint, power] of the
   file's soft rod; null for the single model) and ``"units"`` (the unit of every
   entry of ``parameters``): everything an engine built from scratch needs.
2. The engine answers one JSON line: ``{"protocol": "cipval-chunk", "version":
   1, "engine": "NAME"}``, or ``{"error": "why"}`` and exits.  It may add
   ``"sessions": "many"``: it then serves another session after this one (below).
   **Version 2** answers ``"version": 2`` and declares how it steps:
   ``"integrator"``, one of MuJoCo's ``Euler``, ``implicit``, ``implicitfast``,
   ``RK4`` (as MuJoCo defines them: cipval has their exact twins) or ``other``
   (then ``"order"``, its order of accuracy, is required), and ``"rod"``:
   ``soft`` (the file's solref/solimp spring-damper) or ``rigid`` (an exact
   distance constraint).  A known integrator with the soft rod is held to its
   exact twin (relative 1e-9); anything else is judged by time-step refinement
   against the exact solution (:mod:`validation.checks.refinement`: cipval then
   sends headers with ``timestep`` h/2, h/4, h/8 and each control repeated over
   the sub-steps).  A version-1 engine declares nothing: it is held to the model
   file's twin where it matches it, and judged by refinement where it does not.
3. For every chunk cipval writes a **request frame**: int64 n (1 <= n <= d,
   the steps of this chunk), the R start states (R x S float64, row-major),
   the controls (R x n x U float64: control k is held over step k).  The
   engine answers a **response frame**: int64 w (its warnings so far: failed
   steps, instabilities), then the R x n states *after* each step
   (R x n x S float64).
4. A request with n = 0 ends the session.  An engine that did not answer
   ``"sessions": "many"`` exits with status 0.  One that did reads the next line:
   another header (step 1: a new session, with nothing kept from the last one),
   or the end of its stdin, where it exits with status 0.  cipval keeps such an
   engine between sessions (:data:`IDLE_PER_COMMAND` of them per command) instead
   of starting the program for every run: a validation run holds some twenty
   sessions, and a program's start-up (its runtime, its imports, a JIT) is paid
   once.  Its stdin closes when cipval ends, however it ends.

No engine can hang a run.  The handshake must arrive within
:data:`HANDSHAKE_TIMEOUT` s and each chunk's answer within :data:`CHUNK_TIMEOUT`
s plus :data:`STEP_TIMEOUT` s per realisation-step of the chunk (R n), each
write likewise (an engine that stops reading); ``--engine-timeout S`` sets the
first two.  An engine past its time, one that exits, closes its output, sends
a short or garbled answer, a non-finite state (NaN or inf: named with its chunk,
realisation, step and entry) or breaks the protocol raises
:class:`EngineProcessError` naming the command, what was expected, the first
bytes received and the last lines of the engine's stderr, and its whole
process group (it runs in a session of its own) is killed; the CLI then exits
4 naming the engine.  The same happens to every engine still running when
cipval exits, however it exits (SIGINT and SIGTERM included).

``examples/chunk_engine.py`` is a reference implementation of the engine side
(numpy and MuJoCo only).  Anything the child writes to stderr goes on to
cipval's stderr (its last lines are kept for the error message); ``cip-validate
run`` exits 4 with the partial results when the engine breaks.
"""

from __future__ import annotations

import atexit
import base64
import collections
import json
import os
import select
import shlex
import signal
import subprocess
import sys
import threading
import time
import weakref
from dataclasses import asdict
from typing import Any, ClassVar

import mujoco
import numpy as np

from cip.engines.drake_plant import geometry_from_mujoco
from cip.engines.rigid_body import RigidBodyEngine
from cipcore.engine import Capabilities
from cipcore.params import EngineError, ParameterError

__all__ = ["DECLARED_INTEGRATORS", "DECLARED_ORDER", "DECLARED_RODS", "IDLE_PER_COMMAND",
           "PROTOCOL", "UNITS", "VERSION", "VERSIONS", "EngineProcessError", "ProcessRollout",
           "close_idle_engines", "declaration", "declared_engine_terms", "idle_engines",
           "process_engine"]  # fmt: skip

PROTOCOL, VERSION = "cipval-chunk", 1
#: the versions cipval speaks: an engine answers with the highest it speaks
VERSIONS = (1, 2)
#: what a version-2 engine may declare (module docstring)
DECLARED_INTEGRATORS = ("Euler", "implicit", "implicitfast", "RK4", "other")
DECLARED_RODS = ("soft", "rigid")
#: the order of accuracy an engine may declare: (low, high], the low end excluded
DECLARED_ORDER = (0.0, 16.0)
#: the unit of each entry of the header's ``parameters``
UNITS = {
    "n_controllers": "1", "timestep": "s", "gravity": "m/s^2", "cart_mass": "kg",
    "cart_x0": "m", "bob_mass": "kg", "pendulum_length": "m", "bob_inertia": "kg m^2",
    "tip_damping": "N s/m", "cart_damping": "N s/m", "motor_id": "actuator index",
    "motor_gear": "N per unit control", "rod_length": "m", "qpos_x": "index into qpos",
    "qpos_theta": "index into qpos", "dof_x": "index into qvel", "dof_theta": "index into qvel",
}  # fmt: skip
_I64, _F64 = np.dtype("<i8"), np.dtype("<f8")
#: seconds the engine has to answer the handshake (``--engine-timeout``)
HANDSHAKE_TIMEOUT = 60.0
#: seconds the engine has to answer a chunk, plus STEP_TIMEOUT per realisation-step of it
#: (1 ms: 500 times MuJoCo's coupled step, 20 times a Python step loop's)
CHUNK_TIMEOUT, STEP_TIMEOUT = 60.0, 1e-3
#: seconds an engine has to exit once its input is closed
EXIT_GRACE = 3.0
#: the longest handshake line read (bytes) and how much of the engine's stderr is kept
MAX_LINE, STDERR_TAIL = 1 << 16, 2048
#: engines kept between sessions per command (those that answered ``"sessions": "many"``)
IDLE_PER_COMMAND = 2
_idle: dict[tuple[str, ...], list[subprocess.Popen]] = {}
_idle_lock = threading.Lock()


class EngineProcessError(EngineError):
    """The engine's process broke the protocol (exited, answered short or with an error)."""


def _integrator(model: mujoco.MjModel) -> str:
    return mujoco.mjtIntegrator(model.opt.integrator).name.removeprefix("mjINT_").title()


def header(model: mujoco.MjModel, n_realizations: int) -> dict[str, Any]:
    """The header line's content for ``model`` (see the module docstring)."""
    obj = mujoco.mjtObj
    joints = {}
    for j in range(model.njnt):
        name = mujoco.mj_id2name(model, obj.mjOBJ_JOINT, j)
        joints[name] = {"qpos": 1 + int(model.jnt_qposadr[j]),
                        "qvel": 1 + model.nq + int(model.jnt_dofadr[j])}  # fmt: skip
    actuators = {mujoco.mj_id2name(model, obj.mjOBJ_ACTUATOR, a): a for a in range(model.nu)}
    size = mujoco.mj_sizeModel(model)
    buf = np.zeros(size, dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    params = asdict(geometry_from_mujoco(model))
    rod = None
    if model.neq:
        rod = {"length": params["rod_length"], "solref": [float(x) for x in model.eq_solref[0]],
               "solimp": [float(x) for x in model.eq_solimp[0]]}  # fmt: skip
    return {
        "protocol": PROTOCOL, "version": VERSION, "versions": list(VERSIONS),
        "n_realizations": n_realizations, "rod": rod, "units": UNITS,
        "nq": model.nq, "nv": model.nv,
        "nstate": mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS),
        "nu": model.nu, "timestep": float(model.opt.timestep),
        "integrator": _integrator(model),
        "state_layout": "mjSTATE_FULLPHYSICS", "joints": joints, "actuators": actuators,
        "parameters": params, "mjb_base64": base64.b64encode(buf.tobytes()).decode("ascii"),
    }  # fmt: skip


def _kill(proc: subprocess.Popen) -> None:
    """Kill the engine's whole process group (its own session) and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.wait()


def _end(proc: subprocess.Popen) -> None:
    """Close an engine's stdin and wait for it (its group killed after
    :data:`EXIT_GRACE` s, and at once for what it left running)."""
    try:
        proc.stdin.close()
        proc.wait(timeout=EXIT_GRACE)
    except (OSError, ValueError, subprocess.TimeoutExpired):
        pass
    _kill(proc)


def _write(proc: subprocess.Popen, data: bytes, deadline: float) -> None:
    """Write ``data`` to the engine's stdin by ``deadline`` (time.monotonic), else TimeoutError."""
    fd, view = proc.stdin.fileno(), memoryview(data)
    while view:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([], [fd], [], left)[1]:
            raise TimeoutError(f"it read {len(data) - len(view)} of the {len(data)} bytes sent")
        view = view[os.write(fd, view[: 1 << 16]) :]


def _read(proc: subprocess.Popen, want: int, deadline: float, line: bool = False) -> bytes:
    """``want`` bytes from the engine's stdout (or up to a newline, at most ``want``) by
    ``deadline``; fewer where it closed its output.  TimeoutError on the deadline, with
    what arrived in its ``received`` attribute."""
    fd, buf = proc.stdout.fileno(), bytearray()
    while len(buf) < want and not (line and buf.endswith(b"\n")):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            exc = TimeoutError(f"no answer: {len(buf)} of the {want} bytes expected")
            exc.received = bytes(buf)
            raise exc
        chunk = os.read(fd, 1 if line else min(want - len(buf), 1 << 20))
        if not chunk:
            break
        buf += chunk
    return bytes(buf)


def _drain_stderr(proc: subprocess.Popen, tail: collections.deque) -> None:
    """Pass the engine's stderr on to ours, keeping its last :data:`STDERR_TAIL` bytes."""
    out = getattr(sys.stderr, "buffer", None)
    for chunk in iter(lambda: proc.stderr.read1(4096), b""):
        tail.extend(chunk)
        if out is not None:
            try:
                out.write(chunk)
                out.flush()
            except (OSError, ValueError):
                out = None


def _close(proc: subprocess.Popen, session: dict) -> None:
    """End a session (request n = 0): the engine is kept for the next one when it serves
    many and the session ended between frames; else it ends."""
    try:
        if proc.poll() is None and not session["in_frame"]:
            _write(proc, np.zeros(1, _I64).tobytes(), time.monotonic() + 10)
    except (OSError, ValueError, TimeoutError):
        session["reusable"] = False
    if session["reusable"] and not session["in_frame"] and proc.poll() is None:
        with _idle_lock:
            idle = _idle.setdefault(session["key"], [])
            if len(idle) < IDLE_PER_COMMAND:
                idle.append(proc)
                return
    if session["in_frame"] and proc.poll() is None:
        _kill(proc)  # a frame was cut off (an interrupt): its answer is in no known state
    _end(proc)


def _take_idle(key: tuple[str, ...]) -> subprocess.Popen | None:
    """A kept engine of this command still running, or None."""
    with _idle_lock:
        idle = _idle.get(key, [])
        while idle:
            proc = idle.pop()
            if proc.poll() is None:
                return proc
            _end(proc)
    return None


def idle_engines(command: str) -> list[int]:
    """Process ids of the engines of ``command`` kept between sessions (running ones)."""
    with _idle_lock:
        return [p.pid for p in _idle.get(tuple(shlex.split(command)), []) if p.poll() is None]


@atexit.register
def close_idle_engines() -> None:
    """End every engine kept between sessions (at exit; also for tests)."""
    with _idle_lock:
        procs = [p for idle in _idle.values() for p in idle]
        _idle.clear()
    for proc in procs:
        _end(proc)


class ProcessRollout:
    """:class:`cip.runner.RolloutBackend` driving an engine process (module docstring).

    Subclassed per command by :func:`process_engine` (``command`` is the argv).
    """

    command: ClassVar[list[str]] = []
    #: seconds for the handshake, for a chunk, and per realisation-step of a chunk
    handshake_timeout: ClassVar[float] = HANDSHAKE_TIMEOUT
    chunk_timeout: ClassVar[float] = CHUNK_TIMEOUT
    step_timeout: ClassVar[float] = STEP_TIMEOUT

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        self.n_realizations = n_realizations
        self.nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self.nu = model.nu
        self.timestep = float(model.opt.timestep)
        self._warnings = 0
        self._chunks = 0  # chunks answered in this session (the next one's number - 1)
        key = tuple(self.command)
        line = (json.dumps(header(model, n_realizations)) + "\n").encode()
        kept = _take_idle(key)
        if kept is not None:
            try:  # a kept engine that cannot take the header is replaced by a new one
                self._open(kept, key, line)
                return
            except EngineProcessError:
                self._finalizer.detach()
                _kill(kept)
        try:
            proc = subprocess.Popen(self.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, start_new_session=True)  # fmt: skip
        except OSError as exc:
            cmd = shlex.join(self.command)
            raise EngineProcessError(f"cannot start engine {cmd!r}: {exc}") from None
        proc.stderr_tail = collections.deque(maxlen=STDERR_TAIL)
        threading.Thread(target=_drain_stderr, args=(proc, proc.stderr_tail), daemon=True,
                         name=f"engine-stderr-{proc.pid}").start()  # fmt: skip
        self._open(proc, key, line)

    def _open(self, proc: subprocess.Popen, key: tuple[str, ...], line: bytes) -> None:
        """Start a session on ``proc``: the header, the engine's answer."""
        self.proc = proc
        self._session = {"key": key, "reusable": False, "in_frame": False}
        self._finalizer = weakref.finalize(self, _close, proc, self._session)
        deadline = time.monotonic() + self.handshake_timeout
        try:
            _write(proc, line, deadline)
            reply = _read(proc, MAX_LINE, deadline, line=True)
        except TimeoutError as exc:
            raise self._broken(f"did not answer the handshake within "
                               f"{self.handshake_timeout:g} s ({exc})",
                               getattr(exc, "received", b"")) from None  # fmt: skip
        except OSError as exc:  # it stopped reading: what did it say before?
            try:
                said = _read(proc, MAX_LINE, time.monotonic() + 0.5, line=True)
            except (OSError, TimeoutError):
                said = b""
            raise self._broken(f"protocol error: it closed its input during the handshake "
                               f"({exc.strerror or exc})", said) from None  # fmt: skip
        if not reply.endswith(b"\n"):
            what = "closed its output" if len(reply) < MAX_LINE else "sent no newline"
            raise self._broken(f"protocol error: expected one JSON handshake line, {what}",
                               reply)  # fmt: skip
        try:
            answer = json.loads(reply)
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise self._broken('protocol error: expected a JSON line {"protocol": '
                               '"cipval-chunk", "version": ...}', reply) from None  # fmt: skip
        if isinstance(answer, dict) and "error" in answer:
            raise self._broken(f"refused the session: {answer['error']}")
        if (
            not isinstance(answer, dict)
            or answer.get("protocol", PROTOCOL) != PROTOCOL
            or (answer.get("version") not in VERSIONS)
        ):
            raise self._broken(f"protocol error: expected a {PROTOCOL} answer of version "
                               f"{' or '.join(map(str, VERSIONS))}", reply)  # fmt: skip
        self.engine_name = str(answer.get("engine", "?"))
        self._session["reusable"] = answer.get("sessions") == "many"
        try:
            self.declaration = declaration(answer)
        except ValueError as exc:
            raise self._broken(f"answered a version-2 handshake that is not valid: {exc}") from None

    def _broken(self, what: str, received: bytes | None = None) -> EngineProcessError:
        """The error naming the engine, what went wrong, the first bytes it sent and the
        end of its stderr; the engine's process group is killed (its state is unknown)."""
        try:  # a child that died: give the OS a moment to report its status
            code = self.proc.wait(timeout=0.5)
        except subprocess.TimeoutExpired:
            code = None
        self._session["in_frame"] = True  # never kept for another session
        _kill(self.proc)
        msg = f"engine {shlex.join(self.command)!r} {what}"
        if code is not None:
            msg += f" (exited with status {code})"
        if received:
            msg += f"; received {len(received)} bytes, first {bytes(received[:64])!r}"
        tail = bytes(getattr(self.proc, "stderr_tail", b"")).decode("utf-8", "replace")
        tail = " | ".join(x.strip() for x in tail.strip().splitlines()[-3:] if x.strip())
        if tail:
            msg += f"; its stderr ended: {tail[-300:]}"
        return EngineProcessError(msg)

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        n = ctrl.shape[1]
        frame = (np.array([n], _I64).tobytes() + np.ascontiguousarray(state, _F64).tobytes()
                 + np.ascontiguousarray(ctrl, _F64).tobytes())  # fmt: skip
        want = 8 + out.size * 8
        limit = self.chunk_timeout + self.step_timeout * state.shape[0] * n
        deadline = time.monotonic() + limit
        self._session["in_frame"] = True
        try:
            _write(self.proc, frame, deadline)
            data = _read(self.proc, want, deadline)
        except TimeoutError as exc:
            raise self._broken(f"did not answer a chunk of {n} steps x {state.shape[0]} "
                               f"realisations within {limit:g} s ({exc})",
                               getattr(exc, "received", b"")) from None  # fmt: skip
        except OSError as exc:
            raise self._broken(f"broke the pipe ({exc})") from None
        if len(data) != want:
            raise self._broken(f"protocol error: answered {len(data)} of the {want} bytes of "
                               f"a response frame (int64 warnings, {out.size} float64)",
                               data)  # fmt: skip
        self._chunks += 1
        states = np.frombuffer(data[8:], _F64).reshape(out.shape)
        if not np.isfinite(states).all():
            raise self._broken(self._non_finite(states, state))
        self._session["in_frame"] = False
        self._warnings = int(np.frombuffer(data[:8], _I64)[0])
        out[...] = states

    def _non_finite(self, states: np.ndarray, start: np.ndarray) -> str:
        """What :meth:`_broken` says of an answer holding NaN or inf: the chunk (its number
        in the session, its time span in s), the first realisation, step and state entry."""
        r, k, i = (int(x[0]) for x in np.nonzero(~np.isfinite(states)))
        n = states.shape[1]
        t0 = float(start[0, 0])  # a state's first entry is the time (mjSTATE_FULLPHYSICS)
        return (
            f"sent a non-finite state ({float(states[r, k, i])!r}) in its answer to chunk "
            f"{self._chunks} ({n} steps x {states.shape[0]} realisations, t = {t0:g} to "
            f"{t0 + n * self.timestep:g} s): realisation {r}, step {k + 1}, state entry "
            f"{i}"
        )

    def warnings(self) -> int:
        return self._warnings

    def close(self) -> None:
        """End the session (request n = 0; the engine is kept for the next session when
        it serves many); also done when the backend is collected."""
        self._finalizer()


def declaration(answer: dict[str, Any]) -> dict[str, Any] | None:
    """What a version-2 handshake ``answer`` declares (integrator, order, rod), checked;
    None for a version-1 answer.  Raises ValueError naming the field and its domain."""
    if answer.get("version") != 2:
        return None
    integrator, rod, order = answer.get("integrator"), answer.get("rod"), answer.get("order")
    if integrator not in DECLARED_INTEGRATORS:
        raise ValueError(f"integrator must be one of {', '.join(DECLARED_INTEGRATORS)}, "
                         f"got {integrator!r}")  # fmt: skip
    if rod not in DECLARED_RODS:
        raise ValueError(f"rod must be one of {', '.join(DECLARED_RODS)}, got {rod!r}")
    if order is not None or integrator == "other":
        ok = isinstance(order, int | float) and not isinstance(order, bool)
        lo, hi = DECLARED_ORDER
        if not (ok and lo < order <= hi):
            raise ValueError(f"order must be a number in ({lo:g}, {hi:g}], got {order!r}")
        order = float(order)
    return {"integrator": integrator, "order": order, "rod": rod}


def _probe(backend: type[ProcessRollout]) -> dict[str, Any] | None:
    """The engine's declaration, read from one handshake on the shipped coupled model (the
    engine is kept for the next session when it serves many)."""
    from cip.mjcf_params import load_model_file, shipped_model_path

    rollout = backend(load_model_file(shipped_model_path("coupled")), 1, 1)
    try:
        return rollout.declaration
    finally:
        rollout.close()


def declared_engine_terms(decl: dict[str, Any] | None) -> dict[str, Any]:
    """The :class:`~cip.engines.rigid_body.RigidBodyEngine` settings and capabilities of a
    process engine that declared ``decl`` (None: version 1, nothing declared)."""
    if decl is None:
        return {"integrators": ("Euler",), "caps": {
            "integrator": "undeclared", "declared": False, "rod": "soft",
            "twin": "the model file's terms, soft rod and integrator, where the engine "
                    "matches it (it declared nothing)"}}  # fmt: skip
    integrator, order, rod = decl["integrator"], decl["order"], decl["rod"]
    caps = {"integrator": integrator, "order": order, "rod": rod, "declared": True, "twin": None}
    if integrator != "other" and rod == "soft":
        caps["twin"] = (f"the model file's terms, its soft rod and the declared {integrator} "
                        "as MuJoCo defines it")  # fmt: skip
        return {"integrators": (), "caps": caps}
    # no exact twin: the envelope of the agreement margins steps the nearest one
    nearest = "RK4" if (order or 1.0) >= 2 else "Euler"

    def builder(mapping):
        return {**mapping.twin_terms(), "integrator": nearest}

    return {"integrators": (), "caps": caps, "twin_builder": builder}


def process_engine(
    command: str, name: str = "command", timeout: float | None = None
) -> RigidBodyEngine:
    """A registry engine that runs ``command`` (split like a POSIX shell) as its engine.

    Its capabilities are those the suite holds an external rigid-body engine to:
    float64 on the CPU, deterministic, MuJoCo's trajectory tolerance 1e-2 to the
    reduced model; it offers no linearisation.  How it steps is what its handshake
    declares (version 2; :func:`declared_engine_terms`), read from one session started
    here.  ``timeout`` (s) replaces :data:`HANDSHAKE_TIMEOUT` and :data:`CHUNK_TIMEOUT`.
    One process per realisation block; the blocks run one at a time.
    """
    argv = shlex.split(command)
    if not argv:
        raise ParameterError("--engine-cmd: empty command")
    attrs: dict[str, Any] = {"command": argv}
    if timeout is not None:  # --engine-timeout: the handshake's and each chunk's base
        attrs.update(handshake_timeout=float(timeout), chunk_timeout=float(timeout))
    backend = type("ProcessRollout_" + name.replace("-", "_"), (ProcessRollout,), attrs)
    terms = declared_engine_terms(_probe(backend))  # an engine that breaks: EngineProcessError
    return RigidBodyEngine(
        name=name,
        capabilities=Capabilities(precision="float64", device="cpu", rigid_body=True,
                                  family="external process", trajectory_tolerance=1e-2,
                                  **terms["caps"]),
        backend=lambda: backend,
        max_threads=1,
        notes=f"external engine process: {command}",
        integrators=terms["integrators"],
        twin_builder=terms.get("twin_builder"),
    )  # fmt: skip
