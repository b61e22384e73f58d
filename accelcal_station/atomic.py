"""The one way the station replaces a file: whole or not at all, never through a symlink.

``atomic_write(path, data)`` is the writer: whole content, a function that writes a given
temporary path, or (``with atomic_write(path) as f``) output produced in pieces (a results
table chunk by chunk, a raw log).  Every form:

- create the temporary file with ``tempfile.mkstemp`` (O_CREAT | O_EXCL: a planted file or
  symlink is never opened, never followed) in the target's folder, under an unpredictable
  name ``.NAME.accelcal-PID-RANDOM.tmp`` that says which file and which process it belongs to;
- write, fsync, re-check the target and rename over it (then fsync the folder); a target that
  is a symlink, directory, device or FIFO is refused, not replaced; a replaced file keeps its
  permission bits;
- remove the temporary file on any error, and before starting remove the temporaries of
  the same target left by a killed run (their PID no longer alive, see ``remove_stale``).

Errors are :class:`WriteError`: a DataError (one line naming the file, exit 2) that is also an
OSError (``errno``, ``strerror``), so callers that speak OSError keep working.
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any, overload

from .errors import DataError

TAG = "accelcal"  # the recognisable part of every temporary name: .NAME.accelcal-PID-RANDOM.tmp


class WriteError(DataError, OSError):
    """A file could not be written (what and why on one line); an OSError with errno and strerror."""

    def __init__(self, path: str | Path, err: OSError) -> None:
        why = err.strerror or str(err)
        super().__init__(err.errno or errno.EIO, why)
        self.line = " ".join(f"{path}: cannot write ({why})".split())

    def __str__(self) -> str:
        return self.line


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


def _prefix(p: Path) -> str:
    return f".{p.name}.{TAG}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def remove_stale(path: str | Path) -> list[Path]:
    """Remove the temporaries of ``path`` whose owning process is dead (a killed earlier run).

    Only names of the form ``.NAME.accelcal-PID-RANDOM.tmp`` beside ``path``, only regular files
    owned by this user (a planted symlink is unlinked as a name, never followed); returns them.
    """
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    pattern = re.compile(rf"^\.{re.escape(p.name)}\.{TAG}-(\d+)-[^/]*\.tmp$")
    removed: list[Path] = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        m = pattern.match(name)
        if m is None or _alive(int(m.group(1))):
            continue
        q = folder / name
        with contextlib.suppress(OSError):
            st = os.lstat(q)
            if stat.S_ISLNK(st.st_mode) or (stat.S_ISREG(st.st_mode) and st.st_uid == os.getuid()):
                os.unlink(q)
                removed.append(q)
    return removed


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):  # not every file system lets a folder be fsynced
        dfd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


@contextlib.contextmanager
def _stream(path: str | Path, binary: bool = False) -> Iterator[tuple[IO[Any], str]]:
    """Yield an open temporary file beside ``path`` and its name; on a clean exit it replaces ``path``."""
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    try:
        mode = check_target(p)
        remove_stale(p)
        if mode is None:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        fd, tmp = tempfile.mkstemp(prefix=_prefix(p), suffix=".tmp", dir=folder)
    except OSError as e:
        raise WriteError(p, e) from None
    try:
        with os.fdopen(fd, "wb" if binary else "w", newline="" if not binary else None) as f:
            yield f, tmp
            f.flush()
            os.fchmod(f.fileno(), mode)
            os.fsync(f.fileno())
        check_target(p)  # still not a symlink/device planted meanwhile (rename replaces the name only)
        os.replace(tmp, p)
        _fsync_dir(folder)
    except OSError as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise WriteError(p, e) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@overload
def atomic_write(path: str | Path, data: bytes | str | Callable[[str], None]) -> None: ...


@overload
def atomic_write(path: str | Path, data: None = None, *, binary: bool = False
                 ) -> contextlib.AbstractContextManager[IO[Any]]: ...


def atomic_write(path: str | Path, data: bytes | str | Callable[[str], None] | None = None, *,
                 binary: bool = False) -> contextlib.AbstractContextManager[IO[Any]] | None:
    """Replace ``path`` with ``data`` (bytes, text, or a function writing a given temp path).

    Without ``data``: a context manager yielding the open temporary file (text, or ``binary``)
    for output written in pieces; it replaces ``path`` when the block ends without an error.
    """
    if data is None:
        return _pieces(path, binary)
    with _stream(path, binary=True) as (f, tmp):
        if callable(data):
            data(tmp)  # e.g. matplotlib's savefig: writes the (new, private) temp file by name
        else:
            f.write(data.encode() if isinstance(data, str) else bytes(data))
    return None


@contextlib.contextmanager
def _pieces(path: str | Path, binary: bool) -> Iterator[IO[Any]]:
    with _stream(path, binary) as (f, _):
        yield f
