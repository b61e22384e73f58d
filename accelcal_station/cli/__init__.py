"""The `accelcal` command line.  Each command lives in its own module here and
exposes a click command named ``command``; they are discovered automatically."""
from __future__ import annotations

import importlib
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
