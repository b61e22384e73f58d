"""What a burn did (``BurnOutcome``, recorded in the results store) and what the NVM holds after one
that failed, in words (``holds_text``); the writer is nvm/writer.py."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TypedDict

from ..errors import NVMError
from ..jsontypes import JsonObject
from .blob import BlobHeader


class BlobIdentity(TypedDict):
    """Which calibration a slot holds: slot, generation, CRC-32, serial."""

    slot: str
    generation: int
    crc32: int
    serial: str


class NoValidBlob(TypedDict):
    """No slot holds a valid calibration (``{"slot": None}``)."""

    slot: None


@dataclass
class BurnOutcome:
    """Result of one burn, for the results store (``to_dict``)."""

    ok: bool
    slot: str
    addr: int
    generation: int
    length: int
    crc32: int
    serial: str
    station_id: str
    time: int
    previous: BlobIdentity | None  # newest valid blob before the burn: slot, generation, CRC-32, serial
    verified: bool = False  # read back byte for byte and decoded as the newest
    backup: str | None = None
    error: str | None = None
    # the newest valid blob after the burn (slot, generation, CRC-32, serial); {"slot": None}: no valid
    # calibration; None: not read (or reads did not settle)
    nvm_after: BlobIdentity | NoValidBlob | None = None
    # what the written slot held before (writer.SlotStatus.to_dict; a corrupt slot adds raw_base64,
    # the evidence the burn destroys); None: it was erased
    overwrote: JsonObject | None = None

    def to_dict(self) -> JsonObject:
        """The JSON form (the results store, --json)."""
        return asdict(self)


class BurnError(NVMError):
    """A burn failed; ``outcome`` says where, and the previous calibration is untouched."""

    def __init__(self, message: str, outcome: BurnOutcome) -> None:
        super().__init__(message)
        outcome.ok, outcome.error = False, str(self)
        self.outcome = outcome


def identity_of(slot: str, h: BlobHeader) -> BlobIdentity:
    return {"slot": slot, "generation": h.generation, "crc32": h.crc32, "serial": h.serial}


def holds_text(outcome: BurnOutcome) -> str:
    """What the NVM holds after a failed burn, against what it held before, in words."""
    after, prev = outcome.nvm_after, outcome.previous
    if after is None:
        return "what the NVM holds now could not be read (reads disagree)"
    if after["slot"] is None:
        return "the NVM holds no valid calibration" + (", as before the burn" if prev is None else
                                                         f" (it held slot {prev['slot']}, generation "
                                                         f"{prev['generation']} before the burn)")
    here, crc = f"slot {after['slot']}, generation {after['generation']}", f"CRC-32 0x{after['crc32']:08x}"
    if prev is not None and (after["slot"], after["crc32"]) == (prev["slot"], prev["crc32"]):
        return f"previous calibration ({here}) is untouched and is the newest valid one ({crc})"
    return f"the NVM holds {here} ({crc}) as the newest valid calibration"
