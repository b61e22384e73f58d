"""`accelcal probe`: identify the configured device, show its settings and a few averaged readings."""
from __future__ import annotations

import json

import click

from ..config.sections import device_section, with_port
from ..drivers.factory import make_driver
from ..errors import DeviceError
from ._common import Whole, jsonable


@click.command("probe")
@click.option("--config", "config_path", required=True, type=click.Path(dir_okay=False),
              help="Station YAML with a device: section (e.g. configs/mma8451-emulated.yaml).")
@click.option("--port", default=None, help="Override the serial port, or the I2C bus number / /dev/i2c-N.")
@click.option("--readings", default=3, show_default=True, type=Whole(1, 100),
              help="How many averaged readings to take.")
@click.option("--samples", default=32, show_default=True, type=Whole(1, 100000),
              help="Samples averaged per reading.")
@click.option("--scan", is_flag=True,
              help="Bring-up: list what answers on the device's I2C bus (behind each TCA9548A channel too), or "
                   "which serial ports answer the bridge or jig protocol (sends their identify commands).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def command(config_path: str, port: str | None, readings: int, samples: int, scan: bool, as_json: bool) -> None:
    """Identify the device in --config and print its configuration, temperature and averaged readings."""
    section = device_section(config_path)
    if port is not None and not (scan and section.driver == "mpu6050"):
        section = with_port(section, port)
    if scan:
        from ._scan import scan_command

        scan_command(section, port, getattr(section, "baud", 115200), as_json)
        return
    try:
        with make_driver(section) as dev:
            ident = dev.identify()
            settings = dev.settings()
            temp = dev.temperature_c()
            caps = [dev.capture(n=samples) for _ in range(readings)]
            cpg, rng, odr = dev.counts_per_g, dev.range_g, dev.odr_hz
    except OSError as e:  # a driver should not let one escape; if it does, still one line
        raise DeviceError(f"{section.driver}: {e.strerror or e}") from None
    result = {
        "chip": ident.chip, "chip_id": ident.chip_id, "interface": ident.interface, "serial": ident.serial,
        "firmware": ident.firmware, "range_g": rng, "odr_hz": odr, "counts_per_g": cpg, "settings": settings,
        "temperature_c": temp,
        "readings": [{"n": c.n, "dropped": c.dropped, "mean_counts": c.mean_counts, "std_counts": c.std_counts,
                      "mean_g": c.mean_counts / cpg, "t_start": c.t_start, "t_end": c.t_end} for c in caps],
    }
    if as_json:
        click.echo(json.dumps(jsonable(result)))
        return
    click.echo(f"device       {ident.chip} (chip id 0x{ident.chip_id:02X}) on {ident.interface}"
               + (f", serial {ident.serial}" if ident.serial else "")
               + (f", firmware {ident.firmware}" if ident.firmware else ""))
    click.echo(f"range        +-{rng} g, {cpg:g} counts/g")
    click.echo(f"data rate    {odr:g} Hz")
    for k, v in settings.items():
        click.echo(f"{k.replace('_', ' '):12s} {v}")
    click.echo(f"temperature  {'none: chip has no sensor' if temp is None else f'{temp:.2f} C'}")
    click.echo(f"readings     mean of {samples} samples each (counts | g | std counts)")
    for i, c in enumerate(caps, 1):
        cts = " ".join(f"{v:9.1f}" for v in c.mean_counts)
        g = " ".join(f"{v:+8.4f}" for v in c.mean_counts / cpg)
        sd = " ".join(f"{v:6.1f}" for v in c.std_counts)
        click.echo(f"  {i:2d}  {cts} | {g} | {sd}" + (f"  ({c.dropped} dropped)" if c.dropped else ""))
