"""The emulator side of a serial line: a raw pseudo-terminal answered by a background thread.

Emulated instruments (the MPU6050 bridge, the thermal chamber, the motorized jig) are reached
through pyserial on the slave side exactly as real ones are on /dev/ttyUSB*, so the host code
under test is the code that runs on the line.
"""
from __future__ import annotations

import os
import threading
import tty
from abc import ABC, abstractmethod
from typing import Self


class PtyServer(ABC):
    """Mixin: ``start()`` opens a raw pty and runs ``self._run`` on a thread; ``stop()`` closes it.

    The subclass sets ``_thread = None``, ``_stop = threading.Event()``, ``_master = _slave = -1``
    and ``port = None`` in its ``__init__``, and names its thread with ``thread_name``.
    """

    thread_name = "pty-server"
    master_nonblocking = False  # a server that polls its master instead of select()ing on it
    _thread: threading.Thread | None
    _stop: threading.Event
    _master: int
    _slave: int
    port: str | None

    @abstractmethod
    def _run(self) -> None:
        """Answer on ``self._master`` until ``self._stop`` is set (each emulator's own server loop)."""

    def start(self) -> str:
        """Open a new pseudo-terminal, start answering on it, return the slave's path."""
        if self._thread is not None and self.port is not None:
            return self.port
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # bytes pass unchanged: no echo, no CR/LF translation
        if self.master_nonblocking:
            os.set_blocking(self._master, False)
        self.port = port = os.ttyname(self._slave)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"{self.thread_name} {port}", daemon=True)
        self._thread.start()
        return port

    def stop(self) -> None:
        """Stop the thread and close the pseudo-terminal; safe to call twice."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
