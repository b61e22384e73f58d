"""One set of numbers (diagnosis/headline.py): diagnose's headline held-out RMS is `accelcal fit`'s
held-out figure on the same file, and the text carries the --json figures.

The log: a simulated MPU6050 (chip mpu6050 at +-2 g, 16384 counts/g, DLPF 3, 100 Hz; the data sheet's
400 ug/sqrt(Hz) noise density) on the geometry of a real ten-pose log, six faces and four tilts held
~4 s (~400 samples) each, written as a raw t,x,y,z log by the project's forward simulator and jig.
Without references `accelcal fit` chooses model 9; its leave-one-pose-out RMS is read from
`accelcal fit --raw --json`.  Boards 1 and 2: fixed seeds, deterministic.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board

REPO = Path(__file__).resolve().parents[1]
# six faces (z, x, y up and down) and four tilts, as the real log's operator placed them
POSES = [PoseSpec("zup", 0, 0), PoseSpec("zdown", 0, 180), PoseSpec("xup", -90, 0), PoseSpec("xdown", 90, 0),
         PoseSpec("yup", 0, 90), PoseSpec("ydown", 0, -90), PoseSpec("t1", 30, 45), PoseSpec("t2", -30, 135),
         PoseSpec("t3", 45, -45), PoseSpec("t4", -45, -135)]


def _mpu_config(d: Path) -> Path:
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    dev = cfg["device"]
    dev.update({"chip": "mpu6050", "range_g": 2, "odr_hz": 100, "dlpf": 3})
    dev["simulator"]["effects"]["noise"] = {"density_ug_per_rthz": [400.0] * 3}  # MPU-6000/6050 data sheet
    (d / "mpu.yaml").write_text(yaml.safe_dump(cfg))
    return d / "mpu.yaml"


@pytest.fixture(scope="module", params=[1, 2])
def mpu_log(request, tmp_path_factory):
    d = tmp_path_factory.mktemp("mpu")
    cfg = _mpu_config(d)
    run = run_poses(simulated_board(str(cfg), request.param), POSES, "mpu10", samples=400, raw=True, move_s=2.0)
    (t, c), _ = run.raw_table()
    log = d / "mpu.csv"
    log.write_text("t,x,y,z\n" + "\n".join(f"{a:.5f},{int(x)},{int(y)},{int(z)}"
                                            for a, (x, y, z) in zip(t, c, strict=True)) + "\n")
    return cfg, log


def _cli(*args: object) -> str:
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r.output


def test_the_headline_held_out_rms_is_fits_on_the_same_file(mpu_log):
    cfg, log = mpu_log
    fit = json.loads(_cli("fit", "--raw", log, "--json"))
    js = json.loads(_cli("diagnose", "--raw", "--config", cfg, log, "--json"))
    h = js["headline"]
    assert fit["model"] == "9" and h["fit_model"] == "9"
    assert h["held_out_rms_mg"] == pytest.approx(1e3 * fit["crossval_rms_g"], rel=1e-9)
    assert h["gap"] == pytest.approx(h["held_out_rms_mg"] / h["floor_mg"], rel=1e-9)
    # ten poses: the selection holds out one pose at a time too, and model 9 has one spare pose, so its
    # fit interpolates the other nine whatever their weights: the same figure
    assert h["selection_rms_mg"] == pytest.approx(h["held_out_rms_mg"], rel=0.01)


def test_the_text_carries_the_json_figures(mpu_log):
    cfg, log = mpu_log
    js = json.loads(_cli("diagnose", "--raw", "--config", cfg, log, "--json"))
    text = _cli("diagnose", "--raw", "--config", cfg, log)
    h = js["headline"]
    gap_line = re.search(r"GAP  held-out residual ([0-9.]+) mg RMS \(([^)]*)\): ([0-9.]+) x the floor", text)
    assert gap_line is not None, text
    assert gap_line.group(1) == f"{h['held_out_rms_mg']:.4g}" and gap_line.group(3) == f"{h['gap']:.3g}"
    views = re.search(r"static view ([0-9.]+); time view ([0-9.]+)", text)
    assert views is not None
    assert views.group(1) == f"{js['where']['views']['static']:.3g}"
    assert views.group(2) == f"{js['where']['views']['time']:.3g}"
    odd = [p["pose"] for p in js["where"]["by_pose"] if p["stands_out"]]
    line = next(ln for ln in text.splitlines() if "poses that stand out" in ln)
    assert line.endswith("none") if not odd else all(p in line for p in odd[:4])
    # a board the simulator describes: no pose stands out, no effect is suggested, steps are only those taken
    assert odd == [] and js["steps"] == [] and "add to the simulator configuration" not in text
    assert f"VERDICT: {js['verdict']}: {js['verdict_text']}" in text
