"""A second lane of a run: stages computed in order on a thread beside the main one.

``cip-validate run`` computes the engine stages on the main thread and the
stages that need only the reduced model (and the rod-length study) on a lane,
so that the two cores stay busy through each stage's serial parts (estimators,
bootstraps, Python between chunks).  Every stage has its own seeds, so its
numbers do not depend on what runs beside it.

The lane is a daemon thread: an interrupted run does not wait for the lane's
current stage (the engines' and numba's work releases the GIL, so it runs truly
in parallel).  A stage that raises keeps its exception for :meth:`Lane.result`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from concurrent.futures import TimeoutError as WaitTimeout
from typing import Any


class Lane:
    """Compute ``names`` in order with ``compute(name)`` on a daemon thread.

    :meth:`result` waits for one stage: (value, wall seconds), or raises what
    the stage raised.  :meth:`stop` asks the lane to start no further stage.
    """

    def __init__(self, names: Sequence[str], compute: Callable[[str], Any]) -> None:
        self.names = tuple(names)
        self._futures = {name: Future() for name in self.names}
        self._stop = threading.Event()
        self._compute = compute
        self._thread = threading.Thread(target=self._run, name="cip-validate lane", daemon=True)
        self._thread.start()

    def __contains__(self, name: str) -> bool:
        return name in self._futures

    def _run(self) -> None:
        for name in self.names:
            fut = self._futures[name]
            if self._stop.is_set() or not fut.set_running_or_notify_cancel():
                fut.cancel()
                continue
            t = time.perf_counter()
            try:
                value = self._compute(name)
            except BaseException as exc:  # handed to the main thread by result()
                fut.set_exception(exc)
                self._stop.set()  # the stages after it are not computed
                continue
            fut.set_result((value, round(time.perf_counter() - t, 2)))

    def done(self, name: str) -> bool:
        """Whether stage ``name`` has ended (computed, raised or cancelled)."""
        return self._futures[name].done()

    def result(self, name: str) -> tuple[Any, float]:
        """(value, wall seconds) of stage ``name``; waits for it (interruptible)."""
        fut = self._futures[name]
        while True:  # short waits: SIGINT reaches the main thread between them
            try:
                return fut.result(timeout=0.2)
            except WaitTimeout:
                continue

    def stop(self, wait: bool = False) -> None:
        """Start no further stage; with ``wait``, wait for the current one to end."""
        self._stop.set()
        for fut in self._futures.values():
            fut.cancel()  # those not started
        if wait:
            self._thread.join()
