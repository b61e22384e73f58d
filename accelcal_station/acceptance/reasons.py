"""Typed failure reasons: a code (what failed, e.g. a limit key, ``fit``, ``nvm``) and the
words for people.  A Reason is also the string people read, so lists of reasons print as
before; the store keeps each as ``{"code", "message"}`` and summaries group by ``.code``,
never by parsing the text back."""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any


class Reason(str):
    """``Reason("nvm", "read-back differs")`` reads ``"nvm: read-back differs"``; ``.code`` is ``"nvm"``.

    With ``sep=" "`` the text is ``"code message"`` (limit reasons: ``"residual_rms_mg 1.2 > limit 1"``).
    """

    code: str

    def __new__(cls, code: str, message: str, sep: str = ": ") -> Reason:
        return cls.of(code, f"{code}{sep}{message}")

    @classmethod
    def of(cls, code: str, text: str) -> Reason:
        """A reason whose whole text is ``text`` (a wrapped reason keeps its code)."""
        self = str.__new__(cls, text)
        self.code = str(code)
        return self

    def to_dict(self) -> dict[str, str]:
        """The stored form: the code and the whole text people read."""
        return {"code": self.code, "message": str(self)}

    @classmethod
    def from_dict(cls, d: Any) -> Reason:
        """A stored reason back; a bare string (no code kept) gets code ``""``."""
        if isinstance(d, dict):
            return cls.of(str(d.get("code") or ""), str(d.get("message", "")))
        return d if isinstance(d, Reason) else cls.of("", str(d))

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        return (Reason.of, (self.code, str(self)))


def codes(reasons: Iterable[object]) -> list[str]:
    """The codes of a list of reasons (plain strings give '')."""
    return [getattr(r, "code", "") for r in reasons]


def wrap(reason: object, prefix: str) -> Reason:
    """``reason`` with ``prefix`` before its text, keeping its code (``"at 70 C: "`` + a limit reason)."""
    return Reason.of(getattr(reason, "code", ""), f"{prefix}{reason}")
