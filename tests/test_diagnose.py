"""`accelcal diagnose`: the sim-to-real gap, the effect behind it, the report and bad input (the self-test on
withheld effects: test_diagnose_selftest.py)."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.diagnosis.engine import diagnose
from accelcal_station.diagnosis.gap_data import Capture, GapData, value_step
from accelcal_station.diagnosis.gap_effects import evaluate
from accelcal_station.diagnosis.loading import gap_data, load_data, load_simulator
from accelcal_station.diagnosis.noise_floor import bias_var, mean_var, within_spread
from accelcal_station.diagnosis.report import summary_lines
from accelcal_station.diagnosis.request import DiagnoseRequest
from accelcal_station.diagnosis.selection import p_greater as _p_greater
from accelcal_station.fixtures.designs import get_design
from accelcal_station.session import PoseRecord, Session
from accelcal_station.sim.sensor_model import rotation_matrix

REPO = Path(__file__).resolve().parents[1]
CUBIC = [0.003, -0.002, 0.004]


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def one_line_error(r) -> str:
    assert r.exit_code != 0
    assert r.stderr.startswith("error: ") and r.stderr.count("\n") == 1, r.stderr
    assert "Traceback" not in r.output
    return r.stderr


@pytest.fixture(scope="module")
def cubic_table(tmp_path_factory):
    """A simulated board with a cubic nonlinearity the default configuration lacks."""
    d = tmp_path_factory.mktemp("cubic")
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["device"]["simulator"]["effects"]["cubic"] = {"cubic_per_g2": CUBIC}
    (d / "board.yaml").write_text(yaml.safe_dump(cfg))
    r = run("simulate", "--config", d / "board.yaml", "--poses", "optimal-24", "--samples", 200, "--seed", 4,
            "--out", d / "table.csv")
    assert r.exit_code == 0, r.output
    return shuffled(d / "table.csv")


def shuffled(path, seed: int = 0):
    """The pose table's rows in a fixed shuffled order.  optimal-N lists its poses sorted by x: in that
    order every x term (a cubic, a gain change with temperature) follows acquisition order and is
    confounded with a drift (diagnosis/order.py); these boards have no time effect, so the readings
    are the same in any order."""
    lines = path.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")] + [next(ln for ln in lines if not ln.startswith("#"))]
    body = lines[len(head):]
    order = np.random.default_rng(seed).permutation(len(body))
    path.write_text("\n".join(head + [body[i] for i in order]) + "\n")
    return path


# -- the headline only residuals move --------------------------------------------------------------

def _crafted(extra_g, std_factor: float = 1.0, scatter_deg: float = 0.0, seed: int = 5) -> GapData:
    """Pose means made by hand: reference + an off-catalog term + noise of the simulator's floor,
    the poses' std std_factor x the simulator's per-sample sigma, an optional random pose scatter."""
    rng = np.random.default_rng(seed)
    sim = load_simulator()
    sigma = float(sim.sigma_g(None)[0])
    n = 200
    recs = []
    for k, pose in enumerate(list(get_design("optimal-24")) * 2):
        ref = pose.reference_g
        true = rotation_matrix(rng.normal(0, scatter_deg, 3)) @ ref if scatter_deg else ref
        g = true + extra_g(ref) + rng.normal(0, std_factor * sigma / np.sqrt(n), 3)
        recs.append(PoseRecord(f"{pose.name}#{k}", g * 4096.0, np.full(3, std_factor * sigma * 4096.0), n, ref,
                               pose.pitch_deg, pose.roll_deg, 25.0))
    return gap_data([(Session(recs, "counts", 4096.0, None, "mma8451"), None, "crafted")])


def test_noise_and_pose_error_cannot_lower_the_gap():
    """A product term (off-catalog) with three times the simulator's noise: noise is named by its own
    signature, but the gap and the held-out RMS stay where the residuals put them."""
    data = _crafted(lambda r: np.array([0.0, 0.0, 0.02 * r[0] * r[1]]), std_factor=3.0)
    d = diagnose(data, load_simulator())
    assert "noise" in d.selected and d.stochastic["noise"]["passed"]
    assert d.steps == [] and d.gap_after == d.gap_before and d.final.rms_g == d.base.rms_g
    assert d.gap_before > 3 and d.verdict == "unexplained"
    assert not d.stochastic["pose_error"]["passed"]  # a product term leaves a radial part
    assert "radial" in d.stochastic["pose_error"]["reason"]


def test_pose_scatter_is_named_by_geometry_and_leaves_the_gap():
    data = _crafted(lambda r: np.zeros(3), scatter_deg=0.1)
    d = diagnose(data, load_simulator())
    pe = d.stochastic["pose_error"]
    assert d.selected[:1] == ["pose_error"] and pe["passed"], pe
    assert pe["across_ratio"] > 2 and pe["along_ratio"] < 2 and 0.05 < pe["scatter_deg"] < 0.2
    assert d.gap_after == d.gap_before > 2 and d.final.rms_g == d.base.rms_g  # never lowers the headline


def test_a_tilt_that_repeats_on_revisit_is_not_pose_error():
    tilts: dict = {}

    def tilt(ref):
        key = tuple(np.round(ref, 3))
        tilts.setdefault(key, rotation_matrix(np.random.default_rng(len(tilts)).normal(0, 0.15, 3)))
        return tilts[key] @ ref - ref

    d = diagnose(_crafted(tilt), load_simulator())
    pe = d.stochastic["pose_error"]
    assert not pe["passed"] and pe["revisit_ratio"] < 1.5, pe  # revisits repeat the tilt: not a random pose error
    assert d.selected == [] and d.verdict == "unexplained"
    assert "fixed per orientation" in d.leftover["summary"]


def test_forward_cubic_is_the_sensors_physics():
    from accelcal_station.sim.sensor_model import SensorModel

    m = SensorModel.from_config({"offset": {"offset_mg": [20.0, -10.0, 5.0]}, "cubic": {"cubic_per_g2": CUBIC}})
    m.forward = True
    f = np.random.default_rng(2).normal(size=(50, 3))
    u = f @ m.linear_matrix(25.0).T
    np.testing.assert_allclose(m.response_g(f, 25.0), m.offset_g(25.0) + u + np.array(CUBIC) * u**3, atol=1e-15)


def test_identifiability_is_said_in_words():
    """Six faces revisited: six distinct orientations; a cubic next to the gain is confounded there."""
    from accelcal_station.diagnosis.effects.design import describe_design

    recs = [PoseRecord(f"f{k}", p.reference_g * 4096.0, None, 100, p.reference_g, p.pitch_deg, p.roll_deg, 25.0)
            for k, p in enumerate(list(get_design("six-face")) * 3)]
    data = gap_data([(Session(recs, "counts", 4096.0, None, "mma8451"), None, "faces")])
    words = describe_design(data, ("gain", "offset", "cubic"))
    assert words["distinct_orientations"] == 6 and data.P == 18
    assert any("cubic" in " ".join(g) and "gain" in " ".join(g) for g in words["confounded"]), words
    assert "6 distinct orientations cannot determine" in words["text"]


def test_json_names_the_cubic_and_recovers_it(cubic_table):
    r = run("diagnose", cubic_table, "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    for key in ("gap_before", "gap_after", "ranking", "selected", "steps", "untestable", "where", "test"):
        assert key in js
    assert js["selected"] == ["cubic"]
    assert js["gap_before"] > 5 and js["gap_after"] < js["gap_before"] / 2 and js["gap_after"] < 2
    assert js["ranking"][0]["effect"] == "cubic"
    assert all({"effect", "held_out_gap"} <= set(x) for x in js["ranking"])
    assert js["steps"][0]["gap_before"] == pytest.approx(js["gap_before"])
    # AN4399 Eqn 67: the fitted Gamma is minus the simulated cubic coefficient (floor 0.05 mg: < 5 % error)
    gamma = [js["steps"][0]["fitted"][f"Gamma_{a}"] for a in "xyz"]
    np.testing.assert_allclose(gamma, -np.array(CUBIC), rtol=0.15)
    untestable = {u["effect"] for u in js["untestable"]}
    assert {"drift", "settling", "temperature", "gravity", "saturation"} <= untestable
    assert js["stochastic"]["quantization"]["testable"] is False  # stochastic: its own section
    assert js["where"]["by_axis"]["z"] > 2  # the gap is everywhere, not one axis


def test_human_summary_and_report(cubic_table, tmp_path):
    out = tmp_path / "rep"
    r = run("diagnose", cubic_table, "--report", out)
    assert r.exit_code == 0, r.output
    verdict = next(line for line in r.stdout.splitlines() if line.startswith("VERDICT: "))
    assert "cubic" in verdict and "cubic_per_g2" in r.stdout and "STOCHASTIC" in r.stdout
    for name in ("sphere", "level", "temperature", "time"):
        png = out / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "summary.md").read_text()
    for name in ("sphere", "level", "temperature", "time"):
        assert f"]({name}.png)" in md
    assert "cubic (selected)" in md
    assert not list(out.glob(".*tmp*"))  # no half-written files left


def test_report_without_matplotlib_is_one_line(cubic_table, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if the report extra were not installed
    r = run("diagnose", cubic_table, "--report", tmp_path / "rep")
    assert "pip install 'accelcal-station[report]'" in one_line_error(r)
    assert not (tmp_path / "rep").exists()


def test_norm_only_paired_test_counts_one_unit_per_pose(cubic_table, tmp_path):
    """Without references a pose's norm residual is one score: the paired test must not add two zeros per pose."""
    rows = list(csv.DictReader(line for line in cubic_table.read_text().splitlines() if not line.startswith("#")))
    path = tmp_path / "norm.csv"  # no std, no n, no references: the static norm view is the only view
    path.write_text("# units: counts\n# counts_per_g: 4096\npose,x,y,z\n"
                    + "".join(f"{r['pose']},{r['x']},{r['y']},{r['z']}\n" for r in rows))
    sim = load_simulator()
    data = load_data(DiagnoseRequest(files=[path], samples=200))
    d = diagnose(data, sim)
    assert d.selected == ["cubic"]
    cubic = evaluate(data, d.floor, sim.baseline, ("cubic",), None, True)
    diff = d.base.nll_unit - cubic.nll_unit
    assert np.count_nonzero(d.base.nll_unit) == data.P
    assert d.ranking[0]["p_value"] == _p_greater(diff[d.base.nll_unit != 0])


def test_null_table_names_nothing(tmp_path):
    # 72 held-out residuals: the gap's sd is about 0.09, so 0.6-1.5 fails with p < 1e-5
    r = run("simulate", "--config", REPO / "configs" / "sim.yaml", "--poses", "optimal-24", "--samples", 200,
            "--seed", 11, "--out", tmp_path / "t.csv")
    assert r.exit_code == 0
    js = json.loads(run("diagnose", tmp_path / "t.csv", "--json").stdout)
    assert js["selected"] == [] and 0.6 < js["gap_before"] < 1.5 and js["gap_after"] == js["gap_before"]


def test_one_file_per_temperature_names_temperature(tmp_path):
    """Several files at once, one per temperature: the temperature coefficients come back."""
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["device"]["simulator"]["effects"]["temperature"] = {"offset_mg_per_c": [0.2, -0.15, 0.25],
                                                             "gain_ppm_per_c": [100.0, -80.0, 120.0]}
    (tmp_path / "board.yaml").write_text(yaml.safe_dump(cfg))
    files = []
    for t in (0, 25, 50):
        files.append(tmp_path / f"t{t}.csv")
        r = run("simulate", "--config", tmp_path / "board.yaml", "--poses", "optimal-18", "--samples", 100,
                "--seed", 70 + t, "--temps", t, "--out", files[-1])
        assert r.exit_code == 0, r.output
        shuffled(files[-1], t)
    js = json.loads(run("diagnose", *files, "--json").stdout)
    assert js["data"]["poses"] == 54 and js["data"]["temperatures"] == 3
    assert js["selected"] == ["temperature"] and js["gap_after"] < js["gap_before"] / 2
    f = js["steps"][0]["fitted"]
    # u_c += b dT/25: b/25 is minus the offset coefficient (floor 0.07 mg over 50 C: within 15 %)
    np.testing.assert_allclose([-1e3 * f[f"offset_{a}_per_25C"] / 25 for a in "xyz"], [0.2, -0.15, 0.25], rtol=0.15)
    gaps = {round(t["temp_c"]): t["gap"] for t in js["where"]["by_temperature"]}
    assert gaps[0] > 3 * gaps[25] and gaps[50] > 3 * gaps[25]  # the gap lies at the ends of the range


def test_real_imucal_raw_session_names_noise(data_dir):
    """The real IMU's noise is several times the simulated MMA8451's: the noise signature says so, and the
    headline gap (against the data's own within-capture spread) is not lowered by it."""
    path = data_dir / "imucal_annotated_session.csv"
    r = run("diagnose", "--raw", path, "--columns", "-,-,x,y,z,-,-,-", "--rate", "204.8", "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    assert js["data"]["poses"] == 6 and not js["data"]["static_view"]  # six faces cannot hold out model 9
    assert "noise" in js["selected"] and js["stochastic"]["noise"]["passed"]
    assert all(2.5 < x < 4.5 for x in js["stochastic"]["noise"]["ratio"])  # about 3 mg per sample at 204.8 Hz
    assert js["gap_after"] == js["gap_before"] and js["steps"] == []
    assert js["verdict"] == "unexplained" and "time-varying" in js["left"]["summary"]


# -- bad input -----------------------------------------------------------------------------------

def test_bad_input_is_one_line(tmp_path, cubic_table):
    assert "cannot read" in one_line_error(run("diagnose", tmp_path / "missing.csv"))
    assert "no data files" in one_line_error(run("diagnose"))
    assert "--selftest" in one_line_error(run("diagnose", "--selftest", cubic_table))
    assert "--samples" in one_line_error(run("diagnose", cubic_table, "--samples", "many"))
    (tmp_path / "afile").write_text("x")
    assert "not a directory" in one_line_error(run("diagnose", cubic_table, "--report", tmp_path / "afile"))
    assert "driver: simulated" in one_line_error(run("diagnose", cubic_table, "--config",
                                                     REPO / "configs" / "mma8451.yaml"))
    assert "no such simulator configuration" in one_line_error(run("diagnose", cubic_table, "--config",
                                                                   tmp_path / "no.yaml"))
    few = tmp_path / "few.csv"  # five norm-only poses: nothing can be held out
    rows = list(csv.DictReader(line for line in cubic_table.read_text().splitlines() if not line.startswith("#")))
    few.write_text("# units: counts\n# counts_per_g: 4096\npose,pitch_deg,roll_deg,x,y,z\n"
                   + "".join(f"{r['pose']},,,{r['x']},{r['y']},{r['z']}\n" for r in rows[:5]))
    # a run that fails after --report was checked leaves no (empty) report directory behind
    assert "nothing to diagnose" in one_line_error(run("diagnose", few, "--report", tmp_path / "rep"))
    assert not (tmp_path / "rep").exists()
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    for e in ("noise", "quantization"):  # a simulator that claims exact readings: no floor to compare with
        del cfg["device"]["simulator"]["effects"][e]
    (tmp_path / "exact.yaml").write_text(yaml.safe_dump(cfg))
    assert "predicts no noise" in one_line_error(run("diagnose", cubic_table, "--config", tmp_path / "exact.yaml"))


def test_report_failing_midway_leaves_no_half_written_report(cubic_table, tmp_path):
    out = tmp_path / "rep"
    (out / "level.png").mkdir(parents=True)  # the second figure cannot be written
    assert "level.png" in one_line_error(run("diagnose", cubic_table, "--report", out))
    assert sorted(p.name for p in out.iterdir()) == ["level.png"]  # the sphere figure written first is gone


def test_noise_free_data_and_exact_simulator_do_not_crash(tmp_path):
    """Readings equal to their references under a simulator with nothing to fit: held-out gap exactly 0."""
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    for e in ("offset", "gain", "cross_axis"):
        del cfg["device"]["simulator"]["effects"][e]
    (tmp_path / "ideal.yaml").write_text(yaml.safe_dump(cfg))
    rows = "".join(f"{p.name},{','.join(repr(float(v)) for v in p.reference_g)},"
                   f"{','.join(repr(float(v)) for v in p.reference_g)}\n" for p in get_design("optimal-24"))
    (tmp_path / "exact.csv").write_text("# units: g\npose,x,y,z,ref_x,ref_y,ref_z\n" + rows)
    r = run("diagnose", tmp_path / "exact.csv", "--config", tmp_path / "ideal.yaml", "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    assert js["gap_before"] == 0 and js["selected"] == []


def test_raw_captures_too_short_for_time_blocks():
    """Captures under 24 samples give no time view; the breakdown must not need one (Allan needs it)."""
    rng = np.random.default_rng(3)
    records, caps = [], []
    for k, pose in enumerate(get_design("optimal-24")):
        x = np.round(4096 * np.asarray(pose.reference_g) + rng.normal(0, 3, (20, 3)))
        caps.append(Capture(2.0 * k + np.arange(20) / 20.0, x, 1.0))
        records.append(PoseRecord(pose.name, x.mean(0), x.std(0, ddof=1), 20, pose.reference_g))
    data = gap_data([(Session(records, "counts", 4096.0, None, "mma8451"), caps, "short")], rate_hz=20.0)
    d = diagnose(data, load_simulator())
    assert d.base.r_time is None and "allan" not in d.where
    assert "noise" in d.where and np.isfinite(d.gap_before)


# -- the floor ------------------------------------------------------------------------------------

def test_quantization_floor_matches_monte_carlo():
    """Variance of a mean of n quantized noisy samples over random positions: B + (s^2 + q^2/12 - B)/n."""
    assert bias_var(0.0, 1.0) == pytest.approx(1 / 12, rel=0.01)
    assert bias_var(2.0, 1.0) < 1e-12  # noise dithers
    rng = np.random.default_rng(7)
    for sigma, n in ((0.2, 50), (0.05, 20), (1.0, 10)):
        x = rng.uniform(0, 1, 20000)
        means = np.round(x[:, None] + sigma * rng.standard_normal((len(x), n))).mean(axis=1) - x
        # 20000 draws: the variance estimate's relative sd is about 1 %, so 4 % fails with p < 1e-4
        assert np.var(means) == pytest.approx(float(mean_var(sigma, 1.0, n)), rel=0.04), sigma
    assert within_spread(0.05, 1.0) > 100 * within_spread(0.5, 1.0)  # heavy quantization: w(x) swings
    assert value_step(np.array([[0, 64, 128], [-64, 0, 192]])) == 64 \
        and value_step(np.array([0.1, 0.25])) == pytest.approx(0.15)


def test_counts_given_as_g_are_refused(data_dir):
    from click.testing import CliRunner

    from accelcal_station.cli import cli

    log = data_dir / "imucal_annotated_session.csv"
    r = CliRunner().invoke(cli, ["diagnose", "--raw", "--columns", "-,-,x,y,z,-,-,-", "--rate", "204.8",
                                 "--units", "g", str(log)])
    assert r.exit_code == 2 and "median norm of 2066 g" in r.stderr and r.stderr.count("\n") == 1


def test_diagnosis_core_imports_nothing_from_cli_and_loads_like_fit():
    import ast

    import accelcal_station.diagnosis.loading as dl

    pkg = REPO / "accelcal_station"
    files = [*(pkg / "diagnosis").rglob("*.py"), *(pkg / "identifiability").rglob("*.py"),
             pkg / "config" / "sections.py"]
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert "cli" not in (node.module or "").split("."), (f.name, node.module)
    # one loader: diagnose reads files through the function `accelcal fit` uses
    from accelcal_station.cli import fit as cli_fit
    from accelcal_station.data.loader import load

    assert dl.load is load and cli_fit.load is load


# -- a fixed jig rotation: a deterministic 3-parameter rotation fitted on the references ---------------

@pytest.fixture(scope="module")
def sim_without_cross_axis(tmp_path_factory):
    """A simulator whose baseline is offset and gain only: its W cannot absorb a rotation."""
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["device"]["simulator"]["effects"].pop("cross_axis")
    path = tmp_path_factory.mktemp("nox") / "sim.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return load_simulator(path)


def test_a_fixed_jig_rotation_is_fitted_on_the_references(sim_without_cross_axis):
    truth_deg = np.array([0.3, -0.2, 0.1])
    rot = rotation_matrix(truth_deg)
    d = diagnose(_crafted(lambda r: rot @ r - r), sim_without_cross_axis)
    jig = d.stochastic["pose_error"]["jig_rotation"]
    assert jig["passed"] and jig["p_value"] < d.alpha, jig
    assert np.allclose(jig["rotation_deg"], truth_deg, atol=0.02), jig  # the rotation that made the data
    assert "jig rotation (deterministic, 3 parameters): FITTED" in "\n".join(summary_lines(d))


@pytest.mark.parametrize("extra", [lambda r: 0.02 * r**3, lambda r: 0.01 * r**2,
                                   lambda r: np.array([0.0, 0.0, 0.02 * r[0] * r[1]])],
                         ids=["cubic", "quadratic", "product"])
def test_a_jig_rotation_is_never_named_for_a_radial_residual(sim_without_cross_axis, extra):
    jig = diagnose(_crafted(extra), sim_without_cross_axis).stochastic["pose_error"]["jig_rotation"]
    assert jig["testable"] and not jig["passed"] and "radial" in jig["reason"], jig


def test_a_jig_rotation_on_a_null_board_and_under_a_full_cross_axis_matrix(sim_without_cross_axis):
    # fixed seed; a null board names a rotation with probability alpha = 0.01 (chi-square, 3 dof)
    jig = diagnose(_crafted(lambda r: np.zeros(3)), sim_without_cross_axis).stochastic["pose_error"]["jig_rotation"]
    assert not jig["passed"] and "chance" in jig["reason"]
    rot = rotation_matrix([0.3, -0.2, 0.1])
    jig = diagnose(_crafted(lambda r: rot @ r - r), load_simulator()).stochastic["pose_error"]["jig_rotation"]
    assert not jig["testable"] and "absorbs" in jig["reason"]


# -- the catalog: one class per effect, one interface ------------------------------------------------

def test_every_catalog_effect_is_one_class_on_the_shared_interface():
    from accelcal_station.diagnosis.effects.base import DeterministicEffect, StochasticEffect
    from accelcal_station.diagnosis.effects.catalog import DETERMINISTIC, STOCHASTIC
    from accelcal_station.diagnosis.effects.design import static_design
    from accelcal_station.sim.sensor_model import EFFECT_NAMES

    assert set(EFFECT_NAMES) <= set(DETERMINISTIC) | set(STOCHASTIC)
    for eff in DETERMINISTIC.values():
        assert isinstance(eff, DeterministicEffect) and eff.signature(None, None, None, None, 0.01) is None
        assert sys.modules[type(eff).__module__].__file__.endswith(f"{eff.name}.py")  # one file per effect
    for eff in STOCHASTIC.values():
        assert isinstance(eff, StochasticEffect) and not eff.static_columns
    # each static effect's columns come from its own class and carry its name (the diagonal of W is the gain)
    ref = np.array([p.reference_g for p in get_design("optimal-24")], float)
    dT = np.linspace(-10.0, 10.0, len(ref))
    for name, eff in DETERMINISTIC.items():
        _, _, _, labels = static_design({name}, ref, ref, dT, np.zeros((len(ref), 2)), False, 3)
        assert bool(labels) == eff.static_columns, name
        assert {e for e, _ in labels} <= {name, "gain"}, (name, labels)
    # untestable deterministic effects say why in words
    ok, why = DETERMINISTIC["settling"].testable(None, None)
    assert not ok and "raw logs" in why


def _tree(root: Path) -> dict:
    """Every file under root with its bytes (folders as None)."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def test_report_never_deletes_a_file_it_did_not_write(cubic_table, tmp_path):
    """A report folder already holding the user's files: a failed report removes only what it
    wrote, a good one adds its own files beside them; neither touches the user's."""
    out = tmp_path / "rep"
    (out / "sub").mkdir(parents=True)
    (out / "notes.txt").write_text("my notes\n")
    (out / "sub" / "data.csv").write_text("a,b\n1,2\n")
    (out / "summary.md.tmp").write_text("not the report's temporary file\n")
    (out / "level.png").mkdir()  # the second figure cannot be written: the run fails midway
    before = _tree(out)
    assert "level.png" in one_line_error(run("diagnose", cubic_table, "--report", out))
    assert _tree(out) == before  # sphere.png (which it wrote) is gone; nothing of the user's is
    (out / "level.png").rmdir()
    before = _tree(out)
    r = run("diagnose", cubic_table, "--report", out)
    assert r.exit_code == 0, r.output
    after = _tree(out)
    assert {k: v for k, v in after.items() if k in before} == before
    assert "summary.md" in after and "sphere.png" in after


@pytest.mark.parametrize("target", ["/", "/etc", "/usr/share", "/proc/self", "~", "/dev/shm"])
def test_report_refuses_root_and_system_folders(cubic_table, target):
    p = Path(target).expanduser()
    names = ("summary.md", "sphere.png", "level.png")
    before = {n: (p / n).exists() for n in names}
    assert "system folder" in one_line_error(run("diagnose", cubic_table, "--report", target))
    assert {n: (p / n).exists() for n in names} == before  # refused before anything was written


def test_report_refuses_a_link_to_root(cubic_table, tmp_path):
    (tmp_path / "link").symlink_to("/")
    err = one_line_error(run("diagnose", cubic_table, "--report", tmp_path / "link"))
    assert "system folder" in err or "not a directory" in err
