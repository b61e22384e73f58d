"""`accelcal emulate mpu6050-bridge`: run the MPU6050 serial-bridge emulator on a new pseudo-terminal.

Prints the terminal's path and keeps answering on it until Ctrl-C or SIGTERM, so the
station can be tried end to end: point a config's ``port`` (or ``--port``) at the path.
"""
from __future__ import annotations

import json
import signal
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import click

from ..config.kinds import SimulatedBoardSection
from ..drivers.emulator_files import board_config_from_file, emulator_options_from_file
from ..drivers.mpu6050_emulator import MPU6050BridgeEmulator
from ..drivers.simulated import SimulatedBoard
from ._common import MAX_SEED, Finite, Whole

if TYPE_CHECKING:
    from ..drivers.mpu6050_simavr import SimavrBridge
    from ..fixtures.jig_emulator import JigEmulator

KINDS = ("mpu6050-bridge", "motor-jig", "chamber")


@click.command("emulate")
@click.argument("kind", type=click.Choice(KINDS))
@click.option("--seed", type=Whole(0, MAX_SEED), default=None,
              help="Seed of the simulated board (any seed it prints, which may be 128-bit).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Simulated board YAML (e.g. configs/sim.yaml); its chip becomes an MPU6050. An mpu6050 "
                   "station config's device.emulator sets the chip's faults (self_test_share, offset_step_scale).")
@click.option("--motor-jig", "with_jig", is_flag=True,
              help="mpu6050-bridge: also start a motorized jig emulator that turns the same board.")
@click.option("--jig-speed", type=Finite(1.0, 1e5), default=180.0, show_default=True,
              help="Jig axis speed in deg/s (motion runs in real time).")
@click.option("--firmware", "on_avr", is_flag=True,
              help="mpu6050-bridge: run the real bridge firmware on a simulated ATmega328P (simavr; built "
                   "by make -C firmware) instead of the Python emulator.")
@click.option("--speed", type=Finite(0.01, 1e6), default=60.0, show_default=True,
              help="chamber: its clock runs this many times faster than the wall clock.")
@click.option("--start-c", type=Finite(-70, 150), default=25.0, show_default=True,
              help="chamber: air temperature at start, C.")
@click.option("--air-tau-s", type=Finite(1, 1e5), default=240.0, show_default=True,
              help="chamber: air time constant toward the set point, s (chamber clock).")
@click.option("--min-air-c", type=Finite(-100, 300), default=None,
              help="chamber fault: the air never gets colder than this (set points below are never reached).")
@click.option("--alarm-at-s", type=Finite(0, 1e9), default=None,
              help="chamber fault: refrigeration alarm (code 3) at this chamber-clock time, s.")
@click.option("--door-open-at-s", type=Finite(0, 1e9), default=None,
              help="chamber fault: the door opens at this chamber-clock time for 60 s.")
@click.option("--json", "as_json", is_flag=True, help="Print the port(s) as one JSON object.")
def command(**opts: Any) -> None:
    """Start an emulated device (or jig) on a new pseudo-terminal and print its path; Ctrl-C stops it.

    \b
    mpu6050-bridge              the MPU6050 serial bridge (docs/bridge-protocol.md)
    mpu6050-bridge --motor-jig  the bridge plus a motorized jig holding the same board
    mpu6050-bridge --firmware   the real firmware in simavr (AVR toolchain and simavr needed)
    motor-jig                   a motorized two-axis jig alone (docs/jig-protocol.md)
    chamber                     a thermal chamber (docs/chamber-protocol.md) on an accelerated clock
    """
    o = EmulateCommand.from_click(opts)
    if o.kind == "chamber":
        _chamber(o.chamber, o.as_json)
        return
    from ..fixtures.jig_emulator import EmulatedAxes, JigEmulator

    board, bridge = _bridge(o.config_path, o.seed, o.on_avr) if o.kind == "mpu6050-bridge" else (None, None)
    jig: JigEmulator | None = None
    if o.kind == "motor-jig" or o.with_jig:
        jig = JigEmulator(EmulatedAxes(speed_deg_s=o.jig_speed, accel_deg_s2=o.jig_speed * 4), board=board,
                          board_lock=bridge.lock if bridge is not None else None)
    _serve(o.kind, bridge, jig, None if board is None else board.seed, o.on_avr, o.as_json)


@dataclass(frozen=True)
class ChamberScenario:
    """The chamber emulator's clock, air and the faults it is to show (chamber clock seconds, C)."""

    speed: float
    start_c: float
    air_tau_s: float
    min_air_c: float | None
    alarm_at_s: float | None
    door_open_at_s: float | None


@dataclass(frozen=True)
class EmulateCommand:
    """`accelcal emulate`'s options: which emulator, its board (config, seed; simavr), the jig, the chamber."""

    kind: str
    seed: int | None
    config_path: str | None
    with_jig: bool
    jig_speed: float
    on_avr: bool
    chamber: ChamberScenario
    as_json: bool

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> EmulateCommand:
        chamber = ChamberScenario(speed=o["speed"], start_c=o["start_c"], air_tau_s=o["air_tau_s"],
                                  min_air_c=o["min_air_c"], alarm_at_s=o["alarm_at_s"],
                                  door_open_at_s=o["door_open_at_s"])
        return cls(kind=o["kind"], seed=o["seed"], config_path=o["config_path"], with_jig=o["with_jig"],
                   jig_speed=o["jig_speed"], on_avr=o["on_avr"], chamber=chamber, as_json=o["as_json"])


def _serve(kind: str, bridge: SimavrBridge | MPU6050BridgeEmulator | None, jig: JigEmulator | None,
           seed: int | None, on_avr: bool, as_json: bool) -> None:
    """Start the bridge and/or the jig, print their ports, answer until Ctrl-C or SIGTERM, stop them."""
    with _stop_signals() as done:
        try:
            ports: dict[str, str] = {}
            if bridge is not None:
                ports["port"] = bridge.start()
            if jig is not None:
                ports["jig_port"] = jig.start()
            _announce(kind, ports, seed, on_avr, as_json)
            while not done.wait(0.2):
                pass
        finally:
            for e in (bridge, jig):
                if e is not None:
                    e.stop()
    if not as_json:
        click.echo("emulator stopped", err=True)


def _bridge(config_path: str | None, seed: int | None,
            on_avr: bool) -> tuple[SimulatedBoard, SimavrBridge | MPU6050BridgeEmulator]:
    """The simulated board (from --config, --seed) and the bridge serving it: simavr firmware or Python."""
    board_cfg, cfg_seed = board_config_from_file(config_path) if config_path else (None, None)
    board = SimulatedBoard.from_section(board_cfg or SimulatedBoardSection(), chip="mpu6050",
                                        seed=seed if seed is not None else cfg_seed,
                                        path=f"{config_path}: device" if config_path else "simulator")
    # the chip's faults from the config's device.emulator (self_test_share, offset_step_scale, ...)
    faults = emulator_options_from_file(config_path) if config_path else {}
    if on_avr:
        from ..drivers.mpu6050_simavr import SimavrBridge

        return board, SimavrBridge(board, **faults)
    return board, MPU6050BridgeEmulator(board, **faults)


@contextmanager
def _stop_signals() -> Iterator[threading.Event]:
    """An event that Ctrl-C (SIGINT) or SIGTERM sets; the previous handlers come back on leaving."""
    done = threading.Event()
    previous = {s: signal.signal(s, lambda *_: done.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield done
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def _announce(kind: str, ports: dict[str, str], seed: int | None, on_avr: bool, as_json: bool) -> None:
    """Print the emulators' ports (one JSON object, or lines saying what to try)."""
    if as_json:
        click.echo(json.dumps({"emulator": kind, **ports, "seed": seed}))
        return
    if "port" in ports:
        what = "bridge firmware in simavr" if on_avr else "bridge emulator"
        click.echo(f"MPU6050 {what} on {ports['port']} (seed {seed}; Ctrl-C to stop)")
    if "jig_port" in ports:
        click.echo(f"motorized jig emulator on {ports['jig_port']}")
    if "port" in ports and "jig_port" in ports:
        click.echo(f"try: accelcal run --config configs/mpu6050.yaml --port {ports['port']} "
                   f"--jig-port {ports['jig_port']}")
    elif "port" in ports:
        click.echo(f"try: accelcal probe --config configs/mpu6050.yaml --port {ports['port']}")


def _chamber(c: ChamberScenario, as_json: bool) -> None:
    """The chamber emulator, with the faults asked for, until Ctrl-C or SIGTERM."""
    from ..instruments.chamber_emulator import AcceleratedClock, ChamberEmulator, ChamberPhysics

    speed = c.speed
    emu = ChamberEmulator(ChamberPhysics(AcceleratedClock(speed), c.start_c, air_tau_s=c.air_tau_s))
    if c.min_air_c is not None:
        emu.limit_air(min_air_c=c.min_air_c)
    if c.alarm_at_s is not None:
        emu.alarm_at(c.alarm_at_s, 3)
    if c.door_open_at_s is not None:
        emu.open_door(c.door_open_at_s, 60.0)
    with _stop_signals() as done:
        try:
            port = emu.start()
            if as_json:
                click.echo(json.dumps({"emulator": "chamber", "chamber_port": port, "speed": speed}))
            else:
                click.echo(f"chamber emulator on {port} (clock x{speed:g}; Ctrl-C to stop)")
                click.echo(f"try: accelcal chamber set --temp-c -20 --port {port}; "
                           f"accelcal chamber status --port {port}")
            while not done.wait(0.2):
                pass
        finally:
            emu.stop()
    if not as_json:
        click.echo("emulator stopped", err=True)
