"""What reading a raw log inferred, and from where (data/rawlog.py fills it; the commands print it)."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class LogInfo:
    """What reading a log inferred, and from where (printed by the commands)."""

    skipped_rows: int = 0
    preamble: dict[str, str] = field(default_factory=dict)
    rate_source: str | None = None  # "time column", "--rate", "preamble line 1 ('Fs,100')"
    time_unit: str | None = None  # s, ms, us
    time_unit_reason: str = ""
    axis_names: dict[str, str] = field(default_factory=dict)  # x/y/z/t -> the file's column name
    units_hint: str | None = None  # units named in the x, y, z column names: g, mg, mps2, counts
    stated_rate_hz: float | None = None
    time_unit_judged: bool = False  # the time unit was guessed from the step alone
    stated: dict[str, str] = field(default_factory=dict)  # "# key: value" lines before the data (posetable.META_RE)
    stated_line: dict[str, int] = field(default_factory=dict)  # their 1-based line numbers
    text_lines: list[tuple[int, str]] = field(default_factory=list)  # prose skipped among the data (is_text)
    decimals: dict[str, int] = field(default_factory=dict)  # x/y/z -> most decimals printed (value grid's rounding)
