"""The house: layers kept by import-linter (pyproject.toml), sizes, one docstring per subpackage.

The import contracts themselves live in pyproject.toml ([tool.importlinter]); these tests run
``lint-imports`` on the package as it is and on a copy with one deliberately wrong import, so
a broken contract cannot pass unnoticed.
"""
from __future__ import annotations

import ast
import os
import re
import runpy
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "accelcal_station"
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 60
MAX_TOP_LEVEL_MODULES = 10
# the one tree the static checks read (.ci/tree.py): the package folder plus the folders mapped into it
TREE = runpy.run_path(str(ROOT / ".ci" / "tree.py"))


def _lint_imports(cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    exe = shutil.which("lint-imports", path=os.path.dirname(sys.executable)) or shutil.which("lint-imports")
    if exe is None:
        pytest.fail("lint-imports is not installed: pip install -e '.[test]' brings import-linter")
    return subprocess.run([exe, "--no-cache"], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_import_contracts_are_kept(tmp_path):
    """On the tree .ci/tree.py builds (links to the package folder and to drivers/, fixtures/, configs/),
    as `python .ci/tree.py lint-imports --no-cache` does."""
    tree = TREE["build"](ROOT, tmp_path / "tree")
    assert (tree / "accelcal_station" / "drivers" / "mma8451.py").is_file()
    r = _lint_imports(tree, dict(os.environ, PYTHONPATH=str(tree)))  # its pyproject.toml: a link to ours
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert re.search(r"Contracts: \d+ kept, 0 broken", r.stdout), r.stdout[-2000:]


def _copy_with(tmp_path: Path, module: str, line: str) -> Path:
    """A copy of the package as installed (drivers/, fixtures/, configs/ inside it: .ci/tree.py's tree,
    links resolved) with ``line`` added to ``module`` (path inside the package)."""
    tree = TREE["build"](ROOT, tmp_path / "tree")
    shutil.copytree(tree / "accelcal_station", tmp_path / "accelcal_station", symlinks=False,
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    target = tmp_path / "accelcal_station" / module
    target.write_text(target.read_text() + f"\n{line}\n")
    return tmp_path


@pytest.mark.parametrize("module, line, broken", [
    ("station/board.py", "from ..cli import main  # deliberately wrong",
     "accelcal_station.station is not allowed to import accelcal_station.cli"),
    ("models/linear.py", "from ..store.runs import Store  # deliberately wrong",
     "accelcal_station.models is not allowed to import accelcal_station.store"),
    ("drivers/mma8451.py", "from . import mma8451_emulator  # deliberately wrong",
     "accelcal_station.drivers.mma8451 is not allowed to import accelcal_station.drivers.mma8451_emulator"),
    ("lot/batch.py", "import tests.conftest  # deliberately wrong",
     "accelcal_station.lot.batch -> tests"),
    # allowed by the layers (station is above sim and fixtures): only the station contract stops these
    ("station/thermal.py", "from ..sim.sensor_model import SensorModel  # deliberately wrong",
     "accelcal_station.station.thermal -> accelcal_station.sim.sensor_model"),
    ("station/panel.py", "from ..fixtures.simulated_panel import PanelSimulatedJig  # deliberately wrong",
     "accelcal_station.station.panel -> accelcal_station.fixtures.simulated_panel"),
    ("station/board.py", "from ..drivers.mma8451_emulator import MMA8451Emulator  # deliberately wrong",
     "accelcal_station.station.board -> accelcal_station.drivers.mma8451_emulator"),
])
def test_a_wrong_import_breaks_a_contract(tmp_path, module, line, broken):
    """The same contracts on a copy with one wrong import: lint-imports fails and names it."""
    copy = _copy_with(tmp_path, module, line)
    env = dict(os.environ, PYTHONPATH=str(copy))  # the copy is found before the installed package
    r = _lint_imports(copy, env)
    out = " ".join(r.stdout.split())
    assert r.returncode == 1, r.stdout[-3000:] + r.stderr[-2000:]
    assert broken in out, out[-3000:]
    if module.startswith("station/") and "cli" not in line:
        assert "The station flows import no simulation, emulator or CLI code" in out and "BROKEN" in out, out[-3000:]


def _python_files() -> list[Path]:
    """Every Python file of the repository: the package (drivers/ and fixtures/ by their own
    folders), tests, benchmarks and examples."""
    folders = ("accelcal_station", "drivers", "fixtures", "configs", "tests", "benchmarks", "examples")
    return sorted({f for folder in folders for f in (ROOT / folder).rglob("*.py")
                   if f.relative_to(ROOT).parts[:2] != ("tests", "data")})  # upstream scripts kept as they came


def test_no_module_over_500_lines():
    big = {str(f.relative_to(ROOT)): n for f in _python_files() if (n := len(f.read_text().splitlines())) >
           MAX_MODULE_LINES}
    assert not big, f"modules over {MAX_MODULE_LINES} lines: {big}"


def test_no_function_over_60_lines():
    """Counted from the first decorator (a click command's options are part of it) to the last line."""
    long = []
    for f in _python_files():
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                n = node.end_lineno - first + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{f.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert not long, "functions over 60 lines:\n" + "\n".join(long)


def test_top_level_holds_at_most_ten_modules():
    mods = sorted(p.name for p in PKG.glob("*.py"))
    assert len(mods) <= MAX_TOP_LEVEL_MODULES, mods


def test_every_subpackage_says_what_it_holds_and_may_import():
    inits = sorted(PKG.rglob("__init__.py")) + [ROOT / "drivers" / "__init__.py", ROOT / "fixtures" / "__init__.py"]
    for init in inits:
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert len(doc) > 80 and "import" in doc, f"{init.relative_to(ROOT)}: docstring {doc!r}"


def _layout_block() -> list[str]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    section = text.split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    return section.split("```", 2)[1].splitlines()


def test_layout_block_names_exactly_the_folders_there_are():
    """docs/architecture.md's layout block: every tracked top-level folder, every subpackage and top-level
    module of the package, and the folders mapped into it (pyproject.toml), no more and no fewer."""
    lines = _layout_block()
    top = {m.group(1) for ln in lines if (m := re.match(r"^([\w.-]+)/\s", ln))}
    sub = {m.group(1) for ln in lines if (m := re.match(r"^  (\w+)/\s", ln))}
    mods = {m.group(1) for ln in lines if (m := re.match(r"^  (\w+\.py)\s", ln))}
    mapped = {m.group(1): m.group(2) for ln in lines for m in re.finditer(r"\.(\w+) = (\w+)/", ln)}
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if tracked.returncode == 0 and tracked.stdout:
        folders = {p.split("/", 1)[0] for p in tracked.stdout.splitlines() if "/" in p and not p.startswith(".")}
    else:  # not a git checkout (an unpacked source tree): the folders on disk
        folders = {p.name for p in ROOT.iterdir() if p.is_dir() and not p.name.startswith((".", "build"))
                   and not p.name.endswith(".egg-info")}
    assert top == folders, f"docs/architecture.md layout {sorted(top)} vs folders {sorted(folders)}"
    real = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert sub == real, f"docs/architecture.md layout {sorted(sub)} vs subpackages {sorted(real)}"
    assert mods == {p.name for p in PKG.glob("*.py")} - {"__init__.py", "__main__.py"}
    assert mapped == TREE["mapped_folders"](ROOT), f"docs/architecture.md {mapped} vs pyproject.toml package-dir"


MAX_PARAMETERS = 9  # positional + keyword-only, without self/cls; *args/**kwargs not counted
# Functions allowed over MAX_PARAMETERS, each with why (none since issue 52's parameter objects).  The
# list only shrinks: an entry that no longer exceeds the limit fails the test.
PARAMETER_ALLOW_LIST: dict[str, str] = {}


def _parameter_count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = node.args
    n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
    first = (a.posonlyargs + a.args)[:1]
    return n - (1 if first and first[0].arg in ("self", "cls") else 0)


def test_no_function_takes_more_than_nine_parameters():
    """Long signatures become parameter objects named for their concept (issue 52: shape, not packing);
    counted over the package and drivers/, fixtures/ as the 60-line rule counts lines."""
    over, stale = [], []
    seen: set[str] = set()
    for f in _python_files():
        rel = f.relative_to(ROOT)
        if rel.parts[0] not in ("accelcal_station", "drivers", "fixtures"):
            continue
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and _parameter_count(node) > MAX_PARAMETERS:
                key = f"{rel.as_posix()}:{node.name}"
                seen.add(key)
                if key not in PARAMETER_ALLOW_LIST:
                    over.append(f"{key} ({_parameter_count(node)} parameters)")
    stale = sorted(set(PARAMETER_ALLOW_LIST) - seen)
    assert not over, f"functions over {MAX_PARAMETERS} parameters (use a parameter object):\n" + "\n".join(over)
    assert not stale, f"allow-listed but no longer over {MAX_PARAMETERS} parameters (drop them):\n" + "\n".join(stale)
