"""A board's calibration certificate: what it certifies, taken from a stored run, and its hash.

``certified(rec)`` is the certified content of one run (docs/certificate.md lists every field): who,
what and when, the site's gravity, the references, the calibration with its expanded uncertainties
and the whole budget (GUM, JCGM 100:2008), the verification figures, the limits and the decision
rule (ILAC-G8:09/2019), the verdict.  ``content_hash`` is SHA-256 over its canonical JSON (keys
sorted, no spaces, UTF-8, floats as Python's shortest round-trip text).  A run without a calibration
or an uncertainty budget, a station fault (status ``error``) or a damaged row gets no certificate:
``NoCertificate`` says why in one line.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence

import yaml

from ..errors import DataError
from ..jsontypes import JsonObject, JsonValue
from ..store.records import RunRecord, RunSummary, iso

SCHEMA = "accelcal.certificate"
VERSION = 1


class NoCertificate(DataError):
    """This run cannot be certified (a station fault, no calibration, no budget, a damaged row)."""


def canonical_json(content: JsonValue) -> bytes:
    """The bytes the hash is taken over: sorted keys, no spaces, UTF-8, NaN refused."""
    return json.dumps(content, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False).encode("utf-8")


def content_hash(content: JsonValue) -> str:
    """SHA-256 (FIPS 180-4) of the canonical JSON, as 64 hex digits."""
    return hashlib.sha256(canonical_json(content)).hexdigest()


def refusal(rec: RunRecord) -> str | None:
    """Why run ``rec`` gets no certificate (one line), or None when it can have one."""
    rid = rec.id
    if rec.damage:
        cols = ", ".join(sorted({f"{d.table}.{d.column}" for d in rec.damage}))
        return f"run {rid}: damaged values ({cols}); `accelcal report check` lists them; no certificate"
    if rec.status == "error":
        return (f"run {rid}: a station fault (error: {rec.status_reason or 'no reason recorded'}), not a "
                "board's result; no certificate")
    if rec.status != "complete":
        return f"run {rid}: status {rec.status}, not complete; no certificate"
    if rec.calibration is None:
        return f"run {rid}: no calibration was recorded (the fit did not finish); no certificate"
    if rec.uncertainty is None:
        return (f"run {rid}: no uncertainty budget recorded (thermal plans and runs recorded before schema 6 "
                "have none); no certificate")
    return None


def _jig(config_text: str | None) -> JsonObject:
    """The jig as the run's own configuration names it (type, and its stated angle tolerance)."""
    try:
        cfg = yaml.safe_load(config_text or "") or {}
    except yaml.YAMLError:
        cfg = {}
    jig = cfg.get("jig") if isinstance(cfg, dict) else None
    jig = jig if isinstance(jig, dict) else {}
    kind, tol = jig.get("type"), jig.get("angle_tolerance_deg")
    return {"type": kind if isinstance(kind, str) else None,
            "angle_tolerance_deg": tol if isinstance(tol, int | float) and not isinstance(tol, bool) else None}


def _references(rec: RunRecord) -> JsonObject:
    """The pose design, the jig and each pose's reference (expected output, standard g at the site)."""
    fit = rec.fit_summary or {}
    poses: list[JsonValue] = [
        {"name": p.name, "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg,
         "reference_g": None if p.reference_g is None else [float(x) for x in p.reference_g]} for p in rec.poses]
    budget = (rec.uncertainty or {}).get("budget")
    jig_u = next((c.get("value") for c in budget if isinstance(c, dict) and c.get("source") == "jig_angle"),
                 None) if isinstance(budget, list) else None
    return {"design": fit.get("design"), "jig": {**_jig(rec.config_text), "budget_angle_tolerance_deg": jig_u},
            "poses": poses}


def _nvm(rec: RunRecord) -> JsonObject:
    out = rec.nvm_outcome or {}
    return {"status": rec.nvm_status, "slot": out.get("slot"), "generation": out.get("generation"),
            "crc32": out.get("crc32"), "verified": out.get("verified")}


def certified(rec: RunRecord) -> JsonObject:
    """The certified content of one stored run (NoCertificate when it gets none)."""
    if (why := refusal(rec)) is not None:
        raise NoCertificate(why)
    cal, unc, fit = rec.calibration or {}, dict(rec.uncertainty or {}), rec.fit_summary or {}
    rule, warnings = unc.pop("decision_rule", None), unc.pop("warnings", [])
    measured = fit.get("measured")
    return {
        "schema": SCHEMA, "version": VERSION, "run": rec.id, "serial": rec.device_serial, "chip": rec.chip,
        "station": rec.station_id, "operator": rec.operator, "lot": rec.lot, "panel": rec.panel_id,
        "started_utc": iso(rec.started_at), "finished_utc": iso(rec.finished_at),
        "software_version": fit.get("software_version"), "config_sha256": rec.config_hash,
        "site": rec.site, "references": _references(rec), "model": rec.model,
        "calibration": {"W": cal.get("W"), "V_g": cal.get("V"), "Gamma": cal.get("Gamma"),
                        "input_units": cal.get("input_units"), "input_per_g": cal.get("input_per_g")},
        "uncertainty": unc,
        "verification": {"measured": measured if isinstance(measured, dict) else {},
                         "verify_error_max_mg": fit.get("verify_error_max_mg")},
        "limits": dict(rec.limits or {}), "decision_rule": rule, "warnings": warnings,
        "verdict": rec.verdict, "reasons": [str(r) for r in rec.reasons], "nvm": _nvm(rec)}


def lot_choice(listing: Sequence[RunSummary]) -> tuple[list[int], list[str]]:
    """The run certified for each board of a lot, and one line per board left out.

    A board's certificate is its newest complete run (a retest supersedes the run before it; a
    station fault is no result of the board's); a board with none is named.  Boards in the order
    of their first run."""
    newest: dict[str, RunSummary] = {}
    last: dict[str, RunSummary] = {}
    order: list[str] = []
    for r in listing:  # in store order (started, id)
        serial = r["device_serial"] or f"(no serial, run {r['id']})"
        if serial not in last:
            order.append(serial)
        last[serial] = r
        if r["status"] == "complete" and r["id"] is not None and not r.get("damaged"):
            newest[serial] = r
    runs = [newest[s]["id"] for s in order if s in newest]
    left = [f"{s}: no complete run (its newest, run {last[s]['id']}, is {last[s]['status']}); no certificate"
            for s in order if s not in newest]
    return [r for r in runs if r is not None], left
