"""The twin's compiled kernels: one per scheme, each compiling only its own step."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from cipcore.params import BalanceParams
from cipcore.scenario import Execution, Recording, Scenario
from reduced.twin import TwinParams, simulate_twin

_BODY = {"alpha": 22.0, "gamma_tip": 0.1, "gamma_cart": 0.2, "mass_ratio": 0.3, "kappa": 0.05,
         "dt": 1e-3}  # fmt: skip

_ONLY_EULER = """
from cipcore.params import BalanceParams
from cipcore.scenario import Execution, Scenario
from reduced import _twin_kernel, _twin_schemes
from reduced.twin import TwinParams, simulate_twin
from reduced.twin_lyapunov import lyapunov_twin
twin = TwinParams(alpha=22.0, gamma_tip=0.1, gamma_cart=0.2, mass_ratio=0.3, kappa=0.05,
                  dt=1e-3, integrator="Euler")
scn = Scenario("single", BalanceParams(beta=21.0), 0.5, 2, 7, 1e-3)
simulate_twin(scn, twin, execution=Execution(threads=1))
lyapunov_twin(scn, twin, transient=0.1, execution=Execution(threads=1))
steps = {"RK4": _twin_kernel._rk4_step, "Newmark": _twin_schemes.newmark_step,
         "RK-Merson": _twin_schemes.merson_step}
print({name: len(f.overloads) for name, f in steps.items()})
"""


def test_a_euler_twin_compiles_no_other_scheme(tmp_path):
    """In a process with an empty numba cache, the Euler twin (time series and lambda1)
    compiles neither RK4's, Newmark's nor RK-Merson's step (2.4 s of a first run)."""
    repo = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": repo}
    out = subprocess.run([sys.executable, "-c", _ONLY_EULER], capture_output=True, text=True,
                         env=env, timeout=300, check=True)  # fmt: skip
    assert out.stdout.strip() == "{'RK4': 0, 'Newmark': 0, 'RK-Merson': 0}", out.stderr


def test_each_scheme_kernel_is_split_invariant_and_its_own(monkeypatch):
    """Every scheme's kernel gives the same numbers on one thread in one chunk as on two
    threads in chunks of 97 steps (the state and the delay ring carried across calls), and
    no two schemes give the same numbers (a kernel loaded for another scheme would)."""
    import cipcore.driver

    scn = Scenario("single", BalanceParams(beta=21.0), 1.0, 3, 11, 1e-3)
    rec = Recording(decimate=1)
    seen = {}
    for integrator in ("Euler", "implicit", "RK4", "Newmark", "RK-Merson"):
        twin = TwinParams(**_BODY, integrator=integrator)
        a = simulate_twin(scn, twin, recording=rec, execution=Execution(threads=1))
        with monkeypatch.context() as m:
            m.setattr(cipcore.driver, "CHUNK_STEPS", 97)
            b = simulate_twin(scn, twin, recording=rec, execution=Execution(threads=2))
        for name in a.data:
            np.testing.assert_array_equal(a[name], b[name])
        e = a["balancing_error"]
        assert np.all(np.isfinite(e))
        for other, f in seen.items():
            assert not np.array_equal(e, f), (integrator, other)
        seen[integrator] = e
