"""The real bridge firmware on a simulated ATmega328P (simavr), as a port source for MPU6050Bridge.

``make -C firmware`` builds the sketch with the Debian AVR toolchain (arduino-mk) and the
harness firmware/sim/mpu6050_sim.c on libsimavr.  :class:`SimavrBridge` starts the harness
on the built ELF and returns the path of the pseudo-terminal wired to the MCU's UART0;
pyserial opens it as it would /dev/ttyUSB0.  Behind the firmware's TWI sits the harness's
MPU6050 register model; whenever the firmware bursts the data registers (0x3B) and no
sample is queued, the harness asks ("NEED") and waits, simulated time standing still,
while this module answers with one sample of the project's simulated sensor
(``SimulatedBoard.read``, counts at the range the firmware configured) -- so a jig
emulator that turns the board turns what the firmware reads.  The NVM is the AVR's own
EEPROM in simavr.

Same lifecycle as :class:`MPU6050BridgeEmulator` (``start()`` -> port, ``stop()``, ``lock``,
``board``), so ``MPU6050Bridge(port, emulator=SimavrBridge(board))`` and the station's
jig emulator use it unchanged.
"""
from __future__ import annotations

import functools
import os
import queue
import shutil
import subprocess
import threading
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, DeviceError
from .mpu6050 import ACCEL_RATE_HZ, CHIP_ID, rate_base_hz

FIRMWARE_DIR = Path(os.environ.get("ACCELCAL_FIRMWARE_DIR", Path(__file__).resolve().parents[1] / "firmware"))
ELF = FIRMWARE_DIR / "build" / "mpu6050_bridge" / "mpu6050_bridge.elf"
HARNESS = FIRMWARE_DIR / "build" / "mpu6050_sim"
TOOLS = ("avr-gcc", "make", "cc", "pkg-config")
START_TIMEOUT_S = 10.0
TEMP_OFFSET_C, TEMP_LSB_PER_C = 36.53, 340.0  # TEMP_OUT = (T - 36.53) * 340 (register map 4.18)


@functools.lru_cache(maxsize=1)
def unavailable_reason() -> str | None:
    """Why the simavr bridge cannot run here (None if it can, building it once if need be)."""
    if ELF.is_file() and HARNESS.is_file():
        return None
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        return (f"AVR toolchain / simavr not installed (missing {', '.join(missing)}); apt-get install gcc-avr "
                "avr-libc arduino-core-avr arduino-mk simavr libsimavr-dev libsimavrparts1 libelf-dev pkg-config")
    r = subprocess.run(["make", "-C", str(FIRMWARE_DIR)], capture_output=True, text=True)
    if r.returncode != 0:
        last = (r.stdout + r.stderr).strip().splitlines()[-1:] or ["no output"]
        return f"make -C {FIRMWARE_DIR} failed: {last[0]}"
    return None


class SimavrBridge:
    """The bridge firmware in simavr on a pseudo-terminal, fed by a SimulatedBoard."""

    def __init__(self, board: Any = None, seed: int | None = None, factory_offsets: Sequence[int] = (1001, -2000, 3),
                 who_am_i: int = CHIP_ID, chip_ppm: float = 0.0, self_test_codes: Sequence[int] | None = None,
                 self_test_share: Sequence[float] | None = None, offset_step_scale: float = 1.0,
                 sda_held_clocks: int = 0) -> None:
        if board is None:
            from .simulated import SimulatedBoard

            board = SimulatedBoard.from_config(None, chip="mpu6050", seed=seed)
        self.board = board
        self.factory_offsets = tuple(int(v) for v in factory_offsets)
        self.who_am_i = who_am_i
        if not -1e5 < float(chip_ppm) < 1e5:
            raise ConfigError(f"chip_ppm: {chip_ppm!r}; allowed: -100000 < ppm < 100000")
        self.chip_ppm = float(chip_ppm)  # the chip's oscillator against the MCU's, parts per million
        # this chip's factory self-test codes and its response as a share of the factory trim
        # (a draw per board: the spread between parts); faults: a weak axis (share 0.3), none (0)
        rng = np.random.default_rng(getattr(board, "seed", seed))
        self.self_test_codes = tuple(int(c) & 31 for c in (rng.integers(8, 24, 3) if self_test_codes is None
                                                           else self_test_codes))
        self.self_test_share = tuple(float(v) for v in (1.0 + 0.04 * rng.standard_normal(3)
                                                        if self_test_share is None else self_test_share))
        # a fault: the chip model's XA/YA/ZA_OFFS step as a share of 1/2048 g (written in the C model)
        if not 0.0 < float(offset_step_scale) < 10.0:
            raise ConfigError(f"offset_step_scale: {offset_step_scale!r}; allowed: 0 < scale < 10")
        self.offset_step_scale = float(offset_step_scale)
        # a fault: at power-on the chip holds SDA low until it has seen this many SCL clocks (0: never held)
        if not 0 <= int(sda_held_clocks) <= 64:
            raise ConfigError(f"sda_held_clocks: {sda_held_clocks!r}; allowed: 0..64")
        self.sda_held_clocks = int(sda_held_clocks)
        self.lock = threading.RLock()  # held while a sample is taken: take it to move the board
        self.port: str | None = None
        self.registers: dict[str, int] = {}  # the chip's configuration registers as last written
        self._proc: subprocess.Popen[str] | None = None
        self._thread: threading.Thread | None = None
        self._stats: queue.Queue[dict[str, int]] = queue.Queue()

    # --- lifecycle ------------------------------------------------------------------------
    def start(self) -> str:
        """Build if needed, start the harness, return the pseudo-terminal's path."""
        if self._proc is not None:
            if self.port is None:  # an earlier start was interrupted before the harness answered
                raise DeviceError("simavr harness is starting or did not start; stop() it first")
            return self.port
        why = unavailable_reason()
        if why:
            raise DeviceError(f"cannot run the bridge firmware in simavr: {why}")
        off = ",".join(str(v) for v in self.factory_offsets)
        self._proc = subprocess.Popen([str(HARNESS), str(ELF), "-o", off, "-w", str(self.who_am_i),
                                       "-p", repr(self.chip_ppm),
                                       "-t", ",".join(str(c) for c in self.self_test_codes),
                                       "-r", ",".join(repr(v) for v in self.self_test_share),
                                       "-s", repr(self.offset_step_scale), "-H", str(self.sda_held_clocks)],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
        ready: queue.Queue[str] = queue.Queue()
        self._thread = threading.Thread(target=self._serve, args=(ready,), name="simavr-bridge", daemon=True)
        self._thread.start()
        try:
            self.port = port = ready.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            self.stop()
            raise DeviceError(f"simavr harness {HARNESS} did not open its pseudo-terminal "
                              f"within {START_TIMEOUT_S:g} s") from None
        return port

    def stop(self) -> None:
        """Stop the harness; safe to call twice."""
        p, self._proc = self._proc, None
        if p is None:
            return
        try:
            if p.stdin is not None:
                p.stdin.write("Q\n")
                p.stdin.flush()
            p.wait(timeout=2.0)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            p.kill()
            p.wait()
        for f in (p.stdin, p.stdout):
            if f is not None:
                with suppress(OSError):
                    f.close()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> SimavrBridge:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- side channel ---------------------------------------------------------------------
    def _send(self, line: str) -> None:
        p = self._proc
        if p is None or p.stdin is None:
            raise DeviceError("simavr harness is not running")
        p.stdin.write(line + "\n")
        p.stdin.flush()

    def _serve(self, ready: queue.Queue[str]) -> None:
        p = self._proc
        if p is None or p.stdout is None:
            return  # stopped before this thread ran
        try:
            for line in p.stdout:
                word, _, rest = line.strip().partition(" ")
                if word == "PTY":
                    ready.put(rest)
                elif word == "NEED":
                    self._send(self._sample_line(int(rest) if rest.strip() else 1))
                elif word == "CFG":
                    self._configured(*(int(v) for v in rest.split()))
                elif word == "STATS":
                    self._stats.put({k: int(v) for k, v in (kv.split("=") for kv in rest.split())})
        except (OSError, ValueError, DeviceError):
            pass  # the harness went away (stop)

    def _configured(self, accel_config: int, config: int, div: int, pwr: int) -> None:
        """The firmware wrote a configuration register: the board follows the chip's range and rate."""
        self.registers = {"ACCEL_CONFIG": accel_config, "CONFIG": config, "SMPLRT_DIV": div, "PWR_MGMT_1": pwr}
        dlpf = config & 7
        range_g = (2, 4, 8, 16)[(accel_config >> 3) & 3]
        rate = min(rate_base_hz(dlpf) / (1 + div), ACCEL_RATE_HZ)  # the accelerometer samples at 1 kHz
        # mid-CONFIGURE (SMPLRT_DIV written before CONFIG) is refused: the next write completes it
        with self.lock, suppress(ConfigError):
            self.board.configure(range_g, rate, dlpf)

    def _sample_line(self, k: int = 1) -> str:
        """The newest of the k samples the chip made since the last one read: the board moves on by k."""
        with self.lock:
            counts, _ = self.board.read(max(1, min(int(k), 1_000_000)))
            temp_c = self.board.temperature_c
        xyz = np.clip(np.round(np.asarray(counts, dtype=float).reshape(-1, 3)[-1]), -32768, 32767).astype(int)
        t = int(np.clip(round((temp_c - TEMP_OFFSET_C) * TEMP_LSB_PER_C), -32768, 32767))
        return f"D {xyz[0]} {xyz[1]} {xyz[2]} {t}"

    # --- measurements and faults ----------------------------------------------------------
    def stats(self, timeout_s: float = 5.0) -> dict[str, int]:
        """The harness's counters: cycles, sim_us, free_ram_now / free_ram_min (bytes never
        touched by the stack, by stack painting), uart_tx / uart_rx / uart_lost bytes, samples."""
        self._send("S")
        try:
            return self._stats.get(timeout=timeout_s)
        except queue.Empty:
            raise DeviceError("simavr harness did not answer a STATS request") from None

    def wear_cell(self, addr: int | None, value: int = 0xFF) -> None:
        """EEPROM cell ``addr`` always reads ``value`` (a worn-out cell); None: no worn cell."""
        self._send("E -1" if addr is None else f"E {int(addr)} {int(value) & 0xFF}")

    def reset(self, after_samples: int | None = None) -> None:
        """Pull the MCU's reset pin now, or after ``after_samples`` more reads of the data registers."""
        self._send(f"B {0 if after_samples is None else max(1, int(after_samples))}")

    def set_chip_present(self, present: bool) -> None:
        """Connect or disconnect the MPU6050 from the TWI bus (a loose SDA/SCL wire)."""
        self._send(f"A {int(bool(present))}")
