"""Identifiability from the data: distinct orientations, refusals in words, barely determined fits."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.identifiability import assess, assess_batch

FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
DATA_SET_1 = "calibraxis_set_1.csv"


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _board(ref, seed=0, tilt_deg=1.0, noise_g=2e-4):
    """Readings of a board with gain, offset and cross-axis, placed by hand (a small random tilt per pose)."""
    rng = np.random.default_rng(seed)
    W = np.array([[1.02, 0.01, -0.005], [0.004, 0.98, 0.008], [-0.006, 0.003, 1.01]])
    true = []
    for r in ref:
        a = np.deg2rad(tilt_deg) * rng.standard_normal(3)
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        true.append((np.eye(3) + K) @ r)
    return np.array(true) @ W.T + [0.03, -0.02, 0.01] + noise_g * rng.standard_normal((len(ref), 3))


def _table(path, g, ref=None):
    head = "pose,pitch_deg,roll_deg,x,y,z" + (",ref_x,ref_y,ref_z" if ref is not None else "")
    rows = [f"p{i},,,{x!r},{y!r},{z!r}" + ("" if ref is None else ",{},{},{}".format(*ref[i]))
            for i, (x, y, z) in enumerate(g.tolist())]
    path.write_text("# units: g\n" + head + "\n" + "\n".join(rows) + "\n")
    return path


def test_model_9_on_six_faces_revisited_says_why(tmp_path):
    ref = np.concatenate([FACES, FACES])  # every face visited twice: 12 poses, 6 orientations
    table = _table(tmp_path / "revisited.csv", _board(ref))
    r = _run("fit", table, "--model", "9", "-o", tmp_path / "cal.json")
    assert r.exit_code != 0 and r.stderr.count("\n") == 1
    assert ("6 distinct orientations among 12 poses (revisits add no information); "
            "the 9-parameter norm model needs at least 9 well spread") in r.stderr
    assert "converge" not in r.stderr and not (tmp_path / "cal.json").exists()


def test_model_15_on_faces_cubic_cannot_be_told_from_gain(tmp_path):
    table = _table(tmp_path / "faces.csv", _board(FACES), FACES)
    r = _run("fit", table, "--model", "15")
    # the poses determine model 12: its terms are fitted, the cubic held at 0 and said so (models/held.py)
    assert r.exit_code == 0, r.output
    assert "held: x cubic held at 0: a cubic cannot be told from the gain when every reading is about +-1 g" \
        in r.stdout
    assert _run("fit", table, "--model", "12").exit_code == 0


@pytest.mark.parametrize("model", ["6", "12"])
def test_poses_along_one_axis_are_refused(tmp_path, model):
    ref = np.array([[1, 0, 0], [-1, 0, 0]] * 3, float)
    table = _table(tmp_path / "x_only.csv", _board(ref, tilt_deg=0.5), ref)
    r = _run("fit", table, "--model", model, "-o", tmp_path / "cal.json")
    assert r.exit_code != 0 and r.stderr.count("\n") == 1, r.output
    want = {"6": "along one axis (x up or down): the y, z gains are not determined",
            "12": "2 distinct orientations among 6 poses (revisits add no information); model 12 needs at least 4"}
    assert want[model] in r.stderr
    assert not (tmp_path / "cal.json").exists()  # never a degenerate calibration (W diagonal [1, 0, 0])


def test_model_6_names_the_undetermined_gains():
    ref = np.array([[1, 0, 0], [-1, 0, 0]] * 3, float)
    g = _board(ref, tilt_deg=6.0)  # tilted enough that y and z wobble, not enough to determine their gains
    a = assess(g, "6")
    assert not a.determined and "the y, z gains are not determined" in a.reason


def test_barely_determined_fit_is_flagged_in_the_summary(data_dir):
    """Real data (calibraxis set 1): 10 poses for the 9-parameter model, 1 degree of freedom."""
    r = _run("fit", data_dir / DATA_SET_1, "--model", "9")
    assert r.exit_code == 0, r.output
    line = next(s for s in r.stdout.splitlines() if "barely determined" in s)
    assert "10 distinct orientations for 9 coefficients (1 degree of freedom)" in line
    name, se = line.split("least certain: ")[1].split(" +- ")
    assert name.startswith("W_") and name[2] != name[3] and se.split()[1] == "deg"  # a cross term, in degrees
    js = _run("fit", data_dir / DATA_SET_1, "--model", "9", "--json")
    import json
    stderr_W = np.array(json.loads(js.stdout)["stderr"]["W"])
    i, j = "xyz".index(name[2]), "xyz".index(name[3])
    assert float(se.split()[0]) == pytest.approx(np.degrees(np.arcsin(stderr_W[i, j])), rel=5e-3)  # 3 digits printed


def test_well_determined_fit_is_not_flagged(tmp_path):
    from accelcal_station.fixtures.designs import get_design, references

    ref = references(get_design("optimal-14"))
    r = _run("fit", _table(tmp_path / "t.csv", _board(ref), ref), "--model", "12")
    assert r.exit_code == 0 and "barely" not in r.stdout


def test_batch_assessment_matches_one_board_at_a_time():
    boards = np.stack([_board(FACES, s) for s in range(3)] + [_board(np.array([[1, 0, 0], [-1, 0, 0]] * 3, float))])
    for model in ("6", "12", "15"):
        ok, distinct = assess_batch(boards, model)
        assert ok.tolist() == [assess(b, model).determined for b in boards]
        assert distinct.tolist() == [6, 6, 6, 2]
    assert assess_batch(boards, "12")[0].tolist() == [True, True, True, False]


def test_least_certain_parameter_tie_is_not_broken_by_float_noise():
    """A symmetric design gives the three gains the same standard error up to the machine's
    last digits: the named one must not depend on them (issue 41)."""
    from accelcal_station.identifiability import worst_parameter

    for noise in ([0.0, 2e-16, -2e-16], [3e-16, 0.0, 1e-16], [-1e-16, 4e-16, 0.0]):
        W = np.diag(2e-3 * (1 + np.array(noise))) + 1e-4
        got = worst_parameter({"W": W, "V": np.full(3, 1e-4), "Gamma": np.zeros(3)}, "12")
        assert got == ("W_xx", "0.21 %")
    # a real difference still wins: W_zz larger by 5e-4 relative is named
    W = np.diag([2e-3, 2e-3, 2.001e-3]) + 1e-4
    assert worst_parameter({"W": W, "V": np.full(3, 1e-4), "Gamma": np.zeros(3)}, "12")[0] == "W_zz"


def _off_design(design: str, rng: np.random.Generator, D: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """The references (P, 3) of ``design`` and D boards' readings (D, P, 3) in g, off it by small
    and large gains and offsets (up to 1 g: a centre far from 0)."""
    from accelcal_station.fixtures.designs import get_design, references

    ref = np.asarray(references(get_design(design)))
    W = np.eye(3) + rng.choice([0.01, 0.2, 0.6], (D, 1, 1)) * rng.standard_normal((D, 3, 3))
    V = rng.choice([0.02, 0.3, 1.0], (D, 1)) * rng.standard_normal((D, 3))
    return ref, np.einsum("dij,dpj->dpi", np.linalg.inv(W), ref - V[:, None, :]) + 1e-3 * rng.standard_normal(
        (D, len(ref), 3))


@pytest.mark.parametrize("design", ["an4399-8", "six-face", "nine-position", "optimal-12"])
def test_screen_certificates_give_the_pairwise_answers(design):
    """models.screening.screen certifies boards from their references without comparing poses; where it
    does, first_of_orientation, assess_batch and sanity.distinct_directions_batch must give exactly
    what comparing every pair and forming every design gives: boards off their design by small and
    large gains, offsets far from 0 (a centre), revisits and flattened axes included."""
    from accelcal_station.identifiability import assess_batch, first_of_orientation
    from accelcal_station.models.sanity import distinct_directions_batch
    from accelcal_station.models.screening import directions_apart, screen

    rng = np.random.default_rng(7)
    ref, x = _off_design(design, rng)
    D, P = x.shape[:2]
    rv = rng.integers(0, D, 150)
    x[rv, 1] = x[rv, 0] * (1 + 0.01 * rng.standard_normal((150, 1)))  # a revisit
    fl = rng.integers(0, D, 150)
    x[fl, :, 2] *= rng.choice([0.0, 0.01, 0.1], (150, 1))  # a flattened axis
    for model in ("6", "12", "15"):
        s = screen(x, ref, model)
        assert 0.05 < s.apart.mean() < 0.95  # both paths are exercised
        assert s.determined.any() or model == "15"  # six faces cannot determine a cubic: never certified
        first = first_of_orientation(x)
        assert np.array_equal(first_of_orientation(x, apart=s.apart), first)
        want = assess_batch(x, model, first)
        got = assess_batch(x, model, first, s.determined)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert np.array_equal(distinct_directions_batch(x, apart=directions_apart(x, ref)), distinct_directions_batch(x))


@pytest.mark.parametrize("design", ["nine-position", "an4399-8", "optimal-12"])
def test_model_9_screen_certifies_from_the_boards_own_consensus(design):
    """Model 9 has no references: screen certifies boards against the stack's consensus directions
    (any directions serve: the certificates are the triangle inequality and Weyl's).  Where it does,
    first_of_orientation and assess_batch must give exactly the pairwise answers: boards of another
    design in the stack, raw offsets far from 0 (unsigned counts), revisits, flattened axes, a zero
    reading and odd boards among the first ones (the consensus's sample) included."""
    from accelcal_station.identifiability import assess_batch, first_of_orientation
    from accelcal_station.models.screening import screen

    rng = np.random.default_rng(9)
    ref, x = _off_design(design, rng)
    D, P = x.shape[:2]
    other = rng.integers(0, D, 200)
    x[other] = x[other][:, rng.permutation(P)]  # the same poses in another order: another design
    x[rng.integers(0, D, 100)] += 3.0  # unsigned counts: far from 0
    rv = np.concatenate([np.arange(20), rng.integers(0, D, 150)])  # odd boards among the consensus sample too
    x[rv, 1] = x[rv, 0] * (1 + 0.01 * rng.standard_normal((len(rv), 1)))  # a revisit
    fl = rng.integers(0, D, 150)
    x[fl, :, 2] *= rng.choice([0.0, 0.01, 0.1], (150, 1))  # a flattened axis
    x[rng.integers(0, D, 5), 3] = 0.0  # a zero reading: no direction
    s = screen(x, None, "9")
    assert 0.05 < s.apart.mean() < 0.95  # both paths are exercised
    assert s.determined.any() or P < 9  # fewer poses than model 9's coefficients: never certified
    first = first_of_orientation(x)
    assert np.array_equal(first_of_orientation(x, apart=s.apart), first)
    want = assess_batch(x, "9", first)
    got = assess_batch(x, "9", first, s.determined)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert not np.any(s.determined & ~want[0])  # certified only where pose by pose it is determined
