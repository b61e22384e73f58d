"""`accelcal probe --scan`: what answers on the configured device's bus (I2C: every address, the chip by
its WHO_AM_I, behind each TCA9548A channel by channel) or which serial ports answer the bridge or the
jig protocol (USB vendor, product and serial from pyserial's port list)."""
from __future__ import annotations

import json
from typing import Any

import click

from ..config.kinds import DeviceSection, Mma8451Device
from ..drivers.factory import make_driver
from ..drivers.i2c_scan import Found, scan_with_muxes
from ..errors import DeviceError
from ..station.panel_config import panel_sections
from ._common import jsonable


def i2c_bus_of(section: Mma8451Device) -> tuple[Any, str]:
    """The SMBus-like object to scan and its label: smbus2's SMBus on the configured bus, or the
    emulated bus the factory builds (``bus: emulated``: the chip's emulator, or the panel's mux)."""
    if section.bus != "emulated":
        from smbus2 import SMBus

        node = section.bus if isinstance(section.bus, str) else f"/dev/i2c-{section.bus}"
        try:
            return SMBus(node), node
        except OSError as e:
            raise DeviceError(f"i2c bus {section.bus}: cannot open {node}: {e.strerror or e}; list the buses "
                              "with `ls /dev/i2c-*` (Raspberry Pi: enable I2C in raspi-config)") from None
    if section.boards is None:
        # the emulated driver keeps its emulator beside it (drivers/emulated.py): the bus it talks to
        return getattr(make_driver(section), "emulator"), "emulated"  # noqa: B009 - declared on the emulated class only
    buses: dict[Any, Any] = {}
    for sec, path in panel_sections(section):
        make_driver(sec, path, buses)
    return next(iter(buses.values())).smbus, "emulated"


def probe_port(port: str, baud: int) -> str:
    """What answers on a serial port: the motorized jig (its ID: a text line, asked first because the
    bridge's binary frames would leave a text protocol's line half-read), the MPU6050 bridge
    (identified), or nothing."""
    from ..drivers.mpu6050 import MPU6050Bridge
    from ..fixtures.motorized_jig import JigAxes, JigLink, MotorizedJig

    jig = MotorizedJig(port, JigLink(baud=baud, timeout_s=0.3, retries=0), JigAxes(home_on_open=False))
    try:
        jig.open()
        return f"motorized jig, {jig.identity}"
    except DeviceError:
        pass
    finally:
        jig.close()
    bridge = MPU6050Bridge(port, baud=baud, timeout_s=0.3, retries=1, boot_wait_s=0.5)
    try:
        with bridge:
            ident = bridge.identify()
            return f"MPU6050 bridge, {ident.firmware}, chip id 0x{ident.chip_id:02x}, serial {ident.serial or '-'}"
    except DeviceError:
        return "no answer to the jig or the bridge protocol"


def serial_ports() -> list[dict[str, Any]]:
    """The serial ports pyserial lists, with USB vendor/product ids and serial (for udev rules)."""
    from serial.tools import list_ports

    return [{"port": p.device, "vid": None if p.vid is None else f"{p.vid:04x}",
             "pid": None if p.pid is None else f"{p.pid:04x}", "serial_number": p.serial_number,
             "description": p.description} for p in sorted(list_ports.comports(), key=lambda p: p.device)]


def scan_command(section: DeviceSection, port: str | None, baud: int, as_json: bool) -> None:
    """Scan what the config's device sits on and print it (module docstring)."""
    if isinstance(section, Mma8451Device):
        smbus, label = i2c_bus_of(section)
        try:
            found = scan_with_muxes(smbus)
        finally:
            close = getattr(smbus, "close", None)
            if close is not None:
                close()
        _print_i2c(label, found, as_json)
        return
    ports = serial_ports() if port is None else [{"port": port, "vid": None, "pid": None,
                                                  "serial_number": None, "description": "given with --port"}]
    for p in ports:
        p["answers"] = probe_port(str(p["port"]), baud)
    if as_json:
        click.echo(json.dumps(jsonable({"serial_ports": ports})))
        return
    if not ports:
        click.echo("no serial ports found (USB adapters: check `dmesg`; the user needs the dialout group)")
    for p in ports:
        usb = "" if p["vid"] is None else f" USB {p['vid']}:{p['pid']} serial {p['serial_number'] or '-'}"
        click.echo(f"{p['port']:20s}{usb}: {p['answers']}")


def _print_i2c(label: str, found: list[Found], as_json: bool) -> None:
    if as_json:
        click.echo(json.dumps({"bus": label, "found": [f.to_json() for f in found]}))
        return
    click.echo(f"i2c bus {label}: {len(found)} address(es) answer")
    for f in found:
        click.echo(f"  {f.line()}")
