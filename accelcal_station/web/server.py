"""Running an application with uvicorn: in the foreground (`accelcal serve`) or in a thread
beside a station (`accelcal run --ui web`)."""
from __future__ import annotations

import json
import threading
import time
from typing import Any

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

MAX_REQUEST_HEAD = 2**20  # bytes of request line and headers accepted


class JsonErrorH11(H11Protocol):
    """uvicorn's h11 protocol answering a request it cannot parse (a head over MAX_REQUEST_HEAD, a
    malformed line) with the API's JSON error {code, message}, not uvicorn's plain text."""

    def send_400_response(self, msg: str) -> None:
        body = json.dumps({"code": "invalid_request", "message": f"{msg} (a request line and headers "
                           f"are at most {MAX_REQUEST_HEAD} bytes)"}).encode()
        head = (b"HTTP/1.1 400 Bad Request\r\ncontent-type: application/json\r\ncontent-length: "
                + str(len(body)).encode() + b"\r\nconnection: close\r\n\r\n")
        self.transport.write(head + body)  # the connection closes: no h11 state to keep
        self.transport.close()


def _config(app: Any, host: str, port: int) -> uvicorn.Config:
    # h11 and asyncio only: the same on every machine, no optional C speedups needed
    # lifespan on: `serve` starts its heavy pages' worker processes at startup and stops them at shutdown
    # a request line or header up to 1 MiB reaches the application (which answers an over-long
    # parameter with a 422 naming it) instead of h11 dropping the connection at 16 KiB; a longer
    # one is a JSON 400 (JsonErrorH11)
    return uvicorn.Config(app, host=host, port=port, log_level="warning", access_log=False,
                          http=JsonErrorH11, loop="asyncio", lifespan="on", timeout_graceful_shutdown=2,
                          h11_max_incomplete_event_size=MAX_REQUEST_HEAD)


def serve_forever(app: Any, host: str, port: int) -> None:
    uvicorn.Server(_config(app, host, port)).run()


class BackgroundServer:
    """A uvicorn server on a daemon thread; ``stop()`` ends it."""

    def __init__(self, app: Any, host: str, port: int) -> None:
        self.server = uvicorn.Server(_config(app, host, port))
        self.thread = threading.Thread(target=self.server.run, name="web-ui", daemon=True)

    def start(self, timeout_s: float = 10.0) -> None:
        self.thread.start()
        t0 = time.monotonic()
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() - t0 > timeout_s:
                raise OSError("the web server did not start (is the port in use?)")
            time.sleep(0.02)

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=5)
