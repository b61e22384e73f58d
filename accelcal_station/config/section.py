"""The base of every config section (unknown keys refused, numbers finite, strict types) and
``_f``, the field declaration with a description and a range that docs/config.md shows."""
from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field

MAX_BOARDS = 64

# three numbers [x, y, z] (YAML gives a list; a strict tuple would refuse it)
Triple = Annotated[list[Annotated[float, Field(ge=0, le=1e6)]], Field(min_length=3, max_length=3)]


class Section(BaseModel):
    """A config section: unknown keys refused, numbers finite."""

    # strict: a quoted "5" or YAML 1.1's 1e300 (a string: no dot) is not taken for a number
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def _f(default: Any, desc: str, ge: float | None = None, le: float | None = None, gt: float | None = None,
       hexadecimal: bool = False) -> Any:
    """``hexadecimal``: a number written in hex where it is used (an I2C address, a register value);
    docs/config.md shows its default and range so (``0x1d``)."""
    return Field(default, description=desc, ge=ge, le=le, gt=gt,
                 json_schema_extra={"notation": "hex"} if hexadecimal else None)
