"""Faults in the code the engines and the reference share, and the anchor that catches each.

A mistake in :mod:`cipcore` moves the full model, the exact twin and the
reduced model alike, so every full-vs-reduced and full-vs-twin comparison
passes; only an anchor (:mod:`validation.checks.anchors`) that compares the shared
code with something outside it can see it.  Each fault here patches the shared
code for the duration of a ``with`` block, consistently for every user:

* ``shared_noise_scale``: ``BalanceParams.noise_scale`` returns (1 + s) nu /
  sqrt(dt) (the gain noise's strength, in every engine and the reference);
* ``shared_alpha``: the shared default alpha is (1 + s) x 22 (every
  ``BalanceParams`` made without an explicit alpha: the controllers, the
  reduced model, the characteristic roots).

:data:`SHARED_CATALOGUE` lists the sizes the selftest must flag at every seed.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from cipcore.params import BalanceParams
from validation.checks.stats import FAIL


@dataclass(frozen=True)
class SharedFault:
    """A patch of the shared code (``size`` relative)."""

    kind: str
    size: float
    unit: str
    description: str
    patch: Callable[[float], contextlib.AbstractContextManager]

    def applied(self) -> contextlib.AbstractContextManager:
        return self.patch(self.size)


@contextlib.contextmanager
def _noise_scale(s: float) -> Iterator[None]:
    old = BalanceParams.__dict__["noise_scale"]
    BalanceParams.noise_scale = property(lambda p: (1.0 + s) * p.nu / math.sqrt(p.dt))
    try:
        yield
    finally:
        BalanceParams.noise_scale = old


@contextlib.contextmanager
def _alpha(s: float) -> Iterator[None]:
    init = BalanceParams.__init__
    old = init.__defaults__
    init.__defaults__ = (old[0] * (1.0 + s), *old[1:])
    try:
        yield
    finally:
        init.__defaults__ = old


SHARED_FAULT_TYPES: dict[str, Callable[[float], SharedFault]] = {
    "shared_noise_scale": lambda s: SharedFault(
        "shared_noise_scale", s, "relative", "gain noise strength nu/sqrt(dt) x (1 + s), shared",
        _noise_scale,
    ),
    "shared_alpha": lambda s: SharedFault(
        "shared_alpha", s, "relative", "default alpha x (1 + s), shared", _alpha
    ),
}  # fmt: skip

SHARED_CATALOGUE: tuple[tuple[str, float], ...] = (
    ("shared_noise_scale", 0.1),
    ("shared_alpha", 0.01),
)


def flagged_by_shared(fault: SharedFault | None, seed: int) -> list[str]:
    """Names of the anchors that fail with ``fault`` applied (the shipped model files)."""
    from validation.checks.anchors import anchor_checks

    with fault.applied() if fault is not None else contextlib.nullcontext():
        checks = anchor_checks(seed)
    return [c.name for c in checks if c.status == FAIL]


def shared_rows(seed: int, kinds: list[str] | None = None) -> list[dict]:
    """One selftest row per catalogued shared-code fault."""
    rows = []
    for kind, size in SHARED_CATALOGUE:
        if kinds and kind not in kinds:
            continue
        fault = SHARED_FAULT_TYPES[kind](size)
        t = time.perf_counter()
        by = flagged_by_shared(fault, seed)
        rows.append({"path": "shared", "fault": kind, "size": size, "unit": fault.unit,
                     "description": fault.description, "flagged": bool(by), "by": by,
                     "seconds": round(time.perf_counter() - t, 2)})  # fmt: skip
    return rows


def shared_power(kind: str, seed: int, iterations: int = 12) -> dict:
    """Smallest flagged relative size of a shared-code fault (geometric bisection, 1e-12 up)."""
    size = dict(SHARED_CATALOGUE)[kind]
    build = SHARED_FAULT_TYPES[kind]
    hi, lo = abs(size), 1e-12
    sign = math.copysign(1.0, size)
    if not flagged_by_shared(build(sign * hi), seed):
        return {"path": "shared", "fault": kind, "smallest_flagged": None, "note": "not flagged"}
    if flagged_by_shared(build(sign * lo), seed):
        return {"path": "shared", "fault": kind, "smallest_flagged": sign * lo, "deviation": lo,
                "unit": "relative", "note": "flagged down to the bisection's floor"}  # fmt: skip
    for _ in range(iterations):
        mid = math.sqrt(hi * lo)
        if flagged_by_shared(build(sign * mid), seed):
            hi = mid
        else:
            lo = mid
    return {"path": "shared", "fault": kind, "smallest_flagged": sign * hi, "deviation": hi,
            "missed_deviation": lo, "unit": "relative"}  # fmt: skip
