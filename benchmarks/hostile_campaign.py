"""Issue 25's campaign through the real command line: generated hostile files, special files, numbers
and outputs named after inputs, each run as `python -m accelcal_station` in a subprocess.

Each case is one class:
  clean       exit 0, or a non-zero exit with exactly one error line (JSON object under --json), no traceback
  internal    exit 70, a traceback, or killed by a signal (e.g. out of the 2 GiB address space it is given)
  hang        still running after TIMEOUT_S of wall time, or more than CPU_S of CPU (the machine is shared:
              wall time alone would count other sessions' load)
  overwritten a file the command read (or the store) changed
  messy       anything else: a non-zero exit without exactly one error line

Fixed seed: the same cases on every run.  Used by robustness_counts.py.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 60.0
CPU_S = 10.0
MEMORY_BYTES = 2 << 30
HOSTILE_CELLS = ["", "nan", "-inf", "1e308", "-1e308", "1e-320", "abc", "\x1b[31m", "9" * 400, "1,5", "0x10", "\x00"]
Case = tuple[list[str], list[Path], bool]  # (arguments, files that must stay byte for byte, --json)


def _limits() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BYTES, MEMORY_BYTES))


def run_case(args: list[str], protected: list[Path], json_mode: bool, cwd: Path) -> str:
    """The class of one case (module doc)."""
    before = {p: p.read_bytes() for p in protected if p.is_file()}
    argv = [sys.executable, "-m", "accelcal_station", *args] + (["--json"] if json_mode else [])
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        r = subprocess.run(argv, cwd=cwd, capture_output=True, timeout=TIMEOUT_S, preexec_fn=_limits,
                           stdin=subprocess.DEVNULL, env=dict(os.environ, PYTHONHASHSEED="0"))
    except subprocess.TimeoutExpired:
        return "hang"
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if any(p.read_bytes() != b for p, b in before.items() if p.is_file()) or any(not p.is_file() for p in before):
        return "overwritten"
    out, err = r.stdout.decode("utf-8", "replace"), r.stderr.decode("utf-8", "replace")
    if r.returncode == 70 or r.returncode < 0 or "Traceback" in out + err:
        return "internal"
    if (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime) > CPU_S:
        return "hang"
    if r.returncode == 0:
        return "clean"
    return "clean" if _one_line(out, err, json_mode) else "messy"


def _one_line(out: str, err: str, json_mode: bool) -> bool:
    if json_mode:
        try:
            doc = json.loads(out)
        except ValueError:
            return False
        return isinstance(doc, dict) and ("error" in doc or "skipped" in doc)
    errors = [ln for ln in (err + out).splitlines() if ln.startswith("error")]
    skips = [ln for ln in out.splitlines() if ln.startswith("SKIP ")]  # batch: boards skipped with reasons, exit 1
    return len(errors) == 1 or (not errors and bool(skips)) or "nothing erased" in err


def _pose_table(rng: np.random.Generator) -> str:
    """A plausible pose table (AN4399 references, gain, offset, noise) with 0-3 hostile mutations."""
    faces = np.array([(0, 0), (0, 180), (90, 0), (-90, 0), (0, 90), (0, -90), (45, 45), (-45, 135), (30, -60),
                      (-60, 30), (10, 100), (70, -170)], float)[: rng.integers(3, 13)]
    t, p = np.radians(faces[:, 0]), np.radians(faces[:, 1])
    ref = np.stack([-np.sin(t), np.cos(t) * np.sin(p), np.cos(t) * np.cos(p)], axis=1)
    x = ref * rng.uniform(0.95, 1.05) + rng.uniform(-0.05, 0.05) + rng.normal(0, 1e-3, ref.shape)
    rows = [[f"p{i}", repr(faces[i, 0]), repr(faces[i, 1]), *map(repr, x[i])] for i in range(len(faces))]
    for _ in range(rng.integers(0, 4)):
        r, kind = int(rng.integers(len(rows))), int(rng.integers(6))
        if kind <= 2 and rows[r]:
            rows[r][int(rng.integers(len(rows[r])))] = str(rng.choice(HOSTILE_CELLS))
        elif kind == 3:
            rows[r] = rows[r][: int(rng.integers(0, 8))]
        elif kind == 4 and len(rows[r]) >= 3:
            rows = [[w[0], rows[r][1], rows[r][2], *w[3:]] if len(w) >= 3 else w for w in rows]
        else:
            rows += [list(rows[r])] * int(rng.integers(1, 2000))  # many repeats: big tables
    return "# units: g\npose,pitch_deg,roll_deg,x,y,z\n" + "\n".join(",".join(w) for w in rows) + "\n"


def _raw_log(rng: np.random.Generator) -> str:
    n = int(rng.choice([5, 200, 3000]))
    faces = rng.normal(size=(12, 3))
    faces /= np.linalg.norm(faces, axis=1, keepdims=True)
    x = np.repeat(faces, n // 12 + 1, axis=0)[:n] + rng.normal(0, 1e-3, (n, 3))
    lines = [f"{i * 0.01:.2f},{a!r},{b!r},{c!r}" for i, (a, b, c) in enumerate(x)]
    for _ in range(rng.integers(0, 3)):
        lines[int(rng.integers(n))] = ",".join(str(rng.choice(HOSTILE_CELLS)) for _ in range(rng.integers(0, 6)))
    return "time_s,ax,ay,az\n" + "\n".join(lines) + "\n"


def _lot(rng: np.random.Generator, path: Path) -> None:
    """A simulated lot (CSV or Parquet by the suffix) with hostile mutations: other Arrow types, nulls,
    missing serials, rows of the wrong width."""
    from accelcal_station.lot.synthetic import write_lot

    parquet = path.suffix == ".parquet"
    write_lot(path, int(rng.integers(1, 30)), seed=int(rng.integers(1 << 30)), parquet=parquet)
    if parquet:
        import pyarrow as pa
        import pyarrow.parquet as pq

        t = pq.read_table(path)
        n = t.num_rows
        kinds = [pa.array([[1.0]] * n), pa.array([{"a": 1}] * n), pa.array(np.arange(n).astype("datetime64[ns]")),
                 pa.array([b"\xff"] * n), pa.array(["1"] * n), pa.array(["a"] * n).dictionary_encode(),
                 pa.array([True] * n), pa.nulls(n, pa.float64()), pa.array([None if i % 7 == 3 else "B" for i in
                                                                           range(n)])]
        for _ in range(rng.integers(0, 3)):
            i = int(rng.integers(len(t.column_names)))
            t = t.set_column(i, t.column_names[i], kinds[int(rng.integers(len(kinds)))])
        pq.write_table(t, path)
        return
    lines = path.read_text().splitlines()
    for _ in range(rng.integers(0, 3)):
        k = int(rng.integers(3, len(lines)))
        cells = lines[k].split(",")
        kind = int(rng.integers(3))
        if kind == 0:
            cells = cells[: int(rng.integers(1, len(cells)))]
        elif kind == 1:
            cells[0] = ""
        else:
            cells[int(rng.integers(len(cells)))] = str(rng.choice(HOSTILE_CELLS))
        lines[k] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def _yaml(rng: np.random.Generator) -> str:
    from accelcal_station.config.sections import default_config_path

    text = default_config_path().read_text()
    bad = str(rng.choice(["1:0:0:0:0:0:0:0:0:0:0:0", "!!int 1:0", "2024-02-30", "9" * 400, "1.0e+300", ".nan",
                          "[" * 100, "!!binary xx", "'\x1b[2J'", "&a [*a]", "0x" + "f" * 400, "18446744073709551616"]))
    key = str(rng.choice(["max_s: 20", "pose_tolerance_deg: 12", "odr_hz: 100", "hold_s: 0.3", "poses: 1"]))
    return text.replace(key, f"{key.split(':')[0]}: {bad}")


def cases(tmp: Path, n: int, seed: int = 25) -> Iterator[Case]:
    """``n`` generated cases of every kind (module doc), in a fixed order."""
    rng = np.random.default_rng(seed)
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["store"] = {"path": "runs.sqlite"}
    cfg["device"]["seed"] = 5
    (tmp / "sim.yaml").write_text(yaml.safe_dump(cfg))
    os.mkfifo(tmp / "fifo")
    specials = ["/proc/kmsg", "/proc/self/status", "/dev/zero", "/dev/urandom", str(tmp / "fifo"), str(tmp), "/"]
    for k in range(n):
        kind = k % 10
        f = tmp / f"in{k}.csv"
        if kind in (0, 1):
            f.write_text(_pose_table(rng))
            out = str(rng.choice([f"out{k}.json", f.name, f"./{f.name}"]))
            yield ["fit", f.name, "--model", str(rng.choice(["6", "9", "12", "15"])), "-o", out], [f], bool(k % 3 == 0)
        elif kind == 2:
            f.write_text(_raw_log(rng))
            yield ["fit", f.name, "--raw", "--rate", str(rng.choice(["100", "1e-9", "nan"]))], [f], False
        elif kind in (3, 4):
            lot = tmp / f"lot{k}.{'parquet' if kind == 4 else 'csv'}"
            _lot(rng, lot)
            out = str(rng.choice([f"r{k}.csv", lot.name, f"./{lot.name}"]))
            yield ["batch", lot.name, "--out", out, "--chunk-boards", "4"], [lot], bool(k % 3 == 0)
        elif kind == 5:
            c = tmp / f"c{k}.yaml"
            c.write_text(_yaml(rng))
            sub = [["nvm", "read"], ["simulate", "--poses", "six-face", "--out", f"s{k}.csv"], ["report", "list"]]
            yield [*sub[k % 3], "--config", c.name], [c], False
        elif kind == 6:
            s = str(rng.choice(specials))
            sub = [["fit", s], ["fit", s, "--raw"], ["batch", s, "--out", f"r{k}.csv"],
                   ["nvm", "restore", s, "--config", "sim.yaml"], ["run", "--config", s], ["diagnose", s]]
            yield sub[int(rng.integers(len(sub)))], [], False
        elif kind == 7:
            img = tmp / f"img{k}.json"
            img.write_text(str(rng.choice(["[" * 50000, "1" * 5000, '{"schema": "accelcal.nvm-image", "version": 1}',
                                           "\xff", '{"schema": "accelcal.nvm-image", "version": 1, "base_addr": 0, '
                                           '"slot_size": 1e308}'])))
            yield ["nvm", "restore", img.name, "--config", "sim.yaml", "--backup-to", f"b{k}.json"], [img], False
        elif kind == 8:
            yield _number_case(rng, k), [tmp / "sim.yaml"], False
        else:
            args = _output_case(rng, k, tmp)
            reads = [tmp / "runs.sqlite"] + ([] if args[0] == "report" else [tmp / "sim.yaml"])  # its inputs
            yield args, reads, False


def _number_case(rng: np.random.Generator, k: int) -> list[str]:
    """simulate, poses, emulate and fit with option values from the edges."""
    v = str(rng.choice(["nan", "inf", "-1", "0", "1e308", "999999999999", "1000000", "24", "25", "64", "x"]))
    return [["simulate", "--poses", "optimal-24", "--samples", v, "--out", f"s{k}.csv"],
            ["simulate", "--poses", f"optimal-{v}", "--out", f"s{k}.csv"],
            ["simulate", "--poses", "six-face", "--samples", v, "--raw", "--out", f"s{k}.csv"],
            ["simulate", "--poses", "an4399-8", "--temps", ",".join([v] * 3), "--out", f"s{k}.csv"],
            ["simulate", "--poses", "six-face", "--move-s", v, "--seed", v, "--out", f"s{k}.csv"],
            ["poses", f"optimal-{v}"], ["poses", "six-face", "--noise-mg", v],
            ["emulate", "chamber", "--speed", v, "--alarm-at-s", "nan"],
            ["fit", "x.csv", "--counts-per-g", v], ["diagnose", "x.csv", "--samples", v]][k % 10]


def _output_case(rng: np.random.Generator, k: int, tmp: Path) -> list[str]:
    """Outputs named after the config or the store, by name, ./ or a hard link (`report --db` reads no
    config: writing over sim.yaml is then allowed, and the campaign protects only the store)."""
    target = str(rng.choice(["sim.yaml", "runs.sqlite"]))
    if not (tmp / "runs.sqlite").exists():
        from accelcal_station.store.runs import Store

        with Store(tmp / "runs.sqlite"):
            pass
    link = tmp / f"link{k}"
    os.link(tmp / target, link)
    name = str(rng.choice([target, f"./{target}", link.name]))
    return [["simulate", "--config", "sim.yaml", "--poses", "six-face", "--out", name],
            ["report", "export", "--db", "runs.sqlite", "-o", name],
            ["report", "summary", "--db", "runs.sqlite", "--html", name],
            ["nvm", "backup", "--config", "sim.yaml", "--out", name]][k % 4]


def campaign(n: int, verbose: bool = False) -> Counter:
    """Run ``n`` cases in a fresh folder; the count of each class."""
    import tempfile

    counts: Counter = Counter()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for args, protected, json_mode in cases(tmp, n):
            t0 = time.perf_counter()
            cls = run_case(args, protected, json_mode, tmp)
            counts[cls] += 1
            if verbose and cls != "clean":
                print(f"  {cls}: {' '.join(args)[:160]!r} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return counts
