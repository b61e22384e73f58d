"""Issue 12 and 25 closing figures: bad inputs tried / refused cleanly, faults injected / survived,
and issue 25's campaign of hostile files through the real command line, counted by class; issue
34's store figures (store_counts): writers pointed at a store, damaged stores read by every reader
and by the web server, formula cells in exports, the schema-2 store served, a crashed run read.

    python benchmarks/robustness_counts.py [--cases N] [--campaign-only] [--store-only]

The campaign (benchmarks/hostile_campaign.py: generated pose tables, raw logs, CSV and Parquet lots,
YAML configs, NVM backups, special files, edge numbers, outputs named after inputs; each run in a
subprocess with 2 GiB of address space) prints its classes: clean, internal error, hang (60 s wall or
10 s CPU), input overwritten, messy (no single error line).  The target is 0 of every class but clean.

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
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "benchmarks"))

from accelcal_station.cli import cli  # noqa: E402
from accelcal_station.station.settings import default_config_path  # noqa: E402

NUMPY_REPR = re.compile(r"\bnp\.\w+\(|\barray\(")
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
    if NUMPY_REPR.search(r.output):  # a message quoting np.float64(...) is not a clear line
        return False
    if r.exit_code == 1 and not json_mode and r.stdout.startswith("SKIP ") and not r.stderr:
        return True  # batch: the board is skipped with its reason (batch.py), exit 1
    if json_mode and r.exit_code == 1:
        try:
            doc = json.loads(r.stdout)
        except ValueError:
            return False
        if isinstance(doc, dict) and doc.get("fitted") == 0 and doc.get("skipped"):
            return True
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
            for j, (r, v) in enumerate(zip(refs, x, strict=True))]
        p = tmp / f"t{i}.csv"
        p.write_text("\n".join(lines) + "\n")
        yield p, str(rng.choice(["6", "12", "15"]))


GOOD_ROWS = ["p1,0,0,1,0.01,0.02,1.01", "p2,0,0,-1,0.0,0.01,-0.99", "p3,1,0,0,1.02,0.0,0.01",
             "p4,-1,0,0,-0.98,0.01,0.0", "p5,0,1,0,0.0,1.01,0.02", "p6,0,-1,0,0.01,-0.99,0.0"]


def bad_files(tmp: Path) -> list[Path]:
    """Hostile data files: missing, a folder, empty, binary, a FIFO, a link to a device, bad
    header, bad cells (text, nan, inf, 1e308, '' ), too few rows, a CSV injection."""
    head = "# units: g\npose,ref_x,ref_y,ref_z,x,y,z\n"
    texts = {"empty": "", "binary": "\x00\xff\xfe\x01" * 64, "header_only": head,
             "wrong_header": "a,b,c\n1,2,3\n", "one_row": head + GOOD_ROWS[0] + "\n",
             "two_rows": head + "\n".join(GOOD_ROWS[:2]) + "\n",
             "units_bad": head.replace("g", "furlongs", 1) + "\n".join(GOOD_ROWS) + "\n",
             "short_row": head + "\n".join(GOOD_ROWS[:5]) + "\np6,0,-1\n",
             "long_row": head + "\n".join(GOOD_ROWS) + ",9,9\n",
             "dup_header": head + head + "\n".join(GOOD_ROWS) + "\n",
             "latin1": (head + "\n".join(GOOD_ROWS) + "\n").replace("p1", "p\xe9"),
             "huge_line": head + "p1," + "9" * 200000 + ",0,1,0,0,1\n"}
    for cell in ("x", "nan", "inf", "-inf", "1e308", "", "=cmd|' /C calc'!A0", "0x10", "1,5"):
        texts[f"cell_{len(texts)}"] = head + "\n".join(GOOD_ROWS[:-1]) + f"\np6,0,-1,0,{cell},-0.99,0.0\n"
    out = []
    for name, text in texts.items():
        p = tmp / f"bad_{name}.csv"
        p.write_bytes(text.encode("latin-1") if name == "latin1" else text.encode("utf-8", "surrogateescape"))
        out.append(p)
    (tmp / "bad_dir.csv").mkdir(exist_ok=True)
    fifo = tmp / "bad_fifo.csv"
    if not fifo.exists():
        os.mkfifo(fifo)
    (tmp / "bad_dev.csv").unlink(missing_ok=True)
    (tmp / "bad_dev.csv").symlink_to("/dev/zero")
    return out + [tmp / "bad_missing.csv", tmp / "bad_dir.csv", fifo, tmp / "bad_dev.csv"]


def bad_stores(tmp: Path) -> list[str]:
    """Results stores that are not: missing, a folder, text, an empty file, a foreign SQLite
    file, a damaged header, unusable URLs."""
    import sqlite3

    (tmp / "text.sqlite").write_text("hello\n")
    (tmp / "zero.sqlite").write_bytes(b"")
    (tmp / "header.sqlite").write_bytes(b"SQLite format 3\x00" + b"\xff" * 4000)
    (tmp / "dir.sqlite").mkdir(exist_ok=True)
    with sqlite3.connect(tmp / "foreign.sqlite") as c:
        c.execute("CREATE TABLE IF NOT EXISTS t (x)")
    return [str(tmp / n) for n in ("none.sqlite", "text.sqlite", "zero.sqlite", "header.sqlite", "dir.sqlite",
                                   "foreign.sqlite")] + ["postgresql://nobody@127.0.0.1:1/x", "mysql://x/y",
                                                         "sqlite:///" + str(tmp / "nodir" / "x" / "y.sqlite")]


def cli_cases(tmp: Path):
    """Generated bad command lines for every command but `run` (its configs are config_cases):
    each yields the arguments and a path that must not exist afterwards (or None)."""
    files, stores = bad_files(tmp), bad_stores(tmp)
    good = tmp / "good.csv"
    good.write_text("# units: g\npose,ref_x,ref_y,ref_z,x,y,z\n" + "\n".join(GOOD_ROWS) + "\n")
    yield from _fit_batch_cases(tmp, files, good)
    yield from _store_cases(tmp, stores)
    yield from _config_cases(tmp, files, good)
    yield from _simulate_poses_diagnose_cases(tmp, files, good)


def _fit_batch_cases(tmp: Path, files: list, good: Path):
    """fit, batch and diagnose on bad files and bad option values."""
    out = tmp / "out.json"
    nums = ["x", "-1", "0", "nan", "inf", "1e400", "", "-0"]
    for f in files:
        for model in ("6", "12"):
            yield ["fit", str(f), "--model", model, "-o", str(out)], out
        yield ["fit", str(f), "--raw", "-o", str(out)], out
        yield ["batch", str(f), "--out-dir", str(tmp / "cals")], tmp / "cals" / "none"  # a board SKIPped
        yield ["diagnose", str(f)], None
    for opt in ("--counts-per-g", "--gravity", "--rate", "--skip-rows"):
        for v in nums:
            yield ["fit", str(good), opt, v, "--units", "mps2" if opt == "--gravity" else "counts",
                   *(["--raw"] if opt in ("--rate", "--skip-rows") else []), "-o", str(out)], out
            yield ["diagnose", str(good), opt, v], None
    for opt, vals in (("--model", ["7", "0", "x", "12.0", ""]), ("--units", ["furlongs", "", "G "]),
                      ("--temp-method", ["cubic", ""]), ("--columns", ["a,b", "x,x,x", ",,,", "t,x,y"])):
        for v in vals:
            yield ["fit", str(good), opt, v, "-o", str(out)], out
            yield ["batch", str(good), opt, v, "--out", str(tmp / "r.csv")], tmp / "r.csv"
    for opt, vals in (("--chunk-boards", ["0", "-1", "x"]), ("--out", ["/", "/dev/null", str(tmp / "bad_dir.csv"),
                                                                       str(tmp / "r.xls")]),
                      ("--csv", ["/", str(tmp / "bad_dir.csv")]), ("--since", ["yesterday", "2024-13-01"]),
                      ("--run", ["x", "-1"])):
        for v in vals:
            yield ["batch", str(good), opt, v], None

def _store_cases(tmp: Path, stores: list):
    """batch and report on bad stores, and report with bad options."""
    for st in stores:
        yield ["batch", "--from-store", st], None
        for sub in (["list"], ["show", "1"], ["export"], ["summary"], ["export", "-o", str(tmp / "e.csv")]):
            yield ["report", *sub, "--db", st], (tmp / "e.csv") if "-o" in sub else None
    db = tmp / "runs.sqlite"
    for sub in (["show", "x"], ["show", "-1"], ["show", "99"], ["list", "--since", "yesterday"],
                ["list", "--until", "2024-02-30"], ["list", "--verdict", "MAYBE"], ["list", "--status", "done"],
                ["export", "--format", "xml"], ["export", "-o", "/"], ["export", "-o", str(tmp / "bad_dir.csv")],
                ["export", "-o", "/dev/null"], ["export", "-o", str(tmp / "nodir" / "e.csv")],
                ["summary", "--html", "/"], ["summary", "--html", str(tmp / "bad_dir.csv")], ["plot", "x"],
                ["plot", "99"], ["show"], ["nonesuch"]):
        yield ["report", *sub, "--db", str(db)], None

def _config_cases(tmp: Path, files: list, good: Path):
    """nvm, probe, simulate and diagnose with bad configs; nvm restore of bad images."""
    cfgs = [str(tmp / "missing.yaml"), str(tmp / "bad_dir.csv"), str(tmp / "bomb.yaml"), str(tmp / "deep.yaml"),
            str(tmp / "dup.yaml"), str(tmp / "binary.yaml"), str(tmp / "list.yaml"), str(files[0])]
    img = tmp / "image.json"
    for c in cfgs:
        for sub in (["read"], ["backup", str(img)], ["erase", "--yes"], ["restore", str(good)]):
            yield ["nvm", *sub, "--config", c], img if sub[0] == "backup" else None
        yield ["probe", "--config", c], None
        yield ["simulate", "--config", c, "--out", str(tmp / "s.csv")], tmp / "s.csv"
        yield ["diagnose", str(good), "--config", c], None
    for f in files[:8]:
        yield ["nvm", "restore", str(f), "--config", str(REPO / "configs" / "sim.yaml")], None

def _simulate_poses_diagnose_cases(tmp: Path, files: list, good: Path):
    """simulate, poses and diagnose with bad option values."""
    for opt, vals in (("--poses", ["nope", "", "six-face,x"]), ("--samples", ["0", "-1", "x"]),
                      ("--temps", ["a,b", "1e9", "nan", ","]), ("--move-s", ["-1", "nan"]), ("--seed", ["-1", "x"]),
                      ("--out", ["/", str(tmp / "bad_dir.csv"), "/dev/null", str(tmp / "nodir" / "s.csv")]),
                      ("--truth-out", ["/", str(tmp / "bad_dir.csv")])):
        for v in vals:
            args = ["simulate", opt, v] + ([] if opt == "--out" else ["--out", str(tmp / "s.csv")])
            yield args, None if opt == "--out" else tmp / "s.csv"
    for name in ("nope", "", "six-face ", "an4399-8; rm -rf /", "\x1b[31mred", "x" * 5000):
        yield ["poses", name], None
    for opt, vals in (("--model", ["7", "x"]), ("--noise-mg", ["-1", "nan", "x", "inf"])):
        for v in vals:
            yield ["poses", "six-face", opt, v], None
    for sub in (["--samples", "0"], ["--rate", "0"], ["--seed", "-1"], ["--selftest", str(good)],
                ["--report", "/", str(good)], ["--report", "/etc", str(good)], ["--report", str(good), str(good)],
                ["--norm-only", str(files[0])], []):
        yield ["diagnose", *sub], None


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=400, help="cases in the subprocess campaign (default 400)")
    ap.add_argument("--campaign-only", action="store_true", help="only the subprocess campaign")
    ap.add_argument("--store-only", action="store_true", help="only issue 34's store figures")
    a = ap.parse_args()
    from store_counts import store_counts

    if a.store_only:
        store_counts()
        return
    if not a.campaign_only:
        in_process()
        store_counts()
    from hostile_campaign import campaign

    t0 = time.perf_counter()
    c = campaign(a.cases, verbose=bool(os.environ.get("VERBOSE")))
    print(f"campaign through the CLI ({a.cases} cases, {time.perf_counter() - t0:.0f} s): clean {c['clean']}, "
          f"internal error {c['internal']}, hang {c['hang']}, input overwritten {c['overwritten']}, "
          f"messy {c['messy']}")


def in_process() -> None:
    """The issue 12 counts (in-process CliRunner) and the power-loss sweep."""
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
        for args, must_not_exist in cli_cases(tmp):
            for json_mode in (False, True):
                if must_not_exist is not None and must_not_exist.exists():
                    must_not_exist.unlink() if not must_not_exist.is_dir() else None
                r = runner.invoke(cli, args + (["--json"] if json_mode else []))
                good = clean(r, json_mode) and (must_not_exist is None or not must_not_exist.exists())
                if not good and os.environ.get("VERBOSE"):
                    print(f"  ^ {args[:6]}", file=sys.stderr)
                tried, ok = tried + 1, ok + good
        esc = tmp / "escape.csv"  # a valid table whose pose names carry terminal escape codes
        esc.write_text("# units: g\npose,ref_x,ref_y,ref_z,x,y,z\n" + "\n".join(
            r.replace(r.split(",")[0], f"\x1b[31m{r.split(',')[0]}\x1b]0;x\x07") for r in GOOD_ROWS) + "\n")
        for args in (["fit", str(esc), "--model", "6"], ["diagnose", str(esc)], ["batch", str(esc)]):
            for json_mode in (False, True):
                r = runner.invoke(cli, args + (["--json"] if json_mode else []))
                good = r.exit_code != 70 and "Traceback" not in r.output and not {"\x1b", "\x07"} & set(r.output)
                if not good and os.environ.get("VERBOSE"):
                    print(f"RAW ESCAPE ECHOED: {args[:2]}", file=sys.stderr)
                tried, ok = tried + 1, ok + good
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
