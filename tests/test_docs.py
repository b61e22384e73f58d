"""README.md is the front door and docs/ holds the rest: the commands table names exactly the
commands there are (each answers --help), the options it shows exist, every option any command's
--help lists is documented in README.md or a docs/ page, and the README's test command and
layer list are the ones CI runs and import-linter keeps."""
from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def _section(title: str) -> str:
    return README.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def _table_rows() -> list[tuple[list[str], list[str]]]:
    """(command words after `accelcal`, options shown) per row of README's commands table."""
    rows = []
    for line in _section("Commands").splitlines():
        m = re.match(r"^\| `accelcal ([^`]*)` \|", line)
        if m:
            cell = m.group(1).replace("\\|", "|")
            words = [w for w in cell.split() if not w.startswith(("[", "-")) and w == w.lower()]
            rows.append((words, re.findall(r"--[a-z][\w-]*", cell)))
    return rows


def _walk(cmd: click.Command, path: tuple[str, ...], parent: click.Context | None
          ) -> Iterator[tuple[tuple[str, ...], click.Command]]:
    """Every command of the tree, through list_commands/get_command (so a lazily loaded group is
    walked the same way as an eager one)."""
    yield path, cmd
    if isinstance(cmd, click.Group):
        ctx = click.Context(cmd, info_name=path[-1] if path else "accelcal", parent=parent)
        for name in cmd.list_commands(ctx):
            sub = cmd.get_command(ctx, name)
            assert sub is not None, f"{' '.join(path + (name,))} is listed but does not load"
            yield from _walk(sub, path + (name,), ctx)


def _options(cmd: click.Command) -> set[str]:
    """The long options `--help` shows for one command (hidden ones are not shown)."""
    return {o for p in cmd.params if isinstance(p, click.Option) and not p.hidden
            for o in (*p.opts, *p.secondary_opts) if o.startswith("--") and o != "--help"}


TREE = dict(_walk(cli, (), None))


def test_readme_is_a_front_door():
    assert len(README.splitlines()) < 150


def test_table_names_every_command_and_only_real_ones():
    rows = _table_rows()
    tops = {path[0] for path in TREE if len(path) == 1}
    in_table = {words[0] for words, _ in rows}
    assert in_table == tops, f"table {sorted(in_table)} vs CLI {sorted(tops)}"
    for words, _ in rows:
        group = TREE[(words[0],)]
        if isinstance(group, click.Group):  # `accelcal report list|show|...`: all the subcommands
            shown = set(words[1].split("|")) if len(words) > 1 else set()
            real = {p[1] for p in TREE if len(p) == 2 and p[0] == words[0]}
            assert shown == real, f"accelcal {words[0]}: table {sorted(shown)} vs CLI {sorted(real)}"


@pytest.mark.parametrize("words", [w for w, _ in _table_rows()], ids=lambda w: w[0])
def test_each_table_command_answers_help(words):
    """`accelcal CMD --help` exits 0 as a user runs it (a fresh process: an import error of a
    lazily loaded command shows here), and every subcommand of the row does too."""
    r = subprocess.run([sys.executable, "-m", "accelcal_station", words[0], "--help"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Usage:" in r.stdout, r.stderr
    if isinstance(TREE[(words[0],)], click.Group):
        for sub in words[1].split("|"):
            res = CliRunner().invoke(cli, [words[0], sub, "--help"])
            assert res.exit_code == 0 and "Usage:" in res.output, res.output


def test_options_shown_in_the_table_exist():
    for words, shown in _table_rows():
        real = set().union(*(_options(c) for p, c in TREE.items() if p[:1] == (words[0],)))
        assert set(shown) <= real, f"accelcal {words[0]}: no such option {sorted(set(shown) - real)}"


def test_every_option_is_documented():
    text = README + "".join(p.read_text() for p in sorted((ROOT / "docs").glob("*.md")))
    missing = [f"accelcal {' '.join(path)} {o}".replace("  ", " ") for path, cmd in TREE.items()
               for o in sorted(_options(cmd)) if not re.search(re.escape(o) + r"(?![\w-])", text)]
    assert not missing, "options in --help documented nowhere in README.md or docs/*.md:\n" + "\n".join(missing)


def test_readme_lists_every_docs_page_and_each_exists():
    pages = {p.name for p in (ROOT / "docs").glob("*.md")}
    linked = set(re.findall(r"\((?:docs/)?([\w-]+\.md)\)", _section("Documentation")))
    assert pages <= linked, f"docs pages missing from README: {sorted(pages - linked)}"
    assert all((ROOT / "docs" / p).is_file() or p == "README.md" for p in linked)


def test_readme_gives_the_test_command_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    command = ci.split("exactly as README.md gives it:\n", 1)[1].splitlines()[0].strip()
    assert f"\n{command}\n" in README


def test_readme_layers_are_the_contract():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    layers = next(c for c in cfg["tool"]["importlinter"]["contracts"] if c["type"] == "layers")["layers"]
    para = " ".join(_section("Tests and checks").split("The layers, top down", 1)[1].split("\n\n", 1)[0].split())
    shown = re.findall(r"`([^`]+)`", para.split(":", 1)[1])
    assert shown == layers, f"README layers {shown} vs pyproject {layers}"


def test_readme_names_the_system_parts_ci_installs():
    ci = (ROOT / ".ci" / "run").read_text()
    section = _section("Tests and checks")
    for env in re.findall(r"export (ACCELCAL_REQUIRE_\w+)=1", ci):
        assert f"{env}=1" in section, env
    lists = re.findall(r"install -y -qq? ([a-z][\w .-]*?)(?: >|$)", ci, flags=re.M)
    lists += re.findall(r'^\w+_PACKAGES="([^"]+)"', ci, flags=re.M)  # a list installed through a variable
    assert len(lists) >= 3, lists
    for pkgs in lists:
        for pkg in pkgs.split():
            assert pkg in section, f".ci/run installs {pkg}; README's tests section does not say so"


def test_the_get_going_commands_work(tmp_path):
    """The README's first commands, as a newcomer types them (after `pip install .`), in a folder of
    their own with the repository's example: each exits 0 (PASS for the simulated board)."""
    blocks = re.findall(r"```\n(.*?)```", _section("Install and get going"), flags=re.S)
    commands = [c.split("&&")[-1].strip() for b in blocks for c in b.strip().splitlines()]
    assert [c.split()[:2] for c in commands] == [["accelcal", "run"], ["accelcal", "fit"]], commands
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "poses.csv").write_bytes((ROOT / "examples" / "poses.csv").read_bytes())
    for c in commands:
        r = subprocess.run([sys.executable, "-m", "accelcal_station", *c.split()[1:]], cwd=tmp_path,
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, f"{c}: {r.stdout[-1500:]}{r.stderr[-1500:]}"
    assert (tmp_path / "accelcal-runs.sqlite").is_file()  # the run recorded where the README says


def test_the_readme_fits_the_example_with_the_model_its_data_support():
    """examples/make_example.py gives its board a cubic term (0.004, -0.006, 0.003 g/g^3), which only
    model 15 carries: the README's fit command must fit it with model 15 (fit's own choice), not
    force a model the data reject (model 12 left 0.857 mg RMS against model 15's 0.119 mg)."""
    assert "cubic * g**3" in (ROOT / "examples" / "make_example.py").read_text()
    (command,) = [c for b in re.findall(r"```\n(.*?)```", _section("Install and get going"), flags=re.S)
                  for c in b.strip().splitlines() if c.startswith("accelcal fit")]
    r = subprocess.run([sys.executable, "-m", "accelcal_station", *command.split()[1:], "--json"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-1500:]
    assert json.loads(r.stdout)["model"] == "15"


def test_every_pose_design_is_listed_in_the_commands_page():
    """docs/commands.md's design table names each design fixtures/designs.py has, with the model it
    was drawn up for (the pose names were in --help only)."""
    from accelcal_station.fixtures.designs import DESIGNS, design_model
    text = (ROOT / "docs" / "commands.md").read_text()
    rows = dict(re.findall(r"^\| `([\w-]+)` \| .+? \| (\d+)[^|]*\|$", text, flags=re.M))
    assert set(DESIGNS) <= set(rows), sorted(set(DESIGNS) - set(rows))
    for name in DESIGNS:
        if name != "optimal-N":
            assert rows[name] == design_model(name), name
    assert rows["optimal-N"] == design_model("optimal-4") == "12" and design_model("optimal-3") == "6"
