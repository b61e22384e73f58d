"""The operator's language (issue 36): operator-facing text comes from the gettext catalogs, German is
shipped complete, nothing operator-facing bypasses the catalog, and engineers' output (--json) stays
English."""
from __future__ import annotations

import ast
import gettext
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from accelcal_station.i18n import DOMAIN, REASON_TITLES, translations
from accelcal_station.web.operator_text import PAGE_TEXTS

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "accelcal_station"
LOCALE = PKG / "i18n" / "locale" / "de" / "LC_MESSAGES"
TEMPLATE = PKG / "web" / "templates" / "operator.html"
SCRIPT = PKG / "web" / "static" / "operator.js"
# Python modules whose operator-facing text goes through tr(...) / N_(...)
PY_SOURCES = ["i18n/__init__.py", "conventions.py", "fixtures/operator_jig.py",
              "web/operator_text.py", "station/shift.py", "cli/operator_terminal.py",
              "cli/run.py", "web/operator_app.py", "station/station_fault.py", "cli/_operator_web.py",
              "station/warmup.py"]
SAME_IN_GERMAN = {"OK", "Station"}  # the same word in both languages


def _py_msgids() -> set[str]:
    """Every literal passed to N_, tr, self.tr or ui.tr in the operator-facing modules (by the AST)."""
    out: set[str] = set()
    for rel in PY_SOURCES:
        src = (ROOT if rel.startswith("fixtures/") else PKG) / rel  # fixtures/ is top level, mapped in
        for node in ast.walk(ast.parse(src.read_text())):
            if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
                f = node.func
                name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
                if name in ("N_", "tr") and isinstance(node.args[0].value, str):
                    out.add(node.args[0].value)
    return out


def _page_msgids() -> set[str]:
    tpl = set(re.findall(r'_\("((?:[^"\\]|\\.)*)"\)', TEMPLATE.read_text()))
    js = set(re.findall(r'\bT\("((?:[^"\\]|\\.)*)"', SCRIPT.read_text()))
    return tpl | js


def _po(path: Path) -> dict[str, str]:
    """msgid -> msgstr of a .po file (single-line entries, as ours are)."""
    entries, msgid = {}, None
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("msgid "):
            msgid = json.loads(line[6:])
        elif line.startswith("msgstr ") and msgid:
            entries[msgid] = json.loads(line[7:])
    return entries


def test_every_operator_text_has_its_german_translation():
    de = translations("de")
    ids = _py_msgids() | _page_msgids() | set(PAGE_TEXTS) | set(REASON_TITLES.values())
    assert len(ids) > 60
    missing = sorted(m for m in ids if de.gettext(m) == m and m not in SAME_IN_GERMAN)
    assert not missing, f"untranslated in de: {missing}"
    # placeholders survive translation (a German text that drops {serial} would show a hole)
    for m in ids:
        assert set(re.findall(r"\{\w+\}", m)) == set(re.findall(r"\{\w+\}", de.gettext(m))), m


def test_the_shipped_mo_is_the_po_compiled():
    po = _po(LOCALE / f"{DOMAIN}.po")
    with open(LOCALE / f"{DOMAIN}.mo", "rb") as f:
        mo = gettext.GNUTranslations(f)
    assert po and all(mo.gettext(k) == v for k, v in po.items()), "run msgfmt -o ....mo ....po"


def test_the_page_js_asks_only_for_texts_the_station_sends():
    js = set(re.findall(r'\bT\("((?:[^"\\]|\\.)*)"', SCRIPT.read_text()))
    assert js <= set(PAGE_TEXTS), sorted(js - set(PAGE_TEXTS))


def test_no_operator_facing_text_on_the_page_bypasses_the_catalog():
    """The template's text and labels are all {{ _("...") }}; operator.js sets no text from a bare literal."""
    src = TEMPLATE.read_text()
    body = re.sub(r"<script.*?</script>|<title>.*?</title>|\{\{.*?\}\}|\{%.*?%\}", " ", src, flags=re.S)
    text = re.sub(r"<[^>]*>", " ", body)
    words = set(re.findall(r"[A-Za-z]{2,}", text)) - {"accelcal", "Enter"}
    assert not words, f"bare text in operator.html: {sorted(words)}"
    for attr in ("aria-label", "title", "placeholder", "alt"):
        for value in re.findall(rf'{attr}="([^"]*)"', src):
            assert value.startswith("{{ _("), (attr, value)
    bare = []
    for n, line in enumerate(SCRIPT.read_text().splitlines(), 1):
        if "textContent" not in line and "bits.push" not in line:
            continue
        for m in re.finditer(r'"((?:[^"\\]|\\.)*)"', line):
            before = line[:m.start()].rstrip()
            # allowed: an id, a tag, a class, a comparison
            allowed = before.endswith(("T(", "$(", "createElement(", "className =", "==="))
            if re.search(r"[A-Za-z]{2,}", m.group(1)) and not allowed:
                bare.append((n, m.group(1)))
    assert not bare, f"operator.js sets text from literals outside T(): {bare}"


def _german_config(tmp_path: Path) -> Path:
    cfg = yaml.safe_load((ROOT / "configs" / "mma8451-emulated.yaml").read_text())
    cfg["station"] = {"id": "linie1", "language": "de"}
    cfg["store"] = {"path": str(tmp_path / "s.sqlite")}
    p = tmp_path / "de.yaml"
    p.write_text(yaml.safe_dump(cfg, allow_unicode=True))
    return p


def test_a_german_shift_in_the_terminal_and_english_json(tmp_path):
    cfg = _german_config(tmp_path)
    feed = "SN-A\n" + "\n" * 8
    r = subprocess.run([sys.executable, "-m", "accelcal_station", "run", "--shift", "--config", str(cfg)],
                       input=feed, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    de = translations("de")
    for m in ("Board {n}: scan the serial number (end of input ends the shift)",
              "Enter=accept  r=re-place  s=skip  a=abort"):
        assert de.gettext(m).split("{")[0] in r.stderr and m.split("{")[0] not in r.stderr, m
    assert "Lage x+1g: Platine so legen" in r.stdout and "Erstdurchlaufquote 100.0 %" in r.stdout
    assert "first-pass yield" not in r.stdout and "Pose x+1g: put the board" not in r.stdout
    # the pose words themselves in German (the English sentence never shown to this operator)
    assert "auf die -x-Kante stellen, +x zeigt nach oben" in r.stdout, r.stdout[-3000:]
    assert "stand it on its" not in r.stdout and "lay it flat" not in r.stdout
    # the engineers' output stays English whatever the operator reads
    j = subprocess.run([sys.executable, "-m", "accelcal_station", "run", "--shift", "--json", "--config", str(cfg)],
                       input=feed, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert j.returncode == 0, j.stderr[-2000:]
    shift = json.loads(j.stdout.splitlines()[-1])
    assert shift["ended_by"] == "end of input" and shift["pass"] == 1 and "first_pass_yield" in shift


# Data-sheet facts (MMA8451Q "Product orientation", MPU-6000/6050 "Orientation of axes"): a chip
# at rest reads +1 g on the axis pointing away from the Earth, so for a reading of +1 g on +x the
# board stands on its -x edge.  Written here in German, independently of the code's catalog.
GERMAN_FACES = {
    (1, 0, 0): ("-x-Kante", "+x zeigt nach oben"), (-1, 0, 0): ("+x-Kante", "-x zeigt nach oben"),
    (0, 1, 0): ("-y-Kante", "+y zeigt nach oben"), (0, -1, 0): ("+y-Kante", "-y zeigt nach oben"),
    (0, 0, 1): ("Bauteilseite oben",), (0, 0, -1): ("Bauteilseite unten",),
}


def test_the_pose_words_in_german_name_the_same_edges_as_the_data_sheet():
    from accelcal_station.conventions import placement_words, reference_to_angles
    from accelcal_station.fixtures.base import PoseSpec
    from accelcal_station.fixtures.operator_jig import pose_words
    de = translations("de").gettext
    for ref, must in GERMAN_FACES.items():
        words = placement_words(np.array(ref, dtype=float), de)
        assert all(m in words for m in must) and "edge" not in words and "up:" not in words, (ref, words)
    # a tilted pose: the face, then the raised part, with the same signed axes as the reading's lean
    r = np.array([0.3, 0.4, np.sqrt(1 - 0.25)])
    words = placement_words(r, de)
    assert words.startswith("z+ oben") and "+x+y-Ecke angehoben" in words and "30 Grad" in words, words
    pitch, roll = (float(v) for v in reference_to_angles(r))
    line = pose_words(PoseSpec("t", pitch, roll), de)
    assert "Nicken" in line and "erwartet x +0.300 y +0.400" in line and "pitch" not in line, line
    assert pose_words(PoseSpec("t", pitch, roll)).startswith("z+ up: lay it flat")  # English by default


def test_a_language_the_station_does_not_ship_is_one_line(tmp_path):
    cfg = yaml.safe_load((ROOT / "configs" / "mma8451-emulated.yaml").read_text())
    cfg["station"] = {"id": "l1", "language": "fr"}
    p = tmp_path / "fr.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = subprocess.run([sys.executable, "-m", "accelcal_station", "run", "--config", str(p)], input="",
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2 and "station.language" in r.stderr and "Traceback" not in r.stderr, r.stderr
