"""Confounding with acquisition order judged by competition, per term (diagnosis/order.py, confounding.py).

A 26-pose sphere design (tests/diagnose_sphere.py) run by the forward simulator with a cubic (or a
quadratic) on all three axes, largest on y: taken in order of z, only the z column follows row order, and
x and y carry most of the gap, so the effect is selected with the held-out RMS at least halved and only its
z term named as confounded.  With the cubic on z alone, a cubic in u_z is a cubic in row number: the cubic
is the leading candidate, confounded with acquisition order, never "explained".  Shuffled, revisited and
split across two files, the same boards get it right.  Fixed seeds (boards 1 and 2): deterministic.
"""
from __future__ import annotations

import pytest
from diagnose_sphere import config, sphere, tables

from accelcal_station.api import diagnose

ALL_AXES = {"cubic": {"cubic": {"cubic_per_g2": [0.01, 0.02, 0.01]}},
            "quadratic": {"quadratic": {"quadratic_per_g": [0.01, 0.02, 0.01]}}}
Z_ONLY = {"cubic": {"cubic_per_g2": [0.0, 0.0, 0.015]}}
TERM_Z = {"cubic": "Gamma_z", "quadratic": "Q_z"}


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    d = tmp_path_factory.mktemp("competition")
    cfgs = {e: config(d, eff, f"{e}.yaml") for e, eff in ALL_AXES.items()}
    cfgs["cubic_z"] = config(d, Z_ONLY, "cubic_z.yaml")

    def run(cfg: str, order: str, seed: int, files: int = 1) -> dict:
        paths = tables(cfgs[cfg], sphere(26, order, seed), seed, d / f"{cfg}-{order}-{seed}-{files}.csv", files)
        return diagnose(paths).to_json()
    return run


@pytest.mark.parametrize("effect", ["cubic", "quadratic"])
@pytest.mark.parametrize("seed", [1, 2])
def test_an_effect_on_all_axes_in_z_order_is_selected_with_only_its_z_term_confounded(boards, effect, seed):
    js = boards(effect, "z", seed)
    step = js["steps"][0]
    assert step["added"] == effect and effect in js["selected"]
    assert step["rms_mg_after"] <= 0.5 * step["rms_mg_before"]  # the held-out RMS at least halved
    assert set(js["confounded"]) == {effect}
    c = js["confounded"][effect]
    assert not c["alone"] and [t["term"] for t in c["terms"]] == [TERM_Z[effect]] and c["r2"] > 0.8
    assert f"the z part of {effect}" in js["verdict_text"] and "shuffle or revisit" in js["verdict_text"]
    assert step["p_value_vs_order"] < 0.01  # it beat the order trend in the held-out test
    assert js["verdict"] != "unexplained"


@pytest.mark.parametrize("seed", [1, 2])
def test_a_cubic_on_z_alone_in_z_order_is_the_leading_candidate_confounded_with_order(boards, seed):
    js = boards("cubic_z", "z", seed)
    assert js["ranking"][0]["effect"] == "cubic"
    assert "cubic" not in js["selected"] and js["steps"] == []
    c = js["confounded"]["cubic"]
    assert c["alone"] and c["term"] == "Gamma_z" and c["r2"] > 0.8
    assert js["verdict"] not in ("explained", "partly explained")
    assert "the leading candidate is cubic" in js["verdict_text"]
    assert "cubic is confounded with acquisition order" in js["verdict_text"]
    assert "add to the simulator configuration" not in js["verdict_text"]


@pytest.mark.parametrize("order", ["shuffled", "revisited"])
@pytest.mark.parametrize("cfg", ["cubic", "cubic_z"])
def test_shuffled_or_revisited_the_same_boards_select_the_cubic_unconfounded(boards, order, cfg):
    js = boards(cfg, order, 1)
    assert js["steps"][0]["added"] == "cubic" and "cubic" in js["selected"]
    assert js["confounded"] == {}
    assert js["steps"][0]["rms_mg_after"] <= 0.5 * js["steps"][0]["rms_mg_before"]


def test_split_across_two_files_the_order_basis_restarts_per_file(boards):
    js = boards("cubic", "z", 1, files=2)
    assert "cubic" in js["selected"] and [t["term"] for t in js["confounded"]["cubic"]["terms"]] == ["Gamma_z"]
    assert "restarts in every file" in js["order_trend"]["basis"]
    js = boards("cubic_z", "z", 1, files=2)
    assert "cubic" not in js["selected"] and js["confounded"]["cubic"]["alone"]
