"""``cip-validate contract``: the engine contract (:mod:`validation.checks.contract`) as a command,
and ``--engine-cmd``, the option that makes an engine of another program a registry engine."""

from __future__ import annotations

import argparse
import json
import sys
import time

from cipcore.params import EngineError, ParameterError
from validation.cli.args import add_engine_arg, add_json_arg
from validation.cli.ci_options import add_ci_options, junit_file
from validation.cli.engine_options import COMMAND_ENGINE, add_engine_cmd_arg, register_engine_cmd
from validation.cli.exitcodes import EXIT_CRASH, EXIT_FAIL, EXIT_OK
from validation.cli.main import add_command, command


@command(
    "Run the engine contract on one engine, as an engine's own CI would: exit 0 when every check "
    "passes, 1 when one fails, 4 when the engine crashes."
)
def cmd_contract(a: argparse.Namespace) -> int:
    from cipcore.registry import check_engine_name, get_engine
    from validation.checks.contract import run_contract

    if (a.engine is None) == (a.engine_cmd is None):
        raise ParameterError('contract: give one of --engine NAME or --engine-cmd "CMD ARGS"')
    junit = junit_file(a)
    t = time.perf_counter()

    def say(row: dict) -> None:
        if not (a.json or a.quiet):
            print(f"{row['check']:<28} {row['status']:<8} {row['message']}", flush=True)

    try:
        name = register_engine_cmd(a.engine_cmd, a.engine_timeout) or check_engine_name(a.engine)
    except EngineError as exc:  # the engine broke in its first handshake: no check can run
        name = COMMAND_ENGINE
        rows = [{"check": "handshake", "status": "error", "message": " ".join(str(exc).split()),
                 "seconds": round(time.perf_counter() - t, 2)}]  # fmt: skip
        say(rows[0])
    else:
        engine = get_engine(name)  # unknown or unavailable: one line, exit 2
        rows = run_contract(engine, on_check=say)
    if junit:
        from validation.cli.junit import write_junit

        cases = [(f"contract.{name}", f"contract.{name}", r["check"],
                  {"error": "fail"}.get(r["status"], r["status"]), r["message"], "")
                 for r in rows]  # fmt: skip
        write_junit(cases, junit, time.perf_counter() - t)
    crashed = any(r["status"] == "error" for r in rows)
    failed = any(r["status"] == "fail" for r in rows)
    if a.json:
        from validation.cli.ci_options import run_environment

        print(json.dumps({"cipval_contract": 1, "engine": name, "checks": rows,
                          "pass": not (crashed or failed), **run_environment()}))  # fmt: skip
    else:
        for r in rows:  # the engine's own error, in one line
            if r["status"] == "error":
                print(f"cip-validate: {r['message']}", file=sys.stderr)
                break
        verdict = "crashed during" if crashed else "fails" if failed else "passes"
        print(f"engine {name} {verdict} the contract ({time.perf_counter() - t:.1f} s)",
              file=sys.stderr if a.quiet and verdict == "passes" else sys.stdout)  # fmt: skip
    return EXIT_CRASH if crashed else EXIT_FAIL if failed else EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``contract`` to the parser."""
    p = add_command(sub, "contract", cmd_contract)
    add_engine_arg(p, default=None, help="a registered engine")
    add_engine_cmd_arg(p)
    add_json_arg(p, help="one JSON object on stdout")
    add_ci_options(p, verbose=False)
