"""cipcore.quickexit: the status, the streams and the atexit handlers of a normal exit,
without the teardown of the imported modules."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

#: a module global whose finaliser prints: the teardown of __main__ runs it
_SCRIPT = textwrap.dedent(
    """
    import atexit, sys
    from cipcore import quickexit

    quickexit.arm()
    quickexit.arm()  # again: still one handler, still the last to run

    class Torn:
        def __del__(self):
            sys.__stdout__.write("torn down\\n")

    kept = Torn()
    atexit.register(lambda: sys.stdout.write("atexit ran\\n"))
    sys.stdout.write("no newline, buffered")  # flushed by the handler
    sys.stderr.write("to stderr")
    how = sys.argv[1]
    if how == "exit":
        quickexit.exit(int(sys.argv[2]))
    if how == "raise":
        raise RuntimeError("boom")
    sys.exit(int(sys.argv[2]))
    """
)


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _SCRIPT, *args], capture_output=True,
                          text=True, timeout=60, check=False)  # fmt: skip


@pytest.mark.parametrize("status", [0, 3, 143])
def test_exit_keeps_the_status_the_streams_and_the_atexit_handlers_and_skips_the_teardown(
    status,
):
    proc = _run("exit", str(status))
    assert proc.returncode == status
    assert proc.stdout == "no newline, bufferedatexit ran\n"  # no "torn down"
    assert proc.stderr == "to stderr"


def test_a_plain_sys_exit_is_a_normal_exit_with_the_teardown():
    proc = _run("plain", "5")
    assert proc.returncode == 5
    assert proc.stdout.endswith("atexit ran\ntorn down\n")


def test_an_uncaught_exception_ends_as_usual():
    proc = _run("raise", "0")
    assert proc.returncode == 1
    assert "RuntimeError: boom" in proc.stderr
    assert "atexit ran" in proc.stdout


def test_the_console_script_ends_through_it(tmp_path):
    """``cip-validate`` (``python -m validation.cli.main``) keeps its statuses and its
    one-line error when it ends without the teardown."""
    ok = subprocess.run([sys.executable, "-m", "validation.cli.main", "--version"],
                        capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert ok.returncode == 0 and ok.stdout.startswith("cip-validate ")
    bad = subprocess.run([sys.executable, "-m", "validation.cli.main", "run", "--profile",
                          "nope", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [
        "cip-validate: error: --profile must be one of quick, paper, smoke, robustness, got 'nope'"
    ]
