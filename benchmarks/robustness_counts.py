"""Issue 12 closing figures: bad inputs tried / refused cleanly, faults injected / survived.

    python benchmarks/robustness_counts.py

A bad input is clean when the command exits non-zero but not 70 (internal error), prints no
traceback and exactly one error line (under --json: one JSON object on stdout and nothing
else there), and wrote nothing it should not have.  Faults: power loss at every page write
and byte count of `nvm restore` (tests/test_restore_power_loss.py's sweep), and symlinks
planted at <image>.tmp before burns.  Fixed seeds: the counts are the same on every run.
"""
from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from accelcal_station.cli import cli  # noqa: E402
from accelcal_station.station import default_config_path  # noqa: E402

BAD_VALUES = [-1, "x", [], {}, True, math.nan, -math.inf]
BASE = yaml.safe_load(default_config_path().read_text())


def clean(r, json_mode: bool) -> bool:
    good = _clean(r, json_mode)
    if not good and os.environ.get("VERBOSE"):
        print(f"NOT CLEAN (exit {r.exit_code}): {r.output[-300:]!r}", file=sys.stderr)
    return good


def _clean(r, json_mode: bool) -> bool:
    if r.exit_code in (0, 70) or "Traceback" in r.output:
        return False
    if json_mode:
        try:
            obj = json.loads(r.stdout)
        except ValueError:
            return False
        return isinstance(obj, dict) and "error" in obj and obj.get("code") == r.exit_code
    return sum(ln.startswith("error") for ln in r.stderr.splitlines()) == 1


def config_cases(tmp: Path):
    """Every numeric key of capture/acceptance/verify/nvm/jig with each bad value, plus hostile YAML."""
    n = 0
    for section in ("capture", "acceptance", "verify", "nvm"):
        keys = list((BASE.get(section) or {}).keys()) or ["poses"]
        for key in keys:
            for bad in BAD_VALUES + ([0] if section == "capture" and key in ("max_s", "hold_s") else []):
                if (key == "hold_s" and bad == 0) or (isinstance(bad, bool) and key in ("write", "offset_trim")):
                    continue  # allowed values, not bad inputs
                cfg = yaml.safe_load(yaml.safe_dump(BASE))
                cfg.setdefault(section, {})[key] = bad
                cfg["store"] = {"path": str(tmp / "runs.sqlite")}
                p = tmp / f"c{n}.yaml"
                p.write_text(yaml.safe_dump(cfg) if not (isinstance(bad, float) and math.isnan(bad))
                             else yaml.safe_dump(cfg).replace("nan", ".nan"))
                n += 1
                yield p
    for name, text in (("bomb", "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
            f"{chr(98 + i)}: &{chr(98 + i)} [{','.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8))),
                       ("deep", "a: " + "[" * 3000 + "]" * 3000), ("dup", "plan: {}\nplan: {}\n"),
                       ("binary", "\x00\x01\x02"), ("list", "- 1\n- 2\n")):
        p = tmp / f"{name}.yaml"
        p.write_text(text)
        yield p


def fit_tables(tmp: Path, rng):
    """Degenerate or absurd pose tables: poses along one or two axes, a 1e308 reading,
    identical references."""
    faces = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0.0]])
    for i in range(60):
        kind = i % 3
        if kind == 0:
            axes = rng.choice(3, size=rng.integers(1, 3), replace=False)
            refs = np.array([f for f in faces if np.argmax(np.abs(f)) in axes] * 3)
        else:
            refs = np.tile(faces, (2, 1))
        x = refs * rng.uniform(0.97, 1.03, 3) + rng.normal(0, 0.02, 3) + rng.normal(0, 1e-4, refs.shape)
        if kind == 1:
            x[rng.integers(len(x)), rng.integers(3)] = 1e308
        if kind == 2:
            refs = np.tile(refs[0], (len(refs), 1))
        lines = ["# units: g", "pose,ref_x,ref_y,ref_z,x,y,z"] + [
            f"p{j},{r[0]},{r[1]},{r[2]},{float(v[0])!r},{float(v[1])!r},{float(v[2])!r}"
            for j, (r, v) in enumerate(zip(refs, x))]
        p = tmp / f"t{i}.csv"
        p.write_text("\n".join(lines) + "\n")
        yield p, str(rng.choice(["6", "12", "15"]))


def main() -> None:
    rng = np.random.default_rng(12)
    runner = CliRunner()
    tried = ok = 0
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for p in config_cases(tmp):
            for json_mode in (False, True):
                r = runner.invoke(cli, ["run", "--config", str(p)] + (["--json"] if json_mode else []))
                tried, ok = tried + 1, ok + clean(r, json_mode)
        for p, model in fit_tables(tmp, rng):
            out = tmp / "cal.json"
            r = runner.invoke(cli, ["fit", str(p), "--model", model, "-o", str(out)])
            tried, ok = tried + 1, ok + (clean(r, False) and not out.exists())
        for args in (["report", "list", "--db", str(tmp / "none.sqlite")], ["nvm", "read", "--config", "/nonexist"],
                     ["fit", "/nonexist.csv"], ["poses", "nope"], ["run", "--port"], ["report", "show", "x"]):
            for json_mode in (False, True):
                r = runner.invoke(cli, args + (["--json"] if json_mode else []))
                tried, ok = tried + 1, ok + clean(r, json_mode)
    print(f"bad inputs: {tried} tried, {ok} refused cleanly")

    from test_restore_power_loss import SCENARIOS, sweep  # the test's own sweep
    faults = survived = 0
    with tempfile.TemporaryDirectory() as d:
        for b, i in SCENARIOS + [(3, 2), (2, 3), (4, 5), (5, 4)]:
            f, s = sweep(b, i, Path(d))
            faults, survived = faults + f, survived + s
    print(f"faults: {faults} power losses injected into nvm restore, {survived} left the board's previous "
          "or the image's newest calibration bit for bit")


if __name__ == "__main__":
    main()
