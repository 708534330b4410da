"""The benchmark scripts' host-speed probe (``benchmarks/hostspeed.py``), printed beside
every time the benchmarks measure: a positive, finite number in its documented line."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_hostspeed_prints_us_per_mujoco_step_and_the_load():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hostspeed.py")],
                         capture_output=True, text=True, check=True, timeout=120)  # fmt: skip
    m = re.fullmatch(
        r"host: (\d+\.\d{3}) us per MuJoCo step \(single CIP, one thread\), "
        r"load (\d+\.\d\d) (\d+\.\d\d) (\d+\.\d\d)\n",
        out.stdout,
    )
    assert m, out.stdout
    assert 0.05 < float(m.group(1)) < 100.0
