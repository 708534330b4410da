"""MuJoCo's profiling timers switched off while cipval steps the CIP.

MuJoCo fills ``mjData.timer`` (seconds spent per pipeline stage) by calling the C
global ``mjcb_time`` (declared in ``mujoco.h``) at the start and end of every timed
stage, about thirty times per ``mj_step``; a NULL ``mjcb_time`` turns the timers off
(``TM_START`` reads ``mjcb_time ? mjcb_time() : 0``).  MuJoCo's Python bindings
install a steady-clock ``mjcb_time`` of their own, and ``mujoco.set_mjcb_time(None)``
leaves it installed (mujoco 4.0), so every step of a Python program pays for the
clock reads.  cipval reads no timer: the states are bit-identical with and without
them (the timers are outputs only; ``tests/test_mjtimer.py``), and they cost, measured
with ``mujoco.rollout`` on one thread (``benchmarks/bench_mujoco.py --timers``),
about a third of a single-CIP step (1.8 -> 1.2 us) and a sixth of a coupled one
(3.3 -> 2.8 us).

:func:`timers_off` sets ``mjcb_time`` to NULL through ``ctypes`` for as long as any
thread of the process is inside it, and restores the previous callback when the last
one leaves, so that a program embedding cipval keeps its timers outside cipval's
rollouts (``mjData.timer`` of data stepped inside one stays at what it held).  Where
the library or its symbol cannot be found, it changes nothing.
"""

from __future__ import annotations

import ctypes
import glob
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import mujoco

_LOCK = threading.Lock()
_depth = 0
_saved: int | None = None


def _find_callback() -> ctypes.c_void_p | None:
    """``mjcb_time`` of the MuJoCo library the bindings loaded, or None."""
    here = os.path.dirname(mujoco.__file__)
    for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
        for path in sorted(glob.glob(os.path.join(here, pattern))):
            try:
                return ctypes.c_void_p.in_dll(ctypes.CDLL(path), "mjcb_time")
            except (OSError, ValueError):
                continue
    return None


_CALLBACK = _find_callback()

#: True where :func:`timers_off` can switch the timers off (the symbol was found)
AVAILABLE = _CALLBACK is not None


@contextmanager
def timers_off() -> Iterator[None]:
    """MuJoCo's timers off inside the block, for every thread of the process; the
    previous ``mjcb_time`` back when the last thread inside leaves."""
    global _depth, _saved
    if _CALLBACK is None:
        yield
        return
    with _LOCK:
        if _depth == 0:
            _saved = _CALLBACK.value
            _CALLBACK.value = None
        _depth += 1
    try:
        yield
    finally:
        with _LOCK:
            _depth -= 1
            if _depth == 0:
                _CALLBACK.value = _saved
                _saved = None


def timers_on() -> bool:
    """True while MuJoCo's timers are on (``mjcb_time`` is set)."""
    return _CALLBACK is not None and _CALLBACK.value is not None
