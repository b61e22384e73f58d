"""Prose among logged data: the rule that tells a banner or prompt line from damaged data.

A serial monitor's capture holds a banner, a sensor description and prompt lines
(``>>> Place accelerometer ...``) between its samples.  Such a line is skipped and noted;
a data row with a bad cell is an error naming its line.  The rule (``is_text``): split as
the data are, a prose line holds a cell that is not a number and fewer numbers than half
the data's field count; every other line is data and must parse whole.
"""
from __future__ import annotations


def is_number(s: str) -> bool:
    """The cell parses as a float (surrounding spaces allowed, as float() allows them)."""
    try:
        float(s)
        return True
    except ValueError:
        return False


def is_text(cells: list[str], fields: int) -> bool:
    """A line of prose, not data: a banner, a prompt (``>>> Place accelerometer ...``), a repeated
    header.  Its fields (split as the data are) hold a cell that is not a number, and fewer numbers
    than half the data's ``fields``.  A line with half or more of its cells numbers, or with numbers
    only (``0.12,abc,9.81,1``, ``0.12,-0.03``, ``nan,1,2,3``), is data-looking: damaged data, an
    error naming its line, never skipped."""
    nums = sum(is_number(c) for c in cells)
    return nums < fields / 2 and any(c.strip() and not is_number(c) for c in cells)


__all__ = ["is_number", "is_text"]
