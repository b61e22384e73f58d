"""Check a certificate file against itself and the results store (`accelcal report verify-certificate`).

Three checks per board, each naming the field it finds different:
1. the page: every ``data-field`` element reads what the embedded content gives (certificate_fields);
2. the embedded content still has the SHA-256 it states (it was not edited);
3. the store: the content rebuilt from the store's current run equals the embedded content.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field

from ..errors import DataError
from ..jsontypes import JsonObject, JsonValue
from .certificate import content_hash
from .certificate_fields import fields
from .certificate_html import Certified, embedded_certificates, read_page

# what each kind of difference means, as the one line says it
KINDS = {"page": "the file was edited", "hash": "the file was edited", "store": "the store differs",
         "missing": "the file was edited"}


@dataclass(frozen=True)
class Mismatch:
    """One difference: the board's run, the field (a path into the certified content), the two values."""

    run: str
    field: str
    kind: str  # page | hash | store | missing
    file_value: str | None
    store_value: str | None

    def line(self) -> str:
        if self.kind == "page":
            return (f"{KINDS['page']}: run {self.run}'s page shows {self.field} = {self.file_value!r}, its "
                    f"certified content gives {self.store_value!r}")
        if self.kind == "hash":
            return (f"{KINDS['hash']}: run {self.run}'s embedded content no longer has its SHA-256 "
                    f"({self.file_value}); {self.store_value}")
        if self.kind == "store" and self.field == "run":
            return f"{KINDS['store']}: run {self.run}: {self.store_value}"
        if self.kind == "missing":
            return f"{KINDS['missing']}: run {self.run}: {self.field} {self.file_value}"
        return f"{KINDS['store']}: run {self.run} {self.field}: certificate {self.file_value}, store {self.store_value}"

    def to_json(self) -> JsonObject:
        return {"run": self.run, "field": self.field, "kind": self.kind, "file": self.file_value,
                "store": self.store_value, "message": self.line()}


@dataclass
class Verification:
    runs: list[int] = field(default_factory=list)
    mismatches: list[Mismatch] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.mismatches


def _show(x: JsonValue) -> str:
    return json.dumps(x, ensure_ascii=False)[:80]


def diff(a: JsonValue, b: JsonValue, path: str = "") -> list[tuple[str, str, str]]:
    """Where two JSON values differ: (path, a's value, b's value), depth first."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in list(a) + [k for k in b if k not in a]:
            sub = f"{path}.{k}" if path else k
            out += [(sub, _show(a.get(k)), _show(b.get(k)))] if (k in a) != (k in b) else diff(a[k], b[k], sub)
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in diff(x, y, f"{path}[{i}]")]
    same = a == b and type(a) is type(b) if not (isinstance(a, int | float) and isinstance(b, int | float)) else a == b
    return [] if same else [(path or "(content)", _show(a), _show(b))]


def _page(run: str, c: Certified, shown: list[tuple[str, str]] | None) -> list[Mismatch]:
    if shown is None:
        return [Mismatch(run, "page", "missing", "has no page (its <section> was removed)", None)]
    want = fields(c.content) | {"sha256": c.sha256}
    out = [Mismatch(run, path, "page", text, want.get(path, "(no such field)")) for path, text in shown
           if want.get(path) != text]
    gone = sorted(set(want) - {p for p, _ in shown})
    return out + [Mismatch(run, p, "missing", "was removed from the page", None) for p in gone]


def verify(text: str, store_content: Callable[[int], JsonObject]) -> Verification:
    """Check a certificate file's text; ``store_content(run)`` is the run's certified content rebuilt from
    the store (a DataError saying why there is none).  DataError: not an accelcal certificate."""
    page = read_page(text)
    try:
        doc = json.loads(page.embedded) if page.embedded is not None else None
    except ValueError:
        raise DataError("its embedded certificate data is not JSON (the file was edited)") from None
    certs = embedded_certificates(doc)
    if not certs:
        raise DataError("not an accelcal certificate (no embedded accelcal.certificate data)")
    res = Verification()
    for c in certs:
        rid = c.content.get("run")
        run = str(rid)
        res.mismatches += _page(run, c, page.shown.get(run))
        if not isinstance(rid, int) or isinstance(rid, bool):
            res.mismatches.append(Mismatch(run, "run", "hash", "no run id", "the file was edited"))
            continue
        res.runs.append(rid)
        try:
            stored = store_content(rid)
        except DataError as e:
            res.mismatches.append(Mismatch(run, "run", "store", "certified", str(e)))
            continue
        changes = diff(c.content, stored)
        if content_hash(c.content) != c.sha256:
            first = (f"{changes[0][0]}: file {changes[0][1]}, store {changes[0][2]}" if changes
                     else "its content still equals the store's: the stated hash was edited")
            res.mismatches.append(Mismatch(run, "sha256", "hash", c.sha256[:16] + "...", first))
        res.mismatches += [Mismatch(run, p, "store", a, b) for p, a, b in changes]
    extra = sorted(set(page.shown) - {str(c.content.get("run")) for c in certs})
    res.mismatches += [Mismatch(r, "page", "missing", "is on the page but not in the embedded content", None)
                       for r in extra]
    return res
