"""Atomic output files: every file the suite writes appears whole or not at all.

One job.  :func:`atomic_path` hands out a temporary name in the target's own
directory (``.<name>.tmp<pid>``: same file system, and a name no ``*.json`` or
``*.png`` pattern matches, so a file left by a killed process is never taken
for a result; writers that choose a format from the extension are told it, or
ask for ``keep_suffix``); when the caller has written it, the file is flushed
to disk (``fsync``) and renamed over the final name (``os.replace``, atomic on
POSIX); the directory entry is synced too.  On
any error the temporary file is removed, nothing appears under the final name
(an older file there is left as it was), and an :class:`OSError` of the write
(full disk, read-only file system, quota) becomes one :class:`WriteError`
naming the final path.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["WriteError", "atomic_path", "write_bytes", "write_text", "write_with"]


class WriteError(OSError):
    """An output file could not be written; nothing was left under its name.

    ``path`` is the final name, ``reason`` the system's words (e.g. "No space
    left on device"); ``note`` may say where computed results were kept or what
    was lost (set by the caller that knows).
    """

    def __init__(self, path: str | Path, reason: str, note: str = "") -> None:
        super().__init__(f"cannot write {str(path)!r}: {reason}")
        self.path = str(path)
        self.reason = reason
        self.note = note

    def message(self) -> str:
        """One line: the path, the reason, that nothing was written, and the note."""
        text = f"cannot write {self.path!r}: {self.reason} (nothing written under that name)"
        return f"{text}; {self.note}" if self.note else text


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems cannot sync a directory; the rename is still atomic
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | Path, keep_suffix: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it is synced and renamed to ``path``.

    ``keep_suffix`` ends the temporary name with ``path``'s extension
    (``.<stem>.tmp<pid><suffix>``) for a writer that cannot be told the format.

    Raises
    ------
    WriteError
        When writing, syncing or renaming fails with an :class:`OSError`; the
        temporary file is removed and ``path`` is untouched.
    """
    final = Path(path)
    tail = f".tmp{os.getpid()}"
    name = f".{final.stem}{tail}{final.suffix}" if keep_suffix else f".{final.name}{tail}"
    tmp = final.with_name(name)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, final)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, WriteError):
            raise
        raise WriteError(final, exc.strerror or str(exc)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(final.parent)


def write_with(path: str | Path, writer: Callable[[Path], object]) -> Path:
    """``writer(tmp)`` writes the file at a temporary name; then it is moved to ``path``."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return write_with(path, lambda tmp: tmp.write_bytes(data))


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_with(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
