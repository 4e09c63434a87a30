"""Atomic file writes: write a temporary file beside the target, then rename it."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from espin.core.errors import RVEFileError

__all__ = ["atomic_write_bytes", "atomic_write"]


def atomic_write(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp_path)`` and move the finished file onto ``path``.

    The target either keeps its old content or receives the complete new file; a failure
    inside ``write`` leaves no partial file behind.

    Parameters
    ----------
    path
        Destination file. Its folder is created if needed.
    write
        Function that writes the whole file at the temporary path it is given.

    Returns
    -------
    Path
        The destination path.

    Raises
    ------
    RVEFileError
        If the file cannot be written (no permission, a full disk): the old file is kept.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as err:
        raise RVEFileError(f"cannot write {path}: {err.strerror or err}") from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        with open(tmp_path, "rb+") as fh:  # on disk before it replaces the old file
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp creates 0600; give a normal file's mode
        os.replace(tmp_path, path)
    except OSError as err:
        tmp_path.unlink(missing_ok=True)
        if isinstance(err, RVEFileError):
            raise
        raise RVEFileError(f"cannot write {path}: {err.strerror or err} (a full disk?)") from None
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_write(path, lambda tmp: tmp.write_bytes(data))
