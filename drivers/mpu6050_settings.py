"""The MPU6050 bridge driver's settings besides its port (``Mpu6050Settings``, its constructor's keywords),
and ``settings_of``: them from a validated ``device:`` section, with the checks across its keys the
schema alone does not make."""
from __future__ import annotations

from typing import TypedDict

from ..config.kinds import Mpu6050Section
from ..errors import ConfigError
from .mpu6050_registers import check_link_rate, smplrt_div_for


class Mpu6050Settings(TypedDict, total=False):
    """The constructor keywords a ``device:`` section gives (besides its port): :func:`settings_of`."""

    baud: int
    range_g: int
    odr_hz: float
    dlpf: int
    timeout_s: float
    retries: int
    boot_wait_s: float
    accept_who_am_i: tuple[int, ...]


def settings_of(m: Mpu6050Section, path: str = "device") -> tuple[str, Mpu6050Settings]:
    """(port, the driver's keywords) from a validated ``device:`` section, after the checks across its
    keys that the model alone does not make (a port given; the emulator's keys only with ``port:
    emulated``; a sample-rate divider for the data rate; a link fast enough for it).  ``port: emulated``
    is built by the factory (``make_driver``, drivers/emulated.py), which hands the emulator in."""
    port = m.port
    if not port:
        raise ConfigError(f"{path}.port: {port!r}; allowed: a serial port such as /dev/ttyUSB0, or 'emulated'")
    extra = [k for k, v in (("simulator", m.simulator), ("seed", m.seed), ("emulator", m.emulator)) if v is not None]
    if extra and port != "emulated":
        raise ConfigError(f"{path}.{extra[0]}: only used with port: emulated")
    smplrt_div_for(m.odr_hz, m.dlpf, f"{path}.odr_hz")
    check_link_rate(m.odr_hz, m.baud, f"{path}.odr_hz")
    return port, Mpu6050Settings(baud=m.baud, range_g=m.range_g, odr_hz=m.odr_hz, dlpf=m.dlpf,
                                 timeout_s=m.timeout_s, retries=m.retries, boot_wait_s=m.boot_wait_s,
                                 accept_who_am_i=tuple(m.accept_who_am_i))
