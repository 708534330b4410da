"""Frames of a simulated run drawn by MuJoCo's offscreen renderer (GIF / MP4 writer at the edge).

Any engine's :class:`cipcore.schema.Trajectory` is shown on the rigid-body
model (:func:`cip.model.build`): the carts at ``base_position`` (m) and the
poles at ``angle`` (rad) where the run records it, else at
theta = arcsin(e / L) from the balancing error e = L sin(theta) (the reduced
model; |e| > L is drawn as a pole lying flat).  Offscreen rendering needs an
OpenGL backend: ``MUJOCO_GL=egl`` (Debian ``libegl1``, ``libgl1-mesa-dri``) or
``MUJOCO_GL=osmesa`` (``libosmesa6``), chosen before MuJoCo is imported.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from cip.names import cart_joint, hinge_joint
from cipcore.atomic import atomic_path, write_with
from cipcore.params import ParameterError
from cipcore.schema import Trajectory

#: offscreen OpenGL backends MuJoCo can use, in the order tried when MUJOCO_GL is unset
GL_BACKENDS = ("egl", "osmesa")
VIDEO_SUFFIXES = (".gif", ".mp4")


def choose_gl_backend() -> str:
    """Set MUJOCO_GL (if unset) before MuJoCo is imported; returns the backend in use."""
    import sys

    if "mujoco" in sys.modules and "MUJOCO_GL" not in os.environ:
        return "already initialised"
    return os.environ.setdefault("MUJOCO_GL", GL_BACKENDS[0])


def joint_positions(tr: Trajectory, length: float, realization: int) -> np.ndarray:
    """(S, C, 2) cart position (m) and pole angle (rad) of one realisation over time."""
    x = np.asarray(tr["base_position"][realization], dtype=float)
    if "angle" in tr.data:
        th = np.asarray(tr["angle"][realization], dtype=float)
    else:
        e = np.asarray(tr["balancing_error"][realization], dtype=float)
        with np.errstate(invalid="ignore"):
            th = np.arcsin(np.clip(e / length, -1.0, 1.0))
    return np.stack([x, th], axis=-1)


def render_frames(
    mj_model, positions: np.ndarray, width: int = 480, height: int = 320
) -> list[np.ndarray]:
    """RGB frames (height, width, 3) uint8, one per row of ``positions`` (S, C, 2).

    Joints ``x_M<i>`` and ``theta_<i>`` of the rigid-body model are set from
    ``positions``; a non-finite sample ends the frames (the run diverged there).
    Shadows and the floor's reflection are not drawn: on a software OpenGL
    (Mesa's llvmpipe, what CI and most servers have) they took about 80% of the
    rendering time (55 against 11 ms of CPU per 640 x 400 frame) and show nothing
    of the motion.
    """
    import mujoco

    data = mujoco.MjData(mj_model)
    g = mj_model.vis.global_  # the offscreen buffer must hold the frame
    g.offwidth, g.offheight = max(g.offwidth, width), max(g.offheight, height)
    mj_model.vis.headlight.ambient[:] = 0.5
    mj_model.vis.headlight.diffuse[:] = 0.7
    n_c = positions.shape[1]
    adr = [
        (mj_model.joint(cart_joint(i)).qposadr[0], mj_model.joint(hinge_joint(i)).qposadr[0])
        for i in range(1, n_c + 1)
    ]
    try:
        renderer = mujoco.Renderer(mj_model, height, width)
    except Exception as exc:  # no OpenGL context: one line, with what to install
        raise ParameterError(
            f"render: no offscreen OpenGL ({type(exc).__name__}: {exc}); install Debian "
            "libegl1 libgl1-mesa-dri (MUJOCO_GL=egl) or libosmesa6 (MUJOCO_GL=osmesa)"
        ) from None
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
    cam = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(mj_model, cam)
    frames = []
    with renderer:
        for k in range(positions.shape[0]):
            if not np.isfinite(positions[k]).all():
                break
            for i, (ax, ath) in enumerate(adr):
                data.qpos[ax], data.qpos[ath] = positions[k, i]
            mujoco.mj_forward(mj_model, data)
            if k == 0:
                cam.lookat[:] = [data.qpos[[a for a, _ in adr]].mean(), 0.0, 0.25]
                cam.distance, cam.elevation, cam.azimuth = 2.0, -5.0, 90.0
            renderer.update_scene(data, camera=cam)
            frames.append(renderer.render().copy())
    return frames


def overlay_lines(
    tr: Trajectory, positions: np.ndarray, realization: int, engine: str, model: str
) -> list[tuple[list[str], str]]:
    """Per frame: the overlay's text lines and the regime it names.

    Lines: the time (s); the angles theta_i (rad); the balancing errors
    (Delta x for one controller, Delta q_i for two; m); the engine and model;
    whether every angle is inside the small-angle regime |theta| <= theta_s
    (:func:`cip.model.small_angle_limit`), outside it, or fallen (|theta| >
    pi/2).  The regime is one of "inside", "outside", "fallen".
    """
    from cip.model import small_angle_limit

    limit = small_angle_limit()
    e = np.asarray(tr["balancing_error"][realization], dtype=float)
    n_c = positions.shape[1]
    names = ["Delta x"] if n_c == 1 else [f"Delta q{i + 1}" for i in range(n_c)]
    out = []
    for k in range(positions.shape[0]):
        th = positions[k, :, 1]
        largest = float(np.max(np.abs(th)))
        if largest > np.pi / 2:
            regime, text = "fallen", "FALLEN: |theta| > pi/2"
        elif largest > limit:
            regime, text = "outside", f"OUTSIDE the small-angle regime (|theta| > {limit:.3g} rad)"
        else:
            regime, text = "inside", f"inside the small-angle regime (|theta| <= {limit:.3g} rad)"
        lines = [
            f"t = {float(tr.time[k]):6.2f} s      engine {engine}, {model} model",
            "   ".join(f"theta{i + 1} = {th[i]:+.4f} rad" for i in range(n_c)),
            "   ".join(f"{names[i]} = {e[k, i]:+.3e} m" for i in range(n_c)),
            text,
        ]
        out.append((lines, regime))
    return out


#: overlay colour of each regime's line (RGB)
REGIME_COLOURS = {"inside": (120, 230, 120), "outside": (255, 190, 60), "fallen": (255, 90, 90)}


def draw_overlay(frame: np.ndarray, lines: list[str], regime: str) -> np.ndarray:
    """``frame`` (H, W, 3) uint8 with ``lines`` on a dark box at the top left.

    The last line (the regime) is drawn in the regime's colour
    (:data:`REGIME_COLOURS`); the font is matplotlib's DejaVu Sans, sized to
    the frame (about 1/26 of its height).  Only the top-left region the box and
    the text cover is composited (every other pixel is left as it is: the same
    frame as compositing the whole of it, in a tenth of the pixel work).
    """
    from PIL import Image, ImageDraw

    size = max(9, round(frame.shape[0] / 26))
    font = _overlay_font(size)
    pad, step = 6, round(size * 1.3)
    width = max(font.getlength(t) for t in lines)
    box = (0, 0, width + 2 * pad, pad * 2 + step * len(lines))
    tops = [pad + j * step for j in range(len(lines))]
    # the region from the top-left corner that the box and every line's glyphs touch
    glyphs = [font.getbbox(t) for t in lines]
    right = max([box[2]] + [g[2] + pad for g in glyphs])
    bottom = max([box[3]] + [g[3] + y for g, y in zip(glyphs, tops, strict=True)])
    h, w = frame.shape[:2]
    region = (0, 0, min(w, int(np.ceil(right)) + 1), min(h, int(np.ceil(bottom)) + 1))
    img = Image.fromarray(frame)
    part = img.crop(region).convert("RGBA")
    layer = Image.new("RGBA", part.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    draw.rectangle(box, fill=(0, 0, 0, 150))
    for j, (t, y) in enumerate(zip(lines, tops, strict=True)):
        colour = REGIME_COLOURS[regime] if j == len(lines) - 1 else (255, 255, 255)
        draw.text((pad, y), t, font=font, fill=(*colour, 255))
    img.paste(Image.alpha_composite(part, layer).convert("RGB"), region[:2])
    return np.asarray(img)


#: DejaVu Sans as matplotlib ships it (``mpl-data/fonts/ttf``), found without importing
#: matplotlib (0.3 s of a clip's start-up with its font manager)
_BUNDLED_FONT = ("mpl-data", "fonts", "ttf", "DejaVuSans.ttf")


@lru_cache(maxsize=4)
def _overlay_font(size: int):
    """DejaVu Sans at ``size`` px (found and loaded once per size, not once per frame):
    matplotlib's bundled file, else the font its font manager finds."""
    import importlib.util
    import os

    from PIL import ImageFont

    spec = importlib.util.find_spec("matplotlib")
    for root in (spec.submodule_search_locations or []) if spec else []:
        path = os.path.join(root, *_BUNDLED_FONT)
        if os.path.isfile(path):
            return ImageFont.truetype(path, size)
    from matplotlib import font_manager

    return ImageFont.truetype(font_manager.findfont("DejaVu Sans"), size)


def gif_palette(frames: list[np.ndarray]):
    """One 256-colour palette image for every frame of a GIF.

    Built (Pillow's fast octree) from the first and the last frame side by side and
    a strip of the overlay's regime colours, so every frame maps to the same colours
    without dithering.  Quantising each frame on its own (median cut) took 14 ms
    per 640 x 400 frame and gave each frame its own local palette; mapping to
    this one takes 0.4 ms.
    """
    from PIL import Image

    w = frames[0].shape[1]
    strip = np.zeros((8, w, 3), dtype=np.uint8)
    for j, rgb in enumerate(REGIME_COLOURS.values()):
        strip[:, j * w // 4 : (j + 1) * w // 4] = rgb
    strip[:, 3 * w // 4 :] = 255  # the overlay's white text
    source = np.concatenate([frames[0], frames[-1], strip], axis=0)
    return Image.fromarray(source).quantize(256, method=Image.Quantize.FASTOCTREE)


def check_video_path(option: str, path: str | Path) -> Path:
    """``path`` ends in .gif or .mp4 (.mp4 needs ffmpeg on PATH)."""
    import shutil

    p = Path(path)
    if p.suffix.lower() == ".mp4" and shutil.which("ffmpeg") is None:
        raise ParameterError(f"{option}: .mp4 needs ffmpeg on PATH (not found); write a .gif")
    return p


def write_video(frames: list[np.ndarray], path: Path, fps: float) -> Path:
    """Write ``frames`` as an animated GIF (Pillow) or an MP4 (matplotlib's ffmpeg writer)."""
    if not frames:
        raise ParameterError("render: no finite frame to write (the run diverged at once)")
    if path.suffix.lower() == ".gif":
        from PIL import Image

        palette = gif_palette(frames)
        images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE)
                  for f in frames]  # fmt: skip
        write_with(path, lambda tmp: images[0].save(tmp, format="GIF", save_all=True,
                   append_images=images[1:], duration=round(1000 / fps), loop=0))  # fmt: skip
        return path
    import matplotlib.pyplot as plt
    from matplotlib.animation import FFMpegWriter

    h, w = frames[0].shape[:2]
    fig = plt.figure(figsize=(w / 100, h / 100), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.axis("off")
    im = ax.imshow(frames[0])
    writer = FFMpegWriter(fps=fps)
    with atomic_path(path, keep_suffix=True) as tmp, writer.saving(fig, str(tmp), dpi=100):
        for f in frames:
            im.set_data(f)
            writer.grab_frame()
    plt.close(fig)
    return path
