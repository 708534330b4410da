"""Engine processes that cannot hang a run: timeouts, protocol errors, the process group.

Each misbehaving engine is a small Python program that writes its process id to a file
first; ``contract --engine-cmd ... --engine-timeout T`` must exit 4 within the timeout
plus start-up, print one line naming the engine, and leave no process of the engine's
group running.
"""

from __future__ import annotations

import json
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

#: an engine that answers chunks 1 and 2 with its start states held and chunk 3 with a NaN
#: at realisation 1, step 5, state entry 2 (the message names the chunk, not a stage)
NAN_ENGINE = """
import json, sys
import numpy as np
stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
h = json.loads(stdin.readline())
R, S, U = h["n_realizations"], h["nstate"], h["nu"]
stdout.write(json.dumps({"protocol": "cipval-chunk", "version": 1, "engine": "nan"}).encode()
             + b"\\n")
stdout.flush()
for chunk in range(1, 10**6):
    n = int(np.frombuffer(stdin.read(8), "<i8")[0])
    if n == 0:
        break
    start = np.frombuffer(stdin.read(8 * R * S), "<f8").reshape(R, 1, S)
    stdin.read(8 * R * n * U)
    states = np.repeat(start, n, axis=1).copy()
    if chunk == 3:
        states[min(1, R - 1), 4, 2] = np.nan
    stdout.write(np.zeros(1, "<i8").tobytes() + states.tobytes())
    stdout.flush()
"""

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
    "sends NaN states": (NAN_ENGINE, "sent a non-finite state (nan) in its answer to chunk 3"),
    "spawns a child and stalls": (
        "import subprocess, time\nsubprocess.Popen(['sleep', '600'])\ntime.sleep(600)",
        "did not answer the handshake",
    ),
}


#: the engines that never answer: each run waits out its timeout, 1 s; the others answer
#: (wrongly) at once, and get 5 s so that a loaded machine cannot time them out instead
STALLS = {"never answers", "half a handshake", "stalls on its first chunk",
          "floods stderr, then stalls", "spawns a child and stalls"}  # fmt: skip


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
         "--engine-timeout", "1" if name in STALLS else "5", "--quiet"],
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


def test_an_engine_sending_nan_ends_run_with_one_line_naming_the_engine_and_chunk(tmp_path):
    """``run`` (not only ``contract``): exit 4, one stderr line naming the engine and the
    chunk, no warnings with source lines (``tr = simulate_full(``), the partial results
    kept naming the stage."""
    script = tmp_path / "engine.py"
    script.write_text(textwrap.dedent(NAN_ENGINE))
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, "-m", "validation.cli.main", "run", "--profile", "smoke",
         "--no-figures", "--quiet", "--engine-cmd", f"{sys.executable} {script}",
         "--engine-timeout", "5", "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 4, (r.returncode, r.stderr[-2000:])
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, r.stderr[-2000:]
    line = lines[0]
    assert line.startswith("cip-validate: engine ") and str(script) in line, line
    assert "chunk 3 (100 steps x 3 realisations" in line, line
    assert "realisation 1, step 5, state entry 2" in line, line
    assert "crashed" not in line and "simulate_full" not in r.stderr
    results = json.loads((out / "results.json").read_text())
    assert results["partial"] is True and "chunk 3" in results["crashed"]["error"]
