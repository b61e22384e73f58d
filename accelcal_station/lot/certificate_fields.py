"""The text a certificate page shows for each certified field (``fields``), one formatting for all.

The page (certificate_html.py) shows exactly these texts, each in its ``data-field`` element, and
`report verify-certificate` compares a page with them: one function, so the two cannot drift.
"""
from __future__ import annotations

from ..jsontypes import JsonObject, JsonValue

AXES = "xyz"
# the budget's columns: key, header (offsets' u in mg, W's dimensionless)
BUDGET_U = (("V_x", "u V_x (mg)"), ("V_y", "u V_y (mg)"), ("V_z", "u V_z (mg)"), ("W_xx", "u W_xx"),
            ("W_yy", "u W_yy"), ("W_zz", "u W_zz"), ("W_offdiag", "u W_ij (largest)"))
FIGURES = {
    "residual_rms_mg": "residual RMS (mg)", "residual_max_mg": "residual, largest (mg)",
    "crossval_rms_mg": "cross-validated RMS (mg)", "offset_max_mg": "offset, largest |V_i| (mg)",
    "gain_error_max": "gain error, largest |W_ii - 1|", "cross_axis_max": "cross-axis, largest |W_ij|",
    "cubic_max": "cubic, largest |\u0393_i| (1/g\u00b2)", "stderr_offset_max_mg": "offset standard error, largest (mg)",
    "stderr_gain_max": "gain standard error, largest", "verify_error_max_mg": "verification error, largest (mg)",
}


def _num(x: JsonValue, fmt: str, scale: float = 1.0) -> str:
    if isinstance(x, bool) or not isinstance(x, int | float):
        return "-" if x is None else str(x)
    return format(x * scale, fmt)


def _text(x: JsonValue) -> str:
    return "-" if x is None or x == "" else str(x)


def _at(x: JsonValue, *keys: str | int) -> JsonValue:
    """``x[k0][k1]...`` or None where any step is missing (a stored value can be damaged or absent)."""
    for k in keys:
        if isinstance(x, dict) and isinstance(k, str):
            x = x.get(k)
        elif isinstance(x, list) and isinstance(k, int) and 0 <= k < len(x):
            x = x[k]
        else:
            return None
    return x


def count(x: JsonValue, *keys: str | int) -> int:
    """The length of the list at ``x[k0][k1]...`` (0 when it is not a list)."""
    found = _at(x, *keys)
    return len(found) if isinstance(found, list) else 0


def _u_columns(u: JsonValue) -> dict[str, str]:
    """A budget row's u as the page shows it: the offsets', W's diagonal and W's largest off-diagonal."""
    out = {f"V_{a}": _num(_at(u, "V_mg", i), ".4f") for i, a in enumerate(AXES)}
    out |= {f"W_{a}{a}": _num(_at(u, "W", i, i), ".2e") for i, a in enumerate(AXES)}
    off = [_at(u, "W", i, j) for i in range(3) for j in range(3) if i != j]
    nums = [abs(v) for v in off if isinstance(v, int | float) and not isinstance(v, bool)]
    out["W_offdiag"] = _num(max(nums), ".2e") if len(nums) == 6 else "-"
    return out


def figure_keys(content: JsonObject) -> list[str]:
    """The limits the page lists, in FIGURES' order, then any other in the stored order."""
    limits = content.get("limits")
    keys = list(limits) if isinstance(limits, dict) else []
    return [k for k in FIGURES if k in keys] + [k for k in keys if k not in FIGURES]


def _who(c: JsonObject) -> dict[str, str]:
    f = {k: _text(c.get(k)) for k in ("run", "serial", "chip", "station", "operator", "lot", "panel", "model",
                                       "config_sha256", "verdict")}
    for k in ("started_utc", "finished_utc"):  # ISO 8601 UTC as a reader reads it
        t = c.get(k)
        f[k] = t.replace("T", " ").replace("+00:00", " UTC") if isinstance(t, str) else _text(t)
    sw = c.get("software_version")
    f["software_version"] = f"accelcal {sw}" if sw else "not recorded with the run"
    f["site.gravity_mps2"] = _num(_at(c, "site", "gravity_mps2"), ".6f")
    f["site.source"] = _text(_at(c, "site", "source"))
    f["site.gravity_u_mps2"] = _num(_at(c, "site", "gravity_u_mps2"), ".2g")
    f["references.design"] = _text(_at(c, "references", "design"))
    f["references.jig.type"] = _text(_at(c, "references", "jig", "type"))
    f["references.jig.budget_angle_tolerance_deg"] = "\u00b1" + _num(
        _at(c, "references", "jig", "budget_angle_tolerance_deg"), "g")
    poses = _at(c, "references", "poses")
    for i in range(len(poses) if isinstance(poses, list) else 0):
        p = f"references.poses[{i}]"
        f[f"{p}.name"] = _text(_at(poses, i, "name"))
        f[f"{p}.pitch_deg"] = _num(_at(poses, i, "pitch_deg"), ".1f")
        f[f"{p}.roll_deg"] = _num(_at(poses, i, "roll_deg"), ".1f")
        ref = _at(poses, i, "reference_g")
        f[f"{p}.reference_g"] = "-" if not isinstance(ref, list) else ", ".join(_num(x, "+.4f") for x in ref)
    return f


def _result(c: JsonObject) -> dict[str, str]:
    f: dict[str, str] = {"uncertainty.k": _num(_at(c, "uncertainty", "k"), "g")}
    for i in range(3):
        f[f"calibration.V_g[{i}]"] = _num(_at(c, "calibration", "V_g", i), ".3f", 1e3)
        f[f"uncertainty.expanded.V_mg[{i}]"] = _num(_at(c, "uncertainty", "expanded", "V_mg", i), ".3f")
        f[f"calibration.Gamma[{i}]"] = _num(_at(c, "calibration", "Gamma", i), ".3g")
        for j in range(3):
            f[f"calibration.W[{i}][{j}]"] = _num(_at(c, "calibration", "W", i, j), ".6f")
            f[f"uncertainty.expanded.W[{i}][{j}]"] = _num(_at(c, "uncertainty", "expanded", "W", i, j), ".5f")
    budget = _at(c, "uncertainty", "budget")
    for i in range(len(budget) if isinstance(budget, list) else 0):
        b, row = f"uncertainty.budget[{i}]", _at(budget, i)
        f[f"{b}.source"], f[f"{b}.type"] = _text(_at(row, "source")), _text(_at(row, "type"))
        f[f"{b}.distribution"] = _text(_at(row, "distribution"))
        value = _at(row, "value")
        f[f"{b}.input"] = "not evaluated" if value is None else f"{_num(value, '.3g')} {_text(_at(row, 'unit'))}"
        f |= {f"{b}.u.{k}": v for k, v in _u_columns(_at(row, "u")).items()}
    for key in ("combined", "expanded"):
        f |= {f"uncertainty.{key}.{k}": v for k, v in _u_columns(_at(c, "uncertainty", key)).items()}
    return f


def _decision(c: JsonObject) -> dict[str, str]:
    f: dict[str, str] = {}
    for k in figure_keys(c):
        f[f"limits.{k}"] = _num(_at(c, "limits", k), ".4g")
        f[f"verification.measured.{k}"] = _num(_at(c, "verification", "measured", k), ".4g")
    for k in ("rule", "guard_band", "near_limit", "references"):
        f[f"decision_rule.{k}"] = _text(_at(c, "decision_rule", k))
    applies = _at(c, "decision_rule", "applies_to")
    f["decision_rule.applies_to"] = ", ".join(map(str, applies)) if isinstance(applies, list) else _text(applies)
    reasons, warnings = c.get("reasons"), c.get("warnings")
    f["reasons"] = "; ".join(map(str, reasons)) if isinstance(reasons, list) and reasons else "none"
    f["warnings"] = ("; ".join(str(_at(w, "message") or _at(w, "code") or w) for w in warnings)
                     if isinstance(warnings, list) and warnings else "none")
    f["nvm"] = _nvm(c)
    return f


def _nvm(c: JsonObject) -> str:
    status = _at(c, "nvm", "status")
    if status != "written":
        return f"not written ({_text(status)})"
    crc = _at(c, "nvm", "crc32")
    crc_text = f"0x{crc:08x}" if isinstance(crc, int) and not isinstance(crc, bool) else _text(crc)
    verified = "read back and verified" if _at(c, "nvm", "verified") is True else "not verified"
    return (f"written: slot {_text(_at(c, 'nvm', 'slot'))}, generation {_text(_at(c, 'nvm', 'generation'))}, "
            f"CRC-32 {crc_text}, {verified}")


def fields(content: JsonObject) -> dict[str, str]:
    """Every certified field's path and the text the page shows for it."""
    return _who(content) | _result(content) | _decision(content)
