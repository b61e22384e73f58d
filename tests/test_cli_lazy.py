"""The command line loads its commands lazily: the list in cli/__init__.py (COMMANDS) names every
command module with its own help, and `accelcal --version` / `--help` import no heavy package."""
from __future__ import annotations

import ast
import importlib
import json
import pkgutil
import subprocess
import sys

import click
import pytest

import accelcal_station.cli as cli_pkg
from accelcal_station.cli import COMMANDS, cli

HEAVY = ("numpy", "scipy", "pydantic", "sqlalchemy", "pyarrow", "yaml", "accelcal_station.api")


def _command_modules() -> dict[str, click.Command]:
    out = {}
    for m in pkgutil.iter_modules(cli_pkg.__path__):
        if m.name.startswith("_"):
            continue
        mod = importlib.import_module(f"accelcal_station.cli.{m.name}")
        if isinstance(getattr(mod, "command", None), click.Command):
            out[m.name] = mod.command
    return out


def test_every_command_module_is_listed_with_its_own_help() -> None:
    found = _command_modules()
    by_name = {cmd.name: (mod, cmd) for mod, cmd in found.items()}
    assert set(by_name) == set(COMMANDS), "a command module is missing from COMMANDS (or listed but gone)"
    for name, (target, short) in COMMANDS.items():
        mod, cmd = by_name[name]
        assert target == f"{mod}:command"
        assert short == cmd.get_short_help_str(10**6), f"COMMANDS[{name!r}] help differs from the command's"


def _heavy_after(args: list[str]) -> tuple[list[str], str]:
    code = ("import sys\nfrom accelcal_station.cli import cli\n"
            f"try:\n    cli.main({args!r}, prog_name='accelcal')\nexcept SystemExit:\n    pass\n"
            f"print(repr(sorted(m for m in {HEAVY!r} if m in sys.modules)))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    lines = p.stdout.strip().splitlines()
    return ast.literal_eval(lines[-1]), "\n".join(lines[:-1])


@pytest.mark.parametrize("args", [["--version"], ["--help"], ["--json"]])
def test_version_and_help_import_nothing_heavy(args: list[str]) -> None:
    heavy, out = _heavy_after(args)
    assert heavy == [], f"accelcal {' '.join(args)} imported {heavy}"
    if args == ["--help"]:  # every command listed, with the start of its help
        for name, (_, short) in COMMANDS.items():
            line = next(ln for ln in out.splitlines() if ln.strip().startswith(name + " "))
            assert short.split()[0] in line
    if args == ["--json"]:
        doc = json.loads(out)
        assert [s["name"] for s in doc["subcommands"]] == sorted(COMMANDS)
        assert all(s["help"] == COMMANDS[s["name"]][1] for s in doc["subcommands"])


def test_a_command_is_loaded_when_run() -> None:
    ctx = click.Context(cli)
    assert isinstance(cli.get_command(ctx, "poses"), click.Command)
    assert cli.get_command(ctx, "no-such-command") is None
