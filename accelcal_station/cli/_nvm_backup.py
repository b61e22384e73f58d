"""What `nvm restore` checks of a backup before a byte is written, and where a backup may go.

A backup's overall CRC-32 only says the file is as it was written: a byte flipped inside a slot
and the overall CRC computed again passes it.  So each slot of the image is decoded on its own
(nvm.blob: magic, length, its own CRC-32, content); a slot that is neither a valid blob nor
erased refuses the restore in one line, so a damaged slot is never written over a valid
calibration.  A backup goes to a new regular file: an existing file (never overwritten), a
device (``/dev/full``), a FIFO or a directory is named as what it is.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from ..errors import DataError, NVMError
from ..fileguard.jsondoc import read_json
from ..nvm.blob import HEADER_SIZE, BlobError, blob_length, decode
from ..nvm.image_file import IMAGE_SCHEMA, MAX_BACKUP_BYTES
from ..nvm.writer import SLOTS, CalibrationWriter


def _length_field(writer: CalibrationWriter, path: str | Path) -> str | None:
    """The backup's ``length`` field when it, and not the image, is what disagrees with this NVM."""
    try:
        doc = read_json(path, "an NVM backup", MAX_BACKUP_BYTES, "a backup is small", NVMError)
    except NVMError:
        return None
    want = 2 * writer.slot_size
    if isinstance(doc, dict) and doc.get("schema") == IMAGE_SCHEMA and doc.get("length") != want:
        value = doc.get("length")
        return (f"{path}: field 'length' is {value!r}; expected {want} (two slots of {writer.slot_size} bytes); "
                "the backup is damaged; nothing was written")
    return None


def check_backup_slots(writer: CalibrationWriter, path: str | Path) -> None:
    """One NVMError (nothing written) when the backup's file, layout or any slot's own blob is damaged."""
    try:
        img, _ = writer.load_image(path)
    except NVMError as e:
        raise NVMError(_length_field(writer, path) or str(e)) from None
    n = writer.slot_size
    damaged: list[BlobError] = []
    valid = 0
    for i, name in enumerate(SLOTS):
        raw = img[i * n:(i + 1) * n]
        source = f"slot {name} of the backup"
        try:
            length = blob_length(raw[:HEADER_SIZE], source)
            if length > n:
                raise BlobError(f"{source}: length {length} exceeds the {n}-byte slot", "length")
            decode(raw[:length], source)
            valid += 1
        except BlobError as e:
            if e.kind != "empty":
                damaged.append(e)
    if damaged and valid:  # with no valid slot at all, the writer refuses it ("holds no valid calibration")
        raise NVMError(f"{path}: {damaged[0]}; the backup is damaged (its overall CRC-32 matches, a slot's own "
                       "does not); nothing was written")


def check_new_file(label: str, path: str | Path) -> None:
    """A backup target is a new regular file: one line naming what an existing path is instead."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as e:
        raise DataError(f"{label} {path}: cannot use it ({e.strerror}); choose a new file name") from None
    if stat.S_ISREG(st.st_mode):
        raise NVMError(f"{label} {path}: backup file exists; choose another name (backups are never overwritten)")
    kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a character device" if stat.S_ISCHR(st.st_mode)
            else "a block device" if stat.S_ISBLK(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
            else "a symbolic link" if stat.S_ISLNK(st.st_mode) else "a socket")
    raise DataError(f"{label} {path}: {kind}, not a regular file; a backup is written to a new regular file "
                    "(nothing written); choose a file name")
