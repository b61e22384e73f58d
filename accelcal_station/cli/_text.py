"""Text from files and devices, made safe to print: terminal control codes are shown
escaped (\\x1b...), never sent raw to the operator's terminal."""
from __future__ import annotations

import re

_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def clean(text: str) -> str:
    """``text`` with every C0/C1 control character (ESC, BEL, CSI...) written as \\xNN;
    newlines become spaces (one line)."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", str(text).replace("\n", " ").replace("\t", " "))
