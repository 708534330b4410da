"""cip-validate render / view: a GIF of a run on the rigid-body model; view without a display."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from validation.cli.main import main


def test_render_writes_a_gif_of_the_run(tmp_path):
    gif = tmp_path / "run.gif"
    cmd = [sys.executable, "-m", "validation.cli.main", "render", "--model", "coupled", "--beta",
           "21.032", "--amplitude", "0.05", "--duration", "0.5", "--fps", "20", "--width", "160",
           "--height", "120", "--out", str(gif)]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if res.returncode == 2 and "no offscreen OpenGL" in res.stderr:
        pytest.skip(res.stderr.strip().splitlines()[-1])
    assert res.returncode == 0, res.stderr
    from PIL import Image

    with Image.open(gif) as im:
        assert im.size == (160, 120) and im.n_frames == 10
        im.seek(0)
        first = np.asarray(im.convert("RGB"), dtype=float)
        im.seek(9)
        last = np.asarray(im.convert("RGB"), dtype=float)
    assert first.std() > 5  # a drawn scene, not a blank frame
    assert np.abs(first - last).max() > 0  # the poles moved


def test_view_without_a_display_is_one_line(capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", "--beta", "20"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "display" in err[0] and "render" in err[0]
    assert "DISPLAY" not in os.environ


def test_report_clips_inside_and_outside_the_small_angle_regime(tmp_path, capsys):
    """The run's figures stage renders two clips and the HTML report embeds them as GIFs."""
    import dataclasses

    from validation.profiles import PROFILES
    from validation.report.document import figure_lines, html_report
    from validation.run import clips

    prof = dataclasses.replace(PROFILES["quick"], clip_duration=0.4)
    files = clips(tmp_path, prof)
    err = capsys.readouterr().err
    if not files and "no offscreen OpenGL" in err:
        pytest.skip(err.strip().splitlines()[-1])
    assert [f.name for f in files] == [
        "clip_inside_small_angle.gif",
        "clip_outside_small_angle.gif",
    ]
    from PIL import Image

    for f in files:
        with Image.open(f) as im:
            assert im.size == (640, 400)  # readable in the report
    md = "\n".join(figure_lines([f.name for f in files], prof.as_dict()))
    page = html_report(md, tmp_path)
    assert page.count('src="data:image/gif;base64,') == 2
    assert page.count("<figcaption><b>Figure") == 2
    assert "initial balancing error 0.001 m" in page and "inside the small-angle" in page
    assert "initial balancing error 0.1 m" in page and "leaving the small-angle" in page
    assert clips(tmp_path, dataclasses.replace(prof, clip_duration=0.0)) == []


def test_clip_overlay_names_time_angles_errors_engine_and_regime():
    """The overlay's text per frame, and that it is drawn (no OpenGL needed)."""
    from cipcore.schema import Trajectory
    from validation.report.animation import draw_overlay, overlay_lines

    t = np.array([0.0, 0.5, 1.0])
    th = np.array([[[0.01, -0.02], [0.1, 0.05], [2.0, 0.3]]])  # inside, outside, fallen
    tr = Trajectory(t, {"balancing_error": 0.446 * np.sin(th), "angle": th}, {"dt": 0.001})
    pos = np.stack([np.zeros_like(th[0]), th[0]], axis=-1)
    text = overlay_lines(tr, pos, 0, "mujoco", "coupled")
    assert [r for _, r in text] == ["inside", "outside", "fallen"]
    lines = text[1][0]
    assert lines[0].startswith("t =   0.50 s") and "mujoco, coupled model" in lines[0]
    assert "theta1 = +0.1000 rad" in lines[1] and "theta2 = +0.0500 rad" in lines[1]
    assert "Delta q1 = +4.453e-02 m" in lines[2] and "Delta q2" in lines[2]
    assert lines[3].startswith("OUTSIDE the small-angle regime")
    frame = np.full((400, 640, 3), 200, dtype=np.uint8)
    drawn = draw_overlay(frame, *text[0])
    assert drawn.shape == frame.shape
    box = drawn[:100, :300].astype(int)
    assert (np.abs(box - 200) > 50).mean() > 0.2  # a dark box with text on it
    assert np.array_equal(drawn[300:], frame[300:])  # the scene below is untouched


def _whole_frame_overlay(frame, lines, regime):
    """The overlay composited over the whole frame (the reference for the region-only one)."""
    from PIL import Image, ImageDraw

    from validation.report.animation import REGIME_COLOURS, _overlay_font

    img = Image.fromarray(frame).convert("RGBA")
    size = max(9, round(frame.shape[0] / 26))
    font = _overlay_font(size)
    layer = Image.new("RGBA", img.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    pad, step = 6, round(size * 1.3)
    width = max(draw.textlength(t, font=font) for t in lines)
    draw.rectangle((0, 0, width + 2 * pad, pad * 2 + step * len(lines)), fill=(0, 0, 0, 150))
    for j, t in enumerate(lines):
        colour = REGIME_COLOURS[regime] if j == len(lines) - 1 else (255, 255, 255)
        draw.text((pad, pad + j * step), t, font=font, fill=(*colour, 255))
    return np.asarray(Image.alpha_composite(img, layer).convert("RGB"))


@pytest.mark.parametrize("shape", [(400, 640), (120, 160), (30, 40)])
def test_overlay_over_its_region_equals_the_whole_frame_composite(shape):
    """Descenders, a last line wider than the others, text running off a small frame:
    the same pixels as compositing the whole frame, every other pixel untouched."""
    from validation.report.animation import draw_overlay

    frame = np.random.default_rng(5).integers(0, 256, (*shape, 3), dtype=np.uint8)
    lines = ["t =  12.35 s      engine mujoco, coupled model", "gjpqy |theta| (rad)",
             "OUTSIDE the small-angle regime (|theta| > 0.0822 rad)"]  # fmt: skip
    for regime in ("inside", "outside", "fallen"):
        np.testing.assert_array_equal(draw_overlay(frame, lines, regime),
                                      _whole_frame_overlay(frame, lines, regime))  # fmt: skip
