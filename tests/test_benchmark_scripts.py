"""Every script in ``benchmarks/`` runs to its end at a small size and prints what it
measures (marker ``bench``: CI runs them in a step of their own, ``pytest -m bench``).

Nothing in cipval imports these scripts, so a renamed attribute or a changed result
layout breaks them silently: ``bench_engines.py --native`` lost three engines' loops that
way, and ``mf_power.py`` printed "-" for the lambda1 checks' pairs.  Each run here is the
script's whole path at the smallest size that still computes every column (one or two
realisations, short durations, the smoke profile where it takes one), in a fresh process
as a user runs it, with its temporary files under the test's directory; the test asserts
exit status 0 and a line of the script's result.  A script that needs an engine that is
not installed is skipped with the reason.  :data:`ELSEWHERE` names the scripts run by
other tests, and the last test keeps the two lists complete.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"

#: script -> (its arguments, engines it needs, a regular expression its stdout must match)
RUNS: dict[str, tuple[str, tuple[str, ...], str]] = {
    "bench_engines": (
        "--engines mujoco,bullet --realizations 2 --duration 0.2 --threads 1 --native",
        ("bullet",), r"\nbullet +1 +2 .*e\+0\d +\d\.\d{3}\n",
    ),
    "bench_gpu": ("--cpu-smoke", (), r"smoke run on warp's CPU device"),
    "bench_memory": ("--realizations 2 --duration 1", (), r"peak resident memory \d+\.\d\d GiB"),
    "bench_mujoco": (
        "--realizations 2 --duration 0.5 --repeats 1 --timers",
        (), r"coupled +timers on +\d+\.\d+ us/step .*bit-identical: True",
    ),
    "bench_reduced": ("--realizations 2 --duration 2 --repeats 1", (),
                      r"cost ratio model / draws: \d+\.\d\d"),
    "bench_run": ("--profiles smoke --no-figures", (), r"smoke \(seed 2011, no figures\): exit 0"),
    "bench_stcc": ("--realizations 1 --duration 20", (),
                   r"Bartlett level: \d+\.\d+ s per realisation"),
    "bench_sweep": ("--points 2 --duration 0.5", (),
                    r"speed-up 1 -> 2 workers: local x\d+\.\d+, dask x\d+\.\d+"),
    "bench_tests": ("-n 0 tests/test_blas.py", (), r"\d+ passed"),
    "beta_star_duration": (
        "--models single --realizations 32 --duration 400 --checkpoints 100,200 "
        "--long-transient 100 --bootstrap 100 --threads 2",
        (), r"single, transient 10 s: b_inf \d+\.\d{4} \[",
    ),
    "beta_star_parameters": ("--realizations 4 --duration 200 --boot 100 --threads 2", (),
                             r"alpha +\d+\.\d+ \[ +\d"),
    "beta_star_seeds": ("--profiles smoke --seeds 1-2 --threads 2", (),
                        r"single +paper 20\.306: offset [+-]\d"),
    "beta_star_study": (
        "--realizations 4 --duration 200 --long-realizations 2 --long-duration 320 "
        "--bootstrap 100 --threads 2",
        (), r"\| factor \| step \(from dt 1 ms, Benettin, 200 s, 5e-4\)",
    ),
    "engine_distance_table": (
        "--engines mujoco,bullet --duration 0.5 --realizations 1 --mass-ratios 1e-3",
        ("bullet",), r"\| coupled \| 0\.001 \| bullet \| \d\.\d{4}e-0\d \|",
    ),
    "engine_floor": ("--engines mujoco,bullet --seeds 0 --realizations 1 --mass-ratios 1e-3",
                     ("bullet",), r'"engine": "bullet"'),
    "full_vs_reduced_table": ("", (), r"\| coupled \| 0\.03 \| \d\.\d\de-0\d \|"),
    "mf_power": ("--profile quick --seeds 1 --threads 2", (), r"seed 2011 mf .* engine steps"),
    "paper_claims": (
        "--profile smoke --realizations 2 --duration 20 --rms-realizations 2 --rms-duration 10 "
        "--nonlinear-realizations 1 --nonlinear-duration 10 --workers 2 --out {tmp}/claims",
        (), r"# Paper claims, profile smoke \(seed 2011\)",
    ),
    "refinement_power": (
        "--engines mujoco,bullet --integrators Euler --seeds 1 --faults tip_damping "
        "--sizes 1e-3 --models single",
        ("bullet",), r"bullet single: clean at 1 seeds: 0 false failures",
    ),
    "refinement_projection": (
        "--engines mujoco-float32 --models single --seeds 1 --faults tip_damping --sizes 1e-4",
        (), r"c\[mass_ratio\] mean [+-]\d",
    ),
    "rod_stretch": ("--engines mujoco,bullet", ("bullet",), r"\nbullet +\d\.\d{3}e"),
    "seed_robustness": ("--profile smoke --seeds 1 --workers 2 --engine mujoco", (),
                        r"mujoco, smoke profile, seeds 1\.\.1 \(1 runs\):(.|\n)*"
                        r"runs with any failed check: \d+ of 1"),
    "twin_floor": (
        "--engines mujoco,bullet --integrators Euler,RK4 --realizations 1 --duration 0.5 "
        "--amplitudes 1e-6",
        ("bullet",), r"\nbullet +Euler +coupled +1e-06 +\d\.\d\de-\d\d",
    ),
}  # fmt: skip

#: scripts another test runs (test file), and modules that are not scripts
ELSEWHERE: dict[str, str] = {
    "hostspeed": "tests/test_benchmarks.py",
    "targets": "tests/test_benchmarks.py",
    "native_loops": "tests/test_benchmarks.py, marker bench (a module of bench_engines.py)",
    "startup": "tests/test_cli_startup.py",
    "bench_server_load": "tests/test_server_load.py",
    "release_matrix": "not run: it installs other MuJoCo releases from PyPI into venvs",
}


@pytest.mark.bench
@pytest.mark.parametrize("script", sorted(RUNS))
def test_benchmark_script_runs_at_a_small_size(script: str, tmp_path: Path) -> None:
    from cipcore.registry import availability

    args, engines, expected = RUNS[script]
    for name in engines:
        why = availability(name)
        if why is not None:
            pytest.skip(f"{script} runs engine {name!r}: {why}")
    env = {**os.environ, "TMPDIR": str(tmp_path), "MPLBACKEND": "Agg",
           "CIPVAL_HOSTSPEED_STEPS": "50"}  # fmt: skip
    cmd = [sys.executable, str(BENCH / f"{script}.py"), *args.format(tmp=tmp_path).split()]
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-4000:]
    assert "Traceback" not in out.stderr, out.stderr[-4000:]
    assert re.search(expected, out.stdout), out.stdout[-4000:]


def test_every_benchmark_script_is_run_by_a_test() -> None:
    scripts = {p.stem for p in BENCH.glob("*.py")}
    assert scripts == set(RUNS) | set(ELSEWHERE), (
        f"not run by any test: {sorted(scripts - set(RUNS) - set(ELSEWHERE))}; "
        f"listed but gone: {sorted(set(RUNS) | set(ELSEWHERE) - scripts)}"
    )


def test_seed_robustness_refuses_an_engine_run_cannot_validate_in_one_line() -> None:
    # the reference itself is no rigid-body engine: refused before any seed runs, as
    # `cip-validate run --engine reduced` is
    cmd = [sys.executable, str(BENCH / "seed_robustness.py"), "--engine", "reduced"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("seed_robustness.py: error: --engine: engine 'reduced' is not a "
                           "rigid-body engine"), out.stderr  # fmt: skip
    assert "Traceback" not in out.stderr and out.stdout == ""
