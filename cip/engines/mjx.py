"""MJX (MuJoCo XLA) as a registered engine: the same CIP model compiled by JAX.

The backend advances a whole delay chunk inside one compiled ``jax.lax.scan``
over :func:`mujoco.mjx.step`, vmapped over realisations, in float64
(``jax_enable_x64``) on whatever device JAX has (CPU here, GPU where there is
one).  The delayed random-gain control of the chunk is computed beforehand by
:class:`cip.runner.CIPRunner` (it depends only on states a delay old), exactly as
for MuJoCo on the CPU, so both engines see the same controls for the same seed.

Two MJX facts this module works around (measured with MJX 3.17 and MuJoCo 4.0):

* ``jax.lax.scan`` over ``mjx.step`` with the whole ``mjx.Data`` as the carry
  fails under ``jax_enable_x64``: the tendon-wrap fields (``ten_wrapadr``,
  ``ten_wrapnum``, ``wrap_obj``) come back int64 from an int32 carry.  The
  carry is therefore only what the next step needs: qpos, qvel and the
  constraint solver's warm start ``qacc_warmstart``.
* MJX silently ignores actuator and sensor ``delay`` attributes; the CIP model
  uses none (the delay lives in the runner's history buffer).

MJX raises no MuJoCo warnings: divergence is detected from non-finite states.

The constraint solve (a declared discretisation setting, :data:`SOLVER`): MJX
runs MuJoCo's Newton solver for exactly one iteration per step
(``opt.iterations = 1``, :func:`solver_model`), whatever the model file's
``iterations`` and ``tolerance`` say.  That is what MuJoCo on the CPU does with
the CIP: its Newton loop always takes one iteration before testing the
tolerance, and for the rod's one equality row (a quadratic cost) that iteration
is the exact solution (measured: ``mjData.solver_niter`` is 1 at every step, at
1e-8 m and 1e-4 m).  MJX's ``while_loop`` instead tests the tolerance *before*
iterating, so with the file's ``tolerance`` (1e-12) and a small balancing error
the warm start already passes the absolute test and no iteration is taken
(measured, coupled, 1 s, 2 realisations, seed 1: relative L2 distance to the
twin 4.2e-4 at 1e-8 m, 1.2e-6 at 1e-6 m, the rod's stretch 3e3 and 7.7 times
off the twin's).  With one iteration: 1.75e-9, 1.3e-11 and 8.6e-9 at 1e-8,
1e-6 and 1e-4 m (the rod's stretch 1.1e-2, 8.5e-5, 3.0e-6 off), and 1.0e-12,
5.8e-12 and 1.1e-16 from MuJoCo on the CPU: bit for bit what
``opt.tolerance = 0`` (the file's 50 iterations) gives, at 1/60 of its cost.
The single model has no constraint row, so the setting changes nothing there.

Its floor against the exact twin (``benchmarks/twin_floor.py --engines mjx``,
1e-6 m, 4 realisations x 10 s, seed 1) is MuJoCo's: the same tolerances hold.

Compilation: one executable per (model structure, padded batch, chunk length):
the ``mjx.Model`` is an argument of the compiled chunk, so models that differ
only in values (masses, lengths, damping, gravity, the time step: every model
edit of the fault catalogue but the integrator) share one executable (measured:
a coupled model with gravity, cart damping and length faults after the
unmodified one compiled nothing new, 0.4-0.8 s each against 97 s for the first
compile at load 9); the batch padded to :func:`bucket` rows, so batch sizes 1-4,
5-8, 9-16, ... share one, and kept across processes by JAX's persistent
compilation cache (:func:`cache_dir`); each compile's time is appended to
:data:`COMPILE_LOG`. JAX's cache saves XLA's backend compile only, not tracing and
lowering ``mjx.step``: so the traced chunk itself is kept too, serialised with
``jax.export`` in :func:`export_dir`, one file per (model structure, rows, steps,
versions of jax, jaxlib, mujoco and the x64 flag), and a later process deserialises it
instead of tracing (measured: the first call of a coupled 4 x 100-step chunk in a
fresh process, JAX's cache warm, 3.46 s traced, 0.39 s from the exported file, the
states bit-identical). Every process runs the exported module, written or read, so
the numbers never depend on which process traced it; a file that cannot be read is
written again. Measured while the model was a constant (coupled,
100-step chunks, ``python benchmarks/bench_engines.py --engines mjx
--realizations 3,4,8 --duration 0.2`` twice with an empty ``XDG_CACHE_HOME``, 2
cores at load 23-29): first process 75.6 s (4 rows) and 74.0 s (8 rows), batch 4
after batch 3 0.18 s (nothing compiled); second process 28.3 s and 20.8 s (cache
hits).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import os
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from cip.engines.rigid_body import RigidBodyEngine
from cipcore.engine import Capabilities

#: smallest padded batch; a batch of R realisations runs as :func:`bucket` (R) rows
MIN_BUCKET = 4
#: above this many rows the buckets are multiples of it instead of powers of two
BUCKET_STEP = 1024

_CHUNK_FNS: dict[str, Any] = {}  # "chunk" -> jit(vmap(chunk)), built once
_MODELS: dict[str, Any] = {}  # model hash -> mjx.Model
_COMPILED: dict[tuple, Any] = {}  # (model structure, rows, steps) -> executable
#: one entry per compiled chunk shape, in order: model hash, rows, steps, seconds, cache
COMPILE_LOG: list[dict[str, Any]] = []


#: MJX's declared constraint solve per step (module docstring): Newton, one iteration
SOLVER = "Newton, one iteration per step (opt.iterations = 1), as MuJoCo on the CPU takes"
SOLVER_ITERATIONS = 1


def solver_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` with MJX's declared constraint solve (:data:`SOLVER`): MuJoCo's
    Newton solver for exactly :data:`SOLVER_ITERATIONS` iteration per step, the file's
    ``tolerance`` then unused (MJX tests it only between iterations)."""
    m = copy.deepcopy(model)
    m.opt.solver = int(mujoco.mjtSolver.mjSOL_NEWTON)
    m.opt.iterations = SOLVER_ITERATIONS
    return m


def bucket(n_realizations: int) -> int:
    """Rows a batch of ``n_realizations`` is padded to: a power of two >= 4, at most 1024,
    then a multiple of 1024, so any batch size reuses one of a few compiled shapes."""
    if n_realizations <= BUCKET_STEP:
        return max(MIN_BUCKET, 1 << (n_realizations - 1).bit_length())
    return -(-n_realizations // BUCKET_STEP) * BUCKET_STEP


def cache_dir() -> Path:
    """JAX's persistent compilation cache of the engine: ``$JAX_COMPILATION_CACHE_DIR``
    when set, else ``$XDG_CACHE_HOME/cipval/jax`` (``~/.cache/cipval/jax``)."""
    env = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cipval" / "jax"


def export_dir() -> Path:
    """The traced chunks serialised with ``jax.export`` (module docstring):
    ``$CIPVAL_MJX_EXPORT_DIR`` when set, else ``$XDG_CACHE_HOME/cipval/mjx-exported``
    (``~/.cache/cipval/mjx-exported``)."""
    env = os.environ.get("CIPVAL_MJX_EXPORT_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cipval" / "mjx-exported"


def _use_persistent_cache(jax: Any) -> None:
    """Point JAX's persistent cache at :func:`cache_dir` unless one is configured already.

    JAX reads ``JAX_COMPILATION_CACHE_DIR`` itself; a directory set by the caller wins.
    JAX fixes its cache at its first compilation, so this takes effect only when MJX
    compiles first in the process (the usual case for the engine).
    """
    if not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", str(cache_dir()))


def _model_key(model: mujoco.MjModel) -> str:
    buf = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return hashlib.sha256(buf.tobytes()).hexdigest()


def _mjx() -> tuple[Any, Any, Any]:
    """(jax, jax.numpy, mujoco.mjx), JAX in float64 with the persistent cache."""
    import jax

    jax.config.update("jax_enable_x64", True)
    _use_persistent_cache(jax)
    import jax.numpy as jnp

    with contextlib.redirect_stdout(io.StringIO()):
        # mujoco.mjx prints "Failed to import warp" on stdout when warp is absent
        # (its optional warp path); keep stdout clean for --json output.
        from mujoco import mjx
    return jax, jnp, mjx


def _chunk_fn():
    """jit(vmap(scan of mjx.step over a chunk)), the MJX model an argument shared by the
    rows (built once per process)."""
    if _CHUNK_FNS:
        return _CHUNK_FNS["chunk"]
    jax, _, mjx = _mjx()

    def chunk(mx, qpos, qvel, warm, ctrl):
        d0 = mjx.make_data(mx)

        def body(carry, u):
            q, v, w = carry
            d = mjx.step(mx, d0.replace(qpos=q, qvel=v, qacc_warmstart=w, ctrl=u))
            return (d.qpos, d.qvel, d.qacc_warmstart), (d.qpos, d.qvel)

        (_, _, w), (qs, vs) = jax.lax.scan(body, (qpos, qvel, warm), ctrl)
        return qs, vs, w

    _CHUNK_FNS["chunk"] = jax.jit(jax.vmap(chunk, in_axes=(None, 0, 0, 0, 0)))
    return _CHUNK_FNS["chunk"]


def mjx_model(model: mujoco.MjModel) -> Any:
    """The ``mjx.Model`` of ``model`` (float64 arrays), built once per model."""
    key = _model_key(model)
    if key not in _MODELS:
        _, _, mjx = _mjx()
        _MODELS[key] = mjx.put_model(model)
    return _MODELS[key]


def _structure(mx: Any) -> tuple:
    """What an executable depends on: the model's static fields (sizes, topology, the
    integrator, the solver setting) and its arrays' shapes, not their values."""
    import jax

    leaves, tree = jax.tree_util.tree_flatten(mx)
    return tree, tuple((np.shape(x), str(np.asarray(x).dtype)) for x in leaves)


def _stable(x: Any) -> str:
    """A description of a pytree's static data that is the same in every process: arrays
    (bare or wrapped, as MJX's static fields are) by dtype, shape and content hash."""
    if isinstance(x, (tuple, list)):
        return "(" + ", ".join(_stable(v) for v in x) + ")"
    if isinstance(x, dict):
        return "{" + ", ".join(f"{k!r}: {_stable(v)}" for k, v in sorted(x.items())) + "}"
    arr = getattr(x, "array", x)
    if isinstance(arr, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()[:16]
        return f"array({arr.dtype}, {arr.shape}, {digest})"
    if isinstance(x, type):
        return f"{x.__module__}.{x.__qualname__}"
    return repr(x)


def _tree_key(tree: Any) -> str:
    """:func:`_stable` of a treedef: its node types and static data, children in order."""
    node = tree.node_data()
    if node is None:
        return "*"
    kind, aux = node
    return f"{_stable(kind)}[{_stable(aux)}]({', '.join(_tree_key(c) for c in tree.children())})"


def _export_path(jax: Any, structure: tuple, rows: int, steps: int) -> Path | None:
    """The file of the exported chunk for this model structure (:func:`_structure`),
    shape and software; None when the structure has no description that holds across
    processes."""
    import jaxlib

    tree, leaves = structure
    key = repr((_tree_key(tree), leaves, rows, steps, jax.__version__, jaxlib.__version__,
                mujoco.__version__, bool(jax.config.jax_enable_x64)))  # fmt: skip
    if " at 0x" in key:  # an object known only by its address
        return None
    return export_dir() / f"chunk-{hashlib.sha256(key.encode()).hexdigest()[:24]}.jaxexport"


def _exported_chunk(
    jax: Any, mx: Any, path: Path | None, leaf_shapes: list, args: tuple
) -> tuple[Any, str]:
    """(the ``jax.export`` module of the chunk for ``mx``, its leaves' shapes and
    ``args``' shapes, where it came from: "read" from ``path``, else "written" there once
    traced and exported, or "traced" alone when it cannot be kept: no path (no key that
    holds across processes), no flatbuffers, a read-only cache).  The module takes the
    model's leaves (a list), its structure fixed in it."""
    from cipcore.atomic import WriteError, write_bytes

    # any failure to read it (no flatbuffers, which jax.export's serialisation needs and
    # the mjx extra installs; a damaged or foreign file) traces the chunk again
    with contextlib.suppress(Exception):
        if path is not None and path.is_file():
            return jax.export.deserialize(bytearray(path.read_bytes())), "read"
    tree = jax.tree_util.tree_structure(mx)
    fn = _chunk_fn()

    def flat(leaves, qpos, qvel, warm, ctrl):
        return fn(jax.tree_util.tree_unflatten(tree, leaves), qpos, qvel, warm, ctrl)

    exported = jax.export.export(jax.jit(flat))(leaf_shapes, *args)
    if path is None:
        return exported, "traced"
    with contextlib.suppress(ImportError, OSError, WriteError):
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes(path, bytes(exported.serialize()))
        return exported, "written"
    return exported, "traced"


def compiled_chunk(model: mujoco.MjModel, rows: int, steps: int):
    """(the executable advancing ``rows`` realisations by ``steps`` steps, the MJX model
    it takes).  The model's values are an argument: models that differ only in values
    (masses, lengths, damping, gravity, time step: the model edits of the fault catalogue)
    share one executable; compiled once per structure, shape and process, from the chunk
    exported by an earlier process when there is one (:func:`export_dir`), loaded from
    JAX's persistent cache when another process compiled it; its compile time goes to
    :data:`COMPILE_LOG`."""
    mx = mjx_model(model)
    shape = (_structure(mx), rows, steps)
    if shape in _COMPILED:
        return _COMPILED[shape], mx
    jax, jnp, _ = _mjx()

    hits = []
    listener = lambda event, **kw: hits.append(event)  # noqa: E731
    jax.monitoring.register_event_listener(listener)
    f64 = jnp.float64
    args = (
        jax.ShapeDtypeStruct((rows, model.nq), f64),
        jax.ShapeDtypeStruct((rows, model.nv), f64),
        jax.ShapeDtypeStruct((rows, model.nv), f64),
        jax.ShapeDtypeStruct((rows, steps, model.nu), f64),
    )
    t0 = time.perf_counter()
    try:
        leaves = [jax.ShapeDtypeStruct(np.shape(x), np.asarray(x).dtype)
                  for x in jax.tree_util.tree_leaves(mx)]  # fmt: skip
        path = _export_path(jax, shape[0], rows, steps)
        exported, source = _exported_chunk(jax, mx, path, leaves, args)
        executable = jax.jit(exported.call).lower(leaves, *args).compile()
    finally:
        seconds = time.perf_counter() - t0
        jax.monitoring.unregister_event_listener(listener)
    cache = "hit" if "/jax/compilation_cache/cache_hits" in hits else "miss"
    COMPILE_LOG.append({"model": _model_key(model)[:12], "rows": rows, "steps": steps,
                        "seconds": seconds, "persistent_cache": cache,
                        "exported": source})  # fmt: skip

    def chunk(mx, qpos, qvel, warm, ctrl):
        return executable(jax.tree_util.tree_leaves(mx), qpos, qvel, warm, ctrl)

    _COMPILED[shape] = chunk
    return chunk, mx


class MJXRollout:
    """:class:`cip.runner.RolloutBackend` running MJX (float64) over a delay chunk.

    It steps :func:`solver_model` of the model it is given (the declared solver setting).

    The batch is padded to :func:`bucket` rows (copies of the first realisation, whose
    results are dropped), so every batch size of a bucket runs one compiled executable;
    the realisations are independent rows of the vmapped step, so their results are
    bit-identical to an unpadded batch (``tests/test_mjx_compile.py``).
    """

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        self.model = solver_model(model)
        self.nq, self.nv, self.dt = model.nq, model.nv, float(model.opt.timestep)
        self.n, self.rows = n_realizations, bucket(n_realizations)
        self.warm = np.zeros((self.rows, model.nv))

    def _pad(self, x: np.ndarray) -> np.ndarray:
        if self.rows == self.n:
            return np.ascontiguousarray(x)
        return np.concatenate([x, np.repeat(x[:1], self.rows - self.n, axis=0)])

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        nq, nv, n_real = self.nq, self.nv, self.n
        n = ctrl.shape[1]
        fn, mx = compiled_chunk(self.model, self.rows, n)
        qs, vs, warm = fn(
            mx,
            self._pad(state[:, 1 : 1 + nq]),
            self._pad(state[:, 1 + nq : 1 + nq + nv]),
            self.warm,
            self._pad(ctrl),
        )
        out[...] = state[:, None, :]
        out[:, :, 0] = state[:, None, 0] + self.dt * np.arange(1, n + 1)
        out[:, :, 1 : 1 + nq] = np.asarray(qs)[:n_real]
        out[:, :, 1 + nq : 1 + nq + nv] = np.asarray(vs)[:n_real]
        self.warm = np.asarray(warm)

    def warnings(self) -> int:
        """MJX keeps no warning counters: always 0 (non-finite states are still caught)."""
        return 0


ENGINE = RigidBodyEngine(
    name="mjx",
    capabilities=Capabilities(
        family="MuJoCo (XLA)",
        twin="the model file's terms, its soft rod (solref/solimp) and its integrator "
        "(Euler, implicitfast or RK4) as MuJoCo defines them",
        solver=SOLVER,
    ),
    backend=lambda: MJXRollout,
    integrators=("Euler", "implicitfast", "RK4"),
    # its floor against the twin is MuJoCo's with the declared solver (module docstring):
    # MuJoCo's tolerances
    twin_tolerance=1e-9,
    rod_tolerance=1e-3,
    requires=("jax", "mujoco.mjx"),
    max_threads=1,
    notes="MuJoCo XLA: jit(vmap(scan(mjx.step))) over a delay chunk, float64",
)
