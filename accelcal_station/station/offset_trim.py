"""An offset trim written to the chip's registers, measured and judged (docs/self-test.md, "Offset
trims measured"): what the station's trim step records and how it shifts the calibration."""
from __future__ import annotations

from typing import TypedDict

import numpy as np

from ..calibration import Calibration
from ..drivers.base import Capture


def trim_change(expected_g: np.ndarray, before: Capture, after: Capture, counts_per_g: float, tolerance: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """An offset trim's change measured and judged, per axis (g): measured = (mean after - mean before) /
    counts_per_g, sigma = hypot(SEM before, SEM after) / counts_per_g, the allowance
    max(tolerance |expected|, 4 sigma) and ok = |measured - expected| <= allowance (docs/self-test.md)."""
    measured = (after.mean_counts - before.mean_counts) / counts_per_g
    sigma = np.hypot(before.sem_counts, after.sem_counts) / counts_per_g
    allowed = np.maximum(tolerance * np.abs(expected_g), 4.0 * sigma)
    return measured, sigma, allowed, np.abs(measured - expected_g) <= allowed


class OffsetTrimRecord(TypedDict):
    """The trim written to the offset registers (LSB) and before, its unit and the change expected
    and measured per axis (mg), the tolerance it was held to (mg) and whether each axis agreed."""

    lsb: list[int]
    previous_lsb: list[int]
    lsb_mg: float
    expected_mg: list[float]
    measured_mg: list[float]
    sigma_mg: list[float]
    tolerance_mg: list[float]
    ok: list[bool]


def trim_record(total: np.ndarray, old: np.ndarray, lsb_g: float, expected_g: np.ndarray, measured_g: np.ndarray,
                sigma_g: np.ndarray, tol_g: np.ndarray, ok: np.ndarray) -> OffsetTrimRecord:
    """The run record's ``offset_trim``: registers written and before, the change expected and measured (mg)."""
    return {"lsb": total.tolist(), "previous_lsb": old.astype(int).tolist(), "lsb_mg": lsb_g * 1e3,
            "expected_mg": (expected_g * 1e3).tolist(), "measured_mg": (measured_g * 1e3).tolist(),
            "sigma_mg": (sigma_g * 1e3).tolist(), "tolerance_mg": (tol_g * 1e3).tolist(), "ok": ok.tolist()}


def trim_failure(lsb_g: float, expected_g: np.ndarray, measured_g: np.ndarray, tol_g: np.ndarray,
                 ok: np.ndarray) -> str:
    """The ``offset_trim`` reason: each axis whose measured change is not the expected one."""
    bad = ", ".join(f"{'xyz'[i]} measured {measured_g[i] * 1e3:+.2f} mg, expected {expected_g[i] * 1e3:+.2f}"
                    f" +- {tol_g[i] * 1e3:.2f} mg" for i in np.flatnonzero(~ok))
    return f"the trim written did not do what its unit ({lsb_g * 1e3:.3f} mg per LSB) says: {bad}; registers restored"


def trimmed(cal: Calibration, total: np.ndarray, old: np.ndarray, measured_g: np.ndarray) -> Calibration:
    """G = W (G_f' - t) + V: V' = V - W t with t the measured change (0 on an axis not written: its
    difference is noise)."""
    t = np.where(total != old, measured_g, 0.0)
    return Calibration(cal.model, cal.W, cal.V - cal.W @ t, cal.Gamma, cal.input_units, cal.input_per_g,
                       cal.temperature, dict(cal.metadata, offset_trim_lsb=total.tolist(),
                                             offset_trim_measured_mg=(t * 1e3).tolist()))
