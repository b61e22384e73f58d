"""MPU6050 serial-bridge protocol: framing, CRC-16, command codes, streaming parser.

The host side of docs/bridge-protocol.md.  The constants below have the same names
and values as the ``#define`` block of firmware/mpu6050_bridge/mpu6050_bridge.ino
(tests/test_bridge_protocol.py checks that they agree).

Frame (all multi-byte fields little-endian)::

    SYNC0 SYNC1 | LEN | SEQ (u16) | TYPE | TS (u32, MCU microseconds) | PAYLOAD (LEN bytes) | CRC (u16)

CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, xorout 0) over
LEN..PAYLOAD, i.e. everything after the sync bytes and before the CRC.
"""
from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

# --- constants shared with the firmware (same names as its #define block) ---
PROTOCOL_VERSION = 1
DEFAULT_BAUD = 115200
SYNC0 = 0xA5
SYNC1 = 0x5A
HEADER_LEN = 8  # LEN, SEQ(2), TYPE, TS(4)
MAX_PAYLOAD = 64
CRC16_POLY = 0x1021
CRC16_INIT = 0xFFFF
CRC16_XOROUT = 0x0000
CRC16_CHECK = 0x29B1  # CRC of b"123456789" (the catalogue check value)

# host -> bridge commands
CMD_IDENTIFY = 0x01
CMD_CONFIGURE = 0x02
CMD_STREAM = 0x03
CMD_STOP = 0x04
CMD_READ_REG = 0x05
CMD_WRITE_REG = 0x06
CMD_NVM_READ = 0x07
CMD_NVM_WRITE = 0x08
CMD_RESET = 0x09
CMD_SELF_TEST = 0x0A

# bridge -> host frames (high bit set)
RSP_BOOT = 0x80
RSP_ACK = 0x81
RSP_NAK = 0x82
RSP_SAMPLE = 0x83
RSP_STREAM_END = 0x84

# NAK error codes
ERR_UNKNOWN_CMD = 0x01
ERR_BAD_LENGTH = 0x02
ERR_BAD_ARG = 0x03
ERR_I2C = 0x04
ERR_NVM = 0x05

# boot causes (BOOT payload)
BOOT_POWER_ON = 0x00
BOOT_COMMAND = 0x01
BOOT_WATCHDOG = 0x02
BOOT_EXTERNAL = 0x03

NVM_SIZE = 1024
NVM_PAGE_SIZE = 32
REG_MAX_COUNT = 16  # bytes per READ_REG/WRITE_REG (AVR Wire buffer is 32 including the register byte)
SAMPLE_BYTES = 8  # ACCEL_XOUT_H (0x3B) .. TEMP_OUT_L (0x42), big-endian as on the chip
SELF_TEST_MAX_N = 1024  # samples averaged per SELF_TEST phase
SELF_TEST_SETTLE_MS = 200  # after switching the self-test, before averaging (InvenSense's reference driver)

PROTOCOL_CONSTANTS = [n for n in dir() if n.isupper() and not n.startswith("_")]

SYNC = bytes([SYNC0, SYNC1])
FRAME_OVERHEAD = len(SYNC) + HEADER_LEN + 2
MAX_FRAME = FRAME_OVERHEAD + MAX_PAYLOAD

COMMAND_NAMES = {v: k[4:] for k, v in globals().items() if k.startswith("CMD_")}
FRAME_NAMES = {**COMMAND_NAMES, **{v: k[4:] for k, v in globals().items() if k.startswith("RSP_")}}
ERROR_TEXT = {
    ERR_UNKNOWN_CMD: "unknown command",
    ERR_BAD_LENGTH: "bad payload length",
    ERR_BAD_ARG: "argument out of range",
    ERR_I2C: "no I2C answer from the MPU6050",
    ERR_NVM: "NVM write failed",
}
BOOT_CAUSES = {BOOT_POWER_ON: "power-on", BOOT_COMMAND: "RESET command", BOOT_WATCHDOG: "watchdog",
               BOOT_EXTERNAL: "reset pin / DTR"}

_HEADER = struct.Struct("<BHBI")

# payload layouts (struct formats, little-endian)
ACK_PREFIX = struct.Struct("<BH")  # command type, command seq
NAK = struct.Struct("<BHB")  # command type, command seq, error code
BOOT = struct.Struct("<BBBB")  # protocol version, cause, firmware major, minor
IDENTIFY_DATA = struct.Struct("<BBBBBHB8s")  # proto, fw major, minor, i2c addr, WHO_AM_I, nvm size, page, serial
CONFIGURE = struct.Struct("<BBB")  # AFS_SEL, DLPF_CFG, SMPLRT_DIV
CONFIGURE_DATA = struct.Struct("<BBBI")  # ACCEL_CONFIG, CONFIG, SMPLRT_DIV read back, sample period us
STREAM = struct.Struct("<I")  # samples
STREAM_DATA = struct.Struct("<II")  # samples, sample period us
SAMPLE_INDEX = struct.Struct("<I")  # index in the stream, then SAMPLE_BYTES raw register bytes
STREAM_END = struct.Struct("<I")  # samples accounted for (sent or a gap in the index)
SELF_TEST = struct.Struct("<BH")  # self-test on (1) / off (0), samples to average
# n, sum x/y/z (i32), sum of squared deviations from the first sample (u32), first sample (i16),
# SELF_TEST_X, _Y, _Z, _A registers
SELF_TEST_DATA = struct.Struct("<H3i3I3h4s")


def crc16(data: bytes, crc: int = CRC16_INIT) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0)."""
    return binascii.crc_hqx(bytes(data), crc) ^ CRC16_XOROUT


@dataclass(frozen=True)
class Frame:
    type: int
    seq: int
    ts_us: int
    payload: bytes = b""

    @property
    def name(self) -> str:
        return FRAME_NAMES.get(self.type, f"0x{self.type:02x}")


def encode_frame(type_: int, seq: int, ts_us: int = 0, payload: bytes = b"") -> bytes:
    """One frame, sync to CRC."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes; at most {MAX_PAYLOAD}")
    body = _HEADER.pack(len(payload), seq & 0xFFFF, type_ & 0xFF, ts_us & 0xFFFFFFFF) + bytes(payload)
    return SYNC + body + struct.pack("<H", crc16(body))


@dataclass
class ParserStats:
    garbage_bytes: int = 0  # bytes skipped while looking for sync
    crc_errors: int = 0
    bad_length: int = 0  # LEN above MAX_PAYLOAD


class FrameParser:
    """Incremental frame parser: feed it any chunks, get whole CRC-checked frames.

    Resynchronises by scanning for SYNC after garbage; after a CRC failure or an
    oversize LEN it drops one byte and rescans, so a good frame that begins inside
    a damaged one is still found.  Never blocks; the buffer stays below MAX_FRAME
    plus the last chunk.
    """

    def __init__(self, max_payload: int = MAX_PAYLOAD):
        self.max_payload = max_payload
        self.stats = ParserStats()
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        return len(self._buf)

    def reset(self) -> None:
        self._buf.clear()

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        while True:
            i = buf.find(SYNC)
            if i < 0:
                # keep a trailing SYNC0: its SYNC1 may be in the next chunk
                keep = 1 if buf[-1:] == SYNC[:1] else 0
                self.stats.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if i:
                self.stats.garbage_bytes += i
                del buf[:i]
            if len(buf) < len(SYNC) + HEADER_LEN:
                break
            length = buf[2]
            if length > self.max_payload:
                self.stats.bad_length += 1
                del buf[:1]
                continue
            total = FRAME_OVERHEAD + length
            if len(buf) < total:
                break
            body = bytes(buf[2 : total - 2])
            if crc16(body) != buf[total - 2] | (buf[total - 1] << 8):
                self.stats.crc_errors += 1
                del buf[:1]
                continue
            _, seq, type_, ts = _HEADER.unpack_from(body)
            out.append(Frame(type_, seq, ts, body[HEADER_LEN:]))
            del buf[:total]
        return out


def ack(cmd: int, cmd_seq: int, data: bytes = b"") -> bytes:
    """ACK payload: the acknowledged command's type and seq, then its data."""
    return ACK_PREFIX.pack(cmd, cmd_seq & 0xFFFF) + data


def nak(cmd: int, cmd_seq: int, error: int) -> bytes:
    return NAK.pack(cmd, cmd_seq & 0xFFFF, error)
