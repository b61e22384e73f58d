"""`accelcal chamber`: look at a thermal chamber or set it by hand (docs/chamber-protocol.md)."""
from __future__ import annotations

import json

import click

from ..instruments.chamber import AsciiChamber, require_pyvisa
from ._common import Finite, Whole


@click.command("chamber")
@click.argument("action", type=click.Choice(("status", "set", "standby", "clear")))
@click.option("--temp-c", type=Finite(-100.0, 300.0), default=None, help="set: the set point, C (-100 to 300).")
@click.option("--port", required=True, help="Serial device, host:port or VISA resource of the chamber.")
@click.option("--baud", type=Whole(300, 1_000_000), default=9600, show_default=True)
@click.option("--timeout-s", type=Finite(0.01, 60), default=1.0, show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def command(action: str, temp_c: float | None, port: str, baud: int, timeout_s: float, as_json: bool) -> None:
    """Chamber status, set point (`set --temp-c C`: constant mode at C), standby, or clear latched alarms."""
    if (action == "set") != (temp_c is not None):
        raise click.UsageError("give --temp-c with `set` only: accelcal chamber set --temp-c -20 --port P")
    require_pyvisa("accelcal chamber")
    with AsciiChamber(port, baud, timeout_s) as ch:
        if temp_c is not None:  # action == "set": checked above
            ch.set_point(temp_c)
        elif action == "standby":
            ch.standby()
        elif action == "clear":
            ch.clear_alarms()
        st = ch.status()
        ident = ch.identify()
    out = {"port": port, "type": ident, "air_c": st.air_c, "mode": st.mode, "alarms": list(st.alarms),
           "door_open": st.door_open}
    if temp_c is not None:
        out["set_point_c"] = temp_c
    if as_json:
        click.echo(json.dumps(out))
    else:
        click.echo(f"chamber {ident} on {port}: air {st.air_c:.1f} C, {st.mode}"
                   + (f", set point {temp_c:g} C" if temp_c is not None else "")
                   + (f", alarms {st.alarm_text()}" if st.alarms else ", no alarms"))
