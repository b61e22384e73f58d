"""A/B slot calibration writer on any board NVM (EEPROM, bridge flash, simulated).

Two page-aligned slots A and B each hold one blob (nvm/blob.py).  A
burn writes the slot that does NOT hold the newest valid blob, with generation + 1,
and reads it back byte for byte.  Until the new blob is complete its CRC fails, so
an interrupted or failed write leaves the previous calibration as the newest valid
one; because slots are page aligned, no page write ever touches both slots.

A safe A/B burn: (1) never writes the slot holding the newest valid blob (the board keeps a
calibration through a power loss at any byte); (2) with no valid blob, writes an erased slot
before a corrupt one, so a corrupt slot (evidence of a torn write, a worn cell or tampering) is
kept on the board; (3) a corrupt slot that must be written (the other slot holds the only valid
calibration, or both are corrupt) is recorded first: the outcome's ``overwrote`` holds its status
and raw bytes, and the station records the outcome before the first byte (``before_write``);
(4) after the write, the new blob must read back as the newest valid one (slot and CRC-32), else
the new slot is invalidated and the burn fails.

Service functions (``accelcal nvm read|backup|restore|erase``): ``read_newest``,
``status``, ``backup`` (raw image of both slots in a JSON file with its CRC-32: image_file.py),
``restore`` (checks the image, writes, reads back) and ``erase``.
"""
from __future__ import annotations

import base64
import logging
import time as _time
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..calibration import Calibration
from ..drivers.base import NVM
from ..errors import AccelcalError, NVMError
from ..jsontypes import JsonObject
from .blob import GENERATION_MOD, HEADER_SIZE, BlobError, BlobHeader, blob_length, blob_size, decode, encode, newer
from .image_file import IMAGE_SCHEMA, IMAGE_VERSION, BackupSummary, read_image, save_image
from .outcome import BlobIdentity, BurnError, BurnOutcome, NoValidBlob, holds_text, identity_of

SLOTS = ("A", "B")
log = logging.getLogger(__name__)


@dataclass
class SlotStatus:
    """What one slot holds: state is valid, empty (erased) or corrupt (error says why)."""

    slot: str
    addr: int
    size: int
    state: str
    crc_ok: bool | None = None  # None when the CRC could not be reached (bad magic, length)
    generation: int | None = None
    serial: str | None = None
    station_id: str | None = None
    time: int | None = None
    model: str | None = None
    length: int | None = None
    error: str | None = None
    newest: bool = False

    def to_dict(self) -> JsonObject:
        """The JSON form (the results store, --json)."""
        return asdict(self)


# what a scan finds in each slot: its status, and the calibration and header of a valid blob
_Scan = list[tuple[SlotStatus, Calibration | None, BlobHeader | None]]


def _first_difference(a: bytes, b: bytes) -> int:
    return next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))


class CalibrationWriter:
    """A/B calibration slots in ``nvm`` starting at ``base_addr``.

    ``slot_size`` defaults to half the NVM above ``base_addr``, rounded down to whole
    pages (24C32: 2 x 2048 bytes); base address and slot size must be page multiples.
    """

    def __init__(self, nvm: NVM, slot_size: int | None = None, base_addr: int = 0) -> None:
        self.nvm = nvm
        page = max(1, int(getattr(nvm, "page_size", 1) or 1))
        avail = int(nvm.size) - int(base_addr)
        if slot_size is None:
            slot_size = (avail // 2) // page * page
        self.base_addr, self.slot_size, self.page_size = int(base_addr), int(slot_size), page
        if base_addr < 0 or base_addr % page or slot_size % page:
            raise NVMError(f"NVM layout: base address {base_addr} and slot size {slot_size} must be "
                           f"non-negative multiples of the {page}-byte page")
        if slot_size < blob_size(0) or 2 * slot_size > avail:
            raise NVMError(f"NVM layout: two slots of {slot_size} bytes from address {base_addr} do not fit; "
                           f"allowed slot size {blob_size(0)} to {avail // 2} bytes in a {nvm.size}-byte NVM")

    def slot_addr(self, i: int) -> int:
        return self.base_addr + i * self.slot_size

    # -- reading ----------------------------------------------------------------------
    def _inspect(self, i: int, read: Callable[[int, int], bytes]
                 ) -> tuple[SlotStatus, Calibration | None, BlobHeader | None]:
        """Decode slot ``i`` through ``read(offset, n)`` (offsets relative to the slot)."""
        st = SlotStatus(SLOTS[i], self.slot_addr(i), self.slot_size, "corrupt")
        source = f"NVM slot {SLOTS[i]}"
        head = read(0, HEADER_SIZE)
        try:
            length = blob_length(head, source)
            if length > self.slot_size:
                raise BlobError(f"{source}: length {length} exceeds the {self.slot_size}-byte slot", "length")
            cal, h = decode(head + read(HEADER_SIZE, length - HEADER_SIZE), source)
        except BlobError as e:
            st.state = "empty" if e.kind == "empty" else "corrupt"
            st.crc_ok = {"crc": False, "content": True}.get(e.kind)
            st.error = str(e)
            return st, None, None
        st.state, st.crc_ok = "valid", True
        st.generation, st.serial, st.station_id = h.generation, h.serial, h.station_id
        st.time, st.model, st.length = h.time, h.model, h.length
        return st, cal, h

    def _scan(self, image: bytes | None = None) -> _Scan:
        """Status, calibration and header of both slots; marks the newest valid one."""
        out: _Scan = []
        for i in range(2):
            start = self.slot_addr(i) if image is None else i * self.slot_size

            def read(off: int, n: int, start: int = start) -> bytes:
                if image is None:
                    return bytes(self.nvm.read(start + off, n))
                return image[start + off: start + off + n]

            out.append(self._inspect(i, read))
        valid = [i for i in range(2) if out[i][0].state == "valid"]
        if valid:
            best = valid[0]
            for i in valid[1:]:
                if newer(self._valid(out, i)[1].generation, self._valid(out, best)[1].generation):
                    best = i
            out[best][0].newest = True
        return out

    @staticmethod
    def _newest(scan: _Scan) -> int | None:
        return next((i for i, (st, _, _) in enumerate(scan) if st.newest), None)

    @staticmethod
    def _valid(scan: _Scan, i: int) -> tuple[Calibration, BlobHeader]:
        """Calibration and header of slot ``i`` of a scan, which holds a valid blob (e.g. the newest)."""
        _, cal, h = scan[i]
        if cal is None or h is None:
            raise NVMError(f"NVM slot {SLOTS[i]} holds no valid calibration")
        return cal, h

    def status(self) -> list[SlotStatus]:
        return [st for st, _, _ in self._scan()]

    def read_newest(self, serial: str | None = None, allow_other_serial: bool = False, settled: bool = False
                    ) -> tuple[Calibration, BlobHeader, str] | None:
        """(calibration, header, slot) of the newest valid slot, or None when neither is valid.

        With ``serial``, a blob bound to another device serial is refused unless
        ``allow_other_serial``: a calibration belongs to one board.  ``settled``: read the slots
        until two reads agree (``settled_image``) rather than once.
        """
        scan = self._scan(self.settled_image() if settled else None)
        i = self._newest(scan)
        if i is None:
            return None
        cal, h = self._valid(scan, i)
        if serial is not None and h.serial != serial and not allow_other_serial:
            raise NVMError(f"NVM slot {SLOTS[i]} holds a calibration bound to serial {h.serial!r}, not this "
                           f"board's {serial!r}; allow another serial (--any-serial) to read it anyway")
        return cal, h, SLOTS[i]

    # -- writing ----------------------------------------------------------------------
    def _write_verified(self, addr: int, data: bytes, what: str) -> None:
        try:
            self.nvm.write(addr, data)
            back = bytes(self.nvm.read(addr, len(data)))
        except (AccelcalError, OSError) as e:
            raise NVMError(f"{what}: write at address {addr} failed ({e})") from None
        if back != data:
            off = _first_difference(back, data)
            if off >= len(back):
                raise NVMError(f"{what}: read-back returned {len(back)} of {len(data)} bytes")
            raise NVMError(f"{what}: read-back differs at address {addr + off} "
                           f"(wrote 0x{data[off]:02x}, read 0x{back[off]:02x})")

    def burn(self, calibration: Calibration, serial: str, station_id: str, *, time: float | None = None,
             backup_to: str | Path | None = None,
             before_write: Callable[[BurnOutcome], None] | None = None) -> BurnOutcome:
        """Write ``calibration`` to the slot not holding the newest valid blob, with generation + 1.

        The slots are read until two reads agree byte for byte (``settled_image``), so a bus that
        corrupts reads cannot make a valid previous calibration look absent and get overwritten.
        Refuses a blob larger than a slot before writing anything.  A newest blob bound to another
        serial does not stop a burn (the outcome's ``previous`` records it).  When the write or its
        read-back fails, the new slot is invalidated (``revert``) so the previous calibration is
        the newest valid one again, and BurnError carries an outcome whose ``nvm_after`` says what
        the NVM holds afterwards (slot, generation, CRC-32).
        """
        try:
            before = self.settled_image()
            scan = self._scan(before)
        except (AccelcalError, OSError) as e:
            raise NVMError(f"reading the NVM before the burn failed ({getattr(e, 'strerror', None) or e}); "
                           "nothing was written") from None
        prev = self._newest(scan)
        target = self._burn_target(scan, prev)
        gen = 1 if prev is None else (self._valid(scan, prev)[1].generation + 1) % GENERATION_MOD
        now = _time.time() if time is None else time
        blob = encode(calibration, serial, station_id, gen, now)
        if len(blob) > self.slot_size:
            raise NVMError(f"calibration blob is {len(blob)} bytes; an NVM slot holds {self.slot_size}; "
                           "nothing was written (fewer temperature points or a larger slot)")
        _, h = decode(blob)
        previous = None if prev is None else identity_of(SLOTS[prev], self._valid(scan, prev)[1])
        outcome = BurnOutcome(False, SLOTS[target], self.slot_addr(target), gen, len(blob), h.crc32,
                              h.serial, h.station_id, h.time, previous,
                              overwrote=self._evidence(scan[target][0], before, target))
        if backup_to is not None:
            self.backup(backup_to)
            outcome.backup = str(backup_to)
        if before_write is not None:  # e.g. the store records slot, generation and CRC before any byte
            before_write(outcome)
        log.info("burning %s: slot %s, generation %d, %d bytes, CRC-32 %08x", serial, SLOTS[target], gen, len(blob),
                 h.crc32)
        try:
            self._write_verified(outcome.addr, blob, f"burn of NVM slot {SLOTS[target]}")
            outcome.nvm_after = self.holds()
            if outcome.nvm_after is None or outcome.nvm_after.get("slot") != SLOTS[target] \
                    or outcome.nvm_after.get("crc32") != h.crc32:
                raise NVMError(f"burn of NVM slot {SLOTS[target]}: slot is not the newest valid after writing")
        except (AccelcalError, OSError) as e:
            self.revert(outcome)
            log.error("burn of %s failed: %s; %s", serial, e, holds_text(outcome))
            raise BurnError(f"{e}; {holds_text(outcome)}", outcome) from None
        outcome.ok = outcome.verified = True
        log.info("burned %s: slot %s, generation %d, read back and verified", serial, SLOTS[target], gen)
        return outcome

    @staticmethod
    def _burn_target(scan: _Scan, prev: int | None) -> int:
        """The slot a burn writes (module doc, "A safe A/B burn"): never the newest valid one; with
        no valid blob an erased slot before a corrupt one (A when both are alike)."""
        if prev is not None:
            return 1 - prev
        states = [st.state for st, _, _ in scan]
        return 1 if states[0] == "corrupt" and states[1] == "empty" else 0

    def _evidence(self, st: SlotStatus, image: bytes, i: int) -> JsonObject | None:
        """What the slot a burn is about to write held, for the outcome recorded before the first byte:
        None when erased; its status when valid (an older calibration); its status and raw bytes
        (base64) when corrupt, the only copy of the evidence left once the slot is overwritten."""
        if st.state == "empty":
            return None
        out: JsonObject = st.to_dict()
        if st.state == "corrupt":
            raw = image[i * self.slot_size:(i + 1) * self.slot_size]
            out["raw_base64"] = base64.b64encode(raw).decode("ascii")
        return out

    def settled_image(self, tries: int = 5) -> bytes:
        """Raw bytes of both slots, every byte read alike at least twice (up to ``tries`` reads).

        A bus that corrupts reads at random does not corrupt the same byte alike twice; a bus
        that corrupts every read the same way cannot be told from a corrupt slot by reading.
        """
        reads = [np.frombuffer(self.image(), np.uint8)]
        out, agreed = reads[0].copy(), np.zeros(len(reads[0]), bool)
        for _ in range(tries - 1):
            new = np.frombuffer(self.image(), np.uint8)
            for old in reads:
                same = (old == new) & ~agreed
                out[same], agreed = new[same], agreed | same
            if agreed.all():
                return out.tobytes()
            reads.append(new)
        raise NVMError(f"NVM reads disagree ({tries} reads of {len(out)} bytes, {int((~agreed).sum())} bytes "
                       "never read alike twice): the bus corrupts what it reads")

    def holds(self) -> BlobIdentity | NoValidBlob | None:
        """What the NVM holds now: the newest valid blob's slot, generation, CRC-32 and serial
        (``{"slot": None}`` when no slot is valid), or None when reads do not settle."""
        try:
            scan = self._scan(self.settled_image())
        except (AccelcalError, OSError):
            return None
        i = self._newest(scan)
        return NoValidBlob(slot=None) if i is None else identity_of(SLOTS[i], self._valid(scan, i)[1])

    def revert(self, outcome: BurnOutcome, tries: int = 3) -> None:
        """Invalidate the slot a failed burn wrote (erase its header), so the previous calibration,
        if any, is the newest valid one again; sets ``outcome.nvm_after`` to what the NVM holds."""
        for _ in range(tries):
            try:
                self._write_verified(outcome.addr, b"\xff" * HEADER_SIZE, f"revert of NVM slot {outcome.slot}")
                break
            except (AccelcalError, OSError):
                continue
        outcome.verified = False
        outcome.nvm_after = self.holds()


    # -- service: backup, restore, erase ---------------------------------------------
    def image(self) -> bytes:
        """Raw bytes of both slots."""
        return bytes(self.nvm.read(self.base_addr, 2 * self.slot_size))

    def backup(self, path: str | Path, overwrite: bool = False, chip: str | None = None) -> BackupSummary:
        """Save both slots' raw image (read until two reads agree), its CRC-32, slot status and the
        chip it came from to a JSON file (atomically)."""
        path = Path(path)
        if path.exists() and not overwrite:
            raise NVMError(f"{path}: backup file exists; choose another name (backups are never overwritten)")
        img = self.settled_image()
        summary = BackupSummary(
            schema=IMAGE_SCHEMA, version=IMAGE_VERSION, created=_time.time(), nvm_size=int(self.nvm.size),
            page_size=self.page_size, chip=chip, base_addr=self.base_addr, slot_size=self.slot_size,
            length=len(img), crc32=zlib.crc32(img), slots=[st.to_dict() for st, _, _ in self._scan(img)])
        save_image(path, summary, img)
        return summary

    def load_image(self, path: str | Path) -> tuple[bytes, JsonObject]:
        """Image bytes and document of a backup file, checked against its CRC and this layout."""
        return read_image(path, self.base_addr, self.slot_size)

    def restore(self, path: str | Path, *, serial: str | None = None, allow_other_serial: bool = False,
                backup_to: str | Path | None = None, chip: str | None = None) -> list[SlotStatus]:
        """Write a backup image back and read it back.

        Before any byte is written the image is checked: its CRC-32 and layout, at least one
        slot holding a valid calibration (blob CRC), distinct generations, the chip it was taken
        from (when both it and ``chip`` are known) and, with ``serial``, the board its newest
        calibration is bound to.  Slots are written in the order ``_restore_plan`` gives, so an
        interruption leaves a valid calibration (old or restored); the end result is read back.
        """
        img, doc = self.load_image(path)
        image_scan = self._scan(img)
        i = self._newest(image_scan)
        if i is None:
            why = "; ".join(f"slot {st.slot} {st.state}" + (f" ({st.error})" if st.error else "")
                            for st, _, _ in image_scan)
            raise NVMError(f"{path}: the backup holds no valid calibration ({why}); nothing was written")
        gens = [st.generation for st, _, _ in image_scan if st.state == "valid"]
        if len(gens) == 2 and gens[0] == gens[1]:
            raise NVMError(f"{path}: both slots claim generation {gens[0]}; the newest cannot be told; "
                           "nothing was written")
        if chip is not None and doc.get("chip") not in (None, chip):
            raise NVMError(f"{path}: the backup was taken from a {doc['chip']} chip, this board is a {chip}; "
                           "nothing was written")
        bound_to = self._valid(image_scan, i)[1].serial
        if serial is not None and bound_to != serial and not allow_other_serial:
            raise NVMError(f"{path}: image holds a calibration bound to serial {bound_to!r}, "
                           f"not this board's {serial!r}; allow another serial (--any-serial) to restore it")
        if backup_to is not None:
            self.backup(backup_to, chip=chip)
        for j, content in self._restore_plan(self.settled_image(), img):
            self._write_verified(self.slot_addr(j), content, f"restore of NVM slot {SLOTS[j]}")
        want = identity_of(SLOTS[i], self._valid(image_scan, i)[1])
        if self.holds() != want:
            raise NVMError(f"restore: the NVM does not read back the backup's newest calibration "
                           f"(slot {want['slot']}, generation {want['generation']})")
        return self.status()

    def _newest_id(self, image: bytes) -> tuple[int, int, str] | None:
        """Identity (generation, CRC-32, serial) of the newest valid blob of an image, or None."""
        scan = self._scan(image)
        i = self._newest(scan)
        if i is None:
            return None
        h = self._valid(scan, i)[1]
        return h.generation, h.crc32, h.serial

    def _restore_plan(self, cur: bytes, img: bytes) -> list[tuple[int, bytes]]:
        """Slot writes taking the NVM from ``cur`` to ``img`` such that after a power loss at
        any point (a slot torn, i.e. invalid, or whole) the newest valid blob is the board's
        previous newest or the image's newest.  Plans are checked by simulation; the
        three-write plan first copies the image's newest blob over the board's older slot."""
        n = self.slot_size
        allowed = {self._newest_id(cur), self._newest_id(img)}
        part = lambda b, j: b[j * n: (j + 1) * n]  # noqa: E731
        put = lambda b, j, c: b[:j * n] + c + b[(j + 1) * n:]  # noqa: E731
        torn = b"\x00" * n  # any torn slot fails its CRC: modelled as an invalid slot
        plans = [[(0, part(img, 0)), (1, part(img, 1))], [(1, part(img, 1)), (0, part(img, 0))]]
        k = self._newest(self._scan(img))
        if k is not None:
            plans.append([(1 - k, part(img, k)), (k, part(img, k)), (1 - k, part(img, 1 - k))])
        for plan in plans:
            state, safe = cur, True
            for j, content in plan:
                safe &= self._newest_id(put(state, j, torn)) in allowed
                state = put(state, j, content)
                safe &= self._newest_id(state) in allowed
            if safe:
                return plan
        raise NVMError("restore: no write order keeps a valid calibration through a power loss; "
                       "erase the NVM first (nvm erase) and restore again")

    def erase(self, backup_to: str | Path | None = None, chip: str | None = None) -> list[SlotStatus]:
        """Erase both slots to 0xFF (the EEPROM's blank state) and verify."""
        if backup_to is not None:
            self.backup(backup_to, chip=chip)
        for j in self._order():
            self._write_verified(self.slot_addr(j), b"\xff" * self.slot_size, f"erase of NVM slot {SLOTS[j]}")
        return self.status()

    def _order(self, new_valid: list[bool] | None = None) -> list[int]:
        """Slots in write order: the one holding the newest valid calibration last.

        ``new_valid`` (restore): whether each slot's new content is a valid blob.  When the
        slot written first would get no valid blob, it goes second if that keeps one valid
        calibration in NVM throughout (the other slot still holds one while it is written).
        """
        scan = self._scan()
        first = 1 if self._newest(scan) == 0 else 0
        if new_valid is not None and not new_valid[first] and new_valid[1 - first] \
                and scan[first][0].state == "valid":
            first = 1 - first
        return [first, 1 - first]
