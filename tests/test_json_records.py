"""The --json objects against the TypedDicts that type them (issue 39): every key printed is
declared, every required key is printed, and nested records (tests, effects, poses, steps) and
plain values (str, int, float, bool, null, lists) hold what the declaration says -- so what mypy
checks is the output itself, not a guess at it.  Each command runs as a user runs it (a
subprocess), on repository data and a small synthetic lot."""
from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path
from typing import Any, NotRequired, Union, get_args, get_origin, get_type_hints, is_typeddict

import numpy as np
import pytest

from accelcal_station.cli._mes import CommandsDoc
from accelcal_station.cli.fit import FitReport
from accelcal_station.cli.simulate import SimulateSummary
from accelcal_station.diagnosis.result import DiagnosisJson
from accelcal_station.twin.records import CheckReport, TwinFitReport, WhatIfReport

ACCELCAL = [sys.executable, "-m", "accelcal_station"]
REPO = Path(__file__).resolve().parents[1]
DATA, EXAMPLES = REPO / "tests" / "data", REPO / "examples"
OPEN = {"JsonValue": Any, "JsonScalar": Any}  # open JSON (jsontypes): any value json.loads gives


def conforms(v: Any, hint: Any, path: str = "$") -> list[str]:
    """Where ``v`` (parsed JSON) breaks ``hint``; [] when it conforms.  Open JSON (JsonValue)
    accepts anything; numpy arrays are written as lists."""
    if hint is Any:
        return []
    if is_typeddict(hint):
        if not isinstance(v, dict):
            return [f"{path}: {type(v).__name__}, not an object ({hint.__name__})"]
        hints = get_type_hints(hint, localns=OPEN, include_extras=True)
        errs = [f"{path}.{k}: not declared in {hint.__name__}" for k in v if k not in hints]
        for k, h in hints.items():
            optional = get_origin(h) is NotRequired or k in hint.__optional_keys__
            h = get_args(h)[0] if get_origin(h) is NotRequired else h
            if k not in v:
                errs += [] if optional else [f"{path}.{k}: missing (required by {hint.__name__})"]
            else:
                errs += conforms(v[k], h, f"{path}.{k}")
        return errs
    origin, args = get_origin(hint), get_args(hint)
    if origin in (Union, types.UnionType):
        tries = [conforms(v, a, path) for a in args]
        return [] if any(not t for t in tries) else min(tries, key=len)
    if origin is NotRequired:
        return conforms(v, args[0], path)
    if origin is list or hint is np.ndarray:
        if not isinstance(v, list):
            return [f"{path}: {type(v).__name__}, not a list"]
        return [e for i, x in enumerate(v) for e in conforms(x, args[0] if args else Any, f"{path}[{i}]")]
    if origin is dict or hint is dict:
        if not isinstance(v, dict):
            return [f"{path}: {type(v).__name__}, not an object"]
        return [e for k, x in v.items() for e in conforms(x, args[1] if args else Any, f"{path}.{k}")]
    if hint is type(None):
        return [] if v is None else [f"{path}: {v!r}, not null"]
    if hint is float:  # an int is a float to mypy; NaN and infinities are floats too
        return [] if isinstance(v, (int, float)) and not isinstance(v, bool) else [f"{path}: {v!r}, not a number"]
    if hint in (int, str, bool):
        ok = isinstance(v, hint) and (hint is bool or not isinstance(v, bool))
        return [] if ok else [f"{path}: {v!r}, not {hint.__name__}"]
    raise AssertionError(f"{path}: no rule for {hint!r}")


def test_the_checker_finds_what_it_should() -> None:
    """The checker itself: a missing key, an extra key, a wrong type, a wrong union member."""
    assert conforms({"command": "x", "help": "h", "subcommands": []}, CommandsDoc) == []
    assert conforms({"command": "x", "subcommands": []}, CommandsDoc) == ["$.help: missing (required by CommandsDoc)"]
    assert conforms({"command": "x", "help": "h", "subcommands": [], "more": 1}, CommandsDoc) == \
        ["$.more: not declared in CommandsDoc"]
    assert conforms({"command": 1, "help": "h", "subcommands": [{"name": "a", "help": None}]}, CommandsDoc) == \
        ["$.command: 1, not str", "$.subcommands[0].help: None, not str"]
    assert conforms(True, float) and conforms(1.5, int) and not conforms(2, float)
    assert conforms([1, "a"], list[int] | None)


def run_json(*args: str | Path, cwd: Path | None = None) -> Any:
    r = subprocess.run([*ACCELCAL, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                       env={"OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads(r.stdout)


@pytest.mark.parametrize("args", [
    ("fit", EXAMPLES / "poses.csv", "--model", "12", "--json"),
    ("fit", DATA / "nine_position_paper_faces.csv", "--model", "6", "--json"),  # terms held: held[] filled
    ("fit", DATA / "calibraxis_set_1.csv", "--json"),  # no --model: model_choice
])
def test_fit_json_is_a_fit_report(args: tuple[str | Path, ...]) -> None:
    doc = run_json(*args)
    assert conforms(doc, FitReport) == []
    assert "poses" in doc and "W" in doc  # FitReport is total=False: the checks above need the keys there


def test_fit_json_of_a_raw_log_is_a_fit_report(tmp_path: Path) -> None:
    """A raw log (static intervals found): ``segmentation`` and ``inferred`` of the raw reader."""
    run_json("simulate", "--poses", "optimal-12", "--raw", "--out", tmp_path / "r.csv", "--json")
    doc = run_json("fit", tmp_path / "r.csv", "--raw", "--model", "9", "--json")
    assert conforms(doc, FitReport) == []
    assert doc["segmentation"]["count"] == 12


def test_fit_json_at_several_temperatures_is_a_fit_report(tmp_path: Path) -> None:
    run_json("simulate", "--poses", "an4399-8", "--temps", "0,40", "--out", tmp_path / "tt.csv", "--json")
    doc = run_json("fit", tmp_path / "tt.csv", "--model", "12", "--json")
    assert conforms(doc, FitReport) == []
    assert len(doc["temperatures"]) == 2 and all("temp_c" in p for p in doc["poses"])


def test_simulate_and_group_json_are_their_records(tmp_path: Path) -> None:
    doc = run_json("simulate", "--poses", "six-face", "--out", tmp_path / "s.csv", "--json")
    assert conforms(doc, SimulateSummary) == []
    assert conforms(run_json("twin", "--json"), CommandsDoc) == []
    assert conforms(run_json("--json"), CommandsDoc) == []


@pytest.mark.parametrize("args", [
    (EXAMPLES / "poses.csv",),
    (DATA / "nine_position_paper_faces.csv",),
    ("--raw", "--columns", "-,-,x,y,z,-,-,-", "--rate", "204.8", DATA / "imucal_annotated_session.csv"),
])
def test_diagnose_json_is_a_diagnosis_json(args: tuple[str | Path, ...]) -> None:
    doc = run_json("diagnose", *args, "--json")
    assert conforms(doc, DiagnosisJson) == []


@pytest.fixture(scope="module")
def small_lot(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from accelcal_station.lot.synthetic import write_lot

    d = tmp_path_factory.mktemp("lot")
    write_lot(d / "lot.csv", 300, design="optimal-12", seed=7)
    return d


def test_twin_json_is_its_records(small_lot: Path) -> None:
    """fit, check (with the before config) and whatif of a 300-board lot."""
    lot = small_lot / "lot.csv"
    fitted = run_json("twin", "fit", lot, "-o", small_lot / "tw.yaml", "--json")
    assert conforms(fitted, TwinFitReport) == []
    checked = run_json("twin", "check", lot, "--config", small_lot / "tw.yaml", "--seed", "1", "--json")
    assert conforms(checked, CheckReport) == [] and "before" in checked and checked["tests"]
    what = run_json("twin", "whatif", lot, "--config", small_lot / "tw.yaml", "--seed", "1", "--boards", "1000",
                    "--limit", "offset_max_mg=60", "--json")
    assert conforms(what, WhatIfReport) == []
