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


def bulk_store(path: Path, n: int, seed: int = 1, lot_size: int = 5000, stations: int = 8,
               t_end: float = 1.7e9) -> None:
    """An SQLite results store of ``n`` complete runs inserted in one transaction (the schema made by
    Store; the test's set-up, not the station's path): ``stations`` stations, lots of ``lot_size``
    runs (L0, L1, ...), 30 days ending at ``t_end``, ~7 % FAIL on offset; each run carries a
    calibration and the limits it was judged by (offset 60 mg, 50 mg in the second half)."""
    import json
    import sqlite3

    import numpy as np

    from accelcal_station.store.runs import Store

    Store(path).close()
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(t_end - 30 * 86400, t_end, n))
    off = np.abs(rng.normal(40, 8, n))
    V = rng.normal(0, 0.02, (n, 3))
    rows = []
    for i in range(n):
        lim = 60.0 if i < n // 2 else 50.0
        fail = off[i] > lim or rng.uniform() < 0.05
        measured = {"offset_max_mg": float(off[i]), "gain_error_max": 0.01, "cross_axis_max": 0.004,
                    "residual_rms_mg": 0.03}
        reasons = [{"code": "offset_max_mg", "message": f"offset_max_mg {off[i]:.1f} > limit {lim:g}"}] if fail else []
        cal = {"schema": "accelcal.calibration", "version": 1, "model": "12", "input_units": "g", "input_per_g": 1.0,
               "W": [[1.0, 0.001, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "V": V[i].tolist(),
               "Gamma": [0.0, 0.0, 0.0], "temperature": None, "metadata": {}}
        rows.append((float(t[i]), float(t[i]) + 40, f"SN{i:07d}", f"st{i % stations}", f"L{i // lot_size}",
                     "FAIL" if fail else "PASS", json.dumps(reasons), json.dumps({"measured": measured}),
                     json.dumps(cal), json.dumps({"offset_max_mg": lim})))
    db = sqlite3.connect(path)
    with db:
        db.executemany("INSERT INTO runs (started_at, finished_at, status, device_serial, station_id, lot, verdict,"
                       " reasons, fit_summary, calibration, limits, model, nvm_status) VALUES"
                       " (?, ?, 'complete', ?, ?, ?, ?, ?, ?, ?, ?, '12', 'written')", rows)
    db.close()
