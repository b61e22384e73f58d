"""Calibration blob: exact round trip, documented layout, every corruption detected."""
from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accelcal_station.calibration import Calibration, TemperatureTable
from accelcal_station.errors import DataError, NVMError
from accelcal_station.nvm.blob import HEADER_SIZE, MAGIC, BlobError, blob_length, blob_size, decode, encode, newer


def make_cal(seed: int = 0, k: int = 0, method: str = "linear", units: str = "counts") -> Calibration:
    rng = np.random.default_rng(seed)
    table = None
    if k:
        table = TemperatureTable(np.linspace(-20, 60, k), np.eye(3) + rng.normal(0, 0.01, (k, 3, 3)),
                                 rng.normal(0, 0.02, (k, 3)), rng.normal(0, 1e-3, (k, 3)), method)
    return Calibration("15", np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.02, 3),
                       rng.normal(0, 1e-3, 3), units, 4096.0 if units == "counts" else 1.0, table)


def assert_same(a: Calibration, b: Calibration) -> None:
    assert a.model == b.model and a.input_units == b.input_units and a.input_per_g == b.input_per_g
    for name in ("W", "V", "Gamma"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name  # bit-exact
    assert (a.temperature is None) == (b.temperature is None)
    if a.temperature is not None:
        ta, tb = a.temperature, b.temperature
        assert ta.method == tb.method
        for name in ("temps_c", "W", "V", "Gamma"):
            assert np.array_equal(getattr(ta, name), getattr(tb, name)), name


@pytest.mark.parametrize("k,method,units", [(0, "linear", "counts"), (2, "linear", "g"),
                                            (4, "quadratic", "mps2")])
def test_round_trip_exact(k, method, units):
    cal = make_cal(k, k, method, units)
    blob = encode(cal, "SN-0042", "line-3", 7, 1_700_000_123)
    assert len(blob) == blob_size(k) == HEADER_SIZE + 120 + 128 * k + 4
    back, h = decode(blob + b"\xff" * 50)  # trailing slot bytes are ignored
    assert_same(cal, back)
    assert (h.serial, h.station_id, h.generation, h.time, h.temperature_points) == ("SN-0042", "line-3", 7,
                                                                                   1_700_000_123, k)
    assert h.crc32 == zlib.crc32(blob[:-4])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=15, max_size=15),
       st.sampled_from(["6", "9", "12", "15"]), st.integers(0, 2**32 - 1),
       st.text(st.characters(blacklist_characters="\0", blacklist_categories=("Cs",)), max_size=8))
def test_round_trip_any_finite_float(values, model, gen, serial):
    cal = Calibration(model, np.reshape(values[:9], (3, 3)), values[9:12], values[12:])
    back, h = decode(encode(cal, serial, "s", gen, 0))
    assert_same(cal, back)
    assert h.generation == gen and h.serial == serial


def test_layout_is_the_documented_one():
    """Offsets a firmware reader relies on (module docstring)."""
    cal = make_cal(1)
    blob = encode(cal, "SN1", "ST", 0x01020304, 1234)
    assert blob[:4] == MAGIC
    assert struct.unpack_from("<HBBIHBBqd", blob, 4) == (1, 15, 0, 0x01020304, 220, 0, 0, 1234, 4096.0)
    assert blob[32:64].rstrip(b"\0") == b"SN1" and blob[64:96].rstrip(b"\0") == b"ST"
    assert np.array_equal(np.frombuffer(blob, "<f8", 9, 96).reshape(3, 3), cal.W)
    assert np.array_equal(np.frombuffer(blob, "<f8", 3, 96 + 72), cal.V)
    assert struct.unpack_from("<I", blob, 216)[0] == zlib.crc32(blob[:216])


def test_every_single_byte_corruption_is_detected():
    blob = encode(make_cal(2, 2), "SN", "ST", 3, 99)
    for i in range(len(blob)):
        bad = bytearray(blob)
        bad[i] ^= 0x5A
        with pytest.raises(BlobError) as e:
            decode(bytes(bad), "slot A")
        assert e.value.kind in ("magic", "version", "length", "crc")
        assert str(e.value).startswith("slot A:")


def test_error_kinds_and_messages():
    blob = encode(make_cal(3), "SN", "ST", 1, 0)
    with pytest.raises(BlobError, match="empty") as e:
        decode(b"\xff" * 300)
    assert e.value.kind == "empty" and isinstance(e.value, NVMError)
    with pytest.raises(BlobError, match="bad magic"):
        decode(b"XCAL" + blob[4:])
    with pytest.raises(BlobError, match="format version 2") as e:
        decode(blob[:4] + struct.pack("<H", 2) + blob[6:])
    assert e.value.kind == "version"
    with pytest.raises(BlobError, match="truncated") as e:
        decode(blob[:-1])
    assert e.value.kind == "length"
    with pytest.raises(BlobError, match="header needs 96"):
        blob_length(blob[:10])
    # a CRC-valid blob whose model code is not a model: content error, not a crash
    bad = bytearray(blob)
    bad[6] = 7
    bad[-4:] = struct.pack("<I", zlib.crc32(bytes(bad[:-4])))
    with pytest.raises(BlobError, match="model '7'") as e:
        decode(bytes(bad))
    assert e.value.kind == "content"


def test_encode_refuses_bad_fields():
    cal = make_cal(4)
    with pytest.raises(DataError, match="serial .* at most 32 UTF-8 bytes"):
        encode(cal, "x" * 33, "ST", 1, 0)
    with pytest.raises(DataError, match="station id"):
        encode(cal, "SN", "a\0b", 1, 0)
    with pytest.raises(DataError, match="generation"):
        encode(cal, "SN", "ST", 2**32, 0)


def test_generation_order_wraps():
    assert newer(2, 1) and not newer(1, 2) and not newer(5, 5)
    assert newer(0, 0xFFFFFFFF) and not newer(0xFFFFFFFF, 0)
    assert newer(3, 0xFFFFFFFE)


def test_fitted_table_blob_drops_the_redundant_base_and_round_trips_exactly():
    """A table whose first row is the base (every fitted one) is written without the base: a
    3-temperature table fits a 512-byte slot; any other table keeps the base, both exact."""
    rng = np.random.default_rng(7)
    k = 3
    table = TemperatureTable(np.array([-18.5, 26.3, 71.3]), np.eye(3) + rng.normal(0, 0.01, (k, 3, 3)),
                             rng.normal(0, 0.05, (k, 3)), np.zeros((k, 3)), "linear")
    cal = Calibration("12", table.W[0], table.V[0], table.Gamma[0], "counts", 16384.0, temperature=table)
    blob = encode(cal, "SN1", "st", 1, 0)
    assert len(blob) == HEADER_SIZE + 128 * k + 4 <= 512
    back, header = decode(blob)
    assert header.temperature_points == k
    for a, b in ((back.W, cal.W), (back.V, cal.V), (back.temperature.W, table.W), (back.temperature.V, table.V)):
        assert np.array_equal(a, b)
    other = Calibration("12", np.eye(3), np.zeros(3), np.zeros(3), "counts", 16384.0, temperature=table)
    blob2 = encode(other, "SN1", "st", 1, 0)
    assert len(blob2) == blob_size(k)
    assert np.array_equal(decode(blob2)[0].W, np.eye(3))
