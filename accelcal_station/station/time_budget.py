"""A board's time budget and the station's floor for the configured quality (issue 51, docs/timing.md).

Components, s (they sum to ``total_s``; on a simulated board's virtual clock, deterministic but
for host compute):

- ``warmup_s``: samples read while the board warms up (capture.warmup) / ODR
- ``self_test_s``: samples read by the chip's self-test / ODR
- ``sampling_s``: samples averaged at the fit poses / ODR
- ``stillness_s``: samples read at the fit poses but not averaged (waiting for stillness, the hold) / ODR
- ``verification_s``: samples read after the fit (verification poses, an offset trim's captures) / ODR
- ``jig_moves_s``: the jig's moves (settle + angle / rated speed each, fixtures/jig_motion.py)
- ``eeprom_s``: the NVM burn and read-back on the device's clock (the EEPROM's write cycles, the bus)
- ``host_compute_s``: host wall time (fit, judging, NVM preparation and burn calls) not hidden under the
  device's time.  Two overlaps, both modelled (this process computes, then moves and samples):
  the host works on the samples as they arrive, so its wall time inside sampling (captures, warm-up,
  self-test; on a simulated board the simulator's draws, which stand in for the chip) is not counted
  up to the sampling time it runs under (beyond that the host, not the chip, sets the pace);
  and the verification captures are raw counts the calibration is applied to afterwards, so the fit
  (and its judging) runs while the jig turns to the verification poses and the board samples them:
  max(fit, verification) counts, not the sum.  The store write
  comes after the board's time is taken (the next board is being placed meanwhile).
- ``operator_s``: wall time waiting for a person (an operator jig)

``floor_s``: the least time the configured quality allows: the sampling at each fit and verification
pose to reach ``capture.target_sem_mg`` at the chip's measured noise with its effective sample count
(n_need = tau_int sigma^2 / target^2 per axis, models/effective_samples.py), the jig's shortest
travel through the poses (fixtures/pose_path.py) and the EEPROM's write cycles; a panel's adds the
I2C bus time (``bus_time_s``).  ``ratio_to_floor`` = total_s / floor_s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fixtures.base import PoseSpec
from ..fixtures.jig_motion import JigMotion
from ..fixtures.pose_path import shortest_order
from ..session import PoseRecord

# One MMA8451 sample read through a TCA9548A (I2C, 9 bit-times a byte with the ACK): the mux's
# channel select (address + control byte) and a burst read of OUT_X_MSB..OUT_Z_LSB (address + register,
# repeated start, address + 6 data bytes).  Start/stop conditions are a fraction of a bit each and left out.
MUX_SELECT_BYTES = 2
SAMPLE_READ_BYTES = 9
DEFAULT_BUS_HZ = 400_000.0  # I2C Fast-mode, the clock a panel's bus runs at unless its config says


# a budget: seconds by part (COMPONENTS), total_s, floor_s and its parts (floor_sampling_s, floor_jig_s,
# floor_eeprom_s), ratio_to_floor; a panel's also bus_time_s, boards, per_board_s (module docstring)
TimeBudget = dict[str, float]


COMPONENTS = ("warmup_s", "self_test_s", "sampling_s", "stillness_s", "verification_s", "jig_moves_s",
              "eeprom_s", "host_compute_s", "operator_s")


@dataclass(frozen=True)
class BoardCounts:
    """What one board's run counted: samples by phase, seconds on its clock and the host's."""

    odr_hz: float
    warmup_read: int
    self_test_read: int
    fit_read: int
    fit_used: int
    total_read: int
    device_s: float | None  # on the device's clock (None: real hardware, the wall)
    wall_s: float
    operator_s: float
    jig_moves_s: float
    fit_wall_s: float  # the fit and judging, host wall time
    verify_device_s: float  # the verification poses' moves and captures: what the fit runs under
    sampling_wall_s: float = 0.0  # host wall time inside sampling (captures, warm-up, self-test)
    eeprom_s: float = 0.0  # the burn and read-back on the device's clock


def board_budget(c: BoardCounts, floor_s: float) -> TimeBudget:
    """The budget of one board's run (module docstring) against ``floor_s``."""
    odr = c.odr_hz
    b: TimeBudget = {
        "warmup_s": c.warmup_read / odr,
        "self_test_s": c.self_test_read / odr,
        "sampling_s": c.fit_used / odr,
        "stillness_s": max(0, c.fit_read - c.fit_used) / odr,
        "verification_s": max(0, c.total_read - c.fit_read - c.warmup_read - c.self_test_read) / odr,
        "jig_moves_s": c.jig_moves_s,
        "operator_s": c.operator_s,
    }
    sampled = sum(b[k] for k in ("warmup_s", "self_test_s", "sampling_s", "stillness_s",
                                 "verification_s"))
    host = max(0.0, c.wall_s - c.operator_s)
    if c.device_s is None:  # the wall clock holds everything: the host's share is what the rest leaves
        b["eeprom_s"] = 0.0
        b["host_compute_s"] = max(0.0, host - sampled - c.jig_moves_s)
    else:
        b["eeprom_s"] = c.eeprom_s
        rest = max(0.0, host - min(c.sampling_wall_s, sampled))  # beyond the sampling time it is the host's
        b["host_compute_s"] = rest - min(c.fit_wall_s, c.verify_device_s, rest)
    return finish(b, floor_s)


def finish(b: TimeBudget, floor_s: float) -> TimeBudget:
    """``total_s`` (the components' sum), ``floor_s`` and their ratio, rounded to the microsecond."""
    out: TimeBudget = {k: round(float(v), 6) for k, v in b.items()}
    out["total_s"] = round(sum(float(out.get(k, 0.0)) for k in COMPONENTS), 6)
    out["floor_s"] = round(floor_s, 6)
    out["ratio_to_floor"] = round(out["total_s"] / floor_s, 4) if floor_s > 0 else 0.0
    return out


def jig_floor_s(motion: JigMotion | None, fit: list[PoseSpec], verify: list[PoseSpec]) -> float:
    """The jig's time along the shortest path through the fit poses from home, then the verification poses."""
    if motion is None:
        return 0.0
    total, at = 0.0, None
    for poses in (fit, verify):
        for p in shortest_order(at, poses):
            total += motion.pose_move_s(at, p)
            at = p
    return total


def bus_time_s(samples: int, boards: int, bus_hz: float = DEFAULT_BUS_HZ) -> float:
    """Seconds the I2C bus is busy reading ``samples`` samples from each of ``boards`` boards through a
    TCA9548A: samples x boards x (mux select + burst read) bytes x 9 bit-times / bus clock."""
    return samples * boards * (MUX_SELECT_BYTES + SAMPLE_READ_BYTES) * 9.0 / bus_hz


def bus_limit_boards(odr_hz: float, bus_hz: float = DEFAULT_BUS_HZ) -> int:
    """The most boards one bus reads within a sample period: floor(bus_hz / (ODR x bytes x 9)); beyond it the
    bus, not the sampling or the jig, sets the pace."""
    return int(bus_hz // (odr_hz * (MUX_SELECT_BYTES + SAMPLE_READ_BYTES) * 9.0))


@dataclass(frozen=True)
class FloorInputs:
    """What the floor is computed from: the poses, the jig's motion, the target and the chip's measured noise."""

    fit_poses: list[PoseSpec]
    verify_poses: list[PoseSpec]
    motion: JigMotion | None
    target_sem_mg: float  # the per-pose target (capture.target_sem_mg, else capture.DEFAULT_SEM_MG)
    counts_per_g: float
    odr_hz: float
    records: list[PoseRecord]
    verify_target_sem_mg: float | None = None  # a verification pose's target (verify.target_sem_mg); None: the same
    fit_samples: int | None = None  # sequential capture: the fewest fit samples meeting the parameter targets


def samples_needed(records: list[PoseRecord], target_counts: float) -> float:
    """Samples a pose needs for the target at the chip's measured noise, mean over the captured poses: per
    axis tau_int sigma^2 / target^2 with sigma the capture's per-sample standard deviation (quantization
    included: the counts are integers) and tau_int = n / n_eff (1 where not measured); the noisiest axis."""
    need = []
    for r in records:
        if r.std is None or not r.n:
            continue
        tau = np.ones(3) if r.n_eff is None else np.maximum(1.0, r.n / np.asarray(r.n_eff, dtype=float))
        need.append(float(np.max(tau * np.asarray(r.std) ** 2)) / target_counts ** 2)
    return float(np.mean(need)) if need else 0.0


def floor_parts(f: FloorInputs, eeprom_s: float) -> tuple[float, float, float]:
    """(sampling, jig, EEPROM) parts of the floor, s: every fit and verification pose averaged to the target
    at the measured noise, the shortest jig path through them, and the EEPROM's write cycles as measured."""
    def per_pose(target_mg: float) -> float:
        target = target_mg * 1e-3 * f.counts_per_g
        return samples_needed(f.records, target) if target > 0 else 0.0

    fit_n = len(f.fit_poses) * per_pose(f.target_sem_mg) if f.fit_samples is None else float(f.fit_samples)
    verify_n = len(f.verify_poses) * per_pose(f.verify_target_sem_mg or f.target_sem_mg)
    sampling = (fit_n + verify_n) / f.odr_hz
    return sampling, jig_floor_s(f.motion, f.fit_poses, f.verify_poses), eeprom_s


def panel_budget(boards: list[TimeBudget], host_s: float, hidden_s: float, samples_read: int, odr_hz: float,
                 bus_hz: float = DEFAULT_BUS_HZ) -> TimeBudget:
    """A panel's budget: its boards run at once, so the device's parts are the slowest board's; host compute is
    the whole panel's wall time less what hides under the first verification move (``hidden_s``); the floor
    is the slowest board's with the I2C bus time to read every board's samples as a lower bound on its
    sampling (max(sampling, bus)).  ``per_board_s`` = total / boards."""
    slow = max(boards, key=lambda b: b.get("total_s", 0.0) - b.get("host_compute_s", 0.0))
    out: TimeBudget = {k: slow.get(k, 0.0) for k in COMPONENTS}
    out["host_compute_s"] = max(0.0, host_s - hidden_s)
    bus = bus_time_s(samples_read, len(boards), bus_hz)
    floor_bus = bus_time_s(int(round(slow.get("floor_sampling_s", 0.0) * odr_hz)), len(boards), bus_hz)
    sampling = max(slow.get("floor_sampling_s", 0.0), floor_bus)
    jig, eeprom = slow.get("floor_jig_s", 0.0), slow.get("floor_eeprom_s", 0.0)
    out = finish(out, sampling + jig + eeprom)
    out.update(floor_sampling_s=round(sampling, 6), floor_jig_s=jig, floor_eeprom_s=eeprom,
               bus_time_s=round(bus, 6), boards=len(boards), per_board_s=round(out["total_s"] / len(boards), 6))
    return out
