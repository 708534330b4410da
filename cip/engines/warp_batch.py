"""MuJoCo Warp batches of the CIP: device kernels, the delayed random-gain control on the device.

Needs ``warp-lang`` and ``mujoco-warp`` (``pip install 'cipval[warp]'``); imported
only by :mod:`cip.engines.warp` once they are known to be present.

Two ways of driving a batch of worlds (one world per realisation, float32):

* :class:`WarpRollout`, a :class:`cip.runner.RolloutBackend`: the controls of a
  delay chunk come from the host (:class:`cip.runner.CIPRunner`), are uploaded
  once per chunk, and the states after every step come back.  The shared drivers
  :func:`cip.simulate.simulate_full` and :func:`cip.lyapunov.lyapunov_full` run on it.
* :class:`WarpBatch`: the control itself runs on the device.  Each step one
  kernel reads the balancing error e_i(n - d) from a device ring buffer of d
  slots (an integer index, never a time lookup: float32 time would drift),
  overwrites it with e_i(n) = L sin(theta_i(n)), and sets the cart force

      F_i(n) = M beta (1 + nu xi_{i,n} / sqrt(dt)) e_i(n - d)        (paper eq. (5))

  from the draws xi of the chunk, uploaded once per chunk.  The draws are made
  on the host by :class:`cipcore.noise.GainNoise` (one PCG64 stream per
  realisation), so the same seed means the same draws as in every other engine.
  Many grid points can share one batch (world ``w`` is realisation ``w // P`` of
  point ``w % P``, matching MuJoCo Warp's per-world model fields, indexed
  ``world % batch``): see :func:`validation.sweeps.gpu`.

On a CUDA device each chunk of steps (control kernel, ``mujoco_warp.step``,
recording) is captured once as a CUDA graph (``wp.ScopedCapture``) and replayed;
on warp's CPU device the same launches run one by one.
"""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass

import mujoco
import numpy as np
import warp as wp

wp.config.quiet = True  # before mujoco_warp initialises warp: no banner
import mujoco_warp as mjw  # noqa: E402

from cip.names import cart_joint, hinge_joint, motor  # noqa: E402
from cip.runner import schema_fields  # noqa: E402
from cipcore.control_warp import delayed_random_gain  # noqa: E402

wp.init()

f32 = wp.float32

#: Serialises :class:`WarpRollout`: the shared drivers step realisation blocks on several
#: threads, but warp builds kernels on first launch (``ast.parse`` of their Python source,
#: MuJoCo Warp's kernel cache) and neither is thread-safe; on CPython before 3.11.8 two
#: threads parsing at once even fail with "SystemError: AST constructor recursion depth
#: mismatch" (CPython gh-106905).  One block at a time gives the same numbers, since each
#: block has its own worlds.
_LOCK = threading.Lock()


# ---------------------------------------------------------------- kernels
@wp.kernel
def _delayed_gain_control(
    qpos: wp.array2d(dtype=f32),
    th_adr: wp.array(dtype=wp.int32),
    u_idx: wp.array(dtype=wp.int32),
    length: wp.array(dtype=f32),
    gain: wp.array(dtype=f32),
    scale: wp.array(dtype=f32),
    delay: wp.array(dtype=wp.int32),
    xi: wp.array3d(dtype=f32),
    k: int,
    step: wp.array(dtype=wp.int32),
    hist: wp.array3d(dtype=f32),
    ctrl: wp.array2d(dtype=f32),
    max_angle: wp.array(dtype=f32),
):
    """ctrl of step n = step[0] + k from the ring slot n mod d (eq. (5)); slot <- e(n)."""
    w = wp.tid()
    slot = (step[0] + k) % delay[w]
    for c in range(th_adr.shape[0]):
        th = qpos[w, th_adr[c]]
        e = length[w] * wp.sin(th)
        e_delayed = hist[w, c, slot]
        hist[w, c, slot] = e
        ctrl[w, u_idx[c]] = delayed_random_gain(gain[w], scale[w], xi[w, k, c], e_delayed)
        a = wp.abs(th)
        if step[0] + k == 0:  # the largest angle after steps 1.., as the CPU driver records
            continue
        if wp.isnan(a) or wp.isinf(a):
            max_angle[w] = wp.inf
        elif a > max_angle[w]:
            max_angle[w] = a


@wp.kernel
def _record_state(
    qpos: wp.array2d(dtype=f32),
    qvel: wp.array2d(dtype=f32),
    j: int,
    rec: wp.array3d(dtype=f32),
):
    """rec[w, j] = (qpos, qvel) of world w."""
    w = wp.tid()
    nq = qpos.shape[1]
    for i in range(nq):
        rec[w, j, i] = qpos[w, i]
    for i in range(qvel.shape[1]):
        rec[w, j, nq + i] = qvel[w, i]


@wp.kernel
def _set_ctrl(ctrl_chunk: wp.array3d(dtype=f32), k: int, ctrl: wp.array2d(dtype=f32)):
    """ctrl = ctrl_chunk[:, k] (controls computed on the host)."""
    w = wp.tid()
    for i in range(ctrl.shape[1]):
        ctrl[w, i] = ctrl_chunk[w, k, i]


@wp.kernel
def _advance_step(step: wp.array(dtype=wp.int32), n: int):
    step[0] = step[0] + n


# ---------------------------------------------------------------- devices
def cuda_available() -> bool:
    return wp.is_cuda_available()


def put_model(mjm: mujoco.MjModel, device: str, batch_sizes: dict[str, int] | None = None):
    """The model on ``device`` with deterministic reductions (bit-identical reruns)."""
    with wp.ScopedDevice(device):
        mx = mjw.put_model(mjm, batch_sizes=batch_sizes)
    mx.opt.deterministic = int(mjw.DeterminismType.ALL)
    return mx


class _Chunks:
    """Runs ``body(k)`` for k < n, as one CUDA graph per chunk length on a GPU."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.graphs: dict[int, object] = {}
        self.cuda = wp.get_device(device).is_cuda

    def run(self, n: int, body) -> None:
        if not self.cuda:
            for k in range(n):
                body(k)
            return
        if n not in self.graphs:
            with wp.ScopedCapture(device=self.device, force_module_load=True) as cap:
                for k in range(n):
                    body(k)
            self.graphs[n] = cap.graph
        wp.capture_launch(self.graphs[n])


# ------------------------------------------------------- host-side control
class WarpRollout:
    """:class:`cip.runner.RolloutBackend` on MuJoCo Warp (float32), controls from the host."""

    device = "cpu"  # replaced by cip.engines.warp before use

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        self.m = model
        self.nq, self.nv, self.nu = model.nq, model.nv, model.nu
        self.dt = float(model.opt.timestep)
        self.R = n_realizations
        with _LOCK, wp.ScopedDevice(self.device):
            self.mx = put_model(model, self.device)
            self.dx = mjw.put_data(model, mujoco.MjData(model), nworld=n_realizations)
            self.ctrl = wp.zeros((n_realizations, 1, self.nu), dtype=f32)
            self.rec = wp.zeros((n_realizations, 1, self.nq + self.nv), dtype=f32)
        self.chunks = _Chunks(self.device)

    def _buffers(self, n: int) -> None:
        if self.ctrl.shape[1] != n:
            self.ctrl = wp.zeros((self.R, n, self.nu), dtype=f32, device=self.device)
            self.rec = wp.zeros((self.R, n, self.nq + self.nv), dtype=f32, device=self.device)
            self.chunks.graphs.clear()  # graphs hold the old buffers' addresses

    def _body(self, k: int) -> None:
        R, dx = self.R, self.dx
        wp.launch(_set_ctrl, R, inputs=[self.ctrl, k, dx.ctrl], device=self.device)
        mjw.step(self.mx, dx)
        wp.launch(_record_state, R, inputs=[dx.qpos, dx.qvel, k, self.rec], device=self.device)

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        nq, nv, n = self.nq, self.nv, ctrl.shape[1]
        with _LOCK:
            self._buffers(n)
            # the state is uploaded every chunk: it came from this float32 device, so exact
            self.dx.qpos.assign(state[:, 1 : 1 + nq].astype(np.float32))
            self.dx.qvel.assign(state[:, 1 + nq : 1 + nq + nv].astype(np.float32))
            self.ctrl.assign(ctrl.astype(np.float32))
            self.chunks.run(n, self._body)
            rec = self.rec.numpy()
        out[...] = state[:, None, :]
        out[:, :, 0] = state[:, None, 0] + self.dt * np.arange(1, n + 1)
        out[:, :, 1 : 1 + nq + nv] = rec

    def warnings(self) -> int:
        """MuJoCo Warp keeps no MuJoCo warning counters: 0 (non-finite states are still caught)."""
        return 0


# ------------------------------------------------------- device-side control
@dataclass(frozen=True)
class PointControl:
    """Control and initial condition of one grid point (SI units).

    gain : M beta (kg/s^2); scale : nu / sqrt(dt) (1); length : L (m);
    delay : d = tau/dt (steps); amplitude : initial balancing error (m).
    """

    gain: float
    scale: float
    length: float
    delay: int
    amplitude: float


def _joint_addresses(m: mujoco.MjModel, nc: int) -> tuple[np.ndarray, ...]:
    """qpos addresses of the carts and angles, dof addresses, and the motor actuators."""

    def jid(name: str) -> int:
        return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)

    x = np.array([m.jnt_qposadr[jid(cart_joint(i + 1))] for i in range(nc)])
    th = np.array([m.jnt_qposadr[jid(hinge_joint(i + 1))] for i in range(nc)])
    vx = np.array([m.jnt_dofadr[jid(cart_joint(i + 1))] for i in range(nc)])
    om = np.array([m.jnt_dofadr[jid(hinge_joint(i + 1))] for i in range(nc)])
    u = np.array(
        [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, motor(i + 1)) for i in range(nc)]
    )
    return x, th, vx, om, u


def _array_fields(obj, prefix: str = ""):
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name, None)
        if isinstance(v, wp.array):
            yield prefix + f.name, f, v
        elif dataclasses.is_dataclass(v) and not isinstance(v, type):
            yield from _array_fields(v, prefix + f.name + ".")


def batched_model(models: list[mujoco.MjModel], device: str):
    """One device model for P points: fields that differ get a leading batch of P.

    Raises ValueError when the points differ in a field MuJoCo Warp cannot batch
    (then they need separate batches).
    """
    m0 = models[0]
    if len(models) == 1:
        return put_model(m0, device)
    per = [put_model(m, device) for m in models]
    differ: dict[str, list[np.ndarray]] = {}
    for name, f, _ in _array_fields(per[0]):
        vals = [_get(p, name).numpy() for p in per]
        if all(np.array_equal(vals[0], v) for v in vals[1:]):
            continue
        spec = getattr(f.type, "shape", ())
        if not spec or spec[0] != "*":
            raise ValueError(f"points differ in model field {name!r}, which cannot be batched")
        differ[name] = vals
    mx = put_model(m0, device)
    for name, vals in differ.items():
        old = _get(mx, name)
        arr = wp.array(np.concatenate(vals, axis=0), dtype=old.dtype, device=device)
        arr._is_batched = True
        _set(mx, name, arr)
    return mx


def _get(obj, dotted: str):
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


def _set(obj, dotted: str, value) -> None:
    *head, last = dotted.split(".")
    for part in head:
        obj = getattr(obj, part)
    setattr(obj, last, value)


class WarpBatch:
    """R realisations of P grid points as R * P worlds, the control on the device.

    Parameters
    ----------
    models : one MjModel per point (same structure; differing fields are batched).
    controls : one :class:`PointControl` per point.
    n_realizations : R, realisations per point.
    n_controllers : C, 1 (single) or 2 (coupled).
    device : a warp device ("cuda:0", "cpu").
    max_chunk : the longest chunk :meth:`advance` takes (steps).
    every : record the state before every step whose index is a multiple of this
        (0: record nothing, the benchmark's setting).

    World ``w`` is realisation ``w // P`` of point ``w % P``.
    """

    def __init__(
        self,
        models: list[mujoco.MjModel],
        controls: list[PointControl],
        n_realizations: int,
        n_controllers: int,
        device: str,
        *,
        max_chunk: int = 100,
        every: int = 1,
    ) -> None:
        P, R, nc = len(models), n_realizations, n_controllers
        if len(controls) != P:
            raise ValueError("one PointControl per model")
        self.P, self.R, self.nc, self.W = P, R, nc, P * R
        self.device, self.max_chunk, self.every = device, max_chunk, every
        m0 = models[0]
        self.m0 = m0
        self.nq, self.nv = m0.nq, m0.nv
        self.i_x, self.i_th, self.i_vx, self.i_om, i_u = _joint_addresses(m0, nc)
        addresses = _joint_addresses(m0, nc)
        for m in models[1:]:
            same = zip(_joint_addresses(m, nc), addresses, strict=True)
            if m.nq != m0.nq or not all(np.array_equal(a, b) for a, b in same):
                raise ValueError("points must share the model structure")
        W = self.W
        point = np.arange(W) % P
        c = controls
        qpos = np.empty((W, self.nq))
        hist0 = np.empty((W, nc))
        for p, (m, ctl) in enumerate(zip(models, c, strict=True)):
            d = mujoco.MjData(m)
            d.qpos[self.i_th] = np.arcsin(ctl.amplitude / ctl.length)
            qpos[point == p] = d.qpos
            hist0[point == p] = ctl.length * np.sin(d.qpos[self.i_th])
        self.dmax = max(ctl.delay for ctl in c)
        with wp.ScopedDevice(device):
            self.mx = batched_model(models, device)
            self.dx = mjw.put_data(m0, mujoco.MjData(m0), nworld=W)
            self.dx.qpos.assign(qpos.astype(np.float32))

            def per_world(vals, dtype):
                return wp.array(np.asarray(vals)[point], dtype=dtype)

            self.length = per_world([x.length for x in c], f32)
            self.gain = per_world([x.gain for x in c], f32)
            self.scale = per_world([x.scale for x in c], f32)
            self.delay = per_world([x.delay for x in c], wp.int32)
            self.th_adr = wp.array(self.i_th.astype(np.int32), dtype=wp.int32)
            self.u_idx = wp.array(i_u.astype(np.int32), dtype=wp.int32)
            # constant history e(t) = e(0), t in [-tau, 0]
            self.hist = wp.array(
                np.repeat(hist0[:, :, None], self.dmax, axis=2).astype(np.float32), dtype=f32
            )
            self.xi = wp.zeros((W, max_chunk, nc), dtype=f32)
            self.step_dev = wp.zeros(1, dtype=wp.int32)
            self.max_angle = wp.zeros(W, dtype=f32)
            nrec = -(-max_chunk // every) if every else 0
            self.rec = wp.zeros((W, max(nrec, 1), self.nq + self.nv), dtype=f32)
        self.chunks = _Chunks(device)
        self.step = 0
        self._n = 0

    def _body(self, k: int) -> None:
        dx, dev = self.dx, self.device
        if self.every and k % self.every == 0:
            wp.launch(_record_state, self.W, inputs=[dx.qpos, dx.qvel, k // self.every, self.rec],
                      device=dev)  # fmt: skip
        wp.launch(
            _delayed_gain_control, self.W,
            inputs=[dx.qpos, self.th_adr, self.u_idx, self.length, self.gain, self.scale,
                    self.delay, self.xi, k, self.step_dev, self.hist, dx.ctrl, self.max_angle],
            device=dev,
        )  # fmt: skip
        mjw.step(self.mx, dx)
        if k == self._n - 1:
            wp.launch(_advance_step, 1, inputs=[self.step_dev, self._n], device=dev)

    def advance(self, xi: np.ndarray, *, fetch: bool = True) -> np.ndarray | None:
        """Advance every world by n = xi.shape[1] <= max_chunk steps.

        ``xi`` (W, n, C): the draws of steps step .. step+n-1, world order.
        Returns the recorded (qpos, qvel) before each recorded step,
        (W, ceil(n / every), nq + nv) float32, or None when not recording or
        ``fetch`` is False (the benchmark keeps everything on the device).
        """
        n = xi.shape[1]
        if n > self.max_chunk:
            raise ValueError(f"advance at most {self.max_chunk} steps at a time, got {n}")
        if self.every and self.step % self.every:
            raise ValueError("chunks must start on a recorded step (chunk % every == 0)")
        if n == self.max_chunk:
            self.xi.assign(np.asarray(xi, dtype=np.float32))
        else:
            buf = np.zeros((self.W, self.max_chunk, self.nc), dtype=np.float32)
            buf[:, :n] = xi
            self.xi.assign(buf)
        self._n = n
        self.chunks.run(n, self._body)
        self.step += n
        if not (self.every and fetch):
            return None
        return self.rec.numpy()[:, : -(-n // self.every)]

    def synchronize(self) -> None:
        wp.synchronize_device(self.device)

    def max_abs_angle(self) -> np.ndarray:
        """Largest |theta| (rad) of each world after steps 1 .. step (inf once non-finite)."""
        a = np.abs(self.dx.qpos.numpy()[:, self.i_th].astype(float)).max(axis=1)
        a = np.where(np.isfinite(a), a, np.inf)
        return (
            np.maximum(self.max_angle.numpy().astype(float), a) if self.step else np.zeros_like(a)
        )

    def fields(self, rec: np.ndarray, length: np.ndarray) -> dict[str, np.ndarray]:
        """The shared schema's fields (..., C) from recorded (qpos, qvel) (W, S, nq + nv).

        ``length`` (W,) pendulum lengths L (m).  e = L sin(theta) (m),
        e' = L cos(theta) theta' (m/s), tip = cart + e.
        """
        rec = rec.astype(float)
        L = np.asarray(length, dtype=float).reshape(-1, *([1] * (rec.ndim - 1)))
        th = rec[..., self.i_th]
        x = rec[..., self.i_x]
        v = rec[..., self.nq + self.i_vx]
        e = L * np.sin(th)
        edot = L * np.cos(th) * rec[..., self.nq + self.i_om]
        return schema_fields(x, v, e, edot, th)
