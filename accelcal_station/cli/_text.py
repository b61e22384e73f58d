"""Text from files and devices, made safe to print: terminal control codes are shown
escaped (\\x1b...), never sent raw to the operator's terminal."""
from __future__ import annotations

import re

_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


MAX_QUOTED_CHARS = 80  # a value quoted from a file or option, shown in full up to this
MAX_ERROR_CHARS = 1000  # one error line: what, where, what is allowed; never a file's worth
# a quoted value: a quote not closing a word, then no quote, then a quote not opening one
_QUOTED = re.compile(r"(?<![\w'\"])(['\"])([^'\"]{" + str(MAX_QUOTED_CHARS + 1) + r",})\1(?![\w'\"])")


def error_text(text: str) -> str:
    """An error line fit to print: ``clean``, a long quoted value cut to its start and length, and the
    whole line at most MAX_ERROR_CHARS (its start and end kept: what and where, what is allowed)."""
    t = _QUOTED.sub(lambda m: f"{m[1]}{m[2][:60]}...{m[1]} ({len(m[2])} characters)", clean(text))
    if len(t) > MAX_ERROR_CHARS:
        half = MAX_ERROR_CHARS // 2
        t = f"{t[:half]} ... ({len(t) - 2 * half} characters left out) ... {t[-half:]}"
    return t


def clean(text: str) -> str:
    """``text`` with every C0/C1 control character (ESC, BEL, CSI...) written as \\xNN;
    newlines become spaces (one line)."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", str(text).replace("\n", " ").replace("\t", " "))
