"""What a manufacturing execution system (MES) reads: errors as one JSON object on stdout
under --json, and group commands that describe themselves as JSON."""
from __future__ import annotations

import functools
import json
from collections.abc import Callable, Iterable
from typing import Any, TypedDict

import click

from ._text import error_text


def wants_json(args: Iterable[str]) -> bool:
    """--json anywhere on the command line before a bare '--'."""
    for a in args:
        if a == "--":
            return False
        if a == "--json":
            return True
    return False


def emit_error(ctx: click.Context, message: str, code: int, kind: str) -> None:
    """One line: red on stderr, or under --json one JSON object on stdout (nothing else there).
    The one place errors are printed: control characters escaped, long quoted values cut (_text.error_text)."""
    message = error_text(message)
    if ctx.meta.get("accelcal.json"):
        click.echo(json.dumps({"error": message, "code": code, "kind": kind}))
    else:
        click.secho(f"error: {message}" if kind != "internal" else message, fg="red", err=True)


class SubcommandDoc(TypedDict):
    name: str
    help: str


class CommandsDoc(TypedDict):
    """A group's subcommands as JSON (a bare group's --json)."""

    command: str
    help: str
    subcommands: list[SubcommandDoc]


def commands_doc(group: click.Group, ctx: click.Context) -> CommandsDoc:
    """A group's subcommands as JSON: name and one-line help of each."""
    return {"command": ctx.command_path, "help": (group.help or "").strip().split("\n")[0],
            "subcommands": [{"name": n, "help": group.commands[n].get_short_help_str(200)}
                            for n in group.list_commands(ctx)]}


WHOLE = 10**6  # a short-help limit no first sentence reaches: --help lists whole summaries


class JsonGroup(click.Group):
    """A group that, called bare with --json, prints its subcommands as one JSON object."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        kw.setdefault("invoke_without_command", True)
        super().__init__(*a, **kw)
        self.params.append(click.Option(["--json", "group_json"], is_flag=True,
                                         help="Called without a subcommand: print the subcommands as JSON."))
        cb: Callable[..., Any] = self.callback or (lambda **k: None)

        def callback(*args: Any, group_json: bool = False, **kwargs: Any) -> Any:
            ctx = click.get_current_context()
            if ctx.invoked_subcommand is None:  # bare: describe (JSON) or help, nothing else
                click.echo(self.describe(ctx) if group_json else ctx.get_help())
                ctx.exit(0)
            return cb(*args, **kwargs)

        self.callback = functools.update_wrapper(callback, cb)

    def describe(self, ctx: click.Context) -> str:
        """What the bare group prints under --json, as JSON text (a subclass may list something else)."""
        return json.dumps(commands_doc(self, ctx))

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The Commands: section with each subcommand's whole first sentence, wrapped (click's own cuts
        it at the terminal's width, mid-sentence, with '...')."""
        rows = [(n, cmd.get_short_help_str(WHOLE)) for n in self.list_commands(ctx)
                if (cmd := self.get_command(ctx, n)) is not None and not cmd.hidden]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)
