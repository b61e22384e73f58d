"""Reading a file that may be hostile: only a regular file, never more than a stated size.

A FIFO blocks ``open`` until a writer comes, a character device (``/dev/zero``) or a
kernel file (``/proc/kmsg``) never ends or blocks on read, and a sparse or huge file
makes a reader allocate what it states.  So the path is checked with ``stat`` (regular
file, not on procfs or sysfs), opened with ``O_NONBLOCK`` (an open never waits), checked
again with ``fstat`` on what was opened (the same file, still regular), and read
up to ``limit + 1`` bytes at most.
"""
from __future__ import annotations

import io
import os
import stat
from pathlib import Path

from ..errors import AccelcalError, DataError

PSEUDO_ROOTS = ("/proc", "/sys")  # kernel files: sizes they report are not what a read returns


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _on_pseudo_fs(path: Path, st: os.stat_result) -> bool:
    """A /proc or /sys entry, by its resolved path or by the file system it lives on."""
    real = os.path.realpath(path)
    for root in PSEUDO_ROOTS:
        if real == root or real.startswith(root + "/"):
            return True
        try:
            if os.stat(root).st_dev == st.st_dev:
                return True
        except OSError:
            continue
    return False


def check_regular(path: str | Path, what: str, error: type[AccelcalError] = DataError) -> os.stat_result:
    """``path``'s stat when it is a regular file outside /proc and /sys, else one ``error`` line."""
    p = Path(path)
    try:
        st = os.stat(p)
    except (OSError, ValueError) as e:  # ValueError: a NUL byte in the name
        raise error(f"{p}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{p}: {_kind(st.st_mode)}; allowed: a regular file ({what})")
    if _on_pseudo_fs(p, st):
        raise error(f"{p}: a kernel file (/proc or /sys); allowed: a regular file ({what})")
    return st


def open_regular(path: str | Path, what: str, error: type[AccelcalError] = DataError) -> io.BufferedReader:
    """A binary reader on ``path``, which is and stays a regular file (module doc)."""
    p = Path(path)
    st = check_regular(p, what, error)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as e:
        raise error(f"{p}: cannot read ({e.strerror or e})") from None
    try:
        now = os.fstat(fd)
        if not stat.S_ISREG(now.st_mode) or (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
            raise error(f"{p}: changed while being opened ({_kind(now.st_mode)} now); allowed: a regular file")
        return io.BufferedReader(io.FileIO(fd, "rb", closefd=True))
    except BaseException:
        os.close(fd)
        raise


def _size_text(n: int) -> str:
    return f"{n / (1 << 20):g} MiB" if n >= 1 << 20 else f"{n} bytes"


def read_bytes(path: str | Path, what: str, limit_bytes: int, why: str,
               error: type[AccelcalError] = DataError) -> bytes:
    """At most ``limit_bytes`` of a regular file; a larger one is refused with the limit and ``why``."""
    p = Path(path)
    with open_regular(p, what, error) as f:
        size = os.fstat(f.fileno()).st_size
        if size > limit_bytes:  # refused by its stated size before a byte is read
            raise error(f"{p}: {size} bytes; {what} is at most {_size_text(limit_bytes)} ({why})")
        try:
            data = f.read(limit_bytes + 1)
        except OSError as e:
            raise error(f"{p}: cannot read ({e.strerror or e})") from None
    if len(data) > limit_bytes:  # grew while read
        raise error(f"{p}: more than {_size_text(limit_bytes)}; {what} is at most that ({why})")
    return data


def read_text(path: str | Path, what: str, limit_bytes: int, why: str,
              error: type[AccelcalError] = DataError) -> str:
    """``read_bytes`` decoded as UTF-8 (a leading BOM dropped); other bytes are one line."""
    data = read_bytes(path, what, limit_bytes, why, error)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise error(f"{path}: not a text file (expected {what}; line {line} has byte 0x{data[e.start]:02x}, "
                    "not UTF-8)") from None
