"""One loader for every command that reads measurements (`accelcal fit`, `accelcal diagnose`)."""
from __future__ import annotations

from .config import load_yaml
from .errors import ConfigError, DataError
from .posetable import read_pose_table
from .rawlog import read_raw_log, static_session


def device_section(path: str) -> dict:
    """The ``device:`` section of a station config, or a file that is only a device section."""
    data = load_yaml(path)
    section = data.get("device", data if "driver" in data else None)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: no 'device' section; allowed: a mapping with 'driver: simulated, mma8451 "
                          "or mpu6050'")
    return dict(section)


def load_session(path: str, raw: bool, units=None, counts_per_g=None, gravity=None, columns=None,
                 skip_rows=None, rate=None, references: bool = True):
    """A pose table, or a raw log segmented into static poses: (Session, (RawLog, StaticDetection) or None)."""
    if raw:
        log = read_raw_log(path, columns, skip_rows or 0, rate)
        session, det = static_session(log, units or "counts", counts_per_g, gravity)
        return session, (log, det)
    for flag, v in (("--columns", columns), ("--skip-rows", skip_rows), ("--rate", rate)):
        if v is not None:
            raise DataError(f"{flag} is for raw sample logs; add --raw to read {path} as one")
    return read_pose_table(path, units, counts_per_g, gravity, references=references), None
