"""`accelcal report certificate` and `report verify-certificate` (issue 54) on boards the simulated station
calibrated into a real SQLite store.

The figures a certificate shows are checked against the stored row read with sqlite3 (not against the
program's own reading of it); a figure edited in the file, the embedded content edited, and the store
changed must each fail the verification naming the field.  In Chromium: a 3-board lot prints to 3 PDF
pages (DevTools Page.printToPDF), a board's certificate to 1, and a screenshot is kept for a reader.
"""
from __future__ import annotations

import base64
import hashlib
import json
import re
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station import __version__
from accelcal_station.cli import cli
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store

REPO = Path(__file__).resolve().parents[1]
LOT = "LC-7"
SERIALS = ["CERT-1", "CERT-2", "CERT-3"]


def _config(tmp: Path, k: int) -> Path:
    """configs/sim.yaml with a fixed seed per board and each board's own offsets."""
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["device"]["seed"] = 500 + k
    cfg["device"]["simulator"]["effects"]["offset"]["offset_mg"] = [18.0 + 3 * k, -27.0, 41.0 - 2 * k]
    p = tmp / f"board{k}.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Runs 1-3: three boards of lot LC-7, each a real `accelcal run`; run 4: a station fault of a fourth
    board of the lot; run 5: a complete run without a calibration; run 6: CERT-2 again, interrupted."""
    tmp = tmp_path_factory.mktemp("cert")
    db = tmp / "runs.sqlite"
    for k, serial in enumerate(SERIALS):
        r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp, k)), "--serial", serial,
                                     "--operator", "ana", "--lot", LOT, "--store", str(db), "--json"])
        assert r.exit_code == 0, r.output
    poses = [PoseRecord(f"p{i}", np.eye(3)[i % 3], None, 10, np.eye(3)[i % 3]) for i in range(6)]
    with Store(db) as st:
        err = st.start_run(device_serial="CERT-4", station_id="sim-station-1", lot=LOT)
        st.interrupt_run(err, "device stopped answering", status="error")
        rid = st.start_run(device_serial="CERT-5", station_id="sim-station-1", lot="other")
        st.finish_run(rid, session=Session(poses, units="g"), calibration=None, verdict="FAIL")
        rid = st.start_run(device_serial="CERT-2", station_id="sim-station-1", lot=LOT)
        st.interrupt_run(rid, "operator aborted at pose p3")
    return db


def _cli(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(cli, list(args))
    return r.exit_code, r.output


def _field(html: str, path: str, run: int | None = None) -> list[str]:
    """The text of every element showing certified field ``path`` (in run ``run``'s page when given)."""
    if run is not None:
        html = html.split(f'data-run="{run}"', 1)[1].split("</section>", 1)[0]
    return re.findall(rf'data-field="{re.escape(path)}">([^<]*)<', html)


def _stored(db: Path, run: int) -> dict[str, object]:
    con = sqlite3.connect(db)
    try:
        row = con.execute("SELECT device_serial, calibration, uncertainty, site FROM runs WHERE id = ?",
                          (run,)).fetchone()
    finally:
        con.close()
    return {"serial": row[0], "calibration": json.loads(row[1]), "uncertainty": json.loads(row[2]),
            "site": json.loads(row[3])}


def test_certificate_names_serial_expanded_uncertainty_and_decision_rule(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "cert.html"
    code, text = _cli("report", "certificate", "1", "-o", str(out), "--store", str(store))
    assert code == 0, text
    html = out.read_text()
    row = _stored(store, 1)
    unc, cal = row["uncertainty"], row["calibration"]
    assert isinstance(unc, dict) and isinstance(cal, dict)
    assert _field(html, "serial") == ["CERT-1", "CERT-1"] and row["serial"] == "CERT-1"
    # U of each offset and gain as stored (mg and dimensionless), and the offsets themselves (g -> mg)
    for i in range(3):
        assert _field(html, f"uncertainty.expanded.V_mg[{i}]") == [f"{unc['expanded']['V_mg'][i]:.3f}"]
        assert _field(html, f"uncertainty.expanded.W[{i}][{i}]") == [f"{unc['expanded']['W'][i][i]:.5f}"]
        assert _field(html, f"calibration.V_g[{i}]") == [f"{cal['V'][i] * 1e3:.3f}"]
    assert _field(html, "uncertainty.k") == ["2"] and unc["k"] == 2
    # the stored budget, every source, with its combined figure: sqrt of the sum of squares of the stored u
    sources = [b["source"] for b in unc["budget"]]
    assert [_field(html, f"uncertainty.budget[{i}].source")[0] for i in range(len(sources))] == sources
    u_c = float(np.sqrt(sum(b["u"]["V_mg"][0] ** 2 for b in unc["budget"])))
    assert _field(html, "uncertainty.combined.V_x") == [f"{u_c:.4f}"]
    # the decision rule applied, as stored (the default station judges by guarded acceptance, ILAC-G8)
    rule = unc["decision_rule"]
    assert rule["rule"] == "guarded" and _field(html, "decision_rule.rule") == ["guarded"]
    assert _field(html, "decision_rule.references") == [rule["references"]] and "ILAC-G8" in rule["references"]
    assert _field(html, "site.gravity_mps2") == [f"{row['site']['gravity_mps2']:.6f}"]  # type: ignore[index]
    assert _field(html, "software_version") == [f"accelcal {__version__}"]
    assert _field(html, "verdict") == ["PASS", "PASS"]
    # the hash: SHA-256 of the embedded content's canonical JSON, printed and in a meta element
    doc = json.loads(re.search(r'<script type="application/json" id="accelcal-certificate">(.*?)</script>',
                               html, re.S).group(1))  # type: ignore[union-attr]
    c = doc["certificates"][0]
    canon = json.dumps(c["content"], sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()
    assert hashlib.sha256(canon).hexdigest() == c["sha256"] == _field(html, "sha256")[0]
    assert f'<meta name="accelcal-certificate-sha256" content="{c["sha256"]}">' in html
    assert "http://" not in html and "https://" not in html  # offline: nothing fetched


def test_verify_passes_and_names_an_edited_figure(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "cert.html"
    assert _cli("report", "certificate", "2", "-o", str(out), "--db", str(store))[0] == 0
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(store))
    assert code == 0 and text.startswith("verified:"), text
    html = out.read_text()
    shown = _field(html, "uncertainty.expanded.V_mg[0]")[0]
    edited = html.replace(f'data-field="uncertainty.expanded.V_mg[0]">{shown}<',
                          'data-field="uncertainty.expanded.V_mg[0]">0.100<')
    assert edited != html
    out.write_text(edited)
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(store))
    assert code == 1 and len(text.strip().splitlines()) == 1, text
    assert "edited" in text and "uncertainty.expanded.V_mg[0]" in text and "'0.100'" in text
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(store), "--json")
    doc = json.loads(text)
    assert code == 1 and doc["verified"] is False
    assert [(m["field"], m["kind"]) for m in doc["mismatches"]] == [("uncertainty.expanded.V_mg[0]", "page")]


def test_verify_names_a_field_edited_in_the_embedded_content(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "cert.html"
    assert _cli("report", "certificate", "2", "-o", str(out), "--db", str(store))[0] == 0
    html = out.read_text()
    head, blob = html.split('id="accelcal-certificate">')
    doc = json.loads(blob.split("</script>")[0])
    doc["certificates"][0]["content"]["operator"] = "someone else"
    out.write_text(head + 'id="accelcal-certificate">' + json.dumps(doc) + "</script></body></html>\n")
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(store), "--json")
    res = json.loads(text)
    assert code == 1 and not res["verified"]
    fields = {(m["field"], m["kind"]) for m in res["mismatches"]}
    # the page no longer reads what the content says, the content lost its hash, and differs from the store
    assert {("operator", "page"), ("sha256", "hash"), ("operator", "store")} <= fields, fields
    assert "operator" in res["message"]


def test_verify_fails_when_the_store_differs(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "cert.html"
    assert _cli("report", "certificate", "3", "-o", str(out), "--db", str(store))[0] == 0
    changed = tmp_path / "changed.sqlite"
    shutil.copyfile(store, changed)
    con = sqlite3.connect(changed)
    with con:
        cal = json.loads(con.execute("SELECT calibration FROM runs WHERE id = 3").fetchone()[0])
        cal["V"][1] += 1e-4
        con.execute("UPDATE runs SET calibration = ? WHERE id = 3", (json.dumps(cal),))
    con.close()
    assert _cli("report", "verify-certificate", str(out), "--db", str(store))[0] == 0
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(changed))
    assert code == 1 and "the store differs" in text and "calibration.V_g[1]" in text, text
    con = sqlite3.connect(changed)
    with con:
        con.execute("DELETE FROM poses WHERE run_id = 3")
        con.execute("DELETE FROM runs WHERE id = 3")
    con.close()
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(changed))
    assert code == 1 and "the store differs: run 3:" in text and "no run 3" in text, text
    assert len(text.strip().splitlines()) == 1


def test_lot_certificate_has_one_page_per_board(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "lot.html"
    r = CliRunner().invoke(cli, ["report", "certificate", "--lot", LOT, "-o", str(out), "--db", str(store),
                                 "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    # CERT-2's newest run was interrupted: its certificate is its newest complete run; CERT-4 had a
    # station fault only: left out, named
    assert doc["runs"] == [1, 2, 3] and len(doc["sha256"]) == 3
    assert len(doc["skipped"]) == 1 and doc["skipped"][0].startswith("CERT-4: no complete run")
    assert "SKIP CERT-4" in r.stderr
    html = out.read_text()
    assert re.findall(r'<section class="certificate" data-run="(\d+)">', html) == ["1", "2", "3"]
    assert [_field(html, "serial", k + 1)[0] for k in range(3)] == SERIALS
    assert "break-after: page" in html and "break-inside: avoid" in html and "@page" in html
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(store))
    assert code == 0 and "3 board(s)" in text, text


@pytest.mark.parametrize(("run", "words"), [("4", "station fault"), ("5", "no calibration"),
                                             ("6", "interrupted"), ("999", "no run 999")])
def test_no_certificate_one_line_exit_2(store: Path, tmp_path: Path, run: str, words: str) -> None:
    out = tmp_path / "c.html"
    r = CliRunner().invoke(cli, ["report", "certificate", run, "-o", str(out), "--db", str(store)])
    assert r.exit_code == 2 and words in r.output and len(r.output.strip().splitlines()) == 1, r.output
    assert not out.exists()
    r = CliRunner().invoke(cli, ["report", "certificate", run, "-o", str(out), "--db", str(store), "--json"])
    assert r.exit_code == 2 and words in json.loads(r.stdout)["error"]


def test_outputs_refused_symlink_and_store(store: Path, tmp_path: Path) -> None:
    target = tmp_path / "elsewhere.html"
    target.write_text("<!DOCTYPE html><html><body>keep</body></html>")
    link = tmp_path / "link.html"
    link.symlink_to(target)
    code, text = _cli("report", "certificate", "1", "-o", str(link), "--db", str(store))
    assert code == 2 and "symbolic link" in text and "keep" in target.read_text(), text
    before = store.read_bytes()
    code, text = _cli("report", "certificate", "1", "-o", str(store), "--db", str(store), "--force")
    assert code == 2 and store.read_bytes() == before, text
    assert _cli("report", "certificate", "1", "--lot", LOT, "--db", str(store))[0] == 2  # one of them


def test_verify_refuses_what_is_not_a_certificate(store: Path, tmp_path: Path) -> None:
    page = tmp_path / "page.html"
    page.write_text("<html><body><p>hello</p></body></html>")
    code, text = _cli("report", "verify-certificate", str(page), "--db", str(store))
    assert code == 2 and "not an accelcal certificate" in text and len(text.strip().splitlines()) == 1
    code, text = _cli("report", "verify-certificate", str(tmp_path / "none.html"), "--db", str(store))
    assert code == 2 and "no such file" in text


def _pdf_pages(pdf: bytes) -> int:
    """Pages of a PDF: the /Count of its page tree's root (Chromium writes it uncompressed)."""
    counts = [int(n) for n in re.findall(rb"/Type\s*/Pages\b[^>]*?/Count\s+(\d+)", pdf)]
    counts += [int(n) for n in re.findall(rb"/Count\s+(\d+)[^>]*?/Type\s*/Pages\b", pdf)]
    assert counts, "no page tree found in the PDF"
    return max(counts)


def test_chromium_prints_one_pdf_page_per_board(store: Path, tmp_path: Path) -> None:
    from webtools import chromium

    lot, one = tmp_path / "lot.html", tmp_path / "one.html"
    assert _cli("report", "certificate", "--lot", LOT, "-o", str(lot), "--db", str(store))[0] == 0
    assert _cli("report", "certificate", "1", "-o", str(one), "--db", str(store))[0] == 0
    with chromium(900, 1300) as drv:
        pages = {}
        for name, f in (("lot", lot), ("one", one)):
            drv.get(f.as_uri())
            assert drv.find_element("css selector", "h1").text == "Calibration certificate"
            pdf = base64.b64decode(drv.execute_cdp_cmd("Page.printToPDF", {"preferCSSPageSize": True,
                                                                           "printBackground": True})["data"])
            assert pdf.startswith(b"%PDF")
            (tmp_path / f"{name}.pdf").write_bytes(pdf)
            pages[name] = _pdf_pages(pdf)
        drv.get(one.as_uri())
        shot = tmp_path / "cert-screenshot.png"
        drv.save_screenshot(str(shot))
    assert pages == {"lot": 3, "one": 1}
    assert shot.read_bytes().startswith(b"\x89PNG")
    shutil.copyfile(shot, REPO / "cert-screenshot.png")  # for a reader to look at (not committed)


def test_hostile_names_are_text_and_still_verify(tmp_path: Path) -> None:
    """A serial and operator that are markup (the station refuses such names; a store written by other
    software may hold them) show as text on the page, cannot end the embedded JSON, and the certificate
    still verifies."""
    db, out = tmp_path / "runs.sqlite", tmp_path / "c.html"
    hostile = "</script><script>alert(1)</script>"
    r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp_path, 0)), "--serial", "SN-1",
                                 "--store", str(db), "--json"])
    assert r.exit_code == 0, r.output
    con = sqlite3.connect(db)
    with con:
        con.execute("UPDATE runs SET operator = ?, device_serial = ? WHERE id = 1", (hostile, "SN<b>1</b>"))
    con.close()
    assert _cli("report", "certificate", "1", "-o", str(out), "--db", str(db))[0] == 0
    html = out.read_text()
    assert "<script>alert" not in html and "<b>1</b>" not in html
    assert _field(html, "operator") == ["&lt;/script&gt;&lt;script&gt;alert(1)&lt;/script&gt;"]
    assert html.count("</script>") == 1  # the embedded data's own end, nothing from the names
    code, text = _cli("report", "verify-certificate", str(out), "--db", str(db))
    assert code == 0, text
