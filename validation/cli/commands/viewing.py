"""Seeing the model move: render (a GIF or MP4 of a simulated run), view (MuJoCo's viewer)."""

from __future__ import annotations

import argparse
import os
import time

from cip.names import cart_joint, hinge_joint
from cipcore.params import ParameterError
from cipcore.registry import get_engine
from validation.cli.args import (
    EXIT_OK,
    add_engine_arg,
    add_force_arg,
    add_model_args,
    add_seed_arg,
    add_stepper_arg,
    check_out_file,
    check_work,
    engine_options,
    params_from_args,
)
from validation.cli.ci_options import progress_enabled
from validation.cli.commands.simulation import add_physical_args, physical_from_args
from validation.cli.domains import add_option
from validation.cli.main import add_command, command


def _add_run_args(p: argparse.ArgumentParser) -> None:
    add_model_args(p)
    add_engine_arg(p, default="mujoco")
    add_stepper_arg(p)
    add_option(p, "--duration", domain="duration", default=10.0, help="simulated time (s)")
    add_seed_arg(p, 0, "root seed (the same draws as every other command)")
    add_option(p, "--realization", domain="realization", default=0,
               help="which realisation of the seed to show (index >= 0)")  # fmt: skip
    add_option(p, "--amplitude", domain="amplitude", default=0.01,
               help="initial balancing error (m)")  # fmt: skip
    add_physical_args(p, note="; the rigid body drawn (and simulated by rigid-body engines)")
    add_option(p, "--fps", domain="fps", default=30.0, help="frames per second (1/s)")
    add_force_arg(p)


def _simulate(a: argparse.Namespace):
    """(trajectory, pendulum length L, rigid-body MjModel, joint positions (S, C, 2))."""
    from cip.model import build
    from validation.checks.divergence import pendulum_length
    from validation.report.animation import joint_positions

    params = params_from_args(a)
    phys = physical_from_args(a)
    engine = get_engine(a.engine)
    kw = engine_options(a, engine)
    if engine.capabilities.rigid_body:
        kw["physical"] = phys
    decimate = max(1, round(1.0 / (a.fps * params.dt)))
    n = a.realization + 1  # realisation r draws the same noise whatever the count
    check_work("--duration", n, a.duration, params.dt, force=a.force)
    tr = engine.simulate(a.model, params, a.duration, n, a.seed, amplitude=a.amplitude,
                         decimate=decimate, progress=progress_enabled(), **kw)  # fmt: skip
    length = pendulum_length(params)
    return tr, build(a.model, phys), joint_positions(tr, length, a.realization), decimate


#: memory of all frames (bytes) a render may ask for (a frame's side: the "pixels" domain)
MAX_FRAME_BYTES = 2 * 1024**3


def check_frames(a: argparse.Namespace, pixels: bool = True) -> None:
    """Before any work: the frames' memory (frames x width x height x 3 bytes with
    ``pixels``, else the recorded run's: frames x realisations x 8 fields x 8 bytes)."""
    step = max(1, round(1.0 / (a.fps * a.dt))) * a.dt  # s between frames (whole steps)
    frames = a.duration / step + 1
    size = a.width * a.height * 3 if pixels else (a.realization + 1) * 64
    need = frames * size
    if need > MAX_FRAME_BYTES:
        raise ParameterError(
            f"--duration {a.duration:g} s at --fps {a.fps:g} is {frames:.3g} frames"
            + (f" of {a.width}x{a.height} pixels" if pixels else "")
            + f" ({need / 1024**3:.3g} GiB); at most "
            f"{MAX_FRAME_BYTES / 1024**3:g} GiB of frames: lower "
            + ("--duration, --fps, --width or --height" if pixels else "--duration or --fps")
        )


@command(
    "Simulate a run of any engine (same seed and parameters as the other commands) and draw it on "
    "the rigid-body model with MuJoCo's offscreen renderer (MUJOCO_GL=egl or osmesa)."
)
def cmd_render(a: argparse.Namespace) -> int:
    from validation.report.animation import (
        check_video_path,
        choose_gl_backend,
        draw_overlay,
        overlay_lines,
        render_frames,
        write_video,
    )

    out = check_out_file("--out", a.out, (".gif", ".mp4"))
    check_video_path("--out", out)
    check_frames(a)
    if choose_gl_backend() == "already initialised":
        # MuJoCo was imported (by this process) before an offscreen OpenGL backend
        # could be chosen: render in a child process that chooses it first
        import os
        import subprocess
        import sys

        from validation.report.animation import GL_BACKENDS

        env = {**os.environ, "MUJOCO_GL": GL_BACKENDS[0]}
        cmd = [sys.executable, "-m", "validation.cli.main", *a.argv]
        return subprocess.run(cmd, env=env).returncode
    tr, mj_model, pos, decimate = _simulate(a)
    frames = render_frames(mj_model, pos, a.width, a.height)
    text = overlay_lines(tr, pos, a.realization, tr.attrs.get("engine") or a.engine, a.model)
    frames = [draw_overlay(f, *text[k]) for k, f in enumerate(frames)]
    fps = 1.0 / (decimate * tr.attrs["dt"])
    write_video(frames, out, fps)
    shown = len(frames) / fps
    print(f"{out}: {len(frames)} frames at {fps:.4g} frames/s ({shown:.4g} s of the run), "
          f"{a.engine} {a.model}, seed {a.seed}, realisation {a.realization}")  # fmt: skip
    return EXIT_OK


@command(
    "Play a simulated run in MuJoCo's passive viewer, in real time, until the window is closed "
    "(needs a display)."
)
def cmd_view(a: argparse.Namespace) -> int:
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ParameterError(
            "view needs a display (DISPLAY and WAYLAND_DISPLAY are unset); "
            "use `cip-validate render --out run.gif` instead"
        )
    check_frames(a, pixels=False)
    import mujoco
    import mujoco.viewer

    tr, mj_model, pos, decimate = _simulate(a)
    data = mujoco.MjData(mj_model)
    step = decimate * tr.attrs["dt"]
    adr = [(mj_model.joint(cart_joint(i)).qposadr[0], mj_model.joint(hinge_joint(i)).qposadr[0])
           for i in range(1, pos.shape[1] + 1)]  # fmt: skip
    with mujoco.viewer.launch_passive(mj_model, data) as viewer:
        while viewer.is_running():
            for k in range(pos.shape[0]):
                if not viewer.is_running():
                    break
                t = time.perf_counter()
                for i, (ax, ath) in enumerate(adr):
                    data.qpos[ax], data.qpos[ath] = pos[k, i]
                mujoco.mj_forward(mj_model, data)
                viewer.sync()
                time.sleep(max(0.0, step - (time.perf_counter() - t)))
    return EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``render`` and ``view`` to the parser."""
    p = add_command(sub, "render", cmd_render)
    _add_run_args(p)
    add_option(p, "--width", domain="pixels", default=480, help="frame width (pixels)")
    add_option(p, "--height", domain="pixels", default=320, help="frame height (pixels)")
    add_option(p, "--out", domain="video out", required=True, metavar="FILE.gif",
                   help="video file (.gif, or .mp4 with ffmpeg), required")  # fmt: skip

    p = add_command(sub, "view", cmd_view)
    _add_run_args(p)
