"""The `accelcal` command line.  Each command lives in its own module here and
exposes a click command named ``command``; they are discovered automatically.

The top layer: may import every package below it (``api``, the flows, the parts, the
models, the foundation); only ``accelcal_station.__main__`` imports the CLI.
"""
from __future__ import annotations

import importlib
import os
import pkgutil
import sys
from typing import Any

import click

from .. import __version__
from ..config import event_log
from ..errors import AccelcalError
from ._extras import extra_for, missing_text
from ._mes import JsonGroup, emit_error, wants_json
from ._text import clean


class StationGroup(JsonGroup):
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


@click.group(cls=StationGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="accelcal")
def cli() -> None:
    """accelcal: calibration station for three-axis MEMS accelerometers."""
    event_log.configure(None)  # the outbox's notices on stderr; `run` applies its config's logging:


for _m in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
    if _m.name.startswith("_"):
        continue
    _mod = importlib.import_module(f"{__name__}.{_m.name}")
    if hasattr(_mod, "command"):
        cli.add_command(_mod.command)


def main() -> None:
    """Console entry point; output piped into a reader that stops early (| head) ends quietly."""
    try:
        cli(prog_name="accelcal")
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # Python's own flush at exit must not complain either
        sys.exit(0)
