"""benchmarks/gate.py, the CI speed gate, runs and measures what it says: in --quick mode (tiny sizes,
floors not applied: no wall-clock threshold here) every gate gives a positive ratio, the lot gate's
project results agree with the plain numpy reference (asserted inside), and a results table that
disagrees with the reference is caught."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

GATE = Path(__file__).resolve().parent.parent / "benchmarks" / "gate.py"


@pytest.fixture(scope="module")
def gate():
    spec = importlib.util.spec_from_file_location("accelcal_gate", GATE)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["accelcal_gate"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_quick_gate_runs_and_agrees_with_the_reference(gate, capsys) -> None:
    assert gate.main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert set(gate.FLOORS) == {g for g in gate.FLOORS if f"  {g} " in out}, "a gate did not report"
    assert "agree on 300 boards" in out


def test_every_gate_has_a_floor_and_a_positive_ratio(gate) -> None:
    gates = gate.run_gates(quick=True)
    assert [g.name for g in gates] == list(gate.FLOORS)
    assert all(g.project_s > 0 and g.reference_s > 0 and np.isfinite(g.ratio) for g in gates)


def test_a_disagreeing_result_is_caught(gate, tmp_path) -> None:
    from accelcal_station.acceptance.rules import Limits
    from accelcal_station.lot.streaming import recalibrate_lot
    from accelcal_station.lot.synthetic import write_lot

    lot = write_lot(tmp_path / "lot.csv", 50, "an4399-8", seed=1)
    recalibrate_lot(lot, tmp_path / "p.csv", "12", limits=Limits(dict(gate.LIMITS)))
    ref = gate.reference_lot.run(lot, tmp_path / "r.csv", gate.LIMITS)
    project = gate._read_project_results(tmp_path / "p.csv")
    assert "agree on 50 boards" in gate.check_agreement(project, ref)
    project["V"][7, 1] += 1e-6  # a microg off on one board
    with pytest.raises(AssertionError, match="V: project and reference differ"):
        gate.check_agreement(project, ref)
    project["V"][7, 1] -= 1e-6
    project["passed"][3] = not project["passed"][3]
    with pytest.raises(AssertionError, match="verdicts differ on 1 boards"):
        gate.check_agreement(project, ref)
