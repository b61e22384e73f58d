"""A certificate as one printable HTML page per board (A4, inline CSS, no script that runs), and read back.

Every figure and word the page certifies sits in an element with ``data-field="PATH"`` (PATH names
the value in the certified content, e.g. ``uncertainty.expanded.V_mg[0]``) inside the board's
``<section class="certificate" data-run="ID">``; ``fields(content)`` is the text each such element
must read, so a page can be checked against its content figure by figure.  The content itself and
its SHA-256 are embedded in ``<script type="application/json" id="accelcal-certificate">`` (data,
never run) and in ``<meta name="accelcal-certificate-sha256">``.
"""
from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape
from html.parser import HTMLParser

from ..jsontypes import JsonObject, JsonValue
from .certificate import SCHEMA, VERSION
from .certificate_fields import BUDGET_U, FIGURES, count, fields, figure_keys
from .certificate_style import CSS

AXES = "xyz"


@dataclass(frozen=True)
class Certified:
    """One board's certified content and its SHA-256."""

    content: JsonObject
    sha256: str


class _Page:
    """Builds one board's section: ``v(path)`` is the element showing a certified field."""

    def __init__(self, content: JsonObject, sha256: str) -> None:
        self.f = fields(content)
        self.f["sha256"] = sha256
        self.c = content

    def v(self, path: str, tag: str = "span", cls: str = "") -> str:
        klass = f' class="{cls}"' if cls else ""
        return f'<{tag}{klass} data-field="{escape(path)}">{escape(self.f[path])}</{tag}>'

    def row(self, label: str, path: str) -> str:
        return f"<tr><th>{escape(label)}</th>{self.v(path, 'td')}</tr>"


def _head(p: _Page) -> str:
    verdict = p.f["verdict"]
    cls = "pass" if verdict == "PASS" else "fail"
    return (f'<header><div><h1>Calibration certificate</h1><p class="sub">Three-axis MEMS accelerometer, '
            f'calibrated at a production station (accelcal)</p></div><div class="id"><p>Certificate of run '
            f'{p.v("run")}</p><p class="serial">Serial {p.v("serial")}</p>'
            f'{p.v("verdict", "p", f"verdict {cls}")}</div></header>')


def _who(p: _Page) -> str:
    item = "".join(p.row(a, b) for a, b in (("Serial", "serial"), ("Chip", "chip"), ("Lot", "lot"),
                                              ("Panel", "panel"), ("Model (parameters)", "model")))
    cal = "".join(p.row(a, b) for a, b in (
        ("Station", "station"), ("Operator", "operator"), ("Started (UTC)", "started_utc"),
        ("Finished (UTC)", "finished_utc"), ("Software", "software_version"), ("Config SHA-256", "config_sha256")))
    return (f'<div class="two"><div><h2>Item calibrated</h2><table class="kv">{item}</table></div>'
            f'<div><h2>Calibration</h2><table class="kv">{cal}</table></div></div>')


def _references(p: _Page) -> str:
    ref = "".join(p.row(a, b) for a, b in (
        ("Site gravity (m/s\u00b2)", "site.gravity_mps2"), ("Its source", "site.source"),
        ("Its standard uncertainty (m/s\u00b2)", "site.gravity_u_mps2"), ("Pose design", "references.design"),
        ("Jig", "references.jig.type"), ("Jig angle tolerance (deg)", "references.jig.budget_angle_tolerance_deg")))
    poses = "".join(
        f"<tr>{p.v(f'references.poses[{i}].name', 'td')}{p.v(f'references.poses[{i}].pitch_deg', 'td', 'num')}"
        f"{p.v(f'references.poses[{i}].roll_deg', 'td', 'num')}{p.v(f'references.poses[{i}].reference_g', 'td', 'num')}"
        "</tr>" for i in range(count(p.c, "references", "poses")))
    return (f'<div class="two"><div><h2>References</h2><table class="kv">{ref}</table></div>'
            f'<div><h2>Poses (reference: expected output, standard g)</h2><table class="poses"><tr><th>pose</th>'
            f'<th>pitch (deg)</th><th>roll (deg)</th><th>reference (g)</th></tr>{poses}</table></div></div>')


def _calibration(p: _Page) -> str:
    rows = []
    for i, a in enumerate(AXES):
        w = "".join(f'<td class="num">{p.v(f"calibration.W[{i}][{j}]")} \u00b1 '
                    f'{p.v(f"uncertainty.expanded.W[{i}][{j}]")}</td>' for j in range(3))
        rows.append(f'<tr><th>{a}</th><td class="num">{p.v(f"calibration.V_g[{i}]")} \u00b1 '
                    f'{p.v(f"uncertainty.expanded.V_mg[{i}]")}</td>{w}'
                    f'<td class="num">{p.v(f"calibration.Gamma[{i}]")}</td></tr>')
    return ('<h2>Calibration result: G = W G<sub>f</sub> + V + \u0393 G<sub>f</sub><sup>3</sup> '
            '(G in standard g)</h2><table class="cal"><tr><th>axis</th><th>offset V (mg) \u00b1 U</th>'
            '<th>W<sub>i,x</sub> \u00b1 U</th><th>W<sub>i,y</sub> \u00b1 U</th><th>W<sub>i,z</sub> \u00b1 U</th>'
            f'<th>\u0393 (1/g\u00b2)</th></tr>{"".join(rows)}</table><p class="note">U: expanded uncertainty, '
            f'k = {p.v("uncertainty.k")} (GUM, JCGM 100:2008: U = k u<sub>c</sub>, about 95 % coverage for k = 2). '
            'Gains W<sub>ii</sub> and cross-axis W<sub>ij</sub> are dimensionless; \u0393 is not in the budget '
            '(models 6, 9, 12 fit none).</p>')


def _budget(p: _Page) -> str:
    names = ("source", "type", "input", "distribution", *(h for _, h in BUDGET_U))
    head = "".join(f"<th>{escape(h)}</th>" for h in names)
    rows = []
    for i in range(count(p.c, "uncertainty", "budget")):
        b = f"uncertainty.budget[{i}]"
        us = "".join(p.v(f"{b}.u.{n}", "td", "num") for n, _ in BUDGET_U)
        rows.append(f"<tr>{p.v(f'{b}.source', 'td')}{p.v(f'{b}.type', 'td')}{p.v(f'{b}.input', 'td', 'num')}"
                    f"{p.v(f'{b}.distribution', 'td')}{us}</tr>")
    for key, label in (("combined", "combined standard uncertainty u_c"),
                       ("expanded", "expanded uncertainty U = k u_c")):
        us = "".join(p.v(f"uncertainty.{key}.{n}", "td", "num") for n, _ in BUDGET_U)
        rows.append(f'<tr class="total"><td colspan="4">{escape(label)}</td>{us}</tr>')
    return ('<h2>Uncertainty budget (GUM; sources uncorrelated, root sum of squares)</h2>'
            f'<table class="budget"><tr>{head}</tr>{"".join(rows)}</table>'
            '<p class="note">u of the offsets in mg, of W dimensionless; W off-diagonal: the largest of the six. '
            'Every source\'s full u of V and W is in the embedded content.</p>')


def _acceptance(p: _Page) -> str:
    rows = "".join(f"<tr><th>{escape(FIGURES.get(key, key))}</th>{p.v(f'verification.measured.{key}', 'td', 'num')}"
                   f"{p.v(f'limits.{key}', 'td', 'num')}</tr>" for key in figure_keys(p.c))
    rule = "".join(p.row(a, b) for a, b in (
        ("Decision rule", "decision_rule.rule"), ("Guard band", "decision_rule.guard_band"),
        ("Applies to", "decision_rule.applies_to"), ("Within U of a limit", "decision_rule.near_limit"),
        ("References", "decision_rule.references")))
    return (f'<div class="two"><div><h2>Verification and acceptance limits</h2><table class="acc"><tr><th>figure'
            f'</th><th>measured</th><th>limit</th></tr>{rows}</table></div><div><h2>Decision rule applied</h2>'
            f'<table class="kv">{rule}</table><p class="note">The other limits are figures of the fit and the '
            f'verification, judged as measured.</p>{_verdict(p)}</div></div>')


def _verdict(p: _Page) -> str:
    lines = [p.row("Verdict", "verdict"), p.row("Reasons", "reasons"), p.row("Warnings", "warnings"),
             p.row("Board's NVM", "nvm")]
    return f'<h2>Result</h2><table class="kv">{"".join(lines)}</table>'


def _foot(p: _Page, issued: str) -> str:
    return (f'<footer><p>Content SHA-256 {p.v("sha256", "span", "hash")}</p><p class="note">SHA-256 over the '
            'canonical JSON of the certified content (embedded in this file; docs/certificate.md). Check it '
            'against the results store: <code>accelcal report verify-certificate FILE</code>. '
            f'Issued {escape(issued)} (not part of the hash).</p></footer>')


def section(c: Certified, issued: str) -> str:
    """One board's certificate as one printed page."""
    p = _Page(c.content, c.sha256)
    parts = (_head(p), _who(p), _references(p), _calibration(p), _budget(p), _acceptance(p), _foot(p, issued))
    return f'<section class="certificate" data-run="{escape(p.f["run"])}">{"".join(parts)}</section>'


def document(certs: Sequence[Certified], title: str, issued: str) -> str:
    """The whole HTML file: the boards' pages, their content and hashes embedded."""
    data = {"schema": SCHEMA, "version": VERSION, "hash": "sha256 of canonical JSON (docs/certificate.md)",
            "certificates": [{"run": c.content["run"], "sha256": c.sha256, "content": c.content} for c in certs]}
    # inside <script> only "</" could end the element: every "<" escaped as JSON's \u003c
    blob = json.dumps(data, indent=None, ensure_ascii=False, allow_nan=False).replace("<", "\\u003c")
    metas = "".join(f'<meta name="accelcal-certificate-sha256" content="{c.sha256}">' for c in certs)
    body = "".join(section(c, issued) for c in certs)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{escape(title)}</title>{metas}'
            f'<style>{CSS}</style></head><body>{body}'
            f'<script type="application/json" id="accelcal-certificate">{blob}</script></body></html>\n')


@dataclass
class PageRead:
    """What a certificate file holds: its embedded document and each board's shown fields, in order."""

    embedded: str | None = None
    shown: dict[str, list[tuple[str, str]]] = field(default_factory=dict)  # run -> [(path, text)]


class _Reader(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.out = PageRead()
        self._run: str | None = None
        self._field: str | None = None
        self._text: list[str] = []
        self._script = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "section" and a.get("data-run") is not None:
            self._run = a["data-run"]
            self.out.shown.setdefault(self._run or "", [])
        elif tag == "script" and a.get("id") == "accelcal-certificate":
            self._script, self._text = True, []
        if a.get("data-field") is not None:
            self._field, self._text = a["data-field"], []

    def handle_data(self, data: str) -> None:
        if self._field is not None or self._script:
            self._text.append(data)

    def handle_endtag(self, tag: str) -> None:
        if self._field is not None:
            self.out.shown.setdefault(self._run or "", []).append((self._field, "".join(self._text)))
            self._field = None
        elif tag == "script" and self._script:
            self._script, self.out.embedded = False, "".join(self._text)
        elif tag == "section":
            self._run = None


def read_page(text: str) -> PageRead:
    """The embedded document and the fields each board's page shows."""
    r = _Reader()
    r.feed(text)
    r.close()
    return r.out


def embedded_certificates(doc: JsonValue) -> list[Certified] | None:
    """The boards of an embedded document, or None when it is not an accelcal certificate's."""
    items = doc.get("certificates") if isinstance(doc, dict) and doc.get("schema") == SCHEMA else None
    if not isinstance(items, list):
        return None
    out = []
    for c in items:
        content = c.get("content") if isinstance(c, dict) else None
        sha = c.get("sha256") if isinstance(c, dict) else None
        if not (isinstance(content, dict) and isinstance(sha, str)):
            return None
        out.append(Certified(content, sha))
    return out
