"""A finished run recorded in the store, or kept in the local outbox with the exact truth said.

``finish_run`` writes the poses, calibration, verdict and NVM outcome in one transaction.
When it fails (a disk I/O error, a malformed database, a full disk) after the board's NVM
was burned, the board carries a calibration the store has no record of.  ``record_result``
then closes the run as ``error`` where it still can, writes the whole result into the local
outbox (an SQLite file of its own: store.outbox, default $XDG_STATE_HOME/accelcal/outbox.sqlite),
and raises one StoreError that says exactly what was burned (slot, generation, CRC-32), what
the store holds for the run and where the result was kept.
"""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

from ..errors import AccelcalError
from ..nvm.writer import BurnOutcome
from ..store.outbox import default_outbox
from ..store.records import StoreError
from ..store.runs import Store


def burned_text(nvm: BurnOutcome | dict[str, Any] | None) -> str:
    """What the board's NVM holds after the run, from its burn outcome (a BurnOutcome, its dict or None)."""
    d = nvm.to_dict() if isinstance(nvm, BurnOutcome) else nvm
    if not isinstance(d, dict):
        return "nothing was written to the board's NVM"
    crc = d.get("crc32")
    where = (f"slot {d.get('slot')}, generation {d.get('generation')}, CRC-32 "
             f"{f'0x{crc:08x}' if isinstance(crc, int) else crc}")
    if d.get("ok"):
        return f"the board's NVM WAS written ({where}{', verified' if d.get('verified') else ''})"
    return f"the NVM burn failed ({where}: {d.get('error') or 'not verified'}); the previous calibration is kept"


def _held(store: Store, run_id: int) -> str:
    """What the store holds for ``run_id`` now, read back (never assumed)."""
    try:
        rec = store.get_run(run_id)
    except AccelcalError as e:
        return f"what {store.path} holds for run {run_id} cannot be read ({e})"
    cal = "with" if rec.calibration else "without"
    return (f"{store.path} holds run {run_id} as {rec.status} {cal} a calibration "
            f"(NVM status {rec.nvm_status or 'none'})")


def _keep(outbox: Path, start: dict[str, Any], finish: dict[str, Any], target: str, run_id: int) -> str:
    """The run written whole into the outbox; where it went, or why it could not be."""
    try:
        with Store(outbox) as ob:
            local = ob.start_run(**start)
            ob.log_event(local, "unrecorded", f"not recorded in {target} (run {run_id})",
                         data={"target": target, "run_id": run_id})
            ob.finish_run(local, **finish)
    except (AccelcalError, OSError) as e:
        return f"the result could NOT be kept in the outbox {outbox} either ({e})"
    return (f"its calibration, verdict and NVM outcome are kept in the outbox {outbox} as run {local} "
            f"(`accelcal report show {local} --db {outbox}`)")


def start_args(cfg: Any, rep: Any, operator: str | None, lot: str | None, counts_per_g: float | None,
               **extra: Any) -> dict[str, Any]:
    """Store.start_run's arguments for a run of ``cfg`` (a StationConfig) reported in ``rep``."""
    return {"device_serial": rep.serial, "chip": rep.chip, "station_id": cfg.station_id, "operator": operator,
            "lot": lot, "config_text": cfg.text, "model": cfg.model, "units": "counts",
            "counts_per_g": counts_per_g, **extra}


def record_result(store: Store, run_id: int, start: dict[str, Any], finish: dict[str, Any],
                  outbox: Path | None) -> None:
    """``store.finish_run(run_id, **finish)``; on failure the outbox and one true StoreError (module doc).

    ``start``: the run's Store.start_run arguments, to open it again in the outbox."""
    try:
        store.finish_run(run_id, **finish)
        return
    except AccelcalError as e:
        failed = e
    with contextlib.suppress(AccelcalError):  # never leave the run 'running' where the store still writes
        store.interrupt_run(run_id, f"could not record the result: {failed}", status="error",
                            nvm_outcome=finish.get("nvm_outcome"))
    kept = _keep(outbox or default_outbox(), start, finish, str(store.path), run_id)
    raise StoreError(f"run {run_id}: the result could not be recorded ({failed}); "
                     f"{burned_text(finish.get('nvm_outcome'))}; {_held(store, run_id)}; {kept}") from None
