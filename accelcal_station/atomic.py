"""The one way the station replaces a file: whole or not at all, never through a symlink.

A unique temporary file is created with O_EXCL (no planted file or symlink is ever
opened) in the target's folder, written, fsynced and renamed over the target.  A target
that is a symlink, directory, device or FIFO is refused, not replaced; a replaced file
keeps its permission bits.  Errors are OSError with a strerror that says why.
"""
from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

from .errors import DataError


def check_target(path: str | Path) -> int | None:
    """Refuse a target that is not a regular file (or absent); returns its mode bits or None."""
    p = Path(path)
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return None
    if stat.S_ISLNK(st.st_mode):
        raise OSError(errno.ELOOP, "is a symbolic link; refusing to write through it", str(p))
    if stat.S_ISDIR(st.st_mode):
        raise OSError(errno.EISDIR, "is a directory, not a file", str(p))
    if not stat.S_ISREG(st.st_mode):
        raise OSError(errno.EINVAL, "is a device, FIFO or socket, not a regular file", str(p))
    return stat.S_IMODE(st.st_mode)


def atomic_write(path: str | Path, data: bytes | str | Callable[[str], None]) -> None:
    """Replace ``path`` with ``data`` (bytes, text, or a function writing a given temp path)."""
    p = Path(path)
    mode = check_target(p)
    if mode is None:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
    try:
        if callable(data):
            os.close(fd)
            fd = -1
            data(tmp)  # e.g. matplotlib's savefig: writes the (new, private) temp file by name
            fd = os.open(tmp, os.O_RDWR | os.O_NOFOLLOW)
        else:
            raw = data.encode() if isinstance(data, str) else bytes(data)
            view = memoryview(raw)
            while view:
                view = view[os.write(fd, view):]
        os.fchmod(fd, mode)
        os.fsync(fd)
        os.close(fd)
        fd = -1
        check_target(p)  # still not a symlink/device planted meanwhile (rename replaces the name only)
        os.replace(tmp, p)
    except BaseException:
        if fd >= 0:
            os.close(fd)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """``atomic_write`` for the commands' own outputs: a failure is one DataError line naming the file."""
    try:
        atomic_write(path, text)
    except OSError as e:
        raise DataError(f"{path}: cannot write ({e.strerror or e})") from None
