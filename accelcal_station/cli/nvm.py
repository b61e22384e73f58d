"""`accelcal nvm read|backup|restore|erase`: service access to a board's calibration NVM.

Every command opens the device of a station config (``--config``, default
configs/sim.yaml) and works on its A/B calibration slots (writer.CalibrationWriter).
Nothing is ever overwritten without a backup first: ``restore`` and ``erase`` save
the NVM's current image before writing (``--backup-to FILE``, else an automatic
``nvm-backup-SERIAL-UTCSTAMP.json`` next to the restored image, or in the current
folder for ``erase``), and a backup file is never overwritten.

The NVM of a simulated board (and of the emulated I2C bus) lives in its process:
each command builds a fresh board from the config.  A program that owns a device
(a station GUI, a test) runs these commands on it by passing it as ``obj={"driver": drv}``
to the click command.
"""
from __future__ import annotations

import json
import re
import time as _time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import click
import numpy as np

from ..config.sections import device_section
from ..drivers.base import Driver
from ..drivers.factory import make_driver
from ..errors import DeviceError, NVMError
from ..nvm.writer import CalibrationWriter, SlotStatus
from ..store.records import iso
from ._common import config_store_file
from ._common import jsonable as _clean
from ._mes import JsonGroup
from ._nvm_backup import check_backup_slots, check_new_file
from ._outputs import refuse_output

STATE_COLOUR = {"valid": "green", "empty": "yellow", "corrupt": "red"}

F = TypeVar("F", bound=Callable[..., Any])


@contextmanager
def _device(ctx: click.Context, config_path: str | None) -> Iterator[tuple[Driver, CalibrationWriter]]:
    """(driver, board serial, CalibrationWriter) of the device in ``ctx.obj['driver']`` or the config."""
    injected = (ctx.obj or {}).get("driver") if isinstance(ctx.obj, dict) else None
    if injected is not None:
        dev = injected
    else:
        from ..config.sections import default_config_path

        section = device_section(config_path or str(default_config_path()))
        # the image is written on every page write: never a store the command reaches (checked before
        # the driver reads it)
        refuse_output([("device.eeprom.image", getattr(getattr(section, "eeprom", None), "image", None))],
                      [("--config", config_path)], config=config_path)
        dev = make_driver(section)
    image = getattr(dev.nvm, "image_path", None)
    ctx.meta["accelcal.nvm_inputs"] = [("--config", config_path), ("the board's EEPROM image", image),
                                       ("the store", config_store_file(config_path))]
    try:
        with dev:
            if dev.nvm is None:
                raise NVMError(f"{dev.identify().interface}: the device has no NVM (device.eeprom is off); "
                               "nothing to read or write")
            yield dev, CalibrationWriter(dev.nvm)
    except OSError as e:  # a driver should not let one escape; if it does, still one line
        raise DeviceError(f"{getattr(dev, 'name', 'device')}: {e.strerror or e}") from None


def _refuse_over_inputs(ctx: click.Context, output: tuple[str, str | Path], *inputs: tuple[str, str | None]) -> None:
    """A backup never replaces the config, the board's EEPROM image, the store, the restored image or an
    SQLite database (exit 2, fileguard.kind); any other existing file is refused by the writer (backups
    are never overwritten)."""
    refuse_output([output], [*ctx.meta.get("accelcal.nvm_inputs", []), *inputs])


def _serial(dev: Driver, given: str | None) -> str | None:
    """The board's serial: --serial, else the device's identity (None when it has none)."""
    return given or dev.identify().serial or None


def auto_backup_path(folder: Path, serial: str | None) -> Path:
    """``nvm-backup-SERIAL-UTCSTAMP.json`` in ``folder``, with -2, -3... rather than overwrite a file."""
    tag = re.sub(r"[^A-Za-z0-9._-]+", "_", serial or "board")
    base = f"nvm-backup-{tag}-{_time.strftime('%Y%m%dT%H%M%SZ', _time.gmtime())}"
    path, n = folder / f"{base}.json", 1
    while path.exists():
        n += 1
        path = folder / f"{base}-{n}.json"
    return path


def _snapshot(dev: Driver, writer: CalibrationWriter, serial: str | None) -> dict[str, Any]:
    """Identity, slot status and the newest valid calibration (None when neither slot is valid)."""
    ident = dev.identify()
    newest = writer.read_newest()
    doc: dict[str, Any] = {"device": {"chip": ident.chip, "interface": ident.interface, "serial": ident.serial},
           "board_serial": serial, "slot_size": writer.slot_size, "base_addr": writer.base_addr,
           "slots": [s.to_dict() for s in writer.status()], "newest": None}
    if newest is not None:
        cal, h, slot = newest
        doc["newest"] = {"slot": slot, "model": h.model, "generation": h.generation, "serial": h.serial,
                         "serial_match": None if serial is None else h.serial == serial,
                         "station_id": h.station_id, "time": h.time, "time_iso": iso(h.time),
                         "W": cal.W, "V": cal.V, "Gamma": cal.Gamma, "input_units": cal.input_units,
                         "input_per_g": cal.input_per_g,
                         "temperature_points": 0 if cal.temperature is None else len(cal.temperature.temps_c),
                         "calibration": cal.to_dict()}
    return doc


def _slot_line(s: dict) -> str:
    state = click.style(f"{s['state']:7}", fg=STATE_COLOUR[s["state"]])
    if s["state"] == "valid":
        detail = (f"generation {s['generation']}, model {s['model']}, serial {s['serial']}, "
                  f"station {s['station_id']}, {iso(s['time'])}" + ("  (newest)" if s["newest"] else ""))
    else:
        detail = s["error"] if s["state"] == "corrupt" else ""
    return f"slot {s['slot']}  {state} {detail}".rstrip()


def _vec(v: Any) -> str:
    return "[" + " ".join(f"{x:+.6f}" for x in np.asarray(v, float)) + "]"


def _snapshot_text(doc: dict) -> list[str]:
    d = doc["device"]
    lines = [f"device  {d['chip']} on {d['interface']}" + (f", serial {d['serial']}" if d["serial"] else "")
             + f"; slots of {doc['slot_size']} bytes from address {doc['base_addr']}"]
    lines += [_slot_line(s) for s in doc["slots"]]
    n = doc["newest"]
    if n is None:
        lines.append(click.style("no valid calibration in NVM", fg="yellow"))
        return lines
    units = f"{n['input_units']}" + (f" at {n['input_per_g']:g} per g" if n["input_units"] != "g" else "")
    lines.append(f"newest  slot {n['slot']}: model {n['model']}, generation {n['generation']}, "
                 f"serial {n['serial']}, station {n['station_id']}, written {n['time_iso']}, input {units}"
                 + (f", {n['temperature_points']} temperature points" if n["temperature_points"] else ""))
    if n["serial_match"] is False:
        lines.append(click.style(f"warning: bound to serial {n['serial']!r}, not this board's "
                                 f"{doc['board_serial']!r}", fg="yellow", bold=True))
    lines += [f"W     = {_vec(n['W'][0])}", f"        {_vec(n['W'][1])}", f"        {_vec(n['W'][2])}",
              f"V     = {_vec(n['V'])} g", f"Gamma = {_vec(n['Gamma'])}"]
    return lines


def _emit(as_json: bool, doc: Mapping[str, object], lines: list[str]) -> None:
    if as_json:
        click.echo(json.dumps(_clean(doc), allow_nan=False))
    else:
        click.echo("\n".join(lines))


def _config_option(f: F) -> F:
    return click.option("--config", "config_path", default=None, type=click.Path(dir_okay=False),
                        help="Station YAML with a device: section (default configs/sim.yaml).")(f)


def _json_option(f: F) -> F:
    return click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")(f)


@click.group("nvm", cls=JsonGroup)
def command() -> None:
    """Read, back up, restore or erase the calibration NVM of a board (service)."""


@command.command("read")
@_config_option
@click.option("--serial", default=None, metavar="SN", help="The board's serial (default: the device's own).")
@_json_option
@click.pass_context
def read_cmd(ctx: click.Context, config_path: str | None, serial: str | None, as_json: bool) -> None:
    """Slot status and the newest valid calibration."""
    with _device(ctx, config_path) as (dev, writer):
        doc = _snapshot(dev, writer, _serial(dev, serial))
    _emit(as_json, doc, _snapshot_text(doc))


@command.command("backup")
@_config_option
@click.option("--out", "out", default=None, type=click.Path(dir_okay=False),
              help="Backup file (never overwritten; default nvm-backup-SERIAL-UTCSTAMP.json here).")
@_json_option
@click.pass_context
def backup_cmd(ctx: click.Context, config_path: str | None, out: str | None, as_json: bool) -> None:
    """Save both slots' raw image (with CRC-32) to a JSON file."""
    with _device(ctx, config_path) as (dev, writer):
        path = Path(out) if out else auto_backup_path(Path("."), _serial(dev, None))
        _refuse_over_inputs(ctx, ("--out", out or path))  # as given: Path() would fold a URL's "//"
        check_new_file("--out", path)
        summary = writer.backup(path, chip=dev.identify().chip)
    doc = {**summary, "path": str(path)}
    states = ", ".join(f"slot {s['slot']} {s['state']}" for s in summary["slots"])
    _emit(as_json, doc, [click.style(f"backup written to {path}", fg="green") +
                         f" ({doc['length']} bytes, CRC-32 0x{doc['crc32']:08x}; {states})"])


@command.command("restore")
@click.argument("image", type=click.Path(dir_okay=False))
@_config_option
@click.option("--serial", default=None, metavar="SN", help="The board's serial (default: the device's own).")
@click.option("--backup-to", default=None, type=click.Path(dir_okay=False),
              help="Save the current NVM here first (default: nvm-backup-SERIAL-UTCSTAMP.json next to IMAGE).")
@click.option("--any-serial", "--force", "any_serial", is_flag=True,
              help="Restore an image whose calibration is bound to another board's serial.")
@_json_option
@click.pass_context
def restore_cmd(ctx: click.Context, image: str, config_path: str | None, serial: str | None, backup_to: str | None,
                any_serial: bool, as_json: bool) -> None:
    """Write a backup IMAGE back to the NVM (after backing up what is there) and verify it."""
    with _device(ctx, config_path) as (dev, writer):
        sn = _serial(dev, serial)
        backup = Path(backup_to) if backup_to else auto_backup_path(Path(image).resolve().parent, sn)
        _refuse_over_inputs(ctx, ("--backup-to", backup_to or backup), ("IMAGE", image))
        check_new_file("--backup-to", backup)
        check_backup_slots(writer, image)  # each slot's own CRC, before anything is written
        writer.restore(image, serial=sn, allow_other_serial=any_serial, backup_to=backup, chip=dev.identify().chip)
        doc = _snapshot(dev, writer, sn)
    doc.update(restored=str(image), backup=str(backup))
    _emit(as_json, doc, [click.style(f"restored {image}", fg="green") + f" (previous contents saved to {backup})",
                         *_snapshot_text(doc)])


def _confirm(ctx: click.Context, question: str) -> bool:
    """The operator's yes; no answer at all (end of input, Ctrl-C) is a no with its reason, never a bare 'Aborted!'."""
    try:
        return click.confirm(question, err=True)
    except click.exceptions.Abort:
        click.echo("\nno confirmation (end of input): nothing erased", err=True)
        ctx.exit(1)
        raise  # not reached: ctx.exit raises


@command.command("erase")
@_config_option
@click.option("--backup-to", default=None, type=click.Path(dir_okay=False),
              help="Save the NVM here first (default: nvm-backup-SERIAL-UTCSTAMP.json in the current folder).")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
@_json_option
@click.pass_context
def erase_cmd(ctx: click.Context, config_path: str | None, backup_to: str | None, yes: bool, as_json: bool) -> None:
    """Erase both calibration slots (after a backup); asks first unless --yes."""
    with _device(ctx, config_path) as (dev, writer):
        sn = _serial(dev, None)
        backup = Path(backup_to) if backup_to else auto_backup_path(Path("."), sn)
        _refuse_over_inputs(ctx, ("--backup-to", backup_to or backup))
        check_new_file("--backup-to", backup)
        valid = sum(s.state == "valid" for s in writer.status())
        if not yes and not _confirm(ctx, f"Erase both calibration slots of {sn or 'this board'} "
                                         f"({valid} valid calibration(s)); backup to {backup} first?"):
            click.echo("erase cancelled; nothing was written", err=True)
            ctx.exit(1)
        slots: list[SlotStatus] = writer.erase(backup_to=backup, chip=dev.identify().chip)
        doc = _snapshot(dev, writer, sn)
    doc["backup"] = str(backup)
    _emit(as_json, doc, [click.style("erased both slots", fg="green") + f" (previous contents saved to {backup})",
                         *(_slot_line(s.to_dict()) for s in slots)])
