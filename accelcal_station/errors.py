"""Errors the station reports to its user as one line (what, where, what is allowed).

Every error a user can cause derives from :class:`AccelcalError`; the command line
prints ``str(err)`` on one line and exits non-zero, never a traceback.
"""
from __future__ import annotations

import termios


class AccelcalError(Exception):
    """Base class: a problem with the user's input, configuration or device."""

    exit_code = 2
    # the typed reason a board's run records when this error ends it (a board's capture or
    # device in a panel; subclasses name their own)
    reason_code = "device"

    def __str__(self) -> str:  # one line, always
        return " ".join(super().__str__().split())


class DataError(AccelcalError):
    """Input data is unreadable, malformed or physically implausible."""


class UnitsError(AccelcalError):
    """Data given in units the operation cannot accept."""


class UnderdeterminedError(AccelcalError):
    """The pose set cannot determine the requested model."""


class ConfigError(AccelcalError):
    """A configuration key is unknown or has an impossible value."""


class DeviceError(AccelcalError):
    """The device did not answer, answered wrongly, or is not the expected chip."""

    exit_code = 3
    reason_code = "device"  # the typed reason a run records when this ends it
    # the station's instrument that faulted (device, jig, chamber, mux, store): a fault of an
    # instrument ends a run as the station's error, never as a board's verdict (DESIGN.md)
    instrument = "device"


class JigError(DeviceError):
    """The jig did not open, answer, move or report as it should: the station's fault."""

    reason_code = "jig"
    instrument = "jig"


class PortLostError(DeviceError):
    """A serial port closed or vanished while in use (the driver boundary maps PORT_FAULTS to it)."""

    reason_code = "port_lost"


class JigPortLostError(PortLostError, JigError):
    """The jig's serial port closed or vanished while in use."""

    reason_code = "port_lost"
    instrument = "jig"


# what a lost port raises below the drivers: OSError (pyserial's SerialException is one, as is
# EIO from a hung-up pty) and termios.error (tcflush/tcsetattr on a vanished tty), not an OSError
PORT_FAULTS: tuple[type[BaseException], ...] = (OSError, termios.error)


class TemperatureRangeError(AccelcalError):
    """A temperature outside the calibrated range, with extrapolation not allowed."""


class NVMError(AccelcalError):
    """Non-volatile memory could not be written, read or verified."""

    exit_code = 4
    reason_code = "nvm"
