"""The `accelcal` command line.  Each command lives in its own module here and
exposes a click command named ``command``; they are discovered automatically."""
from __future__ import annotations

import importlib
import os
import pkgutil

import click

from .. import __version__
from ..errors import AccelcalError


class StationGroup(click.Group):
    """Turns every AccelcalError into one red line on stderr and its exit code."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except AccelcalError as e:
            click.secho(f"error: {e}", fg="red", err=True)
            ctx.exit(e.exit_code)
        except KeyboardInterrupt:
            click.echo("interrupted", err=True)
            ctx.exit(130)
        except (click.exceptions.Exit, click.ClickException, click.exceptions.Abort):
            raise
        except OSError as e:  # a file or device error no layer below turned into words
            where = f" ({e.filename})" if getattr(e, "filename", None) else ""
            click.secho(f"error: {e.strerror or e}{where}", fg="red", err=True)
            ctx.exit(2)
        except Exception as e:
            # a bug: still one line for the operator; the traceback on request
            if os.environ.get("ACCELCAL_DEBUG"):
                raise
            click.secho(f"internal error (please report): {type(e).__name__}: {e}; "
                        "set ACCELCAL_DEBUG=1 for the traceback", fg="red", err=True)
            ctx.exit(70)


@click.group(cls=StationGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="accelcal")
def cli() -> None:
    """accelcal: calibration station for three-axis MEMS accelerometers."""


for _m in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
    if _m.name.startswith("_"):
        continue
    _mod = importlib.import_module(f"{__name__}.{_m.name}")
    if hasattr(_mod, "command"):
        cli.add_command(_mod.command)


def main() -> None:
    """Console entry point."""
    cli(prog_name="accelcal")
