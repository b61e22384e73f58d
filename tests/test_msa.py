"""`accelcal report msa`: a Gage R&R study (AIAG MSA 4th ed.) of boards calibrated by the simulated station.

The study is checked against an ANOVA written here from the stored calibrations (read with sqlite3,
sums of squares by the correction-factor formulas, not the program's deviations from means), the
statistics against data simulated with known variance components, and bad input for one line, exit 2.
"""
from __future__ import annotations

import json
import math
import sqlite3
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from scipy import stats

from accelcal_station.cli import cli
from accelcal_station.lot.msa import anova, average_range, figures

REPO = Path(__file__).resolve().parents[1]
BOARDS = [f"SN-{k}" for k in range(1, 6)]
OPERATORS = ["alice", "bob"]
# x offsets of the five boards (mg): spread ~0.06 mg, near the station's repeatability (~0.03 mg), so
# %GRR lands in the interesting 10-60 % range rather than at 0.5 % (a +-17 mg spread would give that)
OFFSET_X_MG = [18.00, 18.05, 18.10, 18.15, 18.20]


def _board_config(tmp: Path, k: int, seed: int) -> Path:
    """configs/sim.yaml with board k's own offsets and gains (the same board every run) and a fresh
    seed per run (fresh noise)."""
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    eff = cfg["device"]["simulator"]["effects"]
    eff["offset"]["offset_mg"] = [OFFSET_X_MG[k], -27.0 + 0.3 * k, 41.0 - 0.2 * k]
    eff["gain"]["gain"] = [1.012 + 0.0004 * k, 0.987, 1.021 - 0.0003 * k]
    cfg["device"]["seed"] = seed
    cfg["device"]["eeprom"].pop("image", None)
    p = tmp / f"board{k}-seed{seed}.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


@pytest.fixture(scope="module")
def study_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five boards x two operators x two trials, trial by trial, each a real `accelcal run`."""
    tmp = tmp_path_factory.mktemp("msa")
    db = tmp / "runs.sqlite"
    seed = 100
    for _trial in range(2):
        for op in OPERATORS:
            for k, serial in enumerate(BOARDS):
                seed += 1
                r = CliRunner().invoke(cli, ["run", "--config", str(_board_config(tmp, k, seed)), "--serial", serial,
                                             "--operator", op, "--store", str(db), "--json"])
                assert r.exit_code in (0, 1), r.output
    return db


def _independent_anova(x: np.ndarray) -> tuple[float, int]:
    """%GRR and ndc of a parts x appraisers x trials array, AIAG MSA 4th ed. Appendix A, computed from
    totals (correction factor CF = T^2/N) instead of deviations from the means."""
    p, o, r = x.shape
    n = x.size
    cf = x.sum() ** 2 / n
    ss_t = float((x ** 2).sum() - cf)
    ss_p = float((x.sum(axis=(1, 2)) ** 2).sum() / (o * r) - cf)
    ss_o = float((x.sum(axis=(0, 2)) ** 2).sum() / (p * r) - cf)
    ss_cells = float((x.sum(axis=2) ** 2).sum() / r - cf)
    ss_po = ss_cells - ss_p - ss_o
    ss_e = ss_t - ss_cells
    df_p, df_o, df_po, df_e = p - 1, o - 1, (p - 1) * (o - 1), n - p * o
    ms_p, ms_o, ms_po, ms_e = ss_p / df_p, ss_o / df_o, ss_po / df_po, ss_e / df_e
    if stats.f.sf(ms_po / ms_e, df_po, df_e) > 0.25:  # pool the interaction (MSA 4th ed. Appendix A)
        ms_e = ms_po = (ss_po + ss_e) / (df_po + df_e)
    var_e = ms_e
    var_po = max((ms_po - ms_e) / r, 0.0)
    var_o = max((ms_o - ms_po) / (p * r), 0.0)
    var_p = max((ms_p - ms_po) / (o * r), 0.0)
    grr = math.sqrt(var_e + var_po + var_o)
    return 100 * grr / math.sqrt(grr ** 2 + var_p), math.floor(1.41 * math.sqrt(var_p) / grr)


def _msa(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(cli, ["report", "msa", *args])
    return r.exit_code, r.output


def test_x_offset_study_matches_an_independent_anova(study_store: Path) -> None:
    con = sqlite3.connect(study_store)
    rows = con.execute("SELECT device_serial, operator, calibration FROM runs WHERE status = 'complete' "
                       "ORDER BY id").fetchall()
    con.close()
    assert len(rows) == 20
    cells: dict[tuple[str, str], list[float]] = {}
    for serial, op, cal in rows:
        cells.setdefault((serial, op), []).append(1e3 * json.loads(cal)["V"][0])
    x = np.array([[cells[(b, op)] for op in OPERATORS] for b in BOARDS])
    assert x.shape == (5, 2, 2)
    want_pct, want_ndc = _independent_anova(x)

    code, out = _msa("--db", str(study_store), "--json")
    assert code == 0, out
    doc = json.loads(out)
    res = {r["parameter"]: r for r in doc["results"]}
    vx = res["V_x"]
    assert (vx["boards"], vx["appraisers"], vx["trials"]) == (5, 2, 2)
    assert vx["pct_grr"] == pytest.approx(want_pct, rel=0.02)
    assert abs(vx["ndc"] - want_ndc) <= 1
    assert 5 < want_pct < 95  # the study is not degenerate: both GRR and PV are seen
    # the tolerance from the stored acceptance limit: 2 x offset_max_mg (configs/sim.yaml: 120 mg)
    assert vx["tolerance"] == pytest.approx(240.0)
    assert vx["pct_tolerance"] == pytest.approx(100 * 6 * vx["grr"] / 240.0)
    assert {"W_xx", "W_xy", "residual_rms_mg", "verify_error_max_mg"} <= set(res)
    assert vx["average_range"]["available"] is True
    code, text = _msa("--db", str(study_store), "--tolerance", "V_x=1.0")
    assert code == 0 and "V_x" in text and "%GRR" in text


def test_html_report_and_its_guards(study_store: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="the report extra (matplotlib) is not installed")
    page = tmp_path / "msa.html"
    code, out = _msa("--db", str(study_store), "--html", str(page))
    assert code == 0, out
    text = page.read_text()
    assert text.count("<img src='data:image/png;base64,") >= 10 and "V_x" in text
    before = study_store.read_bytes()
    code, out = _msa("--db", str(study_store), "--html", str(study_store))
    assert code == 2 and len(out.strip().splitlines()) == 1
    assert study_store.read_bytes() == before


def test_bad_studies_are_refused_with_one_line(study_store: Path, tmp_path: Path) -> None:
    con = sqlite3.connect(study_store)
    last, before = (t for (t,) in con.execute("SELECT started_at FROM runs ORDER BY started_at DESC LIMIT 2"))
    con.close()
    until = datetime.fromtimestamp((last + before) / 2, UTC).isoformat()  # the last run left out
    cases = {
        "unbalanced": (["--until", until], "SN-5/bob has 1"),
        "one appraiser": (["--operator", "alice"], "one operator (alice)"),
        "one part": (["--device", "SN-1"], "one part (SN-1)"),
        "no repeats": (["--status", "interrupted"], "no serial measured more than once"),
        "bad tolerance": (["--tolerance", "V_x=-1"], "--tolerance"),
        "unknown parameter": (["--tolerance", "V_q=1"], "PARAM one of V_x"),
        "one station": (["--by", "station"], "one station (sim-station-1)"),
    }
    for name, (args, words) in cases.items():
        code, out = _msa("--db", str(study_store), "--json", *args)
        assert code == 2, (name, out)
        assert len(out.strip().splitlines()) == 1, (name, out)
        assert words in json.loads(out)["error"], (name, out)


def test_html_without_matplotlib_names_the_extra(study_store: Path, tmp_path: Path) -> None:
    """matplotlib made unimportable in a child process (as tests/test_optional_extras.py does)."""
    child = ("import sys\nsys.modules['matplotlib'] = None\nsys.modules['matplotlib.pyplot'] = None\n"
             "sys.argv = ['accelcal'] + sys.argv[1:]\nfrom accelcal_station.cli import main\nmain()\n")
    page = tmp_path / "msa.html"
    r = subprocess.run([sys.executable, "-c", child, "report", "msa", "--db", str(study_store), "--html", str(page)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "pip install 'accelcal-station[report]'" in r.stderr and not page.exists()


def test_plan_is_random_but_fixed_and_complete(study_store: Path) -> None:
    code, out = _msa("--db", str(study_store), "--plan", "--parts", "4", "--appraisers", "3", "--trials", "2",
                     "--json")
    assert code == 0, out
    doc = json.loads(out)
    runs = doc["runs"]
    assert len(runs) == 4 * 3 * 2 and [r["order"] for r in runs] == list(range(1, 25))
    assert set(doc["parts"]) <= set(BOARDS) and doc["appraisers"][:2] == ["bob", "alice"]
    assert doc["appraisers"][2] == "operator-C"  # a third appraiser the store does not know yet
    cells = {(r["part"], r["appraiser"], r["trial"]) for r in runs}
    assert len(cells) == 24
    assert _msa("--db", str(study_store), "--plan", "--parts", "4", "--appraisers", "3", "--trials", "2",
                "--json")[1] == out  # the same seed, the same order
    orders = [[r["part"] for r in runs if r["appraiser"] == a and r["trial"] == 1] for a in doc["appraisers"]]
    assert len({tuple(o) for o in orders}) > 1  # randomised per appraiser, not the same order for all


def _simulate(rng: np.random.Generator, p: int, o: int, r: int, s_p: float, s_o: float, s_po: float,
              s_e: float) -> np.ndarray:
    return (rng.normal(0, s_p, (p, 1, 1)) + rng.normal(0, s_o, (1, o, 1)) + rng.normal(0, s_po, (p, o, 1))
            + rng.normal(0, s_e, (p, o, r)))


def test_anova_recovers_known_variance_components() -> None:
    """40 parts x 30 appraisers x 3 trials with sigma_p 1.0, sigma_o 0.3, sigma_po 0.2, sigma_e 0.25.
    Each variance estimate must land within 4.5 of its standard errors (from the expected mean squares
    and chi-square variances 2 EMS^2/df): false-failure rate < 1e-4 per estimate (normal tail 7e-6, with
    margin for the chi-square skew); the seed is fixed."""
    p, o, r, s_p, s_o, s_po, s_e = 40, 30, 3, 1.0, 0.3, 0.2, 0.25
    x = _simulate(np.random.default_rng(20261129), p, o, r, s_p, s_o, s_po, s_e)
    a = anova(x)
    assert not a.pooled
    ems_e, ems_po = s_e ** 2, s_e ** 2 + r * s_po ** 2
    ems_o, ems_p = ems_po + p * r * s_o ** 2, ems_po + o * r * s_p ** 2
    df_e, df_po, df_o, df_p = p * o * (r - 1), (p - 1) * (o - 1), o - 1, p - 1

    def se(ms1: float, df1: int, ms2: float, df2: int, div: float) -> float:
        return math.sqrt(2 * ms1 ** 2 / df1 + 2 * ms2 ** 2 / df2) / div

    checks = [(a.ev ** 2, s_e ** 2, math.sqrt(2 / df_e) * ems_e),
              (a.interaction ** 2, s_po ** 2, se(ems_po, df_po, ems_e, df_e, r)),
              (a.av ** 2, s_o ** 2, se(ems_o, df_o, ems_po, df_po, p * r)),
              (a.pv ** 2, s_p ** 2, se(ems_p, df_p, ems_po, df_po, o * r))]
    for est, true, err in checks:
        assert abs(est - true) < 4.5 * err, (est, true, err)
    f = figures(a.ev, a.av, a.interaction, a.pv, tolerance=6.0)
    true_grr = math.sqrt(s_e ** 2 + s_o ** 2 + s_po ** 2)
    assert f.pct_grr == pytest.approx(100 * true_grr / math.sqrt(true_grr ** 2 + s_p ** 2), rel=0.15)
    assert f.pct_tolerance == pytest.approx(100 * f.grr)  # 6 GRR / 6


def test_interaction_pooled_when_absent_and_average_range_by_hand() -> None:
    """Additive cell means (SS_interaction = 0, p = 1 > 0.25): the interaction is pooled and EV is
    sqrt(SS_E / (df_PO + df_E)).  The average-and-range figures by hand with the AIAG K constants
    (MSA 4th ed. figure III-B 15: K1 = 0.8862 for 2 trials, K2 = 0.7071 for 2 appraisers, K3 = 0.5231
    for 3 parts)."""
    cell = np.array([1.0, 2.0, 4.0])[:, None] + np.array([0.0, 0.5])[None, :]
    x = np.stack([cell - 0.1, cell + 0.1], axis=2)  # every range 0.2, cell means additive
    a = anova(x)
    assert a.pooled and a.p_interaction == pytest.approx(1.0)
    ss_e = 12 * 0.1 ** 2
    assert a.ev == pytest.approx(math.sqrt(ss_e / (2 + 6)))
    assert a.interaction == 0.0
    ar = average_range(x)
    assert ar.ev == pytest.approx(0.2 * 0.8862)
    assert ar.av == pytest.approx(math.sqrt((0.5 * 0.7071) ** 2 - (0.2 * 0.8862) ** 2 / (3 * 2)))
    assert ar.pv == pytest.approx(3.0 * 0.5231)
    big = average_range(np.zeros((11, 2, 2)) + np.arange(11)[:, None, None])
    assert big.ev is None and big.unavailable is not None and "2-10 parts" in big.unavailable
