"""`accelcal diagnose --selftest`: forward-physics boards with withheld effects, each named, or said why not."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.diagnosis.report import selftest_lines
from accelcal_station.diagnosis.selftest import selftest as run_selftest

# the effects a pose table or a raw log can reveal (the self-test must name each of them)
REVEALABLE = {"offset", "gain", "cross_axis", "cubic", "quadratic", "temperature", "pose_error", "noise",
              "quantization", "drift", "settling"}


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def selftest():
    r = run("diagnose", "--selftest", "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


# -- the self-test -------------------------------------------------------------------------------
# Fixed seeds (1 through the CLI, with coverage; 2 and 3 in-process): deterministic.  The
# benchmark (benchmarks/bench_diagnose.py, table in benchmarks/README.md, 50 seeds per case) gives
# the per-case miss rates: flicker 0.04, each null case 0.02, every other case 0.00.  A seed drawn
# at random therefore fails some case with probability about 1 - 0.96 * 0.98 * 0.98 = 0.08, and
# three seeds about 0.22: that is the false-failure rate these fixed seeds stand for (alpha = 0.01
# per greedy step and per signature test, Bonferroni over the views).
OFF_CATALOG = {"product", "face_tilt", "flicker", "hysteresis"}
MORE_SEEDS = (2, 3)


def _check_case_rules(result: dict) -> None:
    """The pass rules of the issue, checked here rather than read back from each case's `pass`."""
    for c in result["cases"]:
        if c["kind"] == "named" and c["revealable"]:
            assert c["named"] == c["case"], c
            if c["case"] not in ("pose_error", "noise", "quantization"):
                assert c["rms_mg_after_named"] <= c["rms_mg_before"] / 2, c
        elif c["kind"] == "named":
            assert c["named"] is None, c
        elif c["kind"] == "unexplained":
            assert c["selected"] == [] and c["verdict"] == "unexplained", c
        elif c["kind"] == "both":
            assert set(c["case"].split("+")) <= set(c["selected"]), c
            assert c["rms_mg_after"] < c["rms_mg_before"] / 2, c
        else:
            assert c["kind"] == "null" and c["selected"] == [] and c["verdict"] == "nothing to explain", c


@pytest.mark.parametrize("seed", MORE_SEEDS)
def test_selftest_passes_at_more_fixed_seeds(seed):
    result = run_selftest(seed=seed, coverage=False)
    assert len(result["cases"]) == 21 and result["seed"] == seed
    _check_case_rules(result)
    assert result["passed"]


def test_selftest_rules_hold_at_the_cli_seed(selftest):
    _check_case_rules(selftest)


def test_selftest_names_every_revealable_withheld_effect_first(selftest):
    cases = {c["case"]: c for c in selftest["cases"] if c["kind"] == "named"}
    assert {e for e, c in cases.items() if c["revealable"]} == REVEALABLE
    for effect in REVEALABLE:
        c = cases[effect]
        assert c["named"] == effect, c
        if effect not in ("pose_error", "noise", "quantization"):  # deterministic: held-out RMS at least halved
            assert c["rms_mg_after_named"] <= c["rms_mg_before"] / 2, c
            assert c["gap_before"] > 2, c  # the effect really opened a gap
    assert selftest["passed"] and "forward" in selftest["physics"]


def test_selftest_off_catalog_effects_are_unexplained_with_nothing_named(selftest):
    cases = {c["case"]: c for c in selftest["cases"] if c["kind"] == "unexplained"}
    assert set(cases) == OFF_CATALOG
    for c in cases.values():
        assert c["selected"] == [] and c["verdict"] == "unexplained", c
        assert c["gap_before"] > 3 and c["rms_mg_after"] == c["rms_mg_before"], c  # a real gap, left as it was
    assert "product of axes" in cases["product"]["left"]
    assert "fixed per orientation" in cases["face_tilt"]["left"]
    assert "approach direction" in cases["hysteresis"]["left"]
    assert "time-varying" in cases["flicker"]["left"]


def test_selftest_two_effect_cases_name_both(selftest):
    cases = {c["case"]: c for c in selftest["cases"] if c["kind"] == "both"}
    assert set(cases) == {"cubic+temperature", "drift+settling"}
    for name, c in cases.items():
        assert set(name.split("+")) <= set(c["selected"]), c
        assert c["rms_mg_after"] < c["rms_mg_before"] / 2, c


def test_selftest_null_cases_name_nothing(selftest):
    nulls = [c for c in selftest["cases"] if c["kind"] == "null"]
    assert len(nulls) == 2 and {c["data"].split(",")[0] for c in nulls} == {"pose table with references",
                                                                              "raw log (no references)"}
    for c in nulls:
        assert c["named"] is None and c["selected"] == [] and c["verdict"] == "nothing to explain", c
        assert 0.6 < c["gap_before"] < 1.5, c


def test_selftest_says_which_effects_it_cannot_reveal_and_why(selftest):
    cases = {c["case"]: c for c in selftest["cases"]}
    for effect in ("gravity", "saturation"):  # on every kind of static gravity data
        assert not cases[effect]["revealable"] and cases[effect]["named"] is None
        assert cases[effect]["gap_before"] < 1.5  # and indeed the board's effect left no gap
    assert "gain absorbs" in cases["gravity"]["reason"]
    assert "clips" in cases["saturation"]["reason"]
    cov = selftest["coverage"]
    assert "raw" in cov["drift"]["refs"] and cov["drift"]["raw"] == "testable"
    assert "raw" in cov["settling"]["norm"] and "raw" in cov["quantization"]["refs"]
    assert "rotation" in cov["pose_error"]["norm"] and cov["pose_error"]["refs"] == "testable (signature)"
    assert "temperature" in cov["temperature"]["refs"] and cov["temperature"]["refs-3T"] == "testable"
    text = "\n".join(selftest_lines(selftest))
    for name in cases:
        assert any(line.startswith(name) for line in text.splitlines()), name
    assert "drift / refs:" in text and text.rstrip().endswith("self-test passed")
