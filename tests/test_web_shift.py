"""`accelcal run --shift --ui web` in Chromium (issue 36): one station process calibrates three boards
started by serials typed into the page, with two tabs open and a reload mid-board; both tabs show
each verdict from the station, and End shift ends it with the summary.  A page that loses the
station says so full-screen."""
from __future__ import annotations

import json
import re
import sqlite3
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import yaml
from webtools import chromium, free_port, screenshot

pytest.importorskip("fastapi")
pytest.importorskip("selenium")
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# six-face and two verification poses, the first where the board already lies (verify.mode fit-poses: no prompt)
POSES = 7


def _config(tmp_path: Path) -> Path:
    cfg = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "shift.sqlite")}
    cfg["station"] = {"id": "line1-shift"}
    p = tmp_path / "shift.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def _start(cfg: Path, port: int, *extra: str) -> subprocess.Popen[str]:
    """The station, its output to files (a pipe nobody reads would fill and stall it mid-shift)."""
    out, err = (open(cfg.with_suffix(s), "w") for s in (".out", ".err"))  # noqa: SIM115 (closed with the process)
    return subprocess.Popen([sys.executable, "-m", "accelcal_station", "run", "--config", str(cfg), "--ui", "web",
                             "--ui-port", str(port), *extra], stdout=out, stderr=err, text=True)


def _open(drv, url: str) -> None:
    t0 = time.monotonic()
    while True:
        try:
            drv.get(url)
            return
        except Exception:
            assert time.monotonic() - t0 < 20, "the operator page never answered"
            time.sleep(0.2)


def _text(drv, tab: str, element: str) -> str:
    drv.switch_to.window(tab)
    return drv.find_element(By.ID, element).text


def _accept_poses(drv, tab: str, reload_after: int | None) -> None:
    """Accept every pose from ``tab``; reload it once after ``reload_after`` poses."""
    drv.switch_to.window(tab)
    done = 0
    t0 = time.monotonic()
    while done < POSES:
        assert time.monotonic() - t0 < 120, drv.page_source[-2000:]
        button = drv.find_element(By.ID, "b-accept")
        if button.is_enabled() and "READY" in drv.find_element(By.ID, "ready").text:
            n = drv.find_element(By.ID, "pose-number").text
            button.click()
            done += 1
            # wait until the station took the answer (the next pose, or the verdict)
            WebDriverWait(drv, 30).until(lambda d, n=n: d.find_element(By.ID, "pose-number").text != n
                                         or d.find_element(By.ID, "result").is_displayed())
            if done == reload_after:
                drv.refresh()  # mid-board: the page comes back to the station's pose
        time.sleep(0.05)


def test_three_boards_in_one_web_shift_with_two_tabs_and_a_reload(tmp_path):
    cfg = _config(tmp_path)
    port = free_port()
    proc = _start(cfg, port, "--shift", "--json")
    url = f"http://127.0.0.1:{port}/"
    serials = ["SN-W1", "SN-W2", "SN-W3"]
    try:
        with chromium(1024, 768) as drv:
            _open(drv, url)
            a = drv.current_window_handle
            drv.switch_to.new_window("tab")
            _open(drv, url)
            b = drv.current_window_handle
            for i, sn in enumerate(serials):
                typing = a if i % 2 == 0 else b  # serials scanned into either screen
                drv.switch_to.window(typing)
                field = WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input"))
                WebDriverWait(drv, 30).until(lambda d, f=field: f.is_displayed())
                if i:  # the last verdict stays on both screens until the next board starts
                    assert _text(drv, a, "result-verdict") == "PASS" and _text(drv, b, "result-verdict") == "PASS"
                    assert serials[i - 1] in _text(drv, b, "result-board")
                    drv.switch_to.window(typing)
                # the field has the focus: the scanner's keystrokes go there without a click
                assert drv.switch_to.active_element == field
                drv.switch_to.active_element.send_keys(sn + Keys.ENTER)
                WebDriverWait(drv, 30).until(lambda d, sn=sn: sn in d.find_element(By.ID, "board-id").text)
                _accept_poses(drv, a, reload_after=3 if i == 1 else None)
                for tab in (a, b):  # every screen shows the verdict of this board
                    drv.switch_to.window(tab)
                    WebDriverWait(drv, 30).until(lambda d, sn=sn: d.find_element(By.ID, "result").is_displayed()
                                                 and sn in d.find_element(By.ID, "result-board").text)
                    assert drv.find_element(By.ID, "result-verdict").text == "PASS"
            drv.switch_to.window(b)
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "b-end").is_displayed())
            drv.find_element(By.ID, "b-end").click()
            for tab in (a, b):
                drv.switch_to.window(tab)
                WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "SHIFT OVER")
                assert "3 boards" in drv.find_element(By.ID, "result-board").text
                assert "first-pass yield 100.0 %" in drv.find_element(By.ID, "result-board").text
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, cfg.with_suffix(".err").read_text()[-3000:]
    objs = [json.loads(line) for line in cfg.with_suffix(".out").read_text().splitlines()]
    assert [(o["kind"], o.get("serial"), o.get("verdict")) for o in objs] == [
        ("board", s, "PASS") for s in serials] + [("shift", None, None)]
    assert objs[-1]["ended_by"] == "end of input" and objs[-1]["boards"] == 3
    db = sqlite3.connect(tmp_path / "shift.sqlite")
    rows = db.execute("SELECT device_serial, status, verdict FROM runs ORDER BY id").fetchall()
    db.close()
    assert rows == [(s, "complete", "PASS") for s in serials]


def test_two_screens_show_the_same_pose_and_a_lost_station_full_screen(tmp_path):
    cfg = _config(tmp_path)
    port = free_port()
    proc = _start(cfg, port, "--shift")
    url = f"http://127.0.0.1:{port}/"
    try:
        with chromium(1024, 768) as drv:
            _open(drv, url)
            a = drv.current_window_handle
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input").is_displayed())
            drv.switch_to.active_element.send_keys("SN-X" + Keys.ENTER)
            WebDriverWait(drv, 30).until(lambda d: "READY" in d.find_element(By.ID, "ready").text)
            drv.find_element(By.ID, "b-accept").click()
            WebDriverWait(drv, 30).until(lambda d: "pose 2 " in d.find_element(By.ID, "pose-number").text.lower())
            drv.switch_to.new_window("tab")  # a second screen opened mid-board
            _open(drv, url)
            b = drv.current_window_handle
            WebDriverWait(drv, 30).until(lambda d: "pose 2 " in d.find_element(By.ID, "pose-number").text.lower())
            assert _text(drv, a, "pose-number") == _text(drv, b, "pose-number")
            assert "SN-X" in _text(drv, b, "board-id")
            proc.kill()  # the station is gone
            proc.wait(timeout=30)
            for tab in (a, b):
                drv.switch_to.window(tab)
                WebDriverWait(drv, 10).until(lambda d: d.find_element(By.ID, "lost").is_displayed())
                size = drv.find_element(By.ID, "lost").size
                w, h = drv.execute_script("return [document.documentElement.clientWidth, window.innerHeight]")
                assert size["width"] >= w and size["height"] >= h - 1  # the whole screen, not a corner
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)


PANELS = [(1024, 768), (800, 480)]  # the panel PCs factories put at a line


def _viewport(drv, w: int, h: int) -> None:
    drv.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                        {"width": w, "height": h, "deviceScaleFactor": 1, "mobile": False})


def _inside(drv, ids: list[str], w: int, h: int) -> None:
    """Each button wholly inside the viewport, at least 48 px each way, and the page not scrolled."""
    assert drv.execute_script("return [window.innerWidth, window.innerHeight]") == [w, h]
    assert drv.execute_script("return document.documentElement.scrollHeight") <= h
    for i in ids:
        r = drv.find_element(By.ID, i).rect
        assert r["x"] >= 0 and r["y"] >= 0 and r["x"] + r["width"] <= w and r["y"] + r["height"] <= h, (i, r, w, h)
        assert r["width"] >= 48 and r["height"] >= 48, (i, r)


def _tap(drv, element_id: str) -> None:
    """A finger on the touch screen: CDP touch events at the element's centre (no mouse)."""
    r = drv.find_element(By.ID, element_id).rect
    pt = {"x": r["x"] + r["width"] / 2, "y": r["y"] + r["height"] / 2}
    drv.execute_cdp_cmd("Emulation.setTouchEmulationEnabled", {"enabled": True, "maxTouchPoints": 1})
    drv.execute_cdp_cmd("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": [pt]})
    drv.execute_cdp_cmd("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})


def test_the_operator_page_fits_panel_pcs_by_keys_and_touch(tmp_path):
    from webtools import screenshot

    cfg = _config(tmp_path)
    port = free_port()
    proc = _start(cfg, port, "--shift")
    url = f"http://127.0.0.1:{port}/"
    try:
        with chromium(1024, 768) as drv:
            for k, (w, h) in enumerate(PANELS):
                _viewport(drv, w, h)
                _open(drv, url)
                WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input").is_displayed())
                _inside(drv, ["serial-input", "b-serial", "b-end"], w, h)
                drv.switch_to.active_element.send_keys(f"SN-P{k}" + Keys.ENTER)
                WebDriverWait(drv, 30).until(lambda d: "READY" in d.find_element(By.ID, "ready").text)
                _inside(drv, ["b-accept", "b-replace", "b-skip", "b-abort"], w, h)
                assert drv.find_element(By.ID, "progress-text").text == "pose 1 of 6"  # the design's six poses
                assert len(drv.find_elements(By.CSS_SELECTOR, "#strip .strip-item")) == 8
                assert len(drv.find_elements(By.CSS_SELECTOR, "#strip .strip-item.verify")) == 2
                screenshot(drv, f"operator-{w}x{h}.png")
                if k == 0:  # the key
                    drv.find_element(By.TAG_NAME, "body").send_keys(Keys.ENTER)
                else:  # the finger
                    _tap(drv, "b-accept")
                WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "progress-text").text == "pose 2 of 6")
                assert "done" in drv.find_elements(By.CSS_SELECTOR, "#strip .strip-item")[0].get_attribute("class")
                WebDriverWait(drv, 30).until(lambda d: "READY" in d.find_element(By.ID, "ready").text)
                _tap(drv, "b-abort") if k else drv.find_element(By.TAG_NAME, "body").send_keys("a")
                WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "ABORTED")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "b-end").is_displayed())
            _tap(drv, "b-end")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "SHIFT OVER")
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, cfg.with_suffix(".err").read_text()[-3000:]


def test_the_page_says_capturing_and_labels_verify_poses(tmp_path):
    """The real WebOperator and page, driven in process: during a capture the level says CAPTURING (the
    level is not read then), and a verification pose is counted as such."""
    from accelcal_station.fixtures.designs import get_design
    from accelcal_station.fixtures.operator_jig import pose_words
    from accelcal_station.fixtures.operator_ui import PosePrompt
    from accelcal_station.web.operator import WebOperator
    from accelcal_station.web.operator_app import create_operator_app
    from accelcal_station.web.server import BackgroundServer

    design = get_design("six-face")
    ui = WebOperator(lambda t: None, "st-1", 8, plan=[(p, False) for p in design] + [(p, True) for p in design[:2]])
    port = free_port()
    server = BackgroundServer(create_operator_app(ui, None), "127.0.0.1", port)
    server.start()
    try:
        with chromium(1024, 768) as drv:
            _open(drv, f"http://127.0.0.1:{port}/")
            ui.show_pose(PosePrompt(1, design[0], pose_words(design[0])))
            bar = ui.capture("  capturing x+1g")
            bar(0.4)
            WebDriverWait(drv, 10).until(lambda d: d.find_element(By.ID, "still").text == "CAPTURING")
            assert not drv.find_element(By.ID, "b-accept").is_enabled()
            bar.close()
            for i, p in enumerate(design[1:], start=2):
                ui.show_pose(PosePrompt(i, p, pose_words(p)))
            ui.show_pose(PosePrompt(7, design[0], pose_words(design[0])))  # the first verification pose
            WebDriverWait(drv, 10).until(lambda d: d.find_element(By.ID, "progress-text").text == "verify 1 of 2")
            items = drv.find_elements(By.CSS_SELECTOR, "#strip .strip-item")
            assert [("done" in x.get_attribute("class")) for x in items] == [True] * 6 + [False, False]
            assert "current" in items[6].get_attribute("class") and "verify" in items[6].text
    finally:
        server.stop()


def test_the_operator_page_in_german(tmp_path):
    from webtools import screenshot

    cfg = _config(tmp_path)
    data = yaml.safe_load(cfg.read_text())
    data["station"]["language"] = "de"
    cfg.write_text(yaml.safe_dump(data, allow_unicode=True))
    port = free_port()
    proc = _start(cfg, port, "--shift")
    try:
        with chromium(1024, 768) as drv:
            _viewport(drv, 1024, 768)
            _open(drv, f"http://127.0.0.1:{port}/")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input").is_displayed())
            assert drv.find_element(By.ID, "serial-question").text == "Platine 1: Seriennummer scannen"
            assert drv.find_element(By.ID, "b-end").text == "Schicht beenden"
            drv.switch_to.active_element.send_keys("SN-DE" + Keys.ENTER)
            WebDriverWait(drv, 30).until(lambda d: "BEREIT" in d.find_element(By.ID, "ready").text)
            page = drv.find_element(By.TAG_NAME, "body").text
            for german in ("Übernehmen", "Neu auflegen", "Auslassen", "Abbrechen", "Libelle", "Lage 1 von 6", "RUHIG"):
                assert german in page, german
            # the first six-face pose, x+1g (data sheets: +1 g on the axis pointing up): on its -x edge
            assert "auf die -x-Kante stellen, +x zeigt nach oben" in drv.find_element(By.ID, "instruction").text
            angles = drv.find_element(By.ID, "angles").text  # German numbers: a decimal comma (issue 49)
            assert "1,000" in angles and not re.search(r"\d\.\d", angles), angles
            for english in ("Accept", "Re-place", "Skip", "Live level", "pose 1 of 6", "STILL", "READY",
                            "stand it on its", "pointing up"):
                assert english not in page, english
            assert drv.find_element(By.TAG_NAME, "html").get_attribute("lang") == "de"
            screenshot(drv, "operator-de.png")
            drv.find_element(By.TAG_NAME, "body").send_keys("a")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "ABGEBROCHEN")
            assert "vom Bediener abgebrochen" in drv.find_element(By.ID, "result-reasons").text
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "b-end").is_displayed())
            drv.find_element(By.ID, "b-end").click()
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "SCHICHTENDE")
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0


def test_a_refused_scan_is_shown_over_the_last_verdict(tmp_path):
    """Between boards the station's line (a scan that is not a serial) shows on the page, then the
    next good scan starts the board and clears it."""
    cfg = _config(tmp_path)
    port = free_port()
    proc = _start(cfg, port, "--shift")
    try:
        with chromium(1024, 768) as drv:
            _open(drv, f"http://127.0.0.1:{port}/")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input").is_displayed())
            drv.switch_to.active_element.send_keys("no good!" + Keys.ENTER)
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "notice").is_displayed())
            assert "is not a serial number" in drv.find_element(By.ID, "notice").text
            assert "scan again" in drv.find_element(By.ID, "notice").text
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input").is_displayed())
            drv.switch_to.active_element.send_keys("SN-OK" + Keys.ENTER)
            WebDriverWait(drv, 30).until(lambda d: "SN-OK" in d.find_element(By.ID, "board-id").text)
            WebDriverWait(drv, 30).until(lambda d: not d.find_element(By.ID, "notice").is_displayed())
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "b-abort").is_enabled())
            drv.find_element(By.TAG_NAME, "body").send_keys("a")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "b-end").is_displayed())
            drv.find_element(By.ID, "b-end").click()
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "SHIFT OVER")
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0


def _absent_device_config(tmp_path: Path, language: str = "en") -> Path:
    cfg = yaml.safe_load(_config(tmp_path).read_text())
    cfg["device"]["emulator"] = {"present": False}  # nothing answers at the chip's address
    cfg["station"]["language"] = language
    p = tmp_path / f"absent-{language}.yaml"
    p.write_text(yaml.safe_dump(cfg, allow_unicode=True))
    return p


@contextmanager
def _station_fault_page(tmp_path: Path, language: str, device_wait: str, verdict: str):
    """A shift waiting for a device that does not answer, its operator page in Chromium: SN-1 scanned and
    the station fault's full screen (``verdict``) up; yields the browser and the station's process."""
    port = free_port()
    proc = _start(_absent_device_config(tmp_path, language), port, "--shift", "--device-wait", device_wait)
    try:
        with chromium(1024, 768) as drv:
            _open(drv, f"http://127.0.0.1:{port}/")
            WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "serial-input").is_displayed())
            drv.switch_to.active_element.send_keys("SN-1" + Keys.ENTER)
            WebDriverWait(drv, 60).until(lambda d: d.find_element(By.ID, "result-verdict").text == verdict)
            yield drv, proc
    finally:
        if proc.poll() is None:
            proc.kill()


def test_a_device_that_is_gone_is_a_full_screen_station_fault_with_end_shift(tmp_path):
    """Issue 49: while the shift waits for a device that does not answer, the page shows the station's
    fault full screen (what to check, no verdict) with End shift, never the last board's verdict; End shift
    ends the shift and SHIFT OVER says why, with no stale notice over it."""
    with _station_fault_page(tmp_path, "en", "600", "STATION FAULT") as (drv, proc):
        reasons = drv.find_element(By.ID, "result-reasons").text
        assert "this board is not judged" in reasons and "check the board's cable" in reasons, reasons
        assert "result station fault" in drv.find_element(By.ID, "result").get_attribute("class")
        assert not drv.find_element(By.ID, "notice").is_displayed()
        screenshot(drv, "operator-station-fault.png")
        end = drv.find_element(By.ID, "b-end-fault")
        assert end.is_displayed()
        end.click()
        WebDriverWait(drv, 30).until(lambda d: d.find_element(By.ID, "result-verdict").text == "SHIFT OVER")
        assert "ended by: " in drv.find_element(By.ID, "result-figures").text
        assert not drv.find_element(By.ID, "notice").is_displayed()
        assert proc.wait(timeout=60) == 0


def test_the_station_fault_and_its_end_in_german(tmp_path):
    """The same on a German station: the fault's words and what to check from the catalog; the wait runs
    out (--device-wait 3) and SHIFT OVER says why in German; nothing English in the operator's bar."""
    with _station_fault_page(tmp_path, "de", "3", "STATIONSSTÖRUNG") as (drv, proc):
        reasons = drv.find_element(By.ID, "result-reasons").text
        assert "nicht bewertet" in reasons and "Kabel und Stecker der Platine" in reasons, reasons
        WebDriverWait(drv, 60).until(lambda d: d.find_element(By.ID, "result-board").text.startswith("0 "))
        figures = drv.find_element(By.ID, "result-figures").text
        assert "beendet durch: Gerät weg" in figures, figures
        assert not drv.find_element(By.ID, "notice").is_displayed()
        assert proc.wait(timeout=60) == 3  # the device stayed away: the shift ends with exit 3
