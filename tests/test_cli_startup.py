"""Lazy start-up of ``cip-validate``: what ``--help``, ``--version`` and a usage error import.

Not timed (the machine is shared); ``benchmarks/startup.py`` prints the times.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from validation.cli.args import CLIParser
from validation.cli.main import COMMANDS, build_parser, register_function

ROOT = Path(__file__).resolve().parents[1]
#: modules a start-up must not import: scipy's heavy submodules, the engines' libraries
HEAVY = ("scipy.signal", "scipy.stats", "scipy.spatial", "scipy.optimize", "jax", "mujoco",
         "numba", "pydrake", "matplotlib")  # fmt: skip

PROBE = """
import contextlib, io, json, sys
from validation.cli.main import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    code = main(sys.argv[2:])
print(json.dumps([code, sorted(m for m in json.loads(sys.argv[1]) if m in sys.modules)]))
"""


def imported_by(argv: list[str]) -> tuple[int, list[str]]:
    """Exit status of ``cip-validate argv`` in a fresh interpreter and the HEAVY it imported."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(HEAVY), *argv],
        capture_output=True, text=True, check=True, env=env, cwd=ROOT,
    ).stdout  # fmt: skip
    code, heavy = json.loads(out.strip().splitlines()[-1])
    return code, heavy


@pytest.mark.parametrize(
    "argv, code",
    [(["--version"], 0), (["--help"], 0), ([], 2), (["no-such-command"], 2),
     (["simulate", "--beta", "-1"], 2), (["run", "--help"], 0), (["sweep", "--help"], 0),
     (["engines", "--help"], 0)],
)  # fmt: skip
def test_start_up_imports_nothing_heavy(argv, code):
    got, heavy = imported_by(argv)
    assert got == code
    assert heavy == [], f"cip-validate {' '.join(argv)} imported {heavy}"


def _registered_help() -> dict[str, str]:
    """Each command's ``help=`` as its own module registers it (imports every module)."""
    seen: dict[str, str] = {}

    class Recorder:
        def add_parser(self, name, **kwargs):
            seen[name] = kwargs.get("help")
            return CLIParser(prog=name, add_help=False)

    for register in {register_function(name) for name in COMMANDS}:
        register(Recorder())
    return seen


def test_table_lists_every_command_with_its_own_help():
    registered = _registered_help()
    assert {n: h for n, (_, h) in COMMANDS.items()} == registered


def test_lazy_parser_helps_equal_the_full_parser():
    full = build_parser(full=True)
    full_sub = next(a for a in full._actions if a.dest == "command")
    assert full.format_help() == build_parser().format_help()
    for name in COMMANDS:
        lazy = build_parser(name)
        lazy_sub = next(a for a in lazy._actions if a.dest == "command")
        assert lazy_sub.choices[name].format_help() == full_sub.choices[name].format_help()
