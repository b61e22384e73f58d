"""The one tree the static checks read: build/tree/accelcal_station, a link per entry of the package
folder plus one per folder pyproject.toml's [tool.setuptools.package-dir] maps into it (drivers/,
fixtures/, configs/), i.e. the package as the wheel and the editable install see it.

mypy and import-linter walk a package's folder and know nothing of setuptools' mapping (an editable
install serves the mapped folders through an import-hook finder they cannot follow), so they run in
this tree: ``python .ci/tree.py mypy`` and ``python .ci/tree.py lint-imports --no-cache`` rebuild it
and run the command there, where a link to the repository's pyproject.toml gives both their
configuration; ``python .ci/tree.py`` only builds it and prints its path. Errors name paths inside
the tree (``accelcal_station/drivers/base.py`` is ``drivers/base.py``). Links where the system has
them, copies where it has not.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "accelcal_station"


def mapped_folders(root: Path = ROOT) -> dict[str, str]:
    """Subpackage name (inside the package) -> folder of the repository, from pyproject.toml."""
    table = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    return {name.removeprefix(f"{PACKAGE}."): folder for name, folder in table.items()}


def _link(target: Path, link: Path) -> None:
    try:
        link.symlink_to(target, target_is_directory=target.is_dir())
    except OSError:  # no symlinks here (Windows without the privilege): a copy
        if target.is_dir():
            shutil.copytree(target, link, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(target, link)


def build(root: Path = ROOT, dest: Path | None = None) -> Path:
    """(Re)build the tree under ``dest`` (default root/build/tree); return the folder holding the package."""
    dest = dest or root / "build" / "tree"
    pkg = dest / PACKAGE
    if dest.exists():
        shutil.rmtree(dest)
    pkg.mkdir(parents=True)
    mapped = mapped_folders(root)
    for entry in sorted((root / PACKAGE).iterdir()):
        if entry.name != "__pycache__" and entry.name not in mapped:
            _link(entry.resolve(), pkg / entry.name)
    for sub, folder in mapped.items():
        _link((root / folder).resolve(), pkg / sub)
    _link((root / "pyproject.toml").resolve(), dest / "pyproject.toml")  # the tools' configuration
    return dest


def main(argv: list[str]) -> int:
    tree = build()
    if not argv:
        print(tree)
        return 0
    # the tree first on the path, so the checked package is the tree's, never the editable install's
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run(argv, cwd=tree, env=env).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
