"""Every optional part missing: one line naming the extra to install, exit 2, under --json too.

The real CLI runs in a child process in which the optional module is made unimportable
(``sys.modules[name] = None``: ``import name`` then raises ModuleNotFoundError, as on an
install without the extra).
"""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from accelcal_station.cli._extras import extra_for

CHILD = ("import sys\n"
         "for m in sys.argv[1].split(','):\n"
         "    sys.modules[m] = None\n"
         "sys.argv = ['accelcal'] + sys.argv[2:]\n"
         "from accelcal_station.cli import main\n"
         "main()\n")


def _run(blocked, *args, cwd):
    return subprocess.run([sys.executable, "-c", CHILD, blocked, *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    d = tmp_path_factory.mktemp("extras")
    subprocess.run([sys.executable, "-m", "accelcal_station", "simulate", "--poses", "six-face", "--out",
                    d / "six.csv", "--seed", "1"], check=True, capture_output=True, timeout=120)
    (d / "lot.parquet").write_bytes(b"PAR1")
    return d


CASES = [
    ("psycopg", "postgresql", ["report", "list", "--db", "postgresql://user@localhost:1/none"]),
    ("pyarrow,pyarrow.parquet", "parquet", ["batch", "lot.parquet", "--out", "r.csv"]),
    ("matplotlib,matplotlib.pyplot", "report", ["diagnose", "six.csv", "--report", "rep"]),
    ("fastapi,uvicorn", "web", ["serve", "--db", "none.sqlite"]),  # a server: no --json option
    ("pyvisa", "chamber", ["chamber", "status", "--port", "/dev/null"]),
]


@pytest.mark.parametrize(("blocked", "extra", "args"), CASES, ids=[c[1] for c in CASES])
def test_missing_optional_module_names_its_extra(table, blocked, extra, args):
    r = _run(blocked, *args, cwd=table)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and f"pip install 'accelcal-station[{extra}]'" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    if args[0] == "serve":
        return
    j = _run(blocked, *args, "--json", cwd=table)
    assert j.returncode == 2
    err = json.loads(j.stdout)
    assert err["code"] == 2 and f"accelcal-station[{extra}]" in err["error"]


def test_every_user_extra_is_mapped_from_the_installed_metadata():
    """The extras of pyproject.toml, read back from the installed distribution (not a copy here)."""
    mods = ("psycopg", "pyarrow", "matplotlib", "fastapi", "uvicorn", "jinja2", "pyvisa", "pyvisa_py", "imucal",
            "numpy")
    assert {m: extra_for(m) for m in mods} == {
        "psycopg": "postgresql", "pyarrow": "parquet", "matplotlib": "report", "fastapi": "web", "uvicorn": "web",
        "jinja2": "web", "pyvisa": "chamber", "pyvisa_py": "chamber", "imucal": "bench", "numpy": None}
