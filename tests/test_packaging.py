"""The distribution as a user gets it: the wheel carries py.typed (PEP 561), so a user's mypy sees
the library's own types (fit() returns Fit, not Any); the version has one source, which the
wheel's metadata, `accelcal --version` and `accelcal_station.__version__` all show; the repository
holds no symlinks, and a clone made without them (Windows' default) builds a wheel that runs."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

import accelcal_station

ROOT = Path(__file__).resolve().parent.parent
# what the build reads: the package and the top folders pyproject.toml maps into it (package-dir)
SOURCES = ("pyproject.toml", "setup.py", "README.md", "accelcal_station", "drivers", "fixtures", "configs")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`pip wheel --no-deps` of a copy of the sources (the checkout is left as it was: no build/
    or egg-info written into it by this test)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(p, src / name)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp / "dist"), str(src)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    (whl,) = (tmp / "dist").glob("accelcal_station-*.whl")
    return whl


def test_wheel_ships_py_typed(wheel: Path):
    names = zipfile.ZipFile(wheel).namelist()
    assert "accelcal_station/py.typed" in names
    assert "accelcal_station/api.py" in names and "accelcal_station/drivers/base.py" in names


def test_wheel_ships_the_operators_catalogs(wheel: Path):
    """station.language: de needs the compiled catalog in an installed station (docs/language.md)."""
    names = zipfile.ZipFile(wheel).namelist()
    assert "accelcal_station/i18n/locale/de/LC_MESSAGES/accelcal-operator.mo" in names
    assert "accelcal_station/i18n/locale/de/LC_MESSAGES/accelcal-operator.po" in names


def test_a_users_mypy_sees_fits_return_type(wheel: Path, tmp_path: Path):
    """A user script checked by mypy against the installed wheel (not the source tree: only an
    installed package needs py.typed): reveal_type(fit(...)) is the library's Fit, not Any."""
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    user = tmp_path / "user"
    user.mkdir()
    (user / "script.py").write_text(
        "from accelcal_station import fit as top_fit\n"
        "from accelcal_station.api import fit\n\n"
        'reveal_type(fit("poses.csv"))\n'
        'reveal_type(top_fit("poses.csv").calibration)\n'
    )
    env = {**os.environ, "PYTHONPATH": str(site)}
    r = subprocess.run([sys.executable, "-m", "mypy", "--no-incremental", "script.py"], cwd=user, env=env,
                       capture_output=True, text=True, timeout=600)
    revealed = re.findall(r'Revealed type is "([^"]+)"', r.stdout)
    assert revealed == ["accelcal_station.api.Fit", "accelcal_station.calibration.Calibration"], r.stdout
    assert r.returncode == 0, r.stdout  # no "missing library stubs or py.typed marker"


def test_one_version_source(wheel: Path):
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "version" not in project and "version" in project["dynamic"]
    meta = zipfile.ZipFile(wheel).read(next(n for n in zipfile.ZipFile(wheel).namelist()
                                            if n.endswith(".dist-info/METADATA"))).decode()
    assert re.search(r"^Version: (\S+)$", meta, re.M).group(1) == accelcal_station.__version__
    r = subprocess.run([sys.executable, "-m", "accelcal_station", "--version"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.split() == ["accelcal,", "version", accelcal_station.__version__], r.stdout


def _git(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    if shutil.which("git") is None:
        pytest.skip("git is not installed (a system part)")
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_the_repository_holds_no_symlinks():
    """`git ls-files -s` mode 120000 is a link; drivers/, fixtures/ and configs/ reach the package
    through setuptools' package-dir mapping instead (docs/architecture.md, Layout)."""
    r = _git("ls-files", "-s")
    if r.returncode != 0:
        pytest.skip("not a git checkout (an unpacked source tree): nothing to list")
    assert r.stdout.count("\n") > 100, r.stderr  # the listing is real: the repository's files
    assert [ln for ln in r.stdout.splitlines() if ln.startswith("120000")] == []


def test_a_clone_without_symlinks_builds_a_wheel_that_runs(tmp_path: Path):
    """`git clone -c core.symlinks=false` (what Windows does by default, writing a link as a text file)
    of the committed tree, its wheel installed with its dependencies in a fresh venv (no source tree on
    the path): `accelcal run` on the default simulated station PASSes. When the package reached drivers/
    through links, this wheel lacked them and the run exited 70 (No module named '...fixtures')."""
    if _git("rev-parse", "HEAD").returncode != 0:
        pytest.skip("not a git checkout (an unpacked source tree): nothing to clone")
    clone = tmp_path / "clone"
    r = _git("clone", "-q", "-c", "core.symlinks=false", str(ROOT), str(clone))
    assert r.returncode == 0, r.stderr
    assert _git("config", "core.symlinks", cwd=clone).stdout.strip() == "false"
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path / "dist"),
                        str(clone)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    (whl,) = (tmp_path / "dist").glob("accelcal_station-*.whl")
    names = zipfile.ZipFile(whl).namelist()
    assert {"accelcal_station/drivers/mma8451.py", "accelcal_station/fixtures/designs.py",
            "accelcal_station/configs/sim.yaml"} <= set(names)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    bin_dir = venv / ("Scripts" if os.name == "nt" else "bin")
    r = subprocess.run([str(bin_dir / "python"), "-m", "pip", "install", "-q", str(whl)], capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    store = tmp_path / "runs.sqlite"
    r = subprocess.run([str(bin_dir / "accelcal"), "run", "--serial", "CLONE-1", "--store", str(store)], cwd=tmp_path,
                       env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    assert "PASS board CLONE-1" in r.stdout, r.stdout[-3000:]
