"""The serial-number rule, one for every place a serial enters the station (issue 49): ``--serial``,
a scanned serial, ``device.serial`` and ``device.boards[i].serial`` in a config, and the serial a
device reports (its EEPROM, the bridge).  A board's serial is burned into its NVM blob's 32-byte
serial field (nvm/blob.py ``TEXT_BYTES``), so a board serial longer than that is refused where it
enters, before the first pose, never at the burn after the whole calibration.  Lots and station ids
follow the same characters (station.id is burned too, so it has the same 32-byte limit).
"""
from __future__ import annotations

import re

from ..errors import DataError

# the NVM blob's serial and station-id fields (nvm/blob.py TEXT_BYTES; tests hold the two equal)
BOARD_SERIAL_MAX = 32
LABEL_MAX = 64  # a lot: recorded, never burned
_RULE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:/-]*")


def check_serial(text: str, where: str, max_len: int = BOARD_SERIAL_MAX, what: str = "serial number") -> str:
    """``text`` stripped when it is a serial number (or a lot or station id, ``what``, of the same form):
    1-``max_len`` ASCII letters, digits and . _ : / -, starting with a letter or digit (no markup, no
    formula, no control character); else one DataError naming where it came from and what is allowed."""
    s = text.strip()
    if len(s) > max_len or not _RULE.fullmatch(s):
        raise DataError(f"{where}: {s[:40]!r} is not a {what}; allowed: 1-{max_len} letters, digits and "
                        ". _ : / -, starting with a letter or digit")
    return s


def check_label(text: str, where: str, what: str = "lot name") -> str:
    """A lot name: the serial rule with up to LABEL_MAX characters (a lot is never burned)."""
    return check_serial(text, where, LABEL_MAX, what)
