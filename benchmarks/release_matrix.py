"""Run the regression over several MuJoCo releases, each in its own throwaway venv.

    python benchmarks/release_matrix.py --versions 3.17.0,3.5.0,3.3.7 [--root DIR]

For each release: a venv under ``--root`` that sees this environment's packages
(a ``.pth`` file) but has its own ``mujoco==VERSION`` installed first on the
path; then, with this repository on ``PYTHONPATH``:

1. ``cip-validate selftest --json``: the unmodified model passes the direct
   checks (exact twin, rod, measured delay, declared model) and every
   catalogued fault is flagged;
2. ``cip-validate run --profile smoke --baseline REF``: the smoke profile
   against a baseline made once with this environment's MuJoCo (``auto``
   mode: statistical when the versions differ, exact when they match).

Prints one row per release: installed, selftest, run status, baseline mode,
numbers moved, wall time.  Needs network access to PyPI for the installs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _run(cmd: list[str], env: dict, timeout: int = 1800) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)


def make_venv(root: Path, version: str) -> Path | str:
    """A venv with mujoco==version over this environment's packages; its python or an error."""
    where = root / f"mujoco-{version}"
    py = where / "bin" / "python"
    if not py.exists():
        r = _run([sys.executable, "-m", "venv", "--without-pip", str(where)], dict(os.environ))
        if r.returncode:
            return f"venv failed: {r.stderr.strip().splitlines()[-1]}"
    site = Path(
        _run([str(py), "-c", "import sysconfig;print(sysconfig.get_paths()['purelib'])"],
             dict(os.environ)).stdout.strip()
    )  # fmt: skip
    (site / "base_env.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    r = _run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target",
              str(site), f"mujoco=={version}"], dict(os.environ))  # fmt: skip
    if r.returncode:
        return f"pip failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}"
    return py


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--versions", default="3.17.0,3.5.0,3.3.7,3.2.0")
    ap.add_argument("--root", default="/tmp/cipval-releases")
    ap.add_argument("--profile", default="smoke")
    a = ap.parse_args(argv)
    root = Path(a.root)
    root.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    ref = root / f"baseline_{a.profile}.json"
    if not ref.exists():
        r = _run([sys.executable, "-m", "validation.cli.main", "baseline", "--profile", a.profile,
                  "--out", str(ref)], env)  # fmt: skip
        if r.returncode:
            print(r.stderr[-2000:])
            return 1
    import mujoco

    print(f"reference baseline: {ref} (mujoco {mujoco.__version__}, profile {a.profile})\n")
    head = f"{'mujoco':<8} {'selftest':<26} {'run':<6} {'mode':<12} {'moved':>6} {'wall s':>7}"
    print(head + "\n" + "-" * len(head))
    rows = []
    for version in [v.strip() for v in a.versions.split(",") if v.strip()]:
        t = time.perf_counter()
        py = make_venv(root, version)
        if isinstance(py, str):
            print(f"{version:<8} {py}")
            rows.append({"mujoco": version, "error": py})
            continue
        st = _run([str(py), "-m", "validation.cli.main", "selftest", "--json"], env)
        try:
            s = json.loads(st.stdout.strip().splitlines()[-1])
            flagged = sum(f["flagged"] for f in s["faults"])
            clean = "clean pass" if not s["clean_failures"] else "clean FAIL"
            selftest = f"{clean}, {flagged}/{len(s['faults'])} flagged"
        except (json.JSONDecodeError, IndexError, KeyError):
            errors = [ln for ln in st.stderr.splitlines() if ln.split(":")[0].endswith("Error")]
            selftest = "error: " + (errors or ["?"])[-1][:40]
        out = root / f"run-{version}"
        rr = _run([str(py), "-m", "validation.cli.main", "run", "--profile", a.profile,
                   "--no-figures", "--baseline", str(ref), "--out", str(out)], env)  # fmt: skip
        mode, moved, status = "-", "-", "error"
        if (out / "results.json").exists():
            res = json.loads((out / "results.json").read_text())
            status = res["status"]
            reg = res.get("regression", {})
            mode = reg.get("mode", "-")
            moved = str(len(reg.get("failed", [])))
        wall = time.perf_counter() - t
        print(f"{version:<8} {selftest:<26} {status:<6} {mode:<12} {moved:>6} {wall:>7.0f}")
        rows.append(
            {
                "mujoco": version,
                "selftest": selftest,
                "run": status,
                "mode": mode,
                "moved": moved,
                "stderr_tail": rr.stderr[-300:] if status == "error" else "",
            }
        )
    from cipcore.atomic import write_text

    write_text(root / "release_matrix.json", json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
