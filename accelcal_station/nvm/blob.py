"""The calibration blob: a versioned, CRC-protected binary image of a Calibration for NVM.

Layout (little-endian, format version 1)::

    offset size  field
    0      4     magic b"ACAL"
    4      2     format version (u16)
    6      1     model (u8: 6, 9, 12 or 15)
    7      1     flags (bit 0: temperature table present, bit 1: quadratic interpolation,
                 bit 2: no base coefficients, the table's first row is the base)
    8      4     generation counter (u32, wraps; newer = serial-number arithmetic, RFC 1982)
    12     2     total length in bytes, CRC included (u16)
    14     1     input units (0 counts, 1 g, 2 mps2)
    15     1     K, temperature points (u8)
    16     8     written at, unix seconds (i64)
    24     8     input_per_g (f64)
    32     32    device serial the calibration is bound to (UTF-8, NUL padded)
    64     32    station id (UTF-8, NUL padded)
    96     120   W (9 f64, row major), V (3 f64), Gamma (3 f64)
    216    128K  K x (temp_c, W[9], V[3], Gamma[3]) as f64
    216+128K 4   CRC-32 (zlib.crc32, IEEE 802.3) over every byte before it

f64 throughout so a blob round-trips a Calibration exactly; without a temperature
table a blob is 220 bytes, and each temperature point adds 128.  A table whose first row
equals the base W, V, Gamma (as every fitted table has) is written without the base
(flag bit 2): 100 + 128 K bytes, so a 3-temperature table fits a 512-byte slot (the
MPU6050 bridge's 1 KiB EEPROM holds two).
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..calibration import Calibration, TemperatureTable
from ..errors import DataError, NVMError
from ..jsontypes import JsonObject

MAGIC = b"ACAL"
FORMAT_VERSION = 1
GENERATION_MOD = 1 << 32
TEXT_BYTES = 32  # serial and station id fields

_HEAD = struct.Struct("<4sHBBIHBBqd32s32s")
_COEF = struct.Struct("<15d")
_TEMP = struct.Struct("<16d")
_CRC = struct.Struct("<I")
HEADER_SIZE = _HEAD.size  # 96

UNITS_CODE = {"counts": 0, "g": 1, "mps2": 2}
_UNITS_NAME = {v: k for k, v in UNITS_CODE.items()}
_FLAG_TEMP, _FLAG_QUADRATIC, _FLAG_NO_BASE = 0x01, 0x02, 0x04


class BlobError(NVMError):
    """A blob that cannot be decoded; ``kind`` is empty, magic, version, length, crc or content."""

    def __init__(self, message: str, kind: str):
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class BlobHeader:
    version: int
    model: str
    generation: int
    length: int
    serial: str
    station_id: str
    time: int  # unix seconds
    crc32: int
    temperature_points: int

    def to_dict(self) -> JsonObject:
        """The JSON form (the results store, --json)."""
        return asdict(self)


def blob_size(temperature_points: int = 0, base: bool = True) -> int:
    return HEADER_SIZE + (_COEF.size if base else 0) + temperature_points * _TEMP.size + _CRC.size


def _base_is_first_row(calibration: Calibration) -> bool:
    t = calibration.temperature
    return t is not None and np.array_equal(t.W[0], calibration.W) and np.array_equal(t.V[0], calibration.V) \
        and np.array_equal(t.Gamma[0], calibration.Gamma)


def newer(a: int, b: int) -> bool:
    """True when generation ``a`` is newer than ``b`` (RFC 1982 serial-number arithmetic)."""
    d = (a - b) % GENERATION_MOD
    return 0 < d < GENERATION_MOD // 2


def _text(value: str, what: str) -> bytes:
    raw = str(value).encode("utf-8")
    if len(raw) > TEXT_BYTES or b"\0" in raw:
        raise DataError(f"{what} {value!r}: must be at most {TEXT_BYTES} UTF-8 bytes without NUL")
    return raw.ljust(TEXT_BYTES, b"\0")


def _coef(W: ArrayLike, V: ArrayLike, G: ArrayLike) -> tuple[float, ...]:
    return (*np.asarray(W, dtype=float).ravel(), *np.asarray(V, dtype=float), *np.asarray(G, dtype=float))


def encode(calibration: Calibration, serial: str, station_id: str, generation: int, time: float) -> bytes:
    """The blob of ``calibration`` bound to device ``serial``, written by ``station_id``."""
    if not 0 <= int(generation) < GENERATION_MOD:
        raise DataError(f"generation {generation} outside 0..{GENERATION_MOD - 1}")
    table = calibration.temperature
    k = 0 if table is None else len(table.temps_c)
    if k > 255:
        raise DataError(f"temperature table has {k} points; a blob holds at most 255")
    flags = 0 if table is None else _FLAG_TEMP | (_FLAG_QUADRATIC if table.method == "quadratic" else 0)
    base = not _base_is_first_row(calibration)
    flags |= 0 if base else _FLAG_NO_BASE
    length = blob_size(k, base)
    body = bytearray(_HEAD.pack(
        MAGIC, FORMAT_VERSION, int(calibration.model), flags, int(generation), length,
        UNITS_CODE[calibration.input_units], k, int(round(time)), float(calibration.input_per_g),
        _text(serial, "serial"), _text(station_id, "station id"),
    ))
    if base:
        body += _COEF.pack(*_coef(calibration.W, calibration.V, calibration.Gamma))
    if table is not None:
        for i in range(k):
            body += _TEMP.pack(table.temps_c[i], *_coef(table.W[i], table.V[i], table.Gamma[i]))
    body += _CRC.pack(zlib.crc32(body))
    assert len(body) == length
    return bytes(body)


def blob_length(head: bytes, source: str = "blob") -> int:
    """Total length announced by a blob's first HEADER_SIZE bytes (checks magic and version)."""
    if len(head) < HEADER_SIZE:
        raise BlobError(f"{source}: {len(head)} bytes, a blob header needs {HEADER_SIZE}", "length")
    h = head[:HEADER_SIZE]
    if h == b"\xff" * HEADER_SIZE or h == b"\0" * HEADER_SIZE:
        raise BlobError(f"{source}: empty (erased)", "empty")
    magic, version, _, flags, _, length, _, k = _HEAD.unpack(h)[:8]
    if magic != MAGIC:
        raise BlobError(f"{source}: bad magic {magic!r}; expected {MAGIC!r}", "magic")
    if version != FORMAT_VERSION:
        raise BlobError(f"{source}: blob format version {version}; this station reads {FORMAT_VERSION}", "version")
    want = blob_size(k, not flags & _FLAG_NO_BASE)
    if length != want:
        raise BlobError(f"{source}: length field {length} does not match {k} temperature points "
                        f"({want} bytes)", "length")
    return length


def decode(data: bytes, source: str = "blob") -> tuple[Calibration, BlobHeader]:
    """Calibration and header of the blob at the start of ``data`` (trailing bytes ignored).

    Raises BlobError naming ``source`` on an empty slot, bad magic, version, length or CRC.
    """
    data = bytes(data)
    length = blob_length(data, source)
    if len(data) < length:
        raise BlobError(f"{source}: truncated, {len(data)} of {length} bytes", "length")
    (crc,) = _CRC.unpack_from(data, length - _CRC.size)
    computed = zlib.crc32(data[: length - _CRC.size])
    if crc != computed:
        raise BlobError(f"{source}: CRC mismatch (stored 0x{crc:08x}, computed 0x{computed:08x})", "crc")
    _, version, model, flags, gen, _, units, k, t, per_g, serial, station = _HEAD.unpack_from(data)
    try:
        if flags & ~(_FLAG_TEMP | _FLAG_QUADRATIC | _FLAG_NO_BASE) or bool(flags & _FLAG_TEMP) != (k > 0) \
                or (flags & (_FLAG_NO_BASE | _FLAG_QUADRATIC) and not k):  # only what encode writes
            raise DataError(f"flags 0x{flags:02x} inconsistent with {k} temperature points")
        if units not in _UNITS_NAME:
            raise DataError(f"input units code {units}; allowed {sorted(_UNITS_NAME)}")
        base = not flags & _FLAG_NO_BASE
        start = HEADER_SIZE + (_COEF.size if base else 0)
        # (k, 16) table rows; with no base coefficients the first row is the base (checked above:
        # flag bit 2 needs k >= 1), so no flag combination leaves the base undefined
        rows = np.array([_TEMP.unpack_from(data, start + i * _TEMP.size) for i in range(k)]).reshape(k, 16)
        table = None if not k else TemperatureTable(
            rows[:, 0], rows[:, 1:10].reshape(k, 3, 3), rows[:, 10:13], rows[:, 13:16],
            "quadratic" if flags & _FLAG_QUADRATIC else "linear")
        c = np.array(_COEF.unpack_from(data, HEADER_SIZE)) if base else rows[0, 1:16]
        cal = Calibration(str(model), c[:9].reshape(3, 3), c[9:12], c[12:15], _UNITS_NAME[units], per_g, table)
        header = BlobHeader(version, str(model), gen, length, serial.rstrip(b"\0").decode("utf-8"),
                            station.rstrip(b"\0").decode("utf-8"), t, crc, k)
    except (DataError, UnicodeDecodeError) as e:
        raise BlobError(f"{source}: CRC is valid but the content is not a calibration ({e})", "content") from None
    return cal, header
