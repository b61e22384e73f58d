"""Issue 25 (and 26's reader items): hostile files and numbers are refused in one line naming
the file, the row or column and what is allowed; special files are refused before a read
that could block; nothing hangs."""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.lot.synthetic import write_lot

# issue 53: no Python warning reaches the terminal: any warning raised here fails its test (-W error)
pytestmark = pytest.mark.filterwarnings("error")

pa = pytest.importorskip("pyarrow", reason="Parquet lots need the optional pyarrow (the parquet extra)")
pq = pytest.importorskip("pyarrow.parquet")

REPO = Path(__file__).resolve().parents[1]
NUMERIC = ("pitch_deg", "roll_deg", "x", "y", "z", "n", "std_x", "std_y", "std_z")


def one_line(r, code: int = 2) -> str:
    assert r.exit_code == code, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error")]
    assert "Traceback" not in r.output and len(errors) == 1, r.output
    return errors[0]


def _non_numbers(n: int) -> dict[str, pa.Array]:
    """One Arrow array of n values for each kind of type a numeric column must not have."""
    return {
        "list": pa.array([[1.0, 2.0]] * n), "struct": pa.array([{"a": 1.0}] * n),
        "timestamp": pa.array(np.arange(n).astype("datetime64[ns]")), "binary": pa.array([b"\x00\xff"] * n),
        "string": pa.array(["1.5"] * n), "dictionary": pa.array(["a"] * n).dictionary_encode(),
        "bool": pa.array([True] * n), "date": pa.array(np.arange(n).astype("datetime64[D]")),
        "duration": pa.array(np.arange(n).astype("timedelta64[s]")),
        "map": pa.array([[("k", 1.0)]] * n, type=pa.map_(pa.string(), pa.float64())),
        "large_binary": pa.array([b"x"] * n, type=pa.large_binary()),
    }


@pytest.fixture(scope="module")
def lot_table(tmp_path_factory):
    p = write_lot(tmp_path_factory.mktemp("lot") / "lot.parquet", 4, seed=2, parquet=True)
    return pq.read_table(p)


@pytest.mark.parametrize("kind", list(_non_numbers(1)))
def test_parquet_non_number_in_each_numeric_column_is_refused_naming_column_and_type(tmp_path, lot_table, kind):
    """Every non-number Arrow type in every numeric column: exit 2, one line with the column and the type."""
    for col in NUMERIC:
        arr = _non_numbers(lot_table.num_rows)[kind]
        t = lot_table.set_column(lot_table.schema.get_field_index(col), col, arr)
        p = tmp_path / f"{kind}-{col}.parquet"
        pq.write_table(t, p)
        r = CliRunner().invoke(cli, ["batch", str(p), "--out", str(tmp_path / "r.csv")])
        line = one_line(r)
        stored = pq.read_schema(p).field(col).type  # as the file has it (list<element: ...> after a round trip)
        assert f"column '{col}' is of type {stored}" in line and "allowed: numbers" in line, line
        assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize("kind", ["list", "struct", "binary", "bool", "timestamp"])
def test_parquet_serial_of_a_wrong_type_is_refused(tmp_path, lot_table, kind):
    arr = _non_numbers(lot_table.num_rows)[kind]
    p = tmp_path / "s.parquet"
    pq.write_table(lot_table.set_column(0, "serial", arr), p)
    assert f"column 'serial' is of type {pq.read_schema(p).field('serial').type}" in one_line(
        CliRunner().invoke(cli, ["batch", str(p), "--out", str(tmp_path / "r.csv")]))


def test_parquet_null_serial_is_refused_with_its_row_never_a_board_named_none(tmp_path, lot_table):
    serials = lot_table.column("serial").to_pylist()
    serials[11] = None
    p = tmp_path / "null.parquet"
    pq.write_table(lot_table.set_column(0, "serial", pa.array(serials)), p)
    line = one_line(CliRunner().invoke(cli, ["batch", str(p), "--out", str(tmp_path / "r.csv")]))
    assert "data row 12, column serial: empty or null" in line
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize("reader", ["pyarrow", "python"])
@pytest.mark.parametrize("row", ["B00000002,p1,0,0,1,2", ",p1,0,0,12.1,-30.2,4101.7,200,4,4,4"])
def test_csv_lot_row_of_wrong_width_or_no_serial_names_its_line(tmp_path, monkeypatch, reader, row):
    if reader == "python":
        monkeypatch.setattr("accelcal_station.data.lotfile.arrow_available", lambda: False)
    lot = write_lot(tmp_path / "lot.csv", 4, seed=3)
    lines = lot.read_text().splitlines()
    lines.insert(12, row)  # file line 13
    lot.write_text("\n".join(lines) + "\n")
    line = one_line(CliRunner().invoke(cli, ["batch", str(lot), "--out", str(tmp_path / "r.csv")]))
    assert "line 13" in line, line
    assert ("6 fields; the header has 11" in line) if row.startswith("B") else ("column serial" in line)
    assert not (tmp_path / "r.csv").exists()


def _timed(args: list[str], code: int = 2) -> tuple[float, str]:
    t0 = time.perf_counter()
    r = CliRunner().invoke(cli, args)
    return time.perf_counter() - t0, one_line(r, code)


# A hang guard, not a speed claim (no wall-clock thresholds in unit tests): a blocked open or read of
# a FIFO or kernel file, or a parse that goes quadratic, raises instead of hanging the suite.
HANG_S = 10.0


def _within(limit_s: float, args: list[str], code: int = 2) -> tuple[float, str]:
    """``_timed`` in this thread, interrupted by SIGALRM after ``limit_s``."""
    def expire(signum: int, frame: object) -> None:
        raise TimeoutError(f"{args} did not return within {limit_s} s")

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        return _timed(args, code)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_fit_on_a_fifo_returns_at_once_without_opening_it(tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    _, line = _within(HANG_S, ["fit", str(fifo)])
    assert "a FIFO" in line


def test_fit_on_dev_zero_returns_at_once():
    _, line = _within(HANG_S, ["fit", "/dev/zero"])
    assert "a device" in line


@pytest.mark.parametrize("path", ["/proc/kmsg", "/proc/self/status", "/sys/kernel/mm/transparent_hugepage/enabled"])
def test_fit_on_kernel_files_returns_at_once(path):
    if path.startswith("/sys/") and not os.path.lexists(path):  # an optional kernel feature; /proc is always there
        pytest.skip(f"{path} does not exist on this kernel")
    _, line = _within(HANG_S, ["fit", path, "--raw"])  # a regression would block on read: fail, not hang
    assert "kernel file" in line or "cannot read" in line, line


@pytest.mark.parametrize("args", [["fit", "{f}"], ["fit", "{f}", "--raw"], ["batch", "{f}", "--out", "{o}"],
                                  ["nvm", "restore", "{f}"], ["run", "--config", "{f}"]])
def test_every_reader_refuses_a_fifo(tmp_path, args):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    args = [a.format(f=fifo, o=tmp_path / "r.csv") for a in args]
    _, line = _within(HANG_S, args, 4 if args[0] == "nvm" else 2)  # NVMError: 4
    assert "FIFO" in line, line


def test_sexagesimal_yaml_is_a_string_and_refused_fast(tmp_path):
    """YAML 1.1 base-60 (1:0:0:...) was quadratic then exit 70; now a string the key check refuses."""
    text = default_config_path().read_text().replace("max_s: 20", "max_s: 1" + ":0" * 200_000)
    p = tmp_path / "sexa.yaml"
    p.write_text(text)
    _, line = _within(HANG_S, ["run", "--config", str(p)])  # the quadratic parse took 12.8 s then exit 70
    assert "capture.max_s" in line and "characters)" in line and len(line) < 400  # the value is cut short


@pytest.mark.parametrize("value,words", [("!!int 1:0:0", "base-60"), ("2024-02-30", "day is out of range"),
                                         ("9" * 400, "an integer of 400 digits")])
def test_yaml_values_python_cannot_build_are_one_line(tmp_path, value, words):
    p = tmp_path / "c.yaml"
    p.write_text(default_config_path().read_text().replace("max_s: 20", f"max_s: {value}"))
    assert words in one_line(CliRunner().invoke(cli, ["run", "--config", str(p)]))


@pytest.mark.parametrize("cell,col", [("-1e308", "pitch_deg"), ("1e300", "roll_deg"), ("-1", "std_x"),
                                      ("1e20", "n")])
def test_pose_table_value_out_of_range_is_refused_with_its_row(tmp_path, cell, col):
    head = "pose,pitch_deg,roll_deg,x,y,z,n,std_x,std_y,std_z"
    rows = [f"p{i},{p},{r},0,0,1,100,0.01,0.01,0.01" for i, (p, r) in
            enumerate([(0, 0), (0, 180), (90, 0), (-90, 0), (0, 90), (0, -90)])]
    cells = rows[3].split(",")
    cells[head.split(",").index(col)] = cell
    rows[3] = ",".join(cells)
    p = tmp_path / "t.csv"
    p.write_text("# units: g\n" + head + "\n" + "\n".join(rows) + "\n")
    line = one_line(CliRunner().invoke(cli, ["fit", str(p), "--model", "6"]))
    assert f"line 6, column {col}" in line and "out of range" in line


@pytest.mark.parametrize("text,words", [("[" * 100_000, "nested 100000 levels"), ("1" * 5000, "unreadable JSON"),
                                        ("\xff\xfe", "not a text file"), ('{"schema": 1}', "not an NVM backup")])
def test_nvm_backup_files_that_are_not_are_one_line(tmp_path, text, words):
    p = tmp_path / "img.json"
    p.write_bytes(text.encode("latin-1"))
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["device"]["seed"] = 1
    c = tmp_path / "c.yaml"
    c.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["nvm", "restore", str(p), "--config", str(c), "--backup-to", str(tmp_path / "b.json")])
    assert words in one_line(r, 4)


@pytest.mark.parametrize("text,words", [("[" * 100_000, "nested"), ('{"schema": "accelcal.calibration", "version": 1, '
                                         '"model": "12", "W": [[1,0,0],[0,1,0],[0,0,1]], "V": [0,0,0], '
                                         '"input_units": "g", "input_per_g": 1, "temperature": {"temps_c": [1, 2], '
                                         '"W": [1], "V": [], "Gamma": []}}', "temperature table W: shape")])
def test_calibration_json_that_is_not_is_one_line(tmp_path, text, words):
    from accelcal_station.calibration import Calibration
    from accelcal_station.errors import DataError

    p = tmp_path / "cal.json"
    p.write_text(text)
    with pytest.raises(DataError, match=words):
        Calibration.load(p)


@pytest.mark.parametrize("args,words", [
    (["emulate", "chamber", "--speed", "nan"], "'nan' is not a finite number"),
    (["emulate", "chamber", "--alarm-at-s", "inf"], "inf"),
    (["chamber", "set", "--temp-c", "nan", "--port", "x"], "not a finite number"),
    (["poses", "six-face", "--noise-mg", "inf"], "--noise-mg"),
    (["simulate", "--poses", "six-face", "--out", "s.csv", "--seed", "9" * 60], "--seed"),
    (["report", "show", "9" * 30], "RUN_ID"),
    (["fit", "x.csv", "--counts-per-g", "1e300"], "--counts-per-g '1e300'; allowed: a positive number up to 1e+09"),
    (["batch", "x.csv", "--out", "r.csv", "--chunk-boards", "1000000000"], "--chunk-boards"),
])
def test_command_line_numbers_finite_and_in_range(args, words):
    assert words in one_line(CliRunner().invoke(cli, args))


def test_error_lines_never_echo_control_characters(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("# units: g\npose,x,y,z,\x1b[31mbad\x07\n")
    r = CliRunner().invoke(cli, ["fit", str(p)])
    line = one_line(r)
    assert "\\x1b[31mbad\\x07" in line and not {"\x1b", "\x07"} & set(r.output)
    r = CliRunner().invoke(cli, ["--\x1b]0;title\x07"])
    assert "\\x1b" in one_line(r) and "\x1b" not in r.output


def test_nvm_erase_at_end_of_input_says_why(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, ["nvm", "erase"], input="")
    assert r.exit_code == 1 and "no confirmation (end of input): nothing erased" in r.output
    assert "Aborted!" not in r.output and not list(tmp_path.glob("nvm-backup-*"))


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_optimal_designs_looked_up_are_the_tabled_ones(n):
    """The table (benchmarks/make_optimal_table.py) is what get_design gives; that a fresh search
    agrees with it up to the design's symmetries is tests/test_design_symmetry.py."""
    from accelcal_station.fixtures.designs import get_design
    from accelcal_station.fixtures.optimal_table import OPTIMAL

    assert [(p.pitch_deg, p.roll_deg) for p in get_design(f"optimal-{n}")] == list(OPTIMAL[n])


def test_poses_and_simulate_at_their_limits_are_looked_up_or_refused(tmp_path, monkeypatch):
    """optimal-24 is looked up, never searched for (a search takes some 10 s of CPU): a tripwire in
    the search fails the test if a command falls back to it (machine-independent, no clock)."""
    from accelcal_station.fixtures import designs

    def no_search(u0: object) -> object:
        raise AssertionError("optimal-24 was searched for instead of looked up")

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(designs, "_polish", no_search)
    for args in (["poses", "optimal-24"], ["simulate", "--poses", "optimal-24", "--samples", "2", "--out", "s.csv"]):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code in (0, 2) and r.exception is None or isinstance(r.exception, SystemExit), r.output
    assert "optimal-N (2 <= N <= 24)" in one_line(CliRunner().invoke(cli, ["poses", "optimal-25"]))
    line = one_line(CliRunner().invoke(cli, ["simulate", "--poses", "optimal-24", "--samples", "10000000",
                                             "--out", "s.csv"]))
    assert "240000000 samples; allowed: at most 100000000" in line
    line = one_line(CliRunner().invoke(cli, ["simulate", "--poses", "six-face", "--samples", "10000000", "--raw",
                                             "--temps", "0,25", "--out", "big.csv"]))
    assert "120000000 samples; allowed: at most 100000000" in line and not (tmp_path / "big.csv").exists()
