"""`--help`'s Commands: section gives each command's one-line summary whole: the first sentence of
its help, wrapped, never cut mid-sentence with '...' (click cuts it at the terminal's width)."""
from __future__ import annotations

import re

import click
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli


def _groups() -> dict[str, click.Group]:
    """Every group of the command line by its path (accelcal, accelcal report, ...)."""
    ctx = click.Context(cli, info_name="accelcal")
    out: dict[str, click.Group] = {"accelcal": cli}
    for name in cli.list_commands(ctx):
        cmd = cli.get_command(ctx, name)
        if isinstance(cmd, click.Group):
            out[f"accelcal {name}"] = cmd
    return out


def _first_sentence(help_text: str) -> str:
    """The help's first sentence, read from the docstring itself: its first paragraph up to the first
    '. ' (or the paragraph's end), whitespace joined."""
    para = " ".join(help_text.strip().split("\n\n", 1)[0].split())
    m = re.match(r"(.*?\.)(?: |$)", para)
    return m.group(1) if m else para


def _listed(help_out: str) -> dict[str, str]:
    """name -> summary from a --help page's Commands: section, wrapped lines joined."""
    section = help_out.split("\nCommands:\n", 1)[1]
    rows: dict[str, str] = {}
    name = ""
    for line in section.splitlines():
        if m := re.match(r"^  (\S+)\s+(.*)$", line):
            name, rows[m.group(1)] = m.group(1), m.group(2)
        elif line.startswith("    ") and name:
            rows[name] += " " + line.strip()
    return rows


GROUPS = _groups()


def test_the_groups_are_found():
    assert {"accelcal", "accelcal report", "accelcal twin", "accelcal nvm"} <= set(GROUPS)


@pytest.mark.parametrize("path", sorted(GROUPS))
def test_every_summary_in_help_is_whole(path: str):
    r = CliRunner().invoke(cli, [*path.split()[1:], "--help"], terminal_width=80)
    assert r.exit_code == 0, r.output
    rows = _listed(r.output)
    group = GROUPS[path]
    ctx = click.Context(group, info_name=path.split()[-1])
    names = [n for n in group.list_commands(ctx) if not group.get_command(ctx, n).hidden]
    assert sorted(rows) == sorted(names), rows
    for n, summary in rows.items():
        assert not summary.endswith("..."), f"{path} {n}: {summary!r}"
        assert summary == _first_sentence(group.get_command(ctx, n).help or ""), f"{path} {n}"
        assert summary.endswith("."), f"{path} {n}: not a whole sentence: {summary!r}"
