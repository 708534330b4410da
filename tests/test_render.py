"""cip-validate render / view: a GIF of a run on the rigid-body model; view without a display."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from validation.cli import main


def test_render_writes_a_gif_of_the_run(tmp_path):
    gif = tmp_path / "run.gif"
    cmd = [sys.executable, "-m", "validation.cli", "render", "--model", "coupled", "--beta",
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

    from validation.harness import clips
    from validation.profiles import PROFILES
    from validation.report import html_report

    prof = dataclasses.replace(PROFILES["quick"], clip_duration=0.4)
    files = clips(tmp_path, prof)
    err = capsys.readouterr().err
    if not files and "no offscreen OpenGL" in err:
        pytest.skip(err.strip().splitlines()[-1])
    assert [f.name for f in files] == [
        "clip_inside_small_angle.gif",
        "clip_outside_small_angle.gif",
    ]
    md = "\n".join(f"![{f.name}]({f.name})" for f in files)
    page = html_report(md, tmp_path)
    assert page.count('src="data:image/gif;base64,') == 2
    assert clips(tmp_path, dataclasses.replace(prof, clip_duration=0.0)) == []
