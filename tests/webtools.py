"""Helpers for the web tests: a live `accelcal serve` application on a free localhost port
(uvicorn in a thread, the real server) and headless Debian Chromium through selenium.

Where chromium, chromedriver or selenium is missing the browser tests skip with the reason,
unless ACCELCAL_REQUIRE_BROWSER=1 (set by .ci/run), which makes that a failure.
"""
from __future__ import annotations

import os
import shutil
import socket
import tempfile
from contextlib import contextmanager
from pathlib import Path

import pytest

REQUIRE_ENV = "ACCELCAL_REQUIRE_BROWSER"
SCREENSHOTS = Path(__file__).resolve().parents[1] / "docs" / "screenshots"


def unavailable(reason: str):
    if os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"browser tests required ({REQUIRE_ENV}=1) but {reason}")
    pytest.skip(reason)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def live_server(store: str, **settings):
    """`accelcal serve`'s application over ``store`` on a free localhost port; yields its base URL."""
    pytest.importorskip("fastapi")
    from accelcal_station.web.app import create_app
    from accelcal_station.web.server import BackgroundServer
    from accelcal_station.web.settings import WebSettings

    port = free_port()
    server = BackgroundServer(create_app(WebSettings(str(store), **settings)), "127.0.0.1", port)
    server.start()
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.stop()


def _find(name: str, *paths: str) -> str | None:
    return shutil.which(name) or next((p for p in paths if os.path.exists(p)), None)


@contextmanager
def chromium(width: int = 1400, height: int = 1000):
    """Headless Chromium (Debian's) driven by selenium, with a fresh profile."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        unavailable("selenium is not installed (pip install -e '.[test]')")
    browser = _find("chromium", "/usr/bin/chromium") or _find("chromium-browser")
    driver_bin = _find("chromedriver", "/usr/bin/chromedriver")
    if browser is None or driver_bin is None:
        unavailable("chromium and chromedriver are not installed (Debian: apt-get install chromium chromium-driver)")
    profile = tempfile.mkdtemp(prefix="accelcal-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = browser
    # the closed network makes Chromium slow unless it stops calling home
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", f"--user-data-dir={profile}", f"--window-size={width},{height}"):
        opts.add_argument(flag)
    drv = webdriver.Chrome(service=Service(driver_bin), options=opts)
    try:
        yield drv
    finally:
        drv.quit()
        shutil.rmtree(profile, ignore_errors=True)


def no_alert(drv) -> bool:
    """True when no JavaScript alert is open (a script from the store did not run)."""
    from selenium.common.exceptions import NoAlertPresentException

    try:
        _ = drv.switch_to.alert
    except NoAlertPresentException:
        return True
    return False


def screenshot(drv, name: str) -> None:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    drv.save_screenshot(str(SCREENSHOTS / name))
