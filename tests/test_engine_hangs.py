"""Engine processes that cannot hang a run: timeouts, protocol errors, the process group.

Each misbehaving engine is a small Python program that writes its process id to a file
first; ``contract --engine-cmd ... --engine-timeout 2`` must exit 4 within the timeout
plus start-up, print one line naming the engine, and leave no process of the engine's
group running.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import pytest

HANDSHAKE = (
    "import json, sys\n"
    "sys.stdin.buffer.readline()\n"
    "print(json.dumps({'protocol': 'cipval-chunk', 'version': 1, 'engine': 'bad'}), flush=True)\n"
)

#: name -> the engine's body (after it wrote its pid), what its message must say
ENGINES = {
    "never answers": ("import time; time.sleep(600)", "did not answer the handshake"),
    "half a handshake": (
        'import sys, time\nsys.stdout.write(\'{"protocol": "cipval-chunk"\'); '
        "sys.stdout.flush(); time.sleep(600)",
        "did not answer the handshake",
    ),
    "echoes its input": (
        "import sys\nfor line in sys.stdin.buffer: sys.stdout.buffer.write(line)",
        "protocol error",
    ),
    "prints garbage": ("print('garbage', flush=True)", "b'garbage"),
    "stalls on its first chunk": (
        HANDSHAKE + "import time; time.sleep(600)",
        "did not answer a chunk",
    ),
    "exits after the handshake": (HANDSHAKE + "sys.exit(3)", "exited with status 3"),
    "writes a partial frame": (
        HANDSHAKE + "sys.stdin.buffer.read(8)\nsys.stdout.buffer.write(b'\\0' * 12)\n"
        "sys.stdout.flush(); sys.exit(0)",
        "protocol error: answered 12 of the",
    ),
    "floods stderr, then stalls": (
        "import sys, time\nfor _ in range(20000): sys.stderr.write('x' * 99 + '\\n')\n"
        "sys.stderr.write('the last words\\n'); sys.stderr.flush(); time.sleep(600)",
        "the last words",
    ),
    "spawns a child and stalls": (
        "import subprocess, time\nsubprocess.Popen(['sleep', '600'])\ntime.sleep(600)",
        "did not answer the handshake",
    ),
}


@pytest.mark.parametrize("name", list(ENGINES))
def test_a_misbehaving_engine_exits_4_in_time_and_leaves_nothing(name, tmp_path):
    body, said = ENGINES[name]
    pid_file = tmp_path / "pid"
    script = tmp_path / "engine.py"
    script.write_text(
        f"import os\nopen({str(pid_file)!r}, 'w').write(str(os.getpid()))\n"
        + textwrap.dedent(body)
        + "\n"
    )
    cmd = f"{sys.executable} {script}"
    t = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "validation.cli.main", "contract", "--engine-cmd", cmd,
         "--engine-timeout", "2", "--quiet"],
        capture_output=True, text=True, timeout=90,
    )  # fmt: skip
    took = time.monotonic() - t
    assert r.returncode == 4, (r.returncode, r.stderr[-2000:])
    assert took < 40, took
    lines = [x for x in r.stderr.splitlines() if x.startswith("cip-validate:")]
    assert len(lines) == 1, r.stderr[-2000:]
    assert "engine " in lines[0] and str(script) in lines[0] and said in lines[0], lines[0]
    assert "Traceback" not in r.stderr
    pgid = int(pid_file.read_text())  # the engine leads its own process group
    for _ in range(50):
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail(f"the engine's process group {pgid} is still running")


def test_engine_timeout_needs_an_engine_command():
    from validation.cli.main import main

    assert main(["contract", "--engine", "mujoco", "--engine-timeout", "5"]) == 2
    assert main(["contract", "--engine-cmd", "x", "--engine-timeout", "-1"]) == 2
