"""The station's event log: ``logging:`` in a station config (``level``, ``file``).

Every module logs under its own name below ``accelcal_station`` (``logging.getLogger(__name__)``):
runs started and finished (``store.runs``), burns (``nvm.writer``), retries and lost ports
(``drivers.*``, ``fixtures.motorized_jig``), the outbox (``store.outbox``). The package's logger
has only a NullHandler (a library adds no other); ``configure`` is the one place handlers are
attached, by the command line. The outbox's notices reach the operator's stderr with or without a
log configured, as they did before there was one. Docs: docs/logging.md.
"""
from __future__ import annotations

import logging
import os
import stat
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import IO, TYPE_CHECKING

from ..errors import ConfigError
from ..fileguard.identity import same_file

if TYPE_CHECKING:
    from .schema import LoggingSection

ROOT = "accelcal_station"
FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
NOTICES = ("accelcal_station.store.outbox",)  # what the operator is told on stderr in any case
_OURS = "_accelcal_event_log"  # marks the handlers configure() attached, so a second call replaces them


class _Stderr(logging.StreamHandler):
    """stderr as it is when a record is written (a test runner swaps sys.stderr between commands)."""

    @property
    def stream(self) -> IO[str]:
        return sys.stderr

    @stream.setter
    def stream(self, _: object) -> None:
        pass


class _AppendFile(logging.StreamHandler):
    """A regular file opened for appending without following a symlink; closed with the handler."""

    def close(self) -> None:
        try:
            self.stream.close()
        finally:
            super().close()


def open_log(path: str | Path, avoid: Iterable[str | Path] = ()) -> IO[str]:
    """``path`` opened for appending: a regular file (created if absent), never through a symlink,
    never one of ``avoid`` (the config, the store); else one line naming the key and the file."""
    p = Path(path)
    for other in avoid:
        if same_file(p, other):
            raise ConfigError(f"logging.file: {p} is {other}; the log needs a file of its own")
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(p, flags, 0o644)
    except OSError as e:
        why = "a symlink (not followed)" if os.path.islink(p) else (e.strerror or str(e))
        raise ConfigError(f"logging.file: {p}: {why}; allowed: a regular file in a writable folder") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ConfigError(f"logging.file: {p}: not a regular file; allowed: a regular file in a writable folder")
    os.set_blocking(fd, True)
    return open(fd, "a", encoding="utf-8", buffering=1)  # line-buffered: each event lands as it happens


def configure(section: LoggingSection | None, avoid: Iterable[str | Path] = ()) -> None:
    """Attach the event log's handlers to the ``accelcal_station`` logger (replacing any an
    earlier call attached). ``None``: only the operator's notices on stderr."""
    logger = logging.getLogger(ROOT)
    for h in [h for h in logger.handlers if getattr(h, _OURS, False)]:
        logger.removeHandler(h)
        h.close()
    notices = _Stderr()
    notices.setLevel(logging.WARNING)
    notices.addFilter(lambda r: r.name in NOTICES)
    handlers: list[logging.Handler] = [notices]
    level = logging.WARNING
    if section is not None:
        level = logging.getLevelNamesMapping()[section.level]
        events: logging.Handler = _Stderr() if section.file is None else _AppendFile(open_log(section.file, avoid))
        events.setLevel(level)
        events.setFormatter(logging.Formatter(FORMAT))
        handlers = [events] if section.file is None else [events, notices]
    for h in handlers:
        setattr(h, _OURS, True)
        logger.addHandler(h)
    logger.setLevel(min(level, logging.WARNING))
