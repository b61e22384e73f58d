"""The NVM backup file (``accelcal nvm backup|restore``): both slots' raw image in base64 in a JSON document
with its CRC-32, the layout it was taken from and each slot's status; written atomically, never over an
existing file, and read back only after every check (schema, version, layout, length, CRC-32)."""
from __future__ import annotations

import base64
import json
import zlib
from pathlib import Path
from typing import Any, TypedDict

from ..atomic import atomic_write
from ..errors import NVMError
from ..fileguard.jsondoc import read_json
from ..jsontypes import JsonObject

IMAGE_SCHEMA = "accelcal.nvm-image"
IMAGE_VERSION = 1
MAX_BACKUP_BYTES = 1 << 20  # two slots of a 64 KiB EEPROM in base64 are 90 kB


class BackupSummary(TypedDict):
    """What a backup file holds besides its image (``backup`` returns it; the file adds image_base64)."""

    schema: str
    version: int
    created: float  # unix seconds
    nvm_size: int
    page_size: int
    chip: str | None
    base_addr: int
    slot_size: int
    length: int  # image bytes
    crc32: int
    slots: list[JsonObject]  # SlotStatus.to_dict() of each slot


def _short(v: Any) -> str:
    """A value from a backup file, quoted short (a hostile file's value may be huge)."""
    r = repr(v)
    return r if len(r) <= 40 else r[:40] + "..."


def save_image(path: Path, summary: BackupSummary, img: bytes) -> None:
    """The backup file: ``summary`` and the image in base64, written atomically."""
    doc = {**summary, "image_base64": base64.b64encode(img).decode("ascii")}
    try:
        atomic_write(path, json.dumps(doc, indent=1) + "\n")
    except OSError as e:
        raise NVMError(f"{path}: cannot write the backup ({e.strerror})") from None


def read_image(path: str | Path, base_addr: int, slot_size: int) -> tuple[bytes, JsonObject]:
    """Image bytes and document of a backup file, checked against its CRC and the layout of two slots of
    ``slot_size`` bytes at ``base_addr``."""
    path = Path(path)
    doc = read_json(path, "an NVM backup", MAX_BACKUP_BYTES,
                    "a backup holds two slots of a small EEPROM, base64", NVMError)
    if not isinstance(doc, dict) or doc.get("schema") != IMAGE_SCHEMA:
        raise NVMError(f"{path}: not an NVM backup (missing schema {IMAGE_SCHEMA!r})")
    v = doc.get("version")
    if type(v) is int and v > IMAGE_VERSION:  # the one line a calibration file from a newer accelcal gets
        raise NVMError(f"{path}: written by a newer accelcal (NVM backup format version {v}); this accelcal "
                       f"reads up to version {IMAGE_VERSION}: restore it with a newer accelcal-station")
    if v != IMAGE_VERSION:
        raise NVMError(f"{path}: backup version {_short(v)}; this station reads {IMAGE_VERSION}")
    if (doc.get("base_addr"), doc.get("slot_size")) != (base_addr, slot_size):
        raise NVMError(f"{path}: image is for slots of {_short(doc.get('slot_size'))} bytes at "
                       f"{_short(doc.get('base_addr'))}; this NVM has slots of {slot_size} bytes "
                       f"at {base_addr}")
    try:
        img = base64.b64decode(doc["image_base64"], validate=True)
    except (KeyError, TypeError, ValueError):
        raise NVMError(f"{path}: image_base64 missing or not base64") from None
    if len(img) != 2 * slot_size or len(img) != doc.get("length"):
        raise NVMError(f"{path}: image is {len(img)} bytes; expected {2 * slot_size}")
    if zlib.crc32(img) != doc.get("crc32"):
        raise NVMError(f"{path}: image CRC-32 0x{zlib.crc32(img):08x} does not match the recorded "
                       f"{_short(doc.get('crc32'))}; the backup is damaged")
    return img, doc
