"""The MPU6050 serial bridge, emulated on a real pseudo-terminal and fed by a SimulatedBoard.

The emulator runs the bridge firmware's behaviour (docs/bridge-protocol.md) in a
background thread on the master side of ``os.openpty()``; the slave side is put in
raw mode, and its path (``os.ttyname``, e.g. /dev/pts/7) is opened by pyserial
exactly as /dev/ttyUSB0 would be.  Behind the protocol sits an MPU6050 register
file: WHO_AM_I, PWR_MGMT_1 (asleep after reset: data registers frozen),
SMPLRT_DIV, CONFIG, ACCEL_CONFIG, the data and TEMP_OUT registers, and
XA/YA/ZA_OFFS whose change from the factory trim shifts the output (1/2048 g per LSB, ``offset_step_scale``).
The NVM is the MCU's 1 KiB EEPROM (an EEPROM24 model with 32-byte pages).

Samples come from ``board.configure()`` / ``board.read()`` on the chip's own clock (the
board's virtual clock); timestamps are MCU time since the last (emulated) MCU boot, which runs
``chip_ppm`` parts per million slow against a fast chip (negative: fast), as the bridge that reads
on the chip's DATA_RDY sees it.  The SAMPLE index counts the chip's samples: one the UART at
``baud`` (24-byte frames, 10 bits a byte) has no room for is dropped without waiting, a gap in
the index, as the firmware does.  Streams run as fast as the pty takes them unless the board is
``realtime``.  Sample rates the simulated chip cannot produce (above 1 kHz, or DLPF_CFG 0 with a
rate other than 1000 / (1 + k)) are NAKed with ERR_BAD_ARG.

Faults for tests: :meth:`corrupt` (flip a bit in each of the next k bytes sent),
:meth:`drop_frames`, :meth:`inject_garbage`, :meth:`stall` (ignore input and send
nothing for t seconds), :meth:`reset` (reboot now or after k samples of the next
stream), ``who_am_i`` (another chip), ``i2c_present=False`` (nothing on the bus),
and the NVM's ``inject_power_loss`` (the bridge reboots during NVM_WRITE).
"""
from __future__ import annotations

import os
import select
import threading
import time
from collections import deque
from typing import Any, Unpack

import numpy as np

from ..config.kinds import Mpu6050Section
from ..errors import ConfigError
from ..sim.pty_server import PtyServer
from . import bridge_protocol as bp
from .eeprom import EEPROM24, PowerLossError
from .emulator_files import BridgeChip, bridge_faults, emulated_board
from .mpu6050 import (
    ACCEL_CONFIG,
    ACCEL_RATE_HZ,
    ACCEL_XOUT_H,
    CHIP_ID,
    CONFIG,
    PWR_MGMT_1,
    PWR_SLEEP,
    SELF_TEST_X,
    SMPLRT_DIV,
    TEMP_OUT_H,
    WHO_AM_I,
    XA_OFFS_H,
    rate_base_hz,
)

# XA/YA/ZA_OFFS: not in the register map (rev 4.2); InvenSense's "MPU Hardware Offset Registers" application
# note gives them in the +-16 g format, 2048 LSB per g, bit 0 reserved.  Written here, not taken from the
# driver, so the emulator is a second reading of the part and not the driver's own assumption; the
# ``offset_step_scale`` fault models a part whose step differs.
XA_OFFS_G_PER_LSB = 1.0 / 2048.0
FIRMWARE = (1, 1)  # as firmware/mpu6050_bridge: 1.1 reads on DATA_RDY and has SELF_TEST
CHUNK = 32  # samples produced between looks at the input (a STOP is seen within 32 samples)
EEPROM_WRITE_S_PER_BYTE = 0.0034  # ATmega328P EEPROM programming time per byte
TX_BUFFER_BYTES = 63  # Arduino core HardwareSerial: a 64-byte ring holds 63


class MPU6050BridgeEmulator(PtyServer):
    """The bridge and its MPU6050 on a pseudo-terminal.  ``start()`` returns the port path."""

    thread_name = "mpu6050-bridge"
    master_nonblocking = True  # _run polls the master between samples

    def __init__(self, board: Any = None, seed: int | None = None, **chip: Unpack[BridgeChip]) -> None:
        if board is None:
            from .simulated import SimulatedBoard

            board = SimulatedBoard.from_config(None, chip="mpu6050", seed=seed)
        self.board = board
        self.who_am_i, self.i2c_present = chip.get("who_am_i", CHIP_ID), chip.get("i2c_present", True)
        chip_ppm = chip.get("chip_ppm", 0.0)
        if not -1e5 < float(chip_ppm) < 1e5:
            raise ConfigError(f"chip_ppm: {chip_ppm!r}; allowed: -100000 < ppm < 100000")
        # the board's clock is the chip's; the MCU's runs chip_ppm slower when the chip is fast
        self.chip_ppm = float(chip_ppm)
        # one SAMPLE frame on the UART: 24 bytes of 10 bits (8N1); the firmware drops a sample
        # (a gap in the index) when the UART has no room for it, and never waits
        self.uart_bytes_per_s = float(chip.get("baud", bp.DEFAULT_BAUD)) / 10.0
        self._tx_level, self._tx_t = 0.0, 0.0  # bytes in the UART's transmit buffer, and when
        serial = chip.get("serial")
        serial = str(getattr(board, "serial", "EMUB0001"))[-8:] if serial is None else serial
        self.serial = serial.encode("ascii", "replace")[:8].ljust(8, b"\0")
        self.i2c_address = chip.get("i2c_address", 0x68)
        self.nvm = EEPROM24(bp.NVM_SIZE, bp.NVM_PAGE_SIZE, EEPROM_WRITE_S_PER_BYTE * bp.NVM_PAGE_SIZE,
                            clock=board.clock)
        rng = np.random.default_rng(getattr(board, "seed", seed))
        # each chip has its own factory trim in XA/YA/ZA_OFFS, bit 0 included
        factory_offsets = chip.get("factory_offsets")
        self.factory_offsets = (rng.integers(-4000, 4000, 3) if factory_offsets is None
                                else np.asarray(factory_offsets, dtype=np.int64).reshape(3))
        self.lock = threading.RLock()  # held while the thread touches the board: take it to move the board
        self.frames_sent = 0
        self.frames_dropped = 0
        self.commands: deque[int] = deque(maxlen=1000)  # the latest command types handled, in order
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._master = self._slave = -1
        self.port: str | None = None
        self._corrupt_after = self._corrupt_left = 0
        self._drop_after = self._drop_left = 0
        self._drop_types: tuple[int, ...] | None = None
        self._stall_until = 0.0
        self._stall_after: tuple[int, float] | None = None
        self._reset_after: int | None = None
        self._reset_repeat = 0
        self._rng = np.random.default_rng(rng.integers(2**32))
        # the accelerometer's factory self-test codes (SELF_TEST_X/Y/Z/A) and this chip's response as a
        # share of its factory trim (a draw per part; faults: a weak axis, 0: a self-test that does nothing)
        codes, share = chip.get("self_test_codes"), chip.get("self_test_share")
        self.self_test_codes = (rng.integers(8, 24, 3) if codes is None
                                else np.asarray(codes, dtype=np.int64).reshape(3)) & 31
        self.self_test_share = (1.0 + 0.04 * rng.standard_normal(3) if share is None
                                else np.asarray(share, dtype=float).reshape(3))
        # a fault: this part's XA/YA/ZA_OFFS step differs from the 1/2048 g the driver assumes
        offset_step_scale = chip.get("offset_step_scale", 1.0)
        if not 0.0 < float(offset_step_scale) < 10.0:
            raise ConfigError(f"offset_step_scale: {offset_step_scale!r}; allowed: 0 < scale < 10")
        self.offset_step_scale = float(offset_step_scale)
        self._power_on(bp.BOOT_POWER_ON, send=False)

    @classmethod
    def from_section(cls, m: Mpu6050Section, path: str = "device") -> MPU6050BridgeEmulator:
        """From a device section's ``simulator`` (a board section, or a YAML file as ``board_config_from_file``
        takes), ``seed`` and ``emulator`` (the chip's faults)."""
        return cls(emulated_board(m.simulator, "mpu6050", m.seed, path), **bridge_faults(m.emulator))

    # --- faults ---------------------------------------------------------------------------
    def corrupt(self, n_bytes: int, after_bytes: int = 0) -> None:
        """Flip one random bit in each of n_bytes sent, starting after_bytes from now."""
        with self.lock:
            self._corrupt_after, self._corrupt_left = after_bytes, n_bytes

    def drop_frames(self, n: int, after_frames: int = 0, types: tuple[int, ...] | None = None) -> None:
        """Do not send n frames (of ``types``, default any), after letting after_frames through."""
        with self.lock:
            self._drop_after, self._drop_left, self._drop_types = after_frames, n, types

    def inject_garbage(self, data: bytes) -> None:
        """Send raw bytes between frames (line noise, a bootloader's chatter)."""
        with self.lock:
            self._write(bytes(data))

    def stall(self, seconds: float, after_samples: int | None = None) -> None:
        """Hang for ``seconds`` (wall time), now or after ``after_samples`` samples of the next stream:
        input is lost and nothing is sent, then it carries on where it was."""
        with self.lock:
            if after_samples is None:
                self._stall_until = time.monotonic() + seconds
            else:
                self._stall_after = (after_samples, seconds)

    def reset(self, after_samples: int | None = None, cause: int = bp.BOOT_WATCHDOG, times: int = 1) -> None:
        """Reboot the bridge now, or after ``after_samples`` samples of the current or next stream
        (``times`` streams in a row)."""
        with self.lock:
            if after_samples is None:
                self._power_on(cause)
            else:
                self._reset_after, self._reset_cause, self._reset_repeat = after_samples, cause, times

    # --- the MCU ----------------------------------------------------------------------------
    def _power_on(self, cause: int, send: bool = True) -> None:
        """MCU boot: the firmware resets the chip (PWR_MGMT_1 DEVICE_RESET) and sends BOOT."""
        self.regs = bytearray(0x80)
        self.regs[WHO_AM_I] = self.who_am_i
        self.regs[PWR_MGMT_1] = PWR_SLEEP
        self.regs[XA_OFFS_H:XA_OFFS_H + 6] = self.factory_offsets.astype(">i2").tobytes()
        self._self_test_registers()
        self.board.configure(2, ACCEL_RATE_HZ, 0)
        self.period_us = 1000
        self.seq = 0
        self.streaming = False
        self.stream_n = self.stream_sent = 0
        self._boot_t = self.board.clock.now()
        self._parser = bp.FrameParser()
        if send:
            self._send(bp.RSP_BOOT, bp.BOOT.pack(bp.PROTOCOL_VERSION, cause, *FIRMWARE))

    def _self_test_registers(self) -> None:
        """SELF_TEST_X/Y/Z bits 7:5 = A_TEST[4:2]; SELF_TEST_A bits 5:4, 3:2, 1:0 = A_TEST[1:0] (map 4.1)."""
        c = [int(v) for v in self.self_test_codes]
        for i in range(3):
            self.regs[SELF_TEST_X + i] = ((c[i] >> 2) & 7) << 5
        self.regs[SELF_TEST_X + 3] = ((c[0] & 3) << 4) | ((c[1] & 3) << 2) | (c[2] & 3)

    def _self_test_g(self) -> np.ndarray:
        """The self-test force per axis in g while ACCEL_CONFIG's XA/YA/ZA_ST bits are set: the factory
        trim FT = 4096 * 0.34 * (0.92 / 0.34)^((code - 1) / 30) LSB at +-8 g (register map 4.1), this
        chip's share of it."""
        code = self.self_test_codes.astype(float)
        ft = np.where(code > 0, 4096.0 * 0.34 * (0.92 / 0.34) ** ((code - 1.0) / 30.0), 0.0)
        on = np.array([(self.regs[ACCEL_CONFIG] >> (7 - i)) & 1 for i in range(3)], dtype=float)
        return on * ft / 4096.0 * self.self_test_share

    def _mcu_s(self, t: float | None = None) -> float:
        """MCU time since boot (s) at board (chip) time t."""
        t = self.board.clock.now() if t is None else t
        return (t - self._boot_t) / (1.0 + self.chip_ppm * 1e-6)

    def _ts(self, t: float | None = None) -> int:
        return int(round(self._mcu_s(t) * 1e6)) & 0xFFFFFFFF

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self._stop.is_set() and self._master >= 0:
            try:
                k = os.write(self._master, view)
                view = view[k:]
            except BlockingIOError:
                select.select([], [self._master], [], 0.05)

    def _send(self, type_: int, payload: bytes = b"", t: float | None = None) -> None:
        frame = bytearray(bp.encode_frame(type_, self.seq, self._ts(t), payload))
        self.seq = (self.seq + 1) & 0xFFFF
        if self._drop_left and (self._drop_types is None or type_ in self._drop_types):
            if self._drop_after:
                self._drop_after -= 1
            else:
                self._drop_left -= 1
                self.frames_dropped += 1
                return
        if self._corrupt_left:
            skip = min(self._corrupt_after, len(frame))
            self._corrupt_after -= skip
            for i in range(skip, min(len(frame), skip + self._corrupt_left)):
                frame[i] ^= 1 << int(self._rng.integers(8))
                self._corrupt_left -= 1
        self.frames_sent += 1
        self._write(bytes(frame))

    def _ack(self, cmd: int, seq: int, data: bytes = b"") -> None:
        self._send(bp.RSP_ACK, bp.ack(cmd, seq, data))

    def _nak(self, cmd: int, seq: int, err: int) -> None:
        self._send(bp.RSP_NAK, bp.nak(cmd, seq, err))

    def _run(self) -> None:
        while not self._stop.is_set():
            stalled = time.monotonic() < self._stall_until
            try:
                r, _, _ = select.select([self._master], [], [], 0.0 if self.streaming and not stalled else 0.02)
                data = os.read(self._master, 4096) if r else b""
            except (BlockingIOError, InterruptedError):
                data = b""
            except OSError:  # EIO: no process has the slave open (cannot happen while we hold it)
                time.sleep(0.02)
                continue
            with self.lock:
                if time.monotonic() < self._stall_until:
                    continue  # hung: the UART's bytes are lost
                for f in self._parser.feed(data):
                    self._command(f)
                if self.streaming:
                    self._stream_chunk()

    def _stream_chunk(self) -> None:
        k = min(CHUNK, self.stream_n - self.stream_sent)
        if self._reset_after is not None:
            if self.stream_sent >= self._reset_after:
                self._reset_repeat -= 1
                if self._reset_repeat <= 0:
                    self._reset_after = None
                self._power_on(self._reset_cause)
                return
            k = min(k, self._reset_after - self.stream_sent)
        if self._stall_after is not None:
            if self.stream_sent >= self._stall_after[0]:
                self._stall_until = time.monotonic() + self._stall_after[1]
                self._stall_after = None
                return
            k = min(k, self._stall_after[0] - self.stream_sent)
        raw, t = self._sample(k)
        for row, ti in zip(raw.astype(">i2"), t, strict=True):
            # the index counts the chip's samples; one the UART has no room for is a gap (firmware)
            if self._uart_room(self._mcu_s(float(ti))):
                self._send(bp.RSP_SAMPLE, bp.SAMPLE_INDEX.pack(self.stream_sent) + row.tobytes(), float(ti))
            self.stream_sent += 1
        if self.stream_sent >= self.stream_n:
            self._end_stream()

    def _sample(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """k samples of ACCEL_XOUT..TEMP_OUT as int16 (k, 4) and their board times; updates the registers."""
        if self.regs[PWR_MGMT_1] & PWR_SLEEP:
            # asleep: the data registers hold their last value; the clock still runs
            raw = np.repeat(np.frombuffer(bytes(self.regs[ACCEL_XOUT_H:ACCEL_XOUT_H + 8]), ">i2")[None], k, 0)
            t = self.board.clock.now() + np.arange(1, k + 1) * self.period_us * 1e-6
            self.board.clock.advance_to(float(t[-1]))
            return raw.astype(np.int64), t
        counts, t = self.board.read(k)
        off = ((np.frombuffer(bytes(self.regs[XA_OFFS_H:XA_OFFS_H + 6]), ">i2").astype(np.int64) & ~1)
               - (self.factory_offsets & ~1)) * self.board.counts_per_g * XA_OFFS_G_PER_LSB * self.offset_step_scale
        st = self._self_test_g() * self.board.counts_per_g
        acc = np.clip(np.round(np.asarray(counts, dtype=float) + off + st), -32768, 32767)
        temp = np.clip(round((self.board.temperature_c - 36.53) * 340.0), -32768, 32767)
        raw = np.column_stack([acc, np.full(k, temp)]).astype(np.int64)
        self.regs[ACCEL_XOUT_H:ACCEL_XOUT_H + 8] = raw[-1].astype(">i2").tobytes()
        return raw, t

    def _uart_room(self, t_mcu: float) -> bool:
        """Whether the Arduino core's 64-byte transmit ring (63 usable) has room for a SAMPLE frame at
        MCU time t_mcu, draining at baud / 10 bytes/s; if so, the frame is put in."""
        self._tx_level = max(0.0, self._tx_level - (t_mcu - self._tx_t) * self.uart_bytes_per_s)
        self._tx_t = t_mcu
        frame = 2 + bp.HEADER_LEN + 4 + bp.SAMPLE_BYTES + 2
        if TX_BUFFER_BYTES - self._tx_level < frame:
            return False
        self._tx_level += frame
        return True

    def _end_stream(self) -> None:
        self.streaming = False
        self._send(bp.RSP_STREAM_END, bp.STREAM_END.pack(self.stream_sent))

    # --- commands (as the firmware's handle_frame) ------------------------------------------
    def _command(self, f: bp.Frame) -> None:
        self.commands.append(f.type)
        if self.streaming:
            self._end_stream()  # any command ends a running stream, STREAM_END first
        handler = {bp.CMD_IDENTIFY: self._identify, bp.CMD_CONFIGURE: self._configure, bp.CMD_STREAM: self._stream,
                   bp.CMD_STOP: lambda seq, p: self._ack(bp.CMD_STOP, seq), bp.CMD_READ_REG: self._read_reg,
                   bp.CMD_WRITE_REG: self._write_reg, bp.CMD_NVM_READ: self._nvm_read,
                   bp.CMD_NVM_WRITE: self._nvm_write, bp.CMD_RESET: self._reset,
                   bp.CMD_SELF_TEST: self._self_test}.get(f.type)
        if handler is None:
            return self._nak(f.type, f.seq, bp.ERR_UNKNOWN_CMD)
        handler(f.seq, f.payload)

    def _i2c_read(self, reg: int, n: int) -> bytes | None:
        if not self.i2c_present:
            return None
        if reg <= TEMP_OUT_H + 1 and reg + n > ACCEL_XOUT_H:
            self._sample(1)  # the chip updates its data registers every sample
        return bytes(self.regs[reg:reg + n])

    def _i2c_write(self, reg: int, data: bytes) -> bool:
        if not self.i2c_present:
            return False
        for i, v in enumerate(data):
            r = reg + i
            if r == PWR_MGMT_1 and v & 0x80:  # DEVICE_RESET: registers to default, asleep
                self.regs[XA_OFFS_H:XA_OFFS_H + 6] = self.factory_offsets.astype(">i2").tobytes()
                for q in (SMPLRT_DIV, CONFIG, ACCEL_CONFIG):
                    self.regs[q] = 0
                self.regs[PWR_MGMT_1] = PWR_SLEEP
            elif r not in (WHO_AM_I, *range(ACCEL_XOUT_H, ACCEL_XOUT_H + 14)):  # read-only
                self.regs[r] = v
        return True

    def _identify(self, seq: int, p: bytes) -> None:
        who = self._i2c_read(WHO_AM_I, 1)
        self._ack(bp.CMD_IDENTIFY, seq, bp.IDENTIFY_DATA.pack(
            bp.PROTOCOL_VERSION, *FIRMWARE, self.i2c_address, who[0] if who else 0, bp.NVM_SIZE, bp.NVM_PAGE_SIZE,
            self.serial))

    def _configure(self, seq: int, p: bytes) -> None:
        if len(p) != bp.CONFIGURE.size:
            return self._nak(bp.CMD_CONFIGURE, seq, bp.ERR_BAD_LENGTH)
        afs, dlpf, div = bp.CONFIGURE.unpack(p)
        if afs > 3 or dlpf > 6:
            return self._nak(bp.CMD_CONFIGURE, seq, bp.ERR_BAD_ARG)
        rate = rate_base_hz(dlpf) / (1 + div)
        try:
            self.board.configure((2, 4, 8, 16)[afs], rate, dlpf)
        except ConfigError:
            return self._nak(bp.CMD_CONFIGURE, seq, bp.ERR_BAD_ARG)  # emulator limit, see module doc
        if not (self._i2c_write(SMPLRT_DIV, bytes([div])) and self._i2c_write(CONFIG, bytes([dlpf]))
                and self._i2c_write(ACCEL_CONFIG, bytes([afs << 3]))):
            return self._nak(bp.CMD_CONFIGURE, seq, bp.ERR_I2C)
        self.period_us = int(round(1e6 / rate))
        self._ack(bp.CMD_CONFIGURE, seq, bp.CONFIGURE_DATA.pack(self.regs[ACCEL_CONFIG], self.regs[CONFIG],
                                                                 self.regs[SMPLRT_DIV], self.period_us))

    def _stream(self, seq: int, p: bytes) -> None:
        if len(p) != bp.STREAM.size:
            return self._nak(bp.CMD_STREAM, seq, bp.ERR_BAD_LENGTH)
        n = bp.STREAM.unpack(p)[0]
        if n == 0:
            return self._nak(bp.CMD_STREAM, seq, bp.ERR_BAD_ARG)
        if not self.i2c_present:  # the firmware's first sample read fails: a short stream
            self._ack(bp.CMD_STREAM, seq, bp.STREAM_DATA.pack(n, self.period_us))
            self.stream_n, self.stream_sent = n, 0
            return self._end_stream()
        self._ack(bp.CMD_STREAM, seq, bp.STREAM_DATA.pack(n, self.period_us))
        self.streaming, self.stream_n, self.stream_sent = True, n, 0
        self._tx_level, self._tx_t = 0.0, self._mcu_s()

    def _read_reg(self, seq: int, p: bytes) -> None:
        if len(p) != 2:
            return self._nak(bp.CMD_READ_REG, seq, bp.ERR_BAD_LENGTH)
        reg, n = p
        if not 1 <= n <= bp.REG_MAX_COUNT or reg + n > 0x80:
            return self._nak(bp.CMD_READ_REG, seq, bp.ERR_BAD_ARG)
        data = self._i2c_read(reg, n)
        if data is None:
            return self._nak(bp.CMD_READ_REG, seq, bp.ERR_I2C)
        self._ack(bp.CMD_READ_REG, seq, bytes([reg]) + data)

    def _write_reg(self, seq: int, p: bytes) -> None:
        if not 2 <= len(p) <= 1 + bp.REG_MAX_COUNT:
            return self._nak(bp.CMD_WRITE_REG, seq, bp.ERR_BAD_LENGTH)
        reg, data = p[0], p[1:]
        if reg + len(data) > 0x80:
            return self._nak(bp.CMD_WRITE_REG, seq, bp.ERR_BAD_ARG)
        back = self._i2c_read(reg, len(data)) if self._i2c_write(reg, data) else None
        if back is None:
            return self._nak(bp.CMD_WRITE_REG, seq, bp.ERR_I2C)
        self._ack(bp.CMD_WRITE_REG, seq, bytes([reg]) + back)

    def _nvm_read(self, seq: int, p: bytes) -> None:
        if len(p) != 1:
            return self._nak(bp.CMD_NVM_READ, seq, bp.ERR_BAD_LENGTH)
        if p[0] >= bp.NVM_SIZE // bp.NVM_PAGE_SIZE:
            return self._nak(bp.CMD_NVM_READ, seq, bp.ERR_BAD_ARG)
        self._ack(bp.CMD_NVM_READ, seq, p + self.nvm.read(p[0] * bp.NVM_PAGE_SIZE, bp.NVM_PAGE_SIZE))

    def _nvm_write(self, seq: int, p: bytes) -> None:
        if len(p) != 1 + bp.NVM_PAGE_SIZE:
            return self._nak(bp.CMD_NVM_WRITE, seq, bp.ERR_BAD_LENGTH)
        if p[0] >= bp.NVM_SIZE // bp.NVM_PAGE_SIZE:
            return self._nak(bp.CMD_NVM_WRITE, seq, bp.ERR_BAD_ARG)
        try:
            self.nvm.write(p[0] * bp.NVM_PAGE_SIZE, p[1:])
        except PowerLossError:
            return self._power_on(bp.BOOT_POWER_ON)  # the board lost power mid-write: no ACK, then BOOT
        if self.nvm.read(p[0] * bp.NVM_PAGE_SIZE, bp.NVM_PAGE_SIZE) != p[1:]:
            return self._nak(bp.CMD_NVM_WRITE, seq, bp.ERR_NVM)
        self._ack(bp.CMD_NVM_WRITE, seq, p[:1])

    def _self_test(self, seq: int, p: bytes) -> None:
        """SELF_TEST phase, as the firmware: +-8 g with (on) or without the ST bits, settle, n samples'
        sum, squared deviations from the first, the first; SELF_TEST registers; ACCEL_CONFIG restored."""
        if len(p) != bp.SELF_TEST.size:
            return self._nak(bp.CMD_SELF_TEST, seq, bp.ERR_BAD_LENGTH)
        on, n = bp.SELF_TEST.unpack(p)
        if on > 1 or not 2 <= n <= bp.SELF_TEST_MAX_N:
            return self._nak(bp.CMD_SELF_TEST, seq, bp.ERR_BAD_ARG)
        saved = self.regs[ACCEL_CONFIG]
        if not self._i2c_write(ACCEL_CONFIG, bytes([(0xE0 if on else 0) | (2 << 3)])):
            return self._nak(bp.CMD_SELF_TEST, seq, bp.ERR_I2C)
        rate = self.board.odr_hz
        try:
            self.board.configure(8, rate, self.board.dlpf)
            self._sample(max(1, int(round(bp.SELF_TEST_SETTLE_MS * 1e-3 * rate))))  # settling, discarded
            v = self._sample(n)[0][:, :3]
        finally:
            self._i2c_write(ACCEL_CONFIG, bytes([saved]))
            self.board.configure((2, 4, 8, 16)[(saved >> 3) & 3], rate, self.board.dlpf)
        d = v - v[0]
        self._ack(bp.CMD_SELF_TEST, seq, bp.SELF_TEST_DATA.pack(
            n, *(int(x) for x in v.sum(axis=0)), *(int(x) & 0xFFFFFFFF for x in (d * d).sum(axis=0)),
            *(int(x) for x in v[0]), bytes(self.regs[SELF_TEST_X:SELF_TEST_X + 4])))

    def _reset(self, seq: int, p: bytes) -> None:
        self._ack(bp.CMD_RESET, seq)
        self._power_on(bp.BOOT_COMMAND)
