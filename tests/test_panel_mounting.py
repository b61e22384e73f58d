"""device.mount on a panel: device.mount for every board, device.boards[i].mount over it.

The boards are turned by the simulation's physics, never by the station's mount conversion: a chip
soldered turned on its board (the simulated board's ``true_mount``) or a board seated turned in its
slot (``seated_deg``, a rotation vector the simulated panel jig turns the board by).  Each hint is
followed as printed, and each fit is compared with the simulated sensor's own calibration.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.drivers.simulated import SimulatedBoard

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# the chip's +y along the board's +x, its -x along the board's +y: the chip turned 90 deg about z
TURNED = ["y", "-x", "z"]
HINT = re.compile(r"set (device(?:\.boards\[(\d+)\])?\.mount): \[([^\]]*)\]")


def _panel(tmp_path: Path, boards: int | list[dict] | None, config: str = "panel-sim.yaml",
           **device: object) -> dict:
    cfg = yaml.safe_load((CONFIGS / config).read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    del cfg["device"]["spread"]  # every board the same sensor: one truth for every fit
    if boards is not None:
        cfg["device"]["boards"] = boards
    cfg["device"].update(device)
    return cfg


def _run(cfg: dict, tmp_path: Path) -> tuple[str, list[dict], int]:
    p = tmp_path / "panel.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert "Traceback" not in r.output, r.output
    return r.output, json.loads(r.stdout)["boards"], r.exit_code


def _follow(cfg: dict, text: str) -> list[str]:
    """Set every mounting the run names, as printed (an engineer copying the line): the keys set."""
    keys = set()
    for key, index, axes in HINT.findall(text):
        where = cfg["device"] if not index else cfg["device"]["boards"][int(index)]
        where["mount"] = [a.strip() for a in axes.split(",")]
        keys.add(key)
    return sorted(keys)


def _truth(cfg: dict) -> Calibration:
    """The simulated sensor's exact calibration in its chip axes: how the chip sits does not change it."""
    dev = cfg["device"]
    return SimulatedBoard.from_config({"chip": dev["chip"], "range_g": dev["range_g"],
                                       "simulator": dev["simulator"]}).truth()


def _fits_the_truth(boards: list[dict], truth: Calibration) -> None:
    for b in boards:
        np.testing.assert_allclose(b["W"], truth.W, atol=5e-4)
        np.testing.assert_allclose(b["V"], truth.V, atol=3e-4)  # 0.3 mg


def test_a_turned_board_is_named_with_its_key_and_the_panel_passes_with_it(tmp_path):
    # board 1: its chip soldered turned; board 2: the board seated turned 90 deg about z in its slot
    cfg = _panel(tmp_path, [{}, {"true_mount": TURNED}, {"seated_deg": [0.0, 0.0, 90.0]}, {}])
    text, boards, code = _run(cfg, tmp_path)
    assert code == 1 and [b["verdict"] for b in boards] == ["PASS", "FAIL", "FAIL", "PASS"], text
    for i in (1, 2):
        (reason,) = boards[i]["reasons"]
        assert reason.startswith("pose p1: board is") and "the board looks turned 90 deg about z" in reason
        assert reason.endswith(f"set device.boards[{i}].mount: [y, -x, z]"), reason
        assert boards[i]["nvm"] is None
    assert _follow(cfg, text) == ["device.boards[1].mount", "device.boards[2].mount"]
    text, boards, code = _run(cfg, tmp_path)
    assert code == 0 and {b["verdict"] for b in boards} == {"PASS"}, text
    _fits_the_truth(boards, _truth(cfg))


def test_every_board_turned_alike_is_named_as_the_panels_device_mount(tmp_path):
    cfg = _panel(tmp_path, 4, true_mount=TURNED)
    text, boards, _ = _run(cfg, tmp_path)
    assert [b["verdict"] for b in boards] == ["FAIL"] * 4
    assert all(b["reasons"][0].endswith("set device.mount: [y, -x, z]") for b in boards), text
    # p1 alone could be the panel misplaced; at p2 the readings say every board is turned
    assert text.count("every board reads a wrong pose at") == 1 and "at p1: the panel is not" in text
    assert _follow(cfg, text) == ["device.mount"]
    text, boards, code = _run(cfg, tmp_path)
    assert code == 0 and {b["verdict"] for b in boards} == {"PASS"}, text
    _fits_the_truth(boards, _truth(cfg))


def test_a_boards_own_mount_overrides_the_panels(tmp_path):
    # every chip turned as device.mount says, but board 2's soldered the other way round; three boards:
    # no jig-pose estimate (jig_pose.MIN_BOARDS), each fit takes its records' own references
    cfg = _panel(tmp_path, [{}, {}, {"true_mount": ["-y", "x", "z"]}], true_mount=TURNED, mount=TURNED)
    text, boards, _ = _run(cfg, tmp_path)
    assert [b["verdict"] for b in boards] == ["PASS", "PASS", "FAIL"], text
    assert boards[2]["reasons"][0].endswith("set device.boards[2].mount: [-y, x, z]")
    assert _follow(cfg, text) == ["device.boards[2].mount"]
    text, boards, code = _run(cfg, tmp_path)
    assert code == 0 and {b["verdict"] for b in boards} == {"PASS"}, text
    _fits_the_truth(boards, _truth(cfg))


@pytest.mark.parametrize("mount, why", [(["y", "x", "z"], "not a proper rotation"),
                                        (["y", "-x"], "needs three chip axes"),
                                        (["y", "-x", "w"], "allowed x, y, z")])
def test_a_bad_mount_on_a_panel_board_is_one_line_naming_its_key(tmp_path, mount, why):
    p = tmp_path / "panel.yaml"
    p.write_text(yaml.safe_dump(_panel(tmp_path, [{}, {"mount": mount}])))
    r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and len(lines) == 1, r.output
    assert lines[0].startswith("error: device.boards[1].mount:") and why in lines[0]


def test_a_thermal_panel_names_a_turned_board_and_passes_with_its_mount(tmp_path):
    cfg = _panel(tmp_path, [{}, {"true_mount": TURNED}, {}], config="thermal-panel-sim.yaml")
    text, boards, _ = _run(cfg, tmp_path)
    assert [b["verdict"] for b in boards] == ["PASS", "FAIL", "PASS"], text
    assert boards[1]["reasons"][0].endswith("set device.boards[1].mount: [y, -x, z]")
    assert _follow(cfg, text) == ["device.boards[1].mount"]
    text, boards, code = _run(cfg, tmp_path)
    assert code == 0 and {b["verdict"] for b in boards} == {"PASS"}, text


def test_an_emulated_mma8451_behind_the_mux_turned_about_its_diagonal_is_singled_out(tmp_path):
    """The register emulator read through the real driver over the TCA9548A: its chip turned about the
    board's x+y+z diagonal, which the first cube-vertex pose cannot tell from two other turns; the
    board is read on until one turn is left, named, and then fitted to the emulated sensor's truth."""
    cfg = _panel(tmp_path, None, config="panel-mma8451-emulated.yaml")
    diagonal = ["z", "x", "y"]  # the chip's z along the board's x, its x along y, its y along z
    cfg["device"]["boards"][3]["simulator"] = {**cfg["device"]["simulator"], "true_mount": diagonal}
    text, boards, _ = _run(cfg, tmp_path)
    assert [b["verdict"] for b in boards] == ["PASS"] * 3 + ["FAIL"] + ["PASS"] * 4, text
    (reason,) = boards[3]["reasons"]
    assert reason.startswith("pose p1:") and "(the smallest turn that fits)" not in reason
    assert reason.endswith("set device.boards[3].mount: [z, x, y]"), reason
    assert _follow(cfg, text) == ["device.boards[3].mount"]
    text, boards, code = _run(cfg, tmp_path)
    assert code == 0 and {b["verdict"] for b in boards} == {"PASS"}, text
    dev = cfg["device"]
    truth = SimulatedBoard.from_config({"chip": "mma8451", "range_g": dev["range_g"],
                                        "simulator": dev["simulator"]}).truth()
    _fits_the_truth(boards[3:4], truth)
