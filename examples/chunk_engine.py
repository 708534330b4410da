#!/usr/bin/env python3
"""Reference engine for cipval's chunk exchange protocol (version 1), as a separate program.

cipval starts this program (``cip-validate engines --engine-cmd "python
examples/chunk_engine.py"``), writes one JSON header line with the model,
then for every delay chunk a request frame (int64 n, the R start states, the
R x n controls) and reads a response frame (int64 warnings, the R x n states
after each step); n = 0 ends the session.  It answers ``"sessions": "many"``:
after a session it reads the next header (a new session, nothing kept from
the last) until its stdin ends, so cipval starts it once, not once per run
(``--one-session``: it exits after one, as an engine that does not say so).
The protocol is documented in cipval's README ("Engines in other programs")
and in ``cip/engines/process.py``.

This engine steps the model MuJoCo ships in the header (``mjb_base64``) with
``mujoco.rollout`` (``mj_step`` over each realisation's controls, in C); an
engine in another language would build its own model from the header's
``parameters`` instead.  It imports nothing from cipval: only the
standard library, numpy and mujoco.

``--delay-error`` applies each control one step late (the control of step k
over step k + 1): a one-step delay fault that cipval must catch.

Other discretisations, each a correct engine that cipval must pass: ``--substeps
K`` takes K steps of dt/K per step (the control held over them), ``--integrator
NAME`` steps with another of MuJoCo's integrators (``RK4``, ``implicitfast``,
``implicit``) than the file's.  ``--declare`` answers the handshake in version 2,
declaring what it runs (the integrator, ``other`` with its order when it
sub-steps, and the soft rod); without it the engine declares nothing (version 1)
and cipval finds out.  ``--cart-mass F`` multiplies both carts' masses by F: a
wrong model constant that cipval must catch.
"""

import argparse
import base64
import json
import os
import sys
import tempfile

import mujoco
import numpy as np
from mujoco import rollout

I64, F64 = np.dtype("<i8"), np.dtype("<f8")
#: MuJoCo's integrators and their orders of accuracy (as MuJoCo runs them, dampers explicit)
ORDERS = {"Euler": 1, "implicit": 1, "implicitfast": 1, "RK4": 4}


def read_exact(stream, n: int) -> bytes:
    data = stream.read(n)
    if data is None or len(data) != n:
        raise EOFError(f"expected {n} bytes, got {len(data or b'')}")
    return data


def load_model(header: dict) -> mujoco.MjModel:
    with tempfile.NamedTemporaryFile(suffix=".mjb", delete=False) as f:
        f.write(base64.b64decode(header["mjb_base64"]))
    try:
        return mujoco.MjModel.from_binary_path(f.name)
    finally:
        os.unlink(f.name)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--delay-error", action="store_true", help="apply each control one step late")
    ap.add_argument("--one-session", action="store_true",
                    help="exit after one session instead of serving the next")  # fmt: skip
    ap.add_argument("--substeps", type=int, default=1, help="steps of dt/K per step (K >= 1)")
    ap.add_argument("--integrator", choices=sorted(ORDERS), help="MuJoCo integrator to step with")
    ap.add_argument("--declare", action="store_true", help="declare the discretisation (v2)")
    ap.add_argument("--cart-mass", type=float, default=1.0, help="factor on the carts' masses")
    args = ap.parse_args()
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    while True:
        line = stdin.readline()
        if not line:  # cipval closed our stdin: no further session
            return 0
        status = session(json.loads(line), args, stdin, stdout)
        if status or args.one_session:
            return status


def session(header: dict, args: argparse.Namespace, stdin, stdout) -> int:
    """One session: the answer to ``header``, then chunks until n = 0 (0), or 1 when the
    header is refused."""
    if header.get("protocol") != "cipval-chunk" or header.get("version") != 1:
        stdout.write(b'{"error": "this engine speaks cipval-chunk version 1 (and 2) only"}\n')
        stdout.flush()
        return 1
    model = load_model(header)
    k = max(1, args.substeps)
    model.opt.timestep = header["timestep"] / k
    if args.integrator:
        model.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + args.integrator.upper())
    if args.cart_mass != 1.0:
        for i in range(1, 3):
            b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"cart_{i}")
            if b >= 0:
                model.body_mass[b] *= args.cart_mass
        mujoco.mj_setConst(model, mujoco.MjData(model))
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    R, S, U = header["n_realizations"], header["nstate"], header["nu"]
    assert mujoco.mj_stateSize(model, spec) == S and model.nu == U
    name = "chunk-example" + ("-delay-error" if args.delay_error else "")
    answer = {"protocol": "cipval-chunk", "version": 1, "engine": name}
    if args.declare and 2 in header.get("versions", [1]):
        integ = args.integrator or header["integrator"]
        answer.update(version=2, rod="soft", integrator=integ if k == 1 else "other")
        if k > 1:
            answer["order"] = ORDERS[integ]
    if not args.one_session:
        answer["sessions"] = "many"
    stdout.write((json.dumps(answer) + "\n").encode())
    stdout.flush()
    previous = np.zeros((R, U))  # the control held before the first step (delay error only)
    warnings = 0
    while True:
        (n,) = np.frombuffer(read_exact(stdin, 8), I64)
        if n == 0:
            return 0
        state = np.frombuffer(read_exact(stdin, R * S * 8), F64).reshape(R, S)
        ctrl = np.frombuffer(read_exact(stdin, R * n * U * 8), F64).reshape(R, n, U)
        if args.delay_error:
            applied = np.concatenate([previous[:, None], ctrl[:, :-1]], axis=1)
            previous = ctrl[:, -1].copy()
        else:
            applied = ctrl
        # per realisation: set the start state, then for each step the control, mj_step
        # and the state after it
        out, _ = rollout.rollout(model, data, state, np.ascontiguousarray(np.repeat(applied, k, 1)))
        out = out[:, k - 1 :: k]
        warnings = sum(int(data.warning[w].number) for w in range(len(data.warning)))
        stdout.write(np.array([warnings], I64).tobytes() + out.astype(F64).tobytes())
        stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
