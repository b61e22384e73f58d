"""The operator page's texts in the operator's language: every msgid operator.js shows (through its
``T(...)``) and the words the station sends it (verdicts, phases), translated by the station's
catalog (i18n/) and embedded in the page as JSON; tests/test_i18n.py checks none is missing."""
from __future__ import annotations

import json

from ..i18n import N_, Translate

PAGE_TEXTS: tuple[str, ...] = (
    N_("Board {n}"), N_("Pose {n}"), N_("Put the board {words}"),
    N_("pitch {pitch}°, roll {roll}° · expects x {x}  y {y}  z {z} g"),
    N_("pose {n} of {total}"), N_("verify {n} of {total}"), N_("pose {n}"), N_("verify"), N_("next board"),
    N_("STILL"), N_("MOVING"), N_("right face"), N_("on {face}"), N_("READY — press Accept"), N_("hold still…"),
    N_("WRONG FACE — turn the board"), N_("CAPTURING"), N_("CAPTURING — hold still"),
    N_("board {serial}"), N_("run {id}"), N_("fit residual {mg} mg"), N_("check after calibration {mg} mg"),
    N_("NVM {what}"), N_("SHIFT OVER"),
    N_("{boards} boards · PASS {pass} · FAIL {fail} · aborted {aborted} · error {error} · first-pass yield {fpy}"),
    N_("{boards} board · PASS {pass} · FAIL {fail} · aborted {aborted} · error {error} · first-pass yield {fpy}"),
    N_("{start} to {end} (UTC)"), N_("ended by: {why}"), N_("end of input"), N_("Ctrl-C"), N_("device gone"),
    # what the station sends: verdicts and phases
    N_("PASS"), N_("FAIL"), N_("ABORTED"), N_("ERROR"), N_("STATION FAULT"),
    N_("starting"), N_("working"), N_("place"), N_("ask"), N_("serial"), N_("done"), N_("shift_over"),
    N_("station_fault"),
)


def page_texts_json(tr: Translate) -> str:
    """{msgid: text} for the page's script, safe inside <script type="application/json">."""
    return json.dumps({m: tr(m) for m in PAGE_TEXTS}, ensure_ascii=False).replace("<", "\\u003c")
