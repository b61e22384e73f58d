"""A run's verdict is built in one place (station/verdict.py) from the typed outcomes the flow
records, never set on the run report."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from accelcal_station.acceptance.reasons import Reason
from accelcal_station.station.report import RunReport
from accelcal_station.station.verdict import Outcome, RunVerdict, Stage, run_verdict

STATION = Path(__file__).resolve().parents[1] / "accelcal_station" / "station"


def test_pass_needs_a_judgment_and_no_failing_stage() -> None:
    assert run_verdict([]) == RunVerdict("FAIL")  # never judged: interrupted before its verdict
    assert run_verdict([Outcome(Stage.DEVICE), Outcome(Stage.FIT)]) == RunVerdict("FAIL")
    assert run_verdict([Outcome(Stage.FIT), Outcome(Stage.JUDGED), Outcome(Stage.NVM)]).passed
    nvm = Reason("nvm", "read back differs")
    # a burn that fails after the board was judged PASS fails it, with the burn's reason
    assert run_verdict([Outcome(Stage.JUDGED), Outcome(Stage.NVM, (nvm,))]) == RunVerdict("FAIL", (nvm,))


def test_every_failing_stage_gives_its_reasons_in_order() -> None:
    pose, store = Reason("pose", "p3: on face -x", sep=" "), Reason("store", "disk full")
    v = run_verdict([Outcome(Stage.DEVICE), Outcome(Stage.CAPTURE, (pose,)), Outcome(Stage.STORE, (store,))])
    assert v.label == "FAIL" and v.reasons == (pose, store)
    assert [r.code for r in v.reasons] == ["pose", "store"]


def test_the_report_verdict_is_read_only_and_made_from_its_outcomes() -> None:
    rep = RunReport()
    assert (rep.verdict, rep.reasons, rep.failed) == ("FAIL", [], False)
    rep.record(Stage.JUDGED)
    assert (rep.verdict, rep.failed) == ("PASS", False)
    rep.record(Stage.NVM, Reason("nvm", "no NVM"))
    assert (rep.verdict, rep.failed) == ("FAIL", True)
    d = rep.to_dict()
    assert (d["verdict"], d["reasons"], d["reason_codes"]) == ("FAIL", ["nvm: no NVM"], ["nvm"])
    with pytest.raises(AttributeError):
        rep.verdict = "PASS"  # type: ignore[misc]
    final = rep.final
    with pytest.raises(AttributeError):
        final.label = "PASS"  # type: ignore[misc]


def _verdict_sets(source: str, name: str) -> list[str]:
    """Assignments to ``.verdict``/``.reasons`` and appends to ``.reasons`` (not a set point's ``res``)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        targets = node.targets if isinstance(node, ast.Assign) else []
        assigned = [el for t in targets for el in (t.elts if isinstance(t, ast.Tuple) else [t])]
        found += [f"{name}:{node.lineno} {ast.unparse(el)} =" for el in assigned
                  if isinstance(el, ast.Attribute) and el.attr in ("verdict", "reasons")
                  and ast.unparse(el.value) != "res"]
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and node.func.attr in ("append", "extend") and ast.unparse(node.func.value).endswith(".reasons"):
            found.append(f"{name}:{node.lineno} {ast.unparse(node.func)}")
    return found


def test_no_flow_sets_a_run_verdict() -> None:
    """No station module assigns ``.verdict`` or ``.reasons`` of a run report, nor appends to its
    reasons (a set point's own result, ``res``, keeps its per-temperature verdict)."""
    found = [x for f in sorted(STATION.glob("*.py")) for x in _verdict_sets(f.read_text(), f.name)]
    assert not found, found
    # the scan finds the forms the flows used before
    old = ("rep.verdict, rep.reasons = 'FAIL', [r]\nb.rep.verdict = 'FAIL'\n"
           "b.rep.reasons.append(r)\nres.verdict = 'PASS'\n")
    assert len(_verdict_sets(old, "old")) == 4
