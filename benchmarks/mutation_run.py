"""Mutation run over the decisive code (issue 53): acceptance, nvm, models/linear + crossval,
conventions and store/rowcheck.

A small mutator of our own rather than mutmut 3: mutmut copies the tree into ``mutants/`` and
rewrites every function into a trampoline, which fights the package's layout (``drivers`` and
``fixtures`` are symlinked into the package, the console script is installed editable) and its
subprocess tests (``accelcal`` run as a child process).  Here each mutant is one small AST-level
change applied as a text edit of the source segment it touches, in a temporary copy of the
repository, and the group's test files are run against that copy (the copy first on ``sys.path``
and ``PYTHONPATH``, so child ``accelcal`` processes run the mutant too), one mutant at a time, niced,
by pytest in a child forked from this process with its third-party imports done once (``WARM``).

Operators (the usual set, as mutmut and cosmic-ray use): comparison swapped (< <=, > >=, == !=,
in / not in, is / is not), ``and``/``or`` swapped, arithmetic swapped (+ -, * /, // /, ** *),
``not`` and unary minus removed, a number changed (int n -> n + 1, float x -> x / 2, 0.0 -> 1.0),
True/False swapped, a statement (assignment, call, raise, return, augmented assignment) replaced
by ``pass``.  Docstrings, strings, f-strings and type annotations are not mutated.

A mutant is killed when the tests fail (or time out), survives when they pass.  The sample is
``--per-module`` mutants drawn with ``--seed`` from every site of the group's files (the same
sites and sample for the same source).  Mutants named in EQUIVALENT are equivalent (no test can
tell them: the reason is given) and leave the score's denominator.

  python benchmarks/mutation_run.py                       # every group, 30 mutants each, seed 53
  python benchmarks/mutation_run.py --group nvm --per-module 60
  python benchmarks/mutation_run.py --group acceptance --only rules.py:139:30:BinOp
  python benchmarks/mutation_run.py --list --group nvm    # the sampled mutants, nothing run
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# group -> (files mutated, test files run: the fast, pinned ones first so a kill stops early)
_RULES = ["tests/test_verdict_pinned.py::test_the_rules_judge_the_independent_figures",
          "tests/test_verdict_pinned.py::test_the_verification_error_is_judged_against_its_limit"]
# group -> (files mutated, tests run: the fast, pinned ones first so a kill stops early; the station-level
# tests of the same figures, tests/test_verdict_pinned.py whole, are left to the suite: on a shared
# 2-core machine each station run costs seconds per mutant)
GROUPS: dict[str, tuple[list[str], list[str]]] = {
    "acceptance": (["accelcal_station/acceptance/rules.py", "accelcal_station/acceptance/reasons.py"],
                   ["tests/test_acceptance_pinned.py", *_RULES, "tests/test_verdict_once.py"]),
    "nvm": (["accelcal_station/nvm/blob.py", "accelcal_station/nvm/writer.py", "accelcal_station/nvm/outcome.py"],
            ["tests/test_nvm_pinned.py", "tests/test_blob.py", "tests/test_writer.py"]),
    "models": (["accelcal_station/models/linear.py", "accelcal_station/models/crossval.py"],
               ["tests/test_linear_pinned.py", *_RULES, "tests/test_model9_crossval_pinned.py",
                "tests/test_crossval_orientation.py", "tests/test_models.py"]),
    "conventions": (["accelcal_station/conventions.py"],
                    ["tests/test_conventions_pinned.py", "tests/test_posetable.py"]),
    "rowcheck": (["accelcal_station/store/rowcheck.py"], ["tests/test_rowcheck_pinned.py"]),
}

# mutant id -> why no test can tell it from the original (it leaves the score's denominator)
EQUIVALENT: dict[str, str] = {
    "rules.py:137:75:Number": "reshape(-2, 9) is reshape(-1, 9): numpy takes any negative size as the one "
                              "inferred dimension",
    "conventions.py:178:4:Delete": "angle_deg without a = np.asarray(a): b is an array, so a @ b and "
                                   "np.linalg.norm(a) convert a anyway",
    "conventions.py:229:15:Compare0": "det(P) > 0 -> >= 0: a signed permutation's determinant is +-1, never 0",
    "conventions.py:241:42:Number": "(m + m.T) / 2 -> / 3: scaling a symmetric matrix keeps its eigenvectors and "
                                    "the order of its eigenvalues",
    "conventions.py:266:72:Number": "(trace - 1) / 2 -> / 3 in the tie-break: arccos of either is monotone in the "
                                    "trace, so the smallest turn is the same one",
    "conventions.py:267:11:Compare0": "worst <= 30 -> < 30: differs only for a worst angle of exactly 30.0 in "
                                      "float; arccos rounding kept every reading built for it off by 1 ulp",
    "conventions.py:268:7:Compare0": "fits.sum() > 1 -> >= 1: with exactly one mounting within 30 deg, the "
                                     "smallest turn among those that fit is argmin(worst) too",
    "linear.py:111:31:Number": "_all_paired's rows per block, block // max(2, P) instead of max(1, P): only how "
                               "many rows are compared at once (memory), never the answer",
    "rules.py:219:31:Number": "judge's planned_poses default 0 -> 1: a plan of fewer poses than the model needs "
                              "(>= 3) adds no rule, so 0 and 1 judge alike",
}

_SWAP_CMP = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt, ast.Eq: ast.NotEq,
             ast.NotEq: ast.Eq, ast.In: ast.NotIn, ast.NotIn: ast.In, ast.Is: ast.IsNot, ast.IsNot: ast.Is}
_SWAP_BIN = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult, ast.FloorDiv: ast.Div,
             ast.Pow: ast.Mult, ast.BitAnd: ast.BitOr, ast.BitOr: ast.BitAnd, ast.LShift: ast.RShift,
             ast.RShift: ast.LShift}
_STATEMENTS = (ast.Assign, ast.AugAssign, ast.Expr, ast.Raise, ast.Return)


@dataclass(frozen=True)
class Mutant:
    path: str  # repository-relative
    line: int
    col: int
    end_line: int
    end_col: int
    kind: str
    replacement: str  # the new source text of the segment

    @property
    def id(self) -> str:
        return f"{Path(self.path).name}:{self.line}:{self.col}:{self.kind}"


def _skipped_nodes(tree: ast.AST) -> set[int]:
    """ids of nodes never mutated: docstrings, annotations, f-strings and everything under them."""
    skip: set[int] = set()

    def under(node: ast.AST | None) -> None:
        if node is not None:
            skip.update(id(n) for n in ast.walk(node))

    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
            under(body[0])
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            under(node.returns)
            for a in [*node.args.args, *node.args.kwonlyargs, *node.args.posonlyargs, node.args.vararg,
                      node.args.kwarg]:
                if a is not None:
                    under(a.annotation)
        if isinstance(node, ast.AnnAssign):
            under(node.annotation)
        if isinstance(node, (ast.JoinedStr, ast.ImportFrom, ast.Import)):
            under(node)
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            under(node)
    return skip


def _in_function(tree: ast.AST) -> set[int]:
    """ids of statements inside a function body (statement deletion applies there only)."""
    inside: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            inside.update(id(n) for n in ast.walk(node) if n is not node)
    return inside


def _variants(node: ast.AST) -> Iterator[tuple[str, ast.AST | None]]:
    """(kind, mutated copy of node; None: the statement replaced by ``pass``)."""
    if isinstance(node, ast.Compare):
        for i, op in enumerate(node.ops):
            if type(op) in _SWAP_CMP:
                new = ast.Compare(node.left, list(node.ops), node.comparators)
                new.ops[i] = _SWAP_CMP[type(op)]()
                yield f"Compare{i}", new
    elif isinstance(node, ast.BoolOp):
        yield "BoolOp", ast.BoolOp(ast.Or() if isinstance(node.op, ast.And) else ast.And(), node.values)
    elif isinstance(node, ast.BinOp) and type(node.op) in _SWAP_BIN:
        if not (isinstance(node.left, ast.Constant) and isinstance(node.left.value, str)):
            yield "BinOp", ast.BinOp(node.left, _SWAP_BIN[type(node.op)](), node.right)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.Not, ast.USub)):
        yield "UnaryOp", node.operand
    elif isinstance(node, ast.Constant) and not isinstance(node.value, str | bytes) and node.value is not None:
        v = node.value
        if isinstance(v, bool):
            yield "Bool", ast.Constant(not v)
        elif isinstance(v, int):
            yield "Number", ast.Constant(v + 1)
        elif isinstance(v, float):
            yield "Number", ast.Constant(v / 2 if v else 1.0)
    elif isinstance(node, _STATEMENTS):
        yield "Delete", None


def mutants_of(path: str) -> list[Mutant]:
    """Every mutant of one file, in source order."""
    src = (REPO / path).read_text()
    tree = ast.parse(src)
    skip, inside = _skipped_nodes(tree), _in_function(tree)
    out = []
    for node in ast.walk(tree):
        if id(node) in skip or not hasattr(node, "lineno"):
            continue
        if isinstance(node, _STATEMENTS) and id(node) not in inside:
            continue
        for kind, new in _variants(node):
            text = "pass" if new is None else f"({ast.unparse(new)})"
            out.append(Mutant(path, node.lineno, node.col_offset, node.end_lineno or node.lineno,
                              node.end_col_offset or 0, kind, text))
    return sorted(out, key=lambda m: (m.line, m.col, m.kind))


def apply(src: str, m: Mutant) -> str:
    """``src`` with the mutant's segment replaced (AST offsets are UTF-8 byte offsets)."""
    lines = src.encode("utf-8").splitlines(keepends=True)
    head = b"".join(lines[:m.line - 1]) + lines[m.line - 1][:m.col]
    tail = lines[m.end_line - 1][m.end_col:] + b"".join(lines[m.end_line:])
    return (head + m.replacement.encode("utf-8") + tail).decode("utf-8")


def sample(group: str, n: int, seed: int) -> list[Mutant]:
    """``n`` mutants of the group drawn with ``seed`` (all of them when there are fewer), valid Python only."""
    every = [m for path in GROUPS[group][0] for m in mutants_of(path)]
    valid = []
    for m in every:
        try:
            compile(apply((REPO / m.path).read_text(), m), m.path, "exec")
        except SyntaxError:
            continue
        valid.append(m)
    picked = random.Random(f"{seed}:{group}").sample(valid, min(n, len(valid)))
    return sorted(picked, key=lambda m: (m.path, m.line, m.col, m.kind))


def _copy_repo(dest: Path) -> None:
    ignore = shutil.ignore_patterns(".git", "mutants", "__pycache__", ".mypy_cache", ".ruff_cache", ".pytest_cache",
                                    ".hypothesis", "*.egg-info", ".import_linter_cache")
    shutil.copytree(REPO, dest, symlinks=True, ignore=ignore)


# third-party modules imported once by the runner, so each forked test run starts warm (never the
# package itself: every run imports it afresh from the copy)
WARM = ("numpy", "scipy.optimize", "scipy.stats", "yaml", "click.testing", "pydantic", "sqlalchemy", "alembic",
        "hypothesis", "pyarrow", "pytest")


def _warm_up() -> None:
    import importlib

    for name in WARM:
        try:
            importlib.import_module(name)
        except ImportError:
            continue


_CHILD = [0]  # the test run in progress (killed with the runner)


def _terminate(*_: object) -> None:
    """kill -TERM: end the test run in progress, then unwind (the temporary copy is removed)."""
    if _CHILD[0]:
        try:
            os.kill(_CHILD[0], signal.SIGKILL)
            os.waitpid(_CHILD[0], 0)
        except (ProcessLookupError, ChildProcessError):
            pass
    sys.exit(143)


def run_tests(copy: Path, tests: list[str], timeout_s: float) -> tuple[str, float]:
    """('passed' | 'failed' | 'timeout', seconds) of the tests against the copy: pytest in a forked
    child of this (warm) process, niced, its package imported from the copy."""
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child: never returns
        code = 3
        try:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.nice(10)
            os.chdir(copy)
            sys.path.insert(0, str(copy))
            os.environ.update(PYTHONPATH=str(copy), PYTEST_DISABLE_PLUGIN_AUTOLOAD="1", PYTHONWARNINGS="ignore")
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
            import pytest

            code = int(pytest.main(["-x", "-q", "-p", "no:cacheprovider", *tests]))
        finally:
            os._exit(code)
    _CHILD[0] = pid
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return ("passed" if os.waitstatus_to_exitcode(status) == 0 else "failed"), time.monotonic() - t0
        if time.monotonic() - t0 > timeout_s:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return "timeout", time.monotonic() - t0
        time.sleep(0.05)


def run_group(group: str, mutants: list[Mutant], copy: Path) -> dict[str, object]:
    files, tests = GROUPS[group]
    tests = [t for t in tests if (REPO / t.split("::")[0]).exists()]
    probe = subprocess.run([sys.executable, "-c", "import accelcal_station; print(accelcal_station.__file__)"],
                           cwd=copy, env={**os.environ, "PYTHONPATH": str(copy)}, capture_output=True, text=True)
    assert probe.stdout.startswith(str(copy)), f"the copy is not what the tests import: {probe.stdout}"
    base, base_s = run_tests(copy, tests, 1800)
    if base != "passed":
        raise SystemExit(f"{group}: the tests fail on the unmutated copy; fix them first")
    rows = []
    for i, m in enumerate(mutants):
        target = copy / m.path
        original = target.read_text()
        target.write_text(apply(original, m))
        try:
            outcome, secs = run_tests(copy, tests, max(60.0, 3 * base_s))
        finally:
            target.write_text(original)
        status = {"failed": "killed", "timeout": "killed", "passed": "survived"}[outcome]
        if status == "survived" and m.id in EQUIVALENT:
            status = "equivalent"
        line = original.splitlines()[m.line - 1].strip()
        rows.append({"id": m.id, "status": status, "seconds": round(secs, 1), "line": line,
                     "replacement": m.replacement})
        print(f"  [{i + 1}/{len(mutants)}] {status:10s} {m.id}  {m.replacement[:60]}", flush=True)
    killed = sum(r["status"] == "killed" for r in rows)
    equivalent = sum(r["status"] == "equivalent" for r in rows)
    counted = len(rows) - equivalent
    return {"group": group, "files": files, "tests": tests, "baseline_s": round(base_s, 1), "sampled": len(rows),
            "killed": killed, "equivalent": equivalent, "survived": counted - killed,
            "score": killed / counted if counted else 1.0, "mutants": rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--group", action="append", choices=sorted(GROUPS), help="groups to run (default: all)")
    ap.add_argument("--per-module", type=int, default=30, help="mutants sampled per group (default 30)")
    ap.add_argument("--seed", type=int, default=53)
    ap.add_argument("--only", action="append", help="run only these mutant ids (from a previous run)")
    ap.add_argument("--list", action="store_true", help="print the sampled mutants and run nothing")
    ap.add_argument("--out", type=Path, help="write every result as JSON here")
    ap.add_argument("--small", action="store_true", help="2 mutants of nvm (a smoke run)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no BLAS threads across fork
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _warm_up()
    signal.signal(signal.SIGTERM, _terminate)
    groups = ["nvm"] if args.small else (args.group or list(GROUPS))
    n = 2 if args.small else args.per_module
    results = []
    with tempfile.TemporaryDirectory(prefix="accelcal-mutants-") as tmp:
        copy = Path(tmp) / "repo"
        if not args.list:
            _copy_repo(copy)
        for g in groups:
            ms = sample(g, n, args.seed)
            if args.only:
                ms = [m for m in ms if m.id in args.only]
            total = sum(len(mutants_of(p)) for p in GROUPS[g][0])
            print(f"{g}: {len(ms)} of {total} mutants (seed {args.seed}); tests: {' '.join(GROUPS[g][1])}", flush=True)
            if args.list:
                for m in ms:
                    print(f"  {m.id}  {m.replacement[:70]}")
                continue
            results.append({**run_group(g, ms, copy), "sites": total})
    if results:
        print("\ngroup         sampled  killed  equivalent  survived  score")
        print("-----------  -------  ------  ----------  --------  -----")
        for r in results:
            print(f"{r['group']:11s}  {r['sampled']:7d}  {r['killed']:6d}  {r['equivalent']:10d}  "
                  f"{r['survived']:8d}  {100 * r['score']:4.0f}%")
        for r in results:
            for row in r["mutants"]:
                if row["status"] == "survived":
                    print(f"survived: {row['id']}  `{row['line'][:70]}` -> {row['replacement'][:60]}")
    if args.out:
        args.out.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
