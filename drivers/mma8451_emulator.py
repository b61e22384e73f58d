"""Register-level MMA8451Q emulator behind smbus2's ``SMBus`` API, fed by a simulated board.

One emulated I2C bus carries the MMA8451Q (0x1D or 0x1C) and the board's 24Cxx EEPROM (0x50).
Every SMBus call is decomposed into the I2C messages it puts on a real bus (write the register
pointer, then read or write with auto-increment), so ``read_byte_data``, ``read_i2c_block_data``,
``write_*`` and ``i2c_rdwr`` (with real ``smbus2.i2c_msg`` objects) all reach the same device
models.  A NACK raises ``OSError(EREMOTEIO)``, as Linux i2c adapters do.

Time is the board's virtual clock.  Each transaction costs its bus time (9 bits a byte at
``bus_hz``), and the driver waits on :attr:`MMA8451Emulator.clock`, whose ``sleep`` advances the
board clock; so polling STATUS moves virtual time and tests run fast.  While the chip is ACTIVE,
every instant of the board's ODR grid that time passes is a sample, read with ``board.read()``.
Time moved by others (a jig's ``clock.sleep``) produces no samples until the chip is next
addressed; the driver discards stale data before a capture anyway.

Chip behaviour modelled (MMA8451Q data sheet Rev. 10.3): WHO_AM_I; software reset (registers to
defaults, NACKs while it reboots); configuration writes ignored while ACTIVE (CTRL_REG1 except the
ACTIVE bit, XYZ_DATA_CFG, HP_FILTER_CUTOFF, CTRL_REG2 except RST, OFF_X/Y/Z); STATUS ZYXDR/ZYXOW per axis,
cleared by reading that axis's MSB; 14-bit left-justified output with the OFF_X/Y/Z trim added
(1/512 g per LSB, the data sheet's "2 mg", written here, not taken from the driver) and clipped to the
14-bit range; CTRL_REG2 ST adds this chip's self-test response (typical +181/+255/+1680 LSB at 4 g,
spread 10 % per chip).  MODS (oversampling) sets the board's oversampling mode when the chip goes
ACTIVE: the noise density scales as sqrt(OSR_normal / OSR_mode) (sim/sensor_model.py stage 7).

Faults for tests: :meth:`nack_next`, :meth:`nack_every`, ``never_ready``, :meth:`force_overrun`,
:meth:`self_test_faults` (a weak axis, a dead self-test), :meth:`trim_fault` (another trim step or sign),
``chip_id`` (another part), ``present=False`` (nothing at the address), and a lying bus,
:meth:`corrupt_reads` (``emulator.corrupt_reads: {rate, seed, address}`` in a config): each read
message to that address comes back, with probability ``rate``, with one bit flipped.
"""
from __future__ import annotations

import ctypes
import errno
import os
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
from smbus2.smbus2 import I2C_M_RD

from ..config.kinds import BusEmulatorSection, Mma8451Section
from ..errors import ConfigError
from .eeprom import EEPROM24
from .emulator_files import emulated_board
from .mma8451_registers import (
    CHIP_ID,
    CTRL1_ACTIVE,
    CTRL1_DR_MASK,
    CTRL1_DR_SHIFT,
    CTRL2_MODS_MASK,
    CTRL2_RST,
    CTRL_REG1,
    CTRL_REG2,
    FS_MASK,
    MODS,
    ODR_HZ,
    OFF_X,
    OFF_Z,
    OUT_X_MSB,
    STATUS,
    STATUS_ZYXDR,
    STATUS_ZYXOW,
    WHO_AM_I,
    XYZ_DATA_CFG,
)

N_REGS = 0x32
# The chip's own figures, from the data sheet (not from the driver, whose assumptions they check):
# OFF_X/Y/Z, signed 8-bit, "2 mg/LSB": 1/512 g, i.e. 2 LSB at +-8 g (NXP AN4069's worked example);
# self-test output change, typical at +-4 g, 14-bit: X +181, Y +255, Z +1680 LSB (Table 4).
TRIM_G_PER_LSB = 1.0 / 512.0
SELF_TEST_TYPICAL_G = np.array([181.0, 255.0, 1680.0]) / 2048.0
SELF_TEST_SPREAD = 0.10  # board-to-board, relative standard deviation (a draw per chip)
CTRL2_SELF_TEST = 0x80
BOOT_S = 0.0005  # reboot after a software reset; the part NACKs meanwhile
SYSMOD = 0x0B
# writes ignored while ACTIVE (data sheet: "must be in Standby mode to change"; Linux mma8452.c changes
# these only through mma8452_change_config()): XYZ_DATA_CFG, HP_FILTER_CUTOFF, CTRL_REG2 (except RST),
# OFF_X/Y/Z; CTRL_REG1 except its ACTIVE bit.  Other registers are not used by the driver and write through.
STANDBY_ONLY = frozenset([XYZ_DATA_CFG, 0x0F, CTRL_REG2, OFF_X, OFF_X + 1, OFF_Z])
READ_ONLY = frozenset([0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0B, 0x0C, 0x0D, 0x10, 0x16, 0x1E, 0x22])


def _nack(addr: int) -> OSError:
    return OSError(errno.EREMOTEIO, f"{os.strerror(errno.EREMOTEIO)} (emulated NACK at 0x{addr:02x})")


class _I2CDevice(Protocol):
    """A device model on the emulated bus (the chip, the EEPROM): raw I2C reads and writes."""

    def i2c_read(self, n: int) -> bytes: ...

    def i2c_write(self, data: bytes) -> None: ...


class _Chip:
    """The MMA8451Q register file and sample pipeline."""

    def __init__(self, emu: MMA8451Emulator, chip_id: int) -> None:
        self.emu, self.chip_id = emu, chip_id
        self.ignored_writes: list[tuple[int, int]] = []  # (register, value) dropped while ACTIVE
        self.write_log: list[tuple[int, int, bool]] = []  # (register, value, was ACTIVE)
        self.reset()

    def reset(self) -> None:
        self.pointer = 0
        self._snap: bytes | None = None
        self.regs = bytearray(N_REGS)
        self.regs[WHO_AM_I] = self.chip_id
        self.unread = np.zeros(3, dtype=np.int64)  # samples latched since each axis's MSB was read
        self.out = np.zeros(3, dtype=np.int64)  # latest sample, 14-bit counts before trim

    @property
    def active(self) -> bool:
        return bool(self.regs[CTRL_REG1] & CTRL1_ACTIVE)

    @property
    def range_g(self) -> int:
        return (2, 4, 8)[min(self.regs[XYZ_DATA_CFG] & FS_MASK, 2)]

    @property
    def odr_hz(self) -> float:
        return ODR_HZ[(self.regs[CTRL_REG1] & CTRL1_DR_MASK) >> CTRL1_DR_SHIFT]

    def latch(self, counts: np.ndarray, k: int) -> None:
        self.out = counts
        self.unread += k

    def status(self) -> int:
        dr, ow = self.unread > 0, self.unread > 1
        bits = int(dr @ [1, 2, 4]) | int(ow @ [16, 32, 64])
        return bits | (STATUS_ZYXDR if dr.any() else 0) | (STATUS_ZYXOW if ow.any() else 0)

    def data_bytes(self) -> bytes:
        lsb = np.array(self.regs[OFF_X:OFF_Z + 1], dtype=np.uint8).view(np.int8).astype(float)
        counts_per_g = 8192.0 / self.range_g  # 14-bit: 4096 / 2048 / 1024 per g at 2 / 4 / 8 g
        trim = np.rint(lsb * TRIM_G_PER_LSB * self.emu.trim_step_scale * self.emu.trim_sign * counts_per_g)
        v = np.clip(self.out + trim.astype(np.int64), -8192, 8191)
        return (v << 2).astype(">i2").tobytes()

    # I2C face: a write sets the register pointer, further bytes are written with auto-increment
    def i2c_write(self, data: bytes) -> None:
        if not data:
            return
        self.pointer = data[0]
        for value in data[1:]:
            self.write_register(self.pointer, value)
            self.pointer += 1

    def i2c_read(self, n: int) -> bytes:
        self._snap = None  # MSB/LSB pairs of one burst belong to one sample
        out = bytearray()
        for _ in range(n):
            out.append(self.read_register(self.pointer))
            self.pointer += 1
        return bytes(out)

    def read_register(self, reg: int) -> int:
        if reg == STATUS:
            return self.status()
        if OUT_X_MSB <= reg <= OUT_X_MSB + 5:
            if self._snap is None:
                self._snap = self.data_bytes()
            if (reg - OUT_X_MSB) % 2 == 0:
                self.unread[(reg - OUT_X_MSB) // 2] = 0
            return self._snap[reg - OUT_X_MSB]
        if reg == SYSMOD:
            return 1 if self.active else 0
        return self.regs[reg] if reg < N_REGS else 0

    def write_register(self, reg: int, value: int) -> None:
        was_active = self.active
        self.write_log.append((reg, value, was_active))
        if reg >= N_REGS or reg in READ_ONLY:
            return
        if reg == CTRL_REG2 and value & CTRL2_RST:
            self.reset()
            self.emu._boot_until = self.emu.clock.now() + BOOT_S
            return
        if was_active and (reg in STANDBY_ONLY or (reg == CTRL_REG1 and (value ^ self.regs[reg]) & ~CTRL1_ACTIVE)):
            self.ignored_writes.append((reg, value))
            if reg != CTRL_REG1:
                return
            value = (self.regs[reg] & ~CTRL1_ACTIVE) | (value & CTRL1_ACTIVE)  # only ACTIVE may change
        self.regs[reg] = value
        if reg == CTRL_REG1 and self.active and not was_active:
            self.emu._start_sampling()


class _Clock:
    """The driver's view of time on the emulated bus: the board clock, advanced through the chip."""

    def __init__(self, emu: MMA8451Emulator) -> None:
        self.emu = emu

    @property
    def realtime(self) -> bool:
        return bool(self.emu.board.clock.realtime)

    def now(self) -> float:
        return self.emu.board.clock.now()

    def sleep(self, seconds: float) -> None:
        self.emu._advance(max(0.0, float(seconds)))


class MMA8451Emulator:
    """The subset of ``smbus2.SMBus`` the MMA8451 driver uses, on an emulated bus.

    ``board`` is a SimulatedBoard (``configure``, ``read``, ``clock``, ``eeprom``).
    """

    def __init__(self, board: Any, address: int = 0x1D, eeprom_address: int | None = 0x50, chip_id: int = CHIP_ID,
                 bus_hz: float = 400_000.0, never_ready: bool = False, present: bool = True,
                 sda_held: bool = False) -> None:
        self.board, self.address, self.eeprom_address = board, address, eeprom_address
        self.bus_hz, self.never_ready, self.present = float(bus_hz), never_ready, present
        # a chip holding SDA low (left mid-byte by a reset): every transfer on the bus times out, as a
        # Linux adapter reports it (ETIMEDOUT), until the board is powered off
        self.sda_held = bool(sda_held)
        if board.chip.name != "mma8451":
            raise ConfigError(f"MMA8451 emulator needs a simulated mma8451 board, not {board.chip.name!r}")
        self.clock = _Clock(self)
        self._grid0 = 0.0
        self._boot_until = -np.inf
        self._nacks: list[list[Any]] = []  # [remaining, address or None, register or None, from transaction]
        self._nack_every = 0
        self._overrun, self._overrun_at = 0, 0
        self.samples_produced = 0
        self.transactions = 0
        self.nack_log: list[tuple[int, int | None]] = []  # (address, register) of every NACKed transaction
        self._corrupt: tuple[float, int | None, np.random.Generator] | None = None  # rate, address, rng
        self.corrupted = 0  # read messages returned with a flipped bit
        # this chip's self-test force (the typical response, spread per chip) and trim unit; faults below
        rng = np.random.default_rng(getattr(board, "seed", None))
        self.self_test_g = SELF_TEST_TYPICAL_G * (1.0 + SELF_TEST_SPREAD * rng.standard_normal(3))
        self.trim_step_scale, self.trim_sign = 1.0, 1
        self.chip = _Chip(self, chip_id)

    def self_test_faults(self, scale: Sequence[float] = (1.0, 1.0, 1.0), dead: bool = False) -> None:
        """A weak axis (``scale`` of this chip's response per axis) or a self-test bit that does nothing."""
        self.self_test_g = self.self_test_g * np.asarray(scale, dtype=float) * (0.0 if dead else 1.0)

    def trim_fault(self, step_scale: float = 1.0, sign: int = 1) -> None:
        """OFF_X/Y/Z act with another step than 1/512 g, or with the opposite sign."""
        self.trim_step_scale, self.trim_sign = float(step_scale), int(sign)

    # --- construction from a device config section ----------------------------------------
    @classmethod
    def from_section(cls, m: Mma8451Section, path: str, eeprom_address: int | None) -> MMA8451Emulator:
        """The emulated bus of a ``bus: emulated`` device section.

        ``simulator``: the simulated board (drivers/simulated.py), inline or the path of a YAML file
        (a station config's ``device:`` section, configs/sim.yaml, is taken as it is; absent: an ideal
        MMA8451 of its data sheet).  ``emulator``: bus speed and faults.
        """
        board = emulated_board(m.simulator, "mma8451", m.seed, path)
        e = m.emulator or BusEmulatorSection()
        emu = cls(board, address=m.address, eeprom_address=eeprom_address, chip_id=e.chip_id, bus_hz=e.bus_hz,
                  never_ready=e.never_ready, present=e.present, sda_held=e.sda_held)
        emu.nack_every(e.nack_every)
        emu.self_test_faults(e.self_test_scale, e.self_test_dead)
        emu.trim_fault(e.trim_step_scale, e.trim_sign)
        c = e.corrupt_reads
        if c is not None:
            given = "address" in c.model_fields_set  # default: the EEPROM's address
            emu.corrupt_reads(c.rate, c.seed, c.address if given else (eeprom_address or 0x50))
        return emu

    @property
    def nacked(self) -> int:
        return len(self.nack_log)

    @property
    def eeprom(self) -> EEPROM24:
        return self.board.eeprom

    @property
    def eeprom_size(self) -> int:
        return int(self.board.eeprom.size)

    @property
    def eeprom_page_size(self) -> int:
        return int(self.board.eeprom.page_size)

    # --- faults ---------------------------------------------------------------------------
    def nack_next(self, k: int = 1, register: int | None = None, address: int | None = None,
                  after: int = 0) -> None:
        """NACK the next k transactions (to ``address``, touching ``register`` when given), from
        ``after`` more transactions on (a NACK storm mid-run)."""
        self._nacks.append([int(k), address, register, self.transactions + int(after)])

    def nack_every(self, n: int) -> None:
        """NACK every n-th transaction (0: never)."""
        self._nack_every = int(n)

    def corrupt_reads(self, rate: float, seed: int = 0, address: int | None = 0x50) -> None:
        """A lying bus: each read message to ``address`` (None: any) has one bit flipped with
        probability ``rate`` (0 turns it off); the device itself is unchanged."""
        self._corrupt = (float(rate), address, np.random.default_rng(seed)) if rate > 0 else None

    def _lie(self, addr: int, data: bytes) -> bytes:
        if self._corrupt is None or not data:
            return data
        rate, only, rng = self._corrupt
        if only not in (None, addr) or rng.random() >= rate:
            return data
        out = bytearray(data)
        out[int(rng.integers(len(out)))] ^= 1 << int(rng.integers(8))
        self.corrupted += 1
        return bytes(out)

    def force_overrun(self, n: int = 1, after: int = 0) -> None:
        """After ``after`` more samples, the host misses n: they are produced and overwritten unread (ZYXOW)."""
        self._overrun, self._overrun_at = int(n), self.samples_produced + int(after)

    # --- time and samples -----------------------------------------------------------------
    def _start_sampling(self) -> None:
        mods = {v: k for k, v in MODS.items()}[self.chip.regs[CTRL_REG2] & CTRL2_MODS_MASK]
        self.board.configure(range_g=self.chip.range_g, odr_hz=self.chip.odr_hz, oversampling=mods)
        self._grid0 = self.board.clock.now()  # configure() restarts the board's ODR grid now

    def _advance(self, dt: float) -> None:
        """Let dt seconds pass; while ACTIVE the chip latches every sample of its ODR grid."""
        clock, chip = self.board.clock, self.chip
        target = clock.now() + dt
        if chip.active and not self.never_ready:
            odr = chip.odr_hz
            # grid instants in (now, target], counted as the board does (SimulatedBoard._times)
            k = int(np.floor((target - self._grid0) * odr + 1e-6) - np.floor((clock.now() - self._grid0) * odr + 1e-6))
            if k and self._overrun and self.samples_produced + k > self._overrun_at:
                k, self._overrun = k + self._overrun, 0  # forced overrun: the host stalls while these go by
            if k:
                counts, _ = self.board.read(k)  # the board clock moves to the last grid instant
                st = self.self_test_g * (8192.0 / chip.range_g) if chip.regs[CTRL_REG2] & CTRL2_SELF_TEST else 0.0
                chip.latch(np.rint(np.asarray(counts[-1], dtype=float) + st).astype(np.int64), k)
                self.samples_produced += k
        clock.advance_to(max(target, clock.now()))

    # --- the bus --------------------------------------------------------------------------
    def _device(self, addr: int) -> _I2CDevice | None:
        if addr == self.address and self.present:
            return self.chip
        if self.eeprom_address is not None and addr == self.eeprom_address:
            return self.board.eeprom
        return None

    def _transaction(self, msgs: list[tuple[int, bool, Any]]) -> list[bytes]:
        """Run one combined transaction: ``(addr, is_read, data or length)`` messages; NACK -> OSError."""
        nbytes = sum(1 + (m[2] if m[1] else len(m[2])) for m in msgs)
        self._advance(9 * nbytes / self.bus_hz)
        self.transactions += 1
        addr = msgs[0][0]
        if self.sda_held:
            self.nack_log.append((addr, None))
            raise OSError(errno.ETIMEDOUT, f"{os.strerror(errno.ETIMEDOUT)} (emulated: SDA held low)")
        register = msgs[0][2][0] if not msgs[0][1] and len(msgs[0][2]) else None
        if self._injected_nack(addr, register) or (addr == self.address and self.clock.now() < self._boot_until):
            self.nack_log.append((addr, register))
            raise _nack(addr)
        out: list[bytes] = []  # one entry per message: what a read returned, b"" for a write
        for a, is_read, d in msgs:
            dev = self._device(a)
            if dev is None:
                self.nack_log.append((a, register))
                raise _nack(a)
            try:  # device models NACK by raising OSError(EREMOTEIO), e.g. an EEPROM in its write cycle
                if is_read:
                    out.append(self._lie(a, dev.i2c_read(d)))
                else:
                    dev.i2c_write(bytes(d))
                    out.append(b"")
            except OSError:
                self.nack_log.append((a, register))
                raise
        return out

    def _injected_nack(self, addr: int, register: int | None) -> bool:
        if self._nack_every and self.transactions % self._nack_every == 0:
            return True
        for rule in self._nacks:
            if rule[0] > 0 and rule[1] in (None, addr) and rule[2] in (None, register) \
                    and self.transactions > rule[3]:
                rule[0] -= 1
                return True
        return False

    # --- smbus2.SMBus API subset ----------------------------------------------------------
    def open(self, bus: int | str | None = None) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> MMA8451Emulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        """SMBus receive byte: one byte from the device's current pointer (what ``i2cdetect -r`` sends)."""
        return self._transaction([(i2c_addr, True, 1)])[0][0]

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._transaction([(i2c_addr, False, [register]), (i2c_addr, True, 1)])[1][0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._transaction([(i2c_addr, False, [register, value & 0xFF])])

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int, force: bool | None = None) -> list[int]:
        if length > 32:
            raise ValueError("Desired block length over 32 bytes")  # smbus2's limit (I2C_SMBUS_BLOCK_MAX)
        return list(self._transaction([(i2c_addr, False, [register]), (i2c_addr, True, length)])[1])

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int],
                             force: bool | None = None) -> None:
        if len(data) > 32:
            raise ValueError("Data length cannot exceed 32 bytes")
        self._transaction([(i2c_addr, False, [register, *data])])

    def i2c_rdwr(self, *i2c_msgs: Any) -> None:
        """Combined transaction of ``smbus2.i2c_msg`` objects; read messages are filled in place."""
        msgs = [(m.addr, bool(m.flags & I2C_M_RD), m.len if m.flags & I2C_M_RD else bytes(m)) for m in i2c_msgs]
        for m, data in zip(i2c_msgs, self._transaction(msgs), strict=True):
            if m.flags & I2C_M_RD:
                ctypes.memmove(m.buf, data, m.len)
