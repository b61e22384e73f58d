"""A run's verdict, built in one place: from the typed outcomes of its stages.

Every stage of a board's run that can fail it (opening the device, the chip's self-test, a capture, the fit, the
acceptance limits, the verification, the NVM burn, a fault that ends the flow, the chamber,
recording the result) records an :class:`Outcome` on the run report: its stage and the
reasons it fails the board.  Judging the board on every limit after its verification
records a passing ``judged`` outcome.  :func:`run_verdict` makes the one immutable
:class:`RunVerdict` from them:

- FAIL, with every failing stage's reasons in the order they happened;
- PASS when the board was judged on its limits and nothing failed;
- FAIL with no reason of its own when the run never got as far as its judgment (the store
  records such a run as interrupted or as an error, with what stopped it).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Literal

from ..acceptance.reasons import Reason


class Stage(Enum):
    """The stages of a run that decide its verdict."""

    DEVICE = "device"  # opened, identified, configured
    SELF_TEST = "self_test"  # the chip's built-in self-test, before the poses (docs/self-test.md)
    CAPTURE = "capture"  # a pose captured (a panel's board on a wrong face, not still, NACKed)
    FIT = "fit"  # the model could be fitted
    ACCEPTANCE = "acceptance"  # the limits, before and after verification
    OFFSET_TRIM = "offset_trim"  # the offset trim written, and its change measured (nvm.offset_trim)
    JUDGED = "judged"  # judged on every limit, verification included (passing: the board may PASS)
    NVM = "nvm"  # burned, read back and verified
    FAULT = "fault"  # a device, port or NVM fault that ended the flow
    CHAMBER = "chamber"  # the chamber faulted during a thermal plan
    STORE = "store"  # the result could be recorded


@dataclass(frozen=True)
class Outcome:
    """What one stage found: the reasons it fails the board (none: it passed)."""

    stage: Stage
    reasons: tuple[Reason, ...] = ()

    @property
    def failed(self) -> bool:
        return bool(self.reasons)


@dataclass(frozen=True)
class RunVerdict:
    """A run's verdict and the reasons for it."""

    label: Literal["PASS", "FAIL"]
    reasons: tuple[Reason, ...] = ()

    @property
    def passed(self) -> bool:
        return self.label == "PASS"


def run_verdict(outcomes: Sequence[Outcome]) -> RunVerdict:
    """The verdict of a run from its stages' outcomes (module docstring)."""
    reasons = tuple(r for o in outcomes for r in o.reasons)
    if reasons:
        return RunVerdict("FAIL", reasons)
    judged = any(o.stage is Stage.JUDGED for o in outcomes)
    return RunVerdict("PASS" if judged else "FAIL")
