"""Typed failure reasons: a code (what failed, e.g. a limit key, ``fit``, ``nvm``) and the
words for people.  A Reason is also the string people read, so lists of reasons print and
store as before; summaries group by ``.code`` instead of parsing the text back."""
from __future__ import annotations


class Reason(str):
    """``Reason("nvm", "read-back differs")`` reads ``"nvm: read-back differs"``; ``.code`` is ``"nvm"``.

    With ``sep=" "`` the text is ``"code message"`` (limit reasons: ``"residual_rms_mg 1.2 > limit 1"``).
    """

    code: str

    def __new__(cls, code: str, message: str, sep: str = ": ") -> "Reason":
        self = super().__new__(cls, f"{code}{sep}{message}")
        self.code = code
        return self

    def to_dict(self) -> dict[str, str]:
        return {"code": self.code, "message": str(self)}


def codes(reasons) -> list[str]:
    """The codes of a list of reasons (plain strings from older records give '')."""
    return [getattr(r, "code", "") for r in reasons]
