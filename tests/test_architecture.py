"""The package's import graph has no cycles (a driver never imports its emulator)."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"accelcal_station": ROOT / "accelcal_station", "accelcal_station.drivers": ROOT / "drivers",
            "accelcal_station.fixtures": ROOT / "fixtures"}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg, folder in PACKAGES.items():
        for f in folder.rglob("*.py"):
            rel = f.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([pkg, *parts])] = f
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Modules of the package that ``name`` imports anywhere (module level or inside functions)."""
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets = []
        if isinstance(node, ast.ImportFrom):
            mod = ".".join(base[:len(base) - node.level + 1] + ([node.module] if node.module else [])) \
                if node.level else node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        found |= {t for t in targets if t in known and t != name}
    return found


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


def test_drivers_never_import_their_emulators():
    mods = _modules()
    known = set(mods)
    for drv in ("mma8451", "mpu6050"):
        name = f"accelcal_station.drivers.{drv}"
        assert f"{name}_emulator" not in _imports(name, mods[name], known)


def test_no_import_cycle_between_modules():
    mods = _modules()
    known = set(mods)
    # package __init__ re-exports are edges too, except a package's own submodules importing it
    graph = {n: {m for m in _imports(n, p, known) if not n.startswith(m + ".")} for n, p in mods.items()}
    cycle = _cycle(graph)
    assert cycle is None, " -> ".join(cycle)


def _reach(graph: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for m in graph[todo.pop()] - seen:
            seen.add(m)
            todo.append(m)
    return seen


def test_fitting_never_loads_the_diagnosis_engine():
    """`accelcal fit` and batch stand on models/ and identifiability; the sim-to-real diagnosis
    (gap_effects, effects/, diagnose*) sits above them, never below."""
    mods = _modules()
    known = set(mods)
    graph = {n: _imports(n, p, known) for n, p in mods.items()}
    for low in ("accelcal_station.models", "accelcal_station.identifiability"):
        above = {m for m in _reach(graph, low) if m.split(".")[1].startswith(("gap_", "diagnose", "effects"))}
        assert not above, f"{low} reaches {sorted(above)}"
