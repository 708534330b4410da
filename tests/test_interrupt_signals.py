"""The command line's signal handling (validation.cli.args.interrupt_signals), in process."""

from __future__ import annotations

import signal
import threading

import pytest

from validation.cli import args as cli_args
from validation.cli.args import interrupt_signals, interrupted_status


def _send_from_helper(*signals: int) -> None:
    """Send ``signals`` to a helper thread, which runs their C-level handler at once,
    and return when it is done: Python runs their handlers afterwards, all pending
    together, on this (the main) thread."""

    def send() -> None:
        for s in signals:
            signal.pthread_kill(threading.get_ident(), s)

    t = threading.Thread(target=send)
    t.start()
    t.join()


@pytest.mark.parametrize("first, second", [(signal.SIGTERM, signal.SIGINT),
                                           (signal.SIGINT, signal.SIGTERM)])  # fmt: skip
def test_the_first_signal_to_arrive_decides_when_both_are_pending(first, second):
    """CPython handles pending signals by number (SIGINT before SIGTERM); the exit status
    must follow their arrival."""
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with interrupt_signals() as got:
        with pytest.raises(KeyboardInterrupt):
            _send_from_helper(first, second)
            for _ in range(1000):  # the handlers run between bytecodes
                pass
        for _ in range(1000):
            pass
    assert got["signal"] == first and got["later"] == 1
    assert interrupted_status(got)[1] == {signal.SIGINT: 130, signal.SIGTERM: 143}[first]
    # called in process (not the console script): the old handlers are back
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_later_signal_breaks_off_nothing():
    with interrupt_signals() as got:
        with pytest.raises(KeyboardInterrupt):
            _send_from_helper(signal.SIGTERM)
            for _ in range(1000):
                pass
        _send_from_helper(signal.SIGINT)
        finished = sum(range(1000))  # the saving of finished work, not broken off
    assert finished == 499500 and got["signal"] == signal.SIGTERM and got["later"] == 1


def test_without_a_signal_the_old_handlers_and_wakeup_descriptor_return():
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with interrupt_signals() as got:
        pass
    assert got["signal"] is None
    assert {s: signal.getsignal(s) for s in before} == before
    assert signal.set_wakeup_fd(-1) == -1  # none left installed


def test_the_console_script_keeps_both_signals_ignored_after_one(monkeypatch):
    monkeypatch.setitem(cli_args._AFTER_SIGNAL, "ignore", True)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with interrupt_signals():
            with pytest.raises(KeyboardInterrupt):
                _send_from_helper(signal.SIGINT)
                for _ in range(1000):
                    pass
        assert all(signal.getsignal(s) == signal.SIG_IGN for s in before)
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, set())
        assert {signal.SIGINT, signal.SIGTERM} <= set(blocked)
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
        for s, h in before.items():
            signal.signal(s, h)


def test_outside_the_main_thread_it_refuses_and_leaves_no_descriptor_open():
    import os

    if not os.path.isdir("/proc/self/fd"):
        pytest.skip("no /proc/self/fd to list the open descriptors")
    fds = set(os.listdir("/proc/self/fd"))
    errors = []

    def enter() -> None:
        try:
            with interrupt_signals():
                pass
        except ValueError as exc:
            errors.append(exc)

    t = threading.Thread(target=enter)
    t.start()
    t.join()
    assert len(errors) == 1 and set(os.listdir("/proc/self/fd")) == fds


_THROUGH_PYRUN = """
import ctypes, sys
import validation.cli.main as cli

def interrupted_run(argv=None):
    # a KeyboardInterrupt that leaves code run by PyRun_String (as an extension module's
    # py::exec does, e.g. while a signal arrives during its import), caught by the run
    run = ctypes.pythonapi.PyRun_String
    run.restype = ctypes.py_object
    run.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.py_object, ctypes.py_object]
    try:
        run(b"raise KeyboardInterrupt", 257, {}, {})
    except KeyboardInterrupt:
        return 143
    return 0

cli.main = interrupted_run
if sys.argv[1] == "entry":
    cli.entry()
sys.exit(interrupted_run())
"""


@pytest.mark.parametrize("how", ["entry", "plain"])
def test_a_handled_interrupt_keeps_its_status_when_it_passed_through_pyrun_string(how, tmp_path):
    """Run as ``python -m`` (as the tests run ``python -m validation.cli.main``), CPython
    exits by SIGINT (-2, or 130 with SIGINT blocked) when a KeyboardInterrupt once left
    code run through ``PyRun_String``, even though the program caught it and exits with
    its own status (a run stopped by SIGTERM ended 130 in CI).  ``entry`` clears that
    record (``forget_handled_keyboard_interrupt``); the plain ``sys.exit`` shows the
    record is there to clear."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "through_pyrun.py").write_text(_THROUGH_PYRUN)
    repo = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), repo])}
    proc = subprocess.run([sys.executable, "-m", "through_pyrun", how], capture_output=True,
                          text=True, timeout=120, env=env)  # fmt: skip
    if how == "entry":
        assert proc.returncode == 143, proc.stderr
    else:
        assert proc.returncode in (-signal.SIGINT, 128 + signal.SIGINT), proc.stderr
