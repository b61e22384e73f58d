"""The mutation run's mutator (benchmarks/mutation_run.py): the mutants issue 53 names are among
those it makes, each changes only its own segment and compiles; docstrings and annotations are
left alone; the sample is the same for the same seed."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
RULES = "accelcal_station/acceptance/rules.py"


def load():
    spec = importlib.util.spec_from_file_location("mutation_run_under_test", BENCH / "mutation_run.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses resolve their annotations through it
    spec.loader.exec_module(mod)
    return mod


def test_the_issues_mutants_are_made_and_apply_cleanly():
    mr = load()
    src = (mr.REPO / RULES).read_text()
    lines = src.splitlines()
    made = mr.mutants_of(RULES)

    def find(text: str, kind: str, replacement: str):
        n = next(i for i, ln in enumerate(lines, 1) if text in ln)
        return [m for m in made if m.line == n and m.kind == kind and m.replacement == replacement]

    (a,) = find('m["verify_error_max_mg"] = np.asarray', "Delete", "pass")
    (b,) = find('"residual_rms_mg": lambda f: f.residual_rms_g * 1e3', "Number", "(500.0)")
    (c,) = find('"stderr_offset_max_mg": lambda f: f.stderr_V_max_g * 1e3', "Number", "(500.0)")
    for m in (a, b, c):
        new = mr.apply(src, m)
        compile(new, RULES, "exec")
        diff = [(x, y) for x, y in zip(lines, new.splitlines(), strict=True) if x != y]
        assert len(diff) == 1 and diff[0][0].strip() != diff[0][1].strip()
    assert mr.apply(src, b).count("f.residual_rms_g * (500.0)") == 1
    # no mutant touches a docstring or an annotation line
    doc_line = next(i for i, ln in enumerate(lines, 1) if ln.startswith('"""Acceptance'))
    assert all(m.line != doc_line for m in made)


def test_the_sample_is_fixed_by_its_seed():
    mr = load()
    one, two = mr.sample("acceptance", 10, 53), mr.sample("acceptance", 10, 53)
    assert [m.id for m in one] == [m.id for m in two] and len(one) == 10
    assert [m.id for m in mr.sample("acceptance", 10, 54)] != [m.id for m in one]
