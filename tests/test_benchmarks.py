"""The benchmark scripts' host-speed probe (``benchmarks/hostspeed.py``), printed beside
every time the benchmarks measure: a positive, finite number in its documented line; and
the targets' script (``benchmarks/targets.py``): its rows and verdicts; and each engine's
own loop that ``benchmarks/bench_engines.py --native`` times (``benchmarks/native_loops.py``)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the probe at 50 steps per realisation instead of 2000: these tests check the lines' form
SMALL_PROBE = {**os.environ, "CIPVAL_HOSTSPEED_STEPS": "50"}


def test_hostspeed_prints_us_per_mujoco_step_and_the_load():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hostspeed.py")],
                         capture_output=True, text=True, check=True, timeout=120,
                         env=SMALL_PROBE)  # fmt: skip
    m = re.fullmatch(
        r"host: (\d+\.\d{3}) us per MuJoCo step \(single CIP, one thread\), "
        r"(\d+\.\d{3}) us with every core stepping \((\d+)\), "
        r"load (\d+\.\d\d) (\d+\.\d\d) (\d+\.\d\d)\n",
        out.stdout,
    )
    assert m, out.stdout
    assert 0.05 < float(m.group(1)) < 100.0 and 0.05 < float(m.group(2)) < 100.0
    assert int(m.group(3)) == os.cpu_count()


def test_hostspeed_refuses_a_bad_probe_size_in_one_line():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hostspeed.py")],
                         capture_output=True, text=True, check=False, timeout=60,
                         env={**os.environ, "CIPVAL_HOSTSPEED_STEPS": "0"})  # fmt: skip
    assert out.returncode == 1
    assert out.stderr.strip() == "CIPVAL_HOSTSPEED_STEPS must be a positive integer, got '0'"


def test_targets_prints_each_target_with_its_verdict_host_speed_and_load():
    """``benchmarks/targets.py``, start-up only (the other parts take minutes): one row per
    command with its target, "met" or "NOT MET" as the number says, and the exit status
    1 exactly when a target is not met."""
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "targets.py"), "--repeat", "1",
         "--skip", "smoke,quick,pytest,mjx,drake"],
        capture_output=True, text=True, check=False, timeout=120, env=SMALL_PROBE,
    )  # fmt: skip
    rows = re.findall(
        r"^(cip-validate --version|cip-validate --help|python -c pass) +(\d+\.\d{3}) s "
        r"\(median of 1\) +(< 0\.[57] s)? +(met|NOT MET|n/a) +host (\d+\.\d{3})/\d+\.\d{3} us, "
        r"load ",
        out.stdout,
        re.M,
    )
    assert [r[0] for r in rows] == ["python -c pass", "cip-validate --version",
                                    "cip-validate --help"], out.stdout  # fmt: skip
    for _name, seconds, target, verdict, host in rows:
        assert 0 < float(seconds) < 60 and 0.05 < float(host) < 100
        if target:
            assert verdict == ("met" if float(seconds) < float(target[2:-2]) else "NOT MET")
        else:
            assert verdict == "n/a"
    assert out.returncode == (1 if any(r[3] == "NOT MET" for r in rows) else 0), out.stderr


def test_targets_refuses_an_unknown_part_in_one_line():
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "targets.py"), "--skip", "smok"],
        capture_output=True, text=True, check=False, timeout=60,
    )  # fmt: skip
    assert out.returncode == 2 and "--skip: unknown part(s) ['smok']" in out.stderr


def _worktrees() -> list[str]:
    return subprocess.run(["git", "-C", str(ROOT), "worktree", "list"], capture_output=True,
                          text=True, check=True).stdout.strip().splitlines()  # fmt: skip


def test_bench_run_against_an_unknown_commit_is_one_line():
    """``bench_run.py --against``: git's refusal in one line naming the commit, no tree left."""
    import pytest

    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: bench_run.py --against needs the repository")
    before = _worktrees()
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_run.py"), "--against", "no-such-ref",
         "--profiles", "smoke"], capture_output=True, text=True, check=False, timeout=60,
        env=SMALL_PROBE,
    )  # fmt: skip
    assert out.returncode == 1
    (line,) = out.stderr.strip().splitlines()
    assert line.startswith("bench_run.py: --against no-such-ref: ")
    assert _worktrees() == before


def _native_loops():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import native_loops

    return native_loops


def test_every_registered_engine_has_a_native_loop_or_a_reason():
    """``bench_engines.py --native``: each engine's own loop, or why there is none."""
    from cipcore.registry import engine_names

    nl = _native_loops()
    missing = [n for n in engine_names() if n not in nl.NATIVE_LOOPS and n not in nl.NOT_ISOLATED]
    assert not missing, f"no native loop and no reason for {missing}"


@pytest.mark.bench  # CI's benchmark step: MJX's loop compiles for 10-20 s
@pytest.mark.parametrize("name", sorted(_native_loops().NATIVE_LOOPS))
def test_each_native_loop_steps_the_adapters_model(name):
    """Each engine's own loop runs on the coupled model its adapter builds (the one
    ``bench_engines.py`` times; two realisations, three steps) and returns the seconds of
    its steps: the loops are benchmark code that nothing else runs, so a renamed adapter
    attribute breaks them silently (DART's, Newton's and Simbody's did once)."""
    from cipcore.params import BalanceParams
    from cipcore.registry import availability, get_engine

    why = availability(name)
    if why is not None:
        pytest.skip(why)
    nl = _native_loops()
    case = nl.make_case(get_engine(name), "coupled", BalanceParams(beta=21.032), 2, 3, 1e-3)
    seconds = nl.native_loop(name)(case)
    assert 0.0 < seconds < 60.0, (name, seconds)
