"""Outputs are atomic: a full disk is one line naming the file, exit 2, nothing partial.

Where the test may mount one (root, Linux), a real full disk: a tmpfs of 64 KiB
filled to the brim.  Elsewhere, and for errors at chosen files, a
:class:`helpers.WriteFault` raising ENOSPC.  Every writer under every kind of fault
(the n-th write, ENOSPC, EIO, EACCES) is tested in ``test_write_faults.py``; this file
holds the real full disk and what the messages say beyond the path.
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from helpers import WriteFault

from cipcore.atomic import WriteError, write_text
from validation.cli.main import main


def _mount_full_tmpfs(where: Path) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(where)],
                          capture_output=True)  # fmt: skip
    if done.returncode != 0:
        return False
    fd = os.open(where / "filler", os.O_WRONLY | os.O_CREAT)  # fill it: writes fail with ENOSPC
    try:
        while os.write(fd, b"\0" * 4096):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)
    return True


@pytest.fixture
def full_dir(tmp_path, monkeypatch):
    """A directory on a full file system (a real tmpfs when possible, else a patched writer)."""
    where = tmp_path / "full"
    if _mount_full_tmpfs(where):
        yield where
        subprocess.run(["umount", "-l", str(where)], check=False)
        return
    where.mkdir(exist_ok=True)
    # every write() under it fails after half its data, as on a disk that fills up
    WriteFault(f"{where}/*", "write", errno.ENOSPC, nth=0).install(monkeypatch.setattr)
    yield where


def _fail_at(monkeypatch, name: str) -> None:
    """Make the first ``write()`` of files called ``name`` only fail with ENOSPC."""
    WriteFault(f"*/{name}", "write", errno.ENOSPC).install(monkeypatch.setattr)


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if "cip-validate: error" in ln]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def _leftovers(directory: Path) -> list[str]:
    """Temporary files the atomic writer would leave behind."""
    return [p.name for p in directory.rglob(".*tmp*")]


def test_the_writer_leaves_nothing_and_keeps_an_older_file(full_dir):
    old = full_dir.parent / "results.json"
    old.write_text("older")
    target = full_dir / "a.json"
    with pytest.raises(WriteError) as info:
        write_text(target, "x" * 100_000)
    assert str(target) in info.value.message() and "space" in info.value.message()
    assert not target.exists() and _leftovers(full_dir) == []
    assert old.read_text() == "older"


def test_simulate_on_a_full_disk(capsys, full_dir):
    out = full_dir / "r.npz"
    code = main(["simulate", "--beta", "20", "--duration", "2", "--out", str(out)])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 2
    assert str(out) in line and "No space left on device" in line
    assert "nothing written" in line and "--seed" in line  # what was lost and how to redo it
    assert not out.exists() and _leftovers(full_dir) == []


def test_simulate_writes_the_name_given(capsys, tmp_path):
    out = tmp_path / "r.NPZ"
    assert main(["simulate", "--beta", "20", "--duration", "1", "--out", str(out)]) == 0
    assert out.is_file() and not (tmp_path / "r.NPZ.npz").exists()
    text = capsys.readouterr().out
    assert "diverged: None" not in text


def test_sweep_dataset_write_error_keeps_the_points(capsys, tmp_path, monkeypatch):
    _fail_at(monkeypatch, "sweep.nc")
    out = tmp_path / "sw"
    code = main(["sweep", "--engine", "reduced", "--grid", "beta=20,21", "--metrics", "rms",
                 "--duration", "2", "--realizations", "2", "--workers", "1",
                 "--out", str(out)])  # fmt: skip
    line = _one_error_line(capsys.readouterr().err)
    assert code == 2 and "sweep.nc" in line and "kept in" in line and "points" in line
    assert len(list((out / "points").glob("*.json"))) == 2
    assert not (out / "sweep.nc").exists() and _leftovers(out) == []


def test_stability_plot_and_baseline_on_a_full_disk(capsys, full_dir, tmp_path):
    plot = full_dir / "region.png"
    code = main(["stability", "--beta", "30", "--plot", str(plot), "--beta-grid", "0:80:3",
                 "--tau-grid", "0.05:0.2:3"])  # fmt: skip
    assert code == 2 and str(plot) in _one_error_line(capsys.readouterr().err)
    assert not plot.exists()
    results = tmp_path / "results.json"
    results.write_text('{"cipval_results": 1, "profile": "smoke"}')
    base = full_dir / "b.json"
    code = main(["baseline", "--from", str(results), "--out", str(base)])
    assert code == 2 and str(base) in _one_error_line(capsys.readouterr().err)
    assert not base.exists() and _leftovers(full_dir) == []
