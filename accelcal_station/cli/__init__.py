"""The `accelcal` command line.  Each command lives in its own module here and exposes a
click command named ``command``, listed in ``COMMANDS`` with its one-line help and loaded
only when it is run (click's lazy group pattern): ``accelcal --version`` and ``--help``
import click and this package's small helpers, no numpy, scipy or pydantic.

The top layer: may import every package below it (``api``, the flows, the parts, the
models, the foundation); only ``accelcal_station.__main__`` imports the CLI.
"""
from __future__ import annotations

import importlib
import json
import os
import sys
from typing import Any

import click

from .. import __version__
from ..config import event_log
from ..errors import AccelcalError
from ._mes import WHOLE, CommandsDoc, JsonGroup, emit_error, wants_json
from ._text import clean

# name -> (module:attribute, one-line help as the command's docstring gives it); a test
# (tests/test_cli_lazy.py) checks every module of this package with a ``command`` is listed
# and that each help here is the command's own
COMMANDS: dict[str, tuple[str, str]] = {
    "batch": ("batch:command", "Recalibrate many boards with one model (vectorised); unfittable boards are "
              "reported and skipped."),
    "chamber": ("chamber:command", "Chamber status, set point (`set --temp-c C`: constant mode at C), standby, "
                "or clear latched alarms."),
    "diagnose": ("diagnose:command", "Diagnose the sim-to-real gap of real data against the simulator "
                 "configuration."),
    "emulate": ("emulate:command", "Start an emulated device (or jig) on a new pseudo-terminal and print its "
                "path; Ctrl-C stops it."),
    "fit": ("fit:command", "Fit a calibration to a pose table (CSV) or, with --raw, a raw sample log."),
    "nvm": ("nvm:command", "Read, back up, restore or erase the calibration NVM of a board (service)."),
    "poses": ("poses:command", "Show pose design NAME (AN4399 pitch/roll, where the board goes) and its "
              "predicted standard errors."),
    "probe": ("probe:command", "Identify the device in --config and print its configuration, temperature and "
              "averaged readings."),
    "report": ("report:command", "List, show, export and summarise recorded runs."),
    "run": ("run:command", "Calibrate one board: identify, present each pose, capture, fit, judge, write NVM, "
            "verify, record."),
    "serve": ("serve:command", "Serve the line page (/), board and lot pages and the JSON API (/api/v1, schema "
              "at /openapi.json)."),
    "simulate": ("simulate:command", "Simulate a calibration run and write its pose table (or raw log) and "
                 "ground truth."),
    "twin": ("twin:command", "The population twin: fit a lot's population, check it against the lot, predict "
             "yield."),
}


class LazyGroup(JsonGroup):
    """A group whose subcommands (``lazy_subcommands``: name -> (module:attribute, one-line help))
    are imported when invoked or asked for by name; listing them, in --help or --json, uses the
    help given here and imports nothing (the click documentation's LazyGroup pattern)."""

    def __init__(self, *a: Any, lazy_subcommands: dict[str, tuple[str, str]] | None = None, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self.lazy_subcommands = lazy_subcommands or {}

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy_subcommands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.lazy_subcommands and cmd_name not in self.commands:
            target = self.lazy_subcommands[cmd_name][0]
            module, attr = target.split(":")
            cmd = getattr(importlib.import_module(f"{__name__}.{module}"), attr)
            if not isinstance(cmd, click.Command):
                raise TypeError(f"{target} is not a click command")
            self.commands[cmd_name] = cmd
        return super().get_command(ctx, cmd_name)

    def listed_help(self, name: str, limit: int) -> str:
        """A subcommand's one-line help cut to ``limit`` as click cuts it, without importing it."""
        cmd = self.commands.get(name)
        if cmd is None:  # a stand-in with the stored help: click's own cutting, whatever its version
            cmd = click.Command(name, help=self.lazy_subcommands[name][1])
        return cmd.get_short_help_str(limit)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The Commands: section from the stored help, each summary whole and wrapped (JsonGroup's)."""
        names = self.list_commands(ctx)
        if not names:
            return
        with formatter.section("Commands"):
            formatter.write_dl([(n, self.listed_help(n, WHOLE)) for n in names])

    def describe(self, ctx: click.Context) -> str:
        doc: CommandsDoc = {"command": ctx.command_path, "help": (self.help or "").strip().split("\n")[0],
                            "subcommands": [{"name": n, "help": self.listed_help(n, 200)}
                                            for n in self.list_commands(ctx)]}
        return json.dumps(doc)


class StationGroup(LazyGroup):
    """Turns every AccelcalError into one line and its exit code: red on stderr, or under
    --json one JSON object on stdout (cli/_mes.py)."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        ctx.meta["accelcal.json"] = wants_json(args)
        try:
            return super().parse_args(ctx, args)
        except click.UsageError as e:  # `accelcal --bogus`: the same one line as every other error
            emit_error(ctx, f"{e.format_message()} (see accelcal --help)", e.exit_code, "usage")
            ctx.exit(e.exit_code)

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except AccelcalError as e:
            emit_error(ctx, clean(str(e)), e.exit_code, type(e).__name__)
            ctx.exit(e.exit_code)
        except KeyboardInterrupt:
            emit_error(ctx, "interrupted", 130, "interrupted")
            ctx.exit(130)
        except click.exceptions.Exit:
            raise
        except click.ClickException as e:  # usage errors too: one line, with where to look
            sub = getattr(e, "ctx", None)
            hint = f" (see {sub.command_path} --help)" if isinstance(e, click.UsageError) and sub else ""
            emit_error(ctx, clean(e.format_message()) + hint, e.exit_code, "usage")
            ctx.exit(e.exit_code)
        except click.exceptions.Abort:
            raise
        except BrokenPipeError:
            raise  # the reader went away (| head): main() ends quietly
        except OSError as e:  # a file or device error no layer below turned into words
            where = f" ({e.filename})" if getattr(e, "filename", None) else ""
            emit_error(ctx, clean(f"{e.strerror or e}{where}"), 2, "os")
            ctx.exit(2)
        except ModuleNotFoundError as e:
            from ._extras import extra_for, missing_text  # importlib.metadata: only on this path

            extra = extra_for(e.name)
            if extra is None and not os.environ.get("ACCELCAL_DEBUG"):
                emit_error(ctx, f"internal error (please report): ModuleNotFoundError: {clean(str(e))}", 70,
                           "internal")
                ctx.exit(70)
            if extra is None:
                raise
            emit_error(ctx, missing_text(str(e.name)), 2, "missing_extra")  # an optional part not installed
            ctx.exit(2)
        except Exception as e:
            # a bug: still one line for the operator; the traceback on request
            if os.environ.get("ACCELCAL_DEBUG"):
                raise
            emit_error(ctx, f"internal error (please report): {type(e).__name__}: {clean(str(e))}; "
                       "set ACCELCAL_DEBUG=1 for the traceback", 70, "internal")
            ctx.exit(70)


@click.group(cls=StationGroup, context_settings={"help_option_names": ["-h", "--help"]},
             lazy_subcommands=COMMANDS)
@click.version_option(__version__, prog_name="accelcal")
def cli() -> None:
    """accelcal: calibration station for three-axis MEMS accelerometers."""
    event_log.configure(None)  # the outbox's notices on stderr; `run` applies its config's logging:


def main() -> None:
    """Console entry point; output piped into a reader that stops early (| head) ends quietly."""
    try:
        cli(prog_name="accelcal")
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # Python's own flush at exit must not complain either
        sys.exit(0)
