"""The Gage R&R report: one HTML page with embedded PNGs (AIAG MSA 4th ed. III-B's usual charts).

Per parameter: the readings by part (every trial, one colour per appraiser, the part means joined), by
appraiser (every reading and the appraiser's mean), and the range chart (range of each part x appraiser
cell, R-bar and the upper limit D4 R-bar).
"""
from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

import numpy as np

from ..atomic import atomic_write
from ..errors import AccelcalError, DataError
from ..fileguard.cells import safe_text
from ..jsontypes import JsonValue
from .msa import range_limits
from .msa_study import PARAMETERS, Study
from .report import _png, _pyplot


def _plt() -> ModuleType:
    """pyplot on Agg; without the report extra one line naming it (exit 2)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise AccelcalError("the Gage R&R report (--html) needs matplotlib: "
                            "pip install 'accelcal-station[report]'") from None
    return _pyplot()


def _e(text: object) -> str:
    return html.escape(safe_text(str(text)))


def _charts(plt: ModuleType, study: Study, name: str, unit: str, x: np.ndarray) -> str:
    """Three panels for one parameter: by part, by appraiser, range chart."""
    p, o, r = x.shape
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.2))
    pos = np.arange(p)
    for b, who in enumerate(study.appraisers):
        for t in range(r):
            ax[0].plot(pos + (b - (o - 1) / 2) * 0.12, x[:, b, t], "o", ms=3, color=f"C{b}",
                       label=who if t == 0 else None)
        ax[1].plot(np.full(p * r, b), x[:, b, :].ravel(), "o", ms=3, color=f"C{b}")
        ax[1].plot([b - 0.3, b + 0.3], [x[:, b, :].mean()] * 2, "k-")
    ax[0].plot(pos, x.mean(axis=(1, 2)), "k-", lw=1)
    ax[0].set_xticks(pos, study.parts, rotation=45, fontsize=7)
    ax[0].set_title(f"{name} by part")
    ax[0].legend(fontsize=7)
    ax[1].set_xticks(np.arange(o), study.appraisers, fontsize=7)
    ax[1].set_title(f"{name} by {study.by}")
    ranges = x.max(axis=2) - x.min(axis=2)
    for b in range(o):
        ax[2].plot(np.arange(p) + b * p, ranges[:, b], "o-", ms=3, color=f"C{b}")
    r_bar, ucl = range_limits(x)
    ax[2].axhline(r_bar, color="k", lw=1)
    if ucl is not None:
        ax[2].axhline(ucl, color="r", ls="--", lw=1)
    ax[0].set_ylabel(unit, fontsize=8)
    ax[2].set_xlabel(f"part x {study.by} cell (the parts, {study.by} by {study.by})", fontsize=8)
    ax[2].set_title(f"range chart (R-bar {r_bar:.3g}" + (f", UCL {ucl:.3g})" if ucl is not None else ")"))
    return _png(fig)


def _row(res: dict[str, JsonValue]) -> str:
    def f(key: str) -> str:
        v = res.get(key)
        return "-" if v is None else f"{v:.4g}" if isinstance(v, float) else _e(v)

    return ("<tr>" + "".join(f"<td>{f(k)}</td>" for k in ("parameter", "ev", "av", "interaction", "grr", "pv",
                                                        "tv", "pct_grr", "pct_tolerance", "ndc", "grr_band"))
            + "</tr>")


def msa_html(study: Study, results: Sequence[dict[str, JsonValue]], title: str) -> str:
    """The whole report as one self-contained page."""
    plt = _plt()
    head = "".join(f"<th>{h}</th>" for h in ("parameter", "EV", "AV", "interaction", "GRR", "PV", "TV", "%GRR",
                                              "%tolerance", "ndc", "band"))
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{_e(title)}</title></head><body>",
             f"<h1>{_e(title)}</h1>",
             f"<p>{len(study.parts)} parts x {len(study.appraisers)} {_e(study.by)}s "
             f"({_e(', '.join(study.appraisers))}) x {study.trials} trials; ANOVA method with interaction "
             "(AIAG MSA 4th ed.), figures are standard deviations; %GRR &lt; 10 acceptable, 10-30 "
             "conditional, &gt; 30 not acceptable; ndc &gt;= 5.</p>",
             f"<table border='1' cellspacing='0' cellpadding='3'><tr>{head}</tr>",
             *(_row(res) for res in results), "</table>"]
    shown = {res["parameter"] for res in results}
    for prm in PARAMETERS:
        x = study.values(prm)
        if prm.name in shown and x is not None:
            parts.append(f"<h2>{_e(prm.name)} ({_e(prm.unit)})</h2>"
                         f"<img src='data:image/png;base64,{_charts(plt, study, prm.name, prm.unit, x)}'>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def write_msa_html(study: Study, results: Sequence[dict[str, JsonValue]], path: str | Path,
                   title: str = "accelcal Gage R&R study") -> None:
    """Written atomically (a temporary file renamed over the target): never half a report."""
    text = msa_html(study, results, title)
    try:
        atomic_write(path, text)
    except OSError as err:
        raise DataError(f"{path}: cannot write the report ({err.strerror})") from None
