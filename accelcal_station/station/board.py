"""The steps of one board's calibration (DESIGN.md, "The flow of one board"); the flow that runs
them for 1..N boards at 1..K temperatures is flow.StationFlow.

plan poses -> for each pose: jig.present, gated capture -> fit -> judge -> closed-loop verify
(fresh captures, calibration applied in software) -> judge again -> burn NVM (A/B slot,
read-back) -> re-verify through the calibration read back from NVM.  A board that fails is
never written.  Each board of a run has its own BoardSteps (its sample counts, its mounting,
its operator's waiting); the flow opens it, starts and records its run.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..acceptance.reasons import Reason
from ..acceptance.rules import judge
from ..calibration import Calibration
from ..conventions import reference_to_angles
from ..drivers.base import Capture, Clock, Driver
from ..errors import ConfigError, NVMError, UnderdeterminedError
from ..fixtures.base import Jig, LiveReading, PoseSpec
from ..fixtures.designs import get_design
from ..fixtures.factory import clock_of, jig_motion
from ..fixtures.operator_jig import PoseSkipped
from ..fixtures.operator_ui import CaptureSink, NoCaptureProgress, OperatorUI
from ..fixtures.pose_path import visit_order
from ..jsontypes import JsonObject
from ..models.fitting import fit_session
from ..nvm.outcome import holds_text
from ..nvm.writer import BurnError, CalibrationWriter
from ..session import PoseRecord, Session
from .capture import (
    DEFAULT_SEM_MG,
    CaptureSettings,
    GatedCapture,
    MountMismatch,
    StillnessGate,
    WrongPose,
    gated_capture,
    with_mounting,
)
from .offset_trim import trim_change, trim_failure, trim_record, trimmed
from .report import RunReport, Timing
from .self_test_step import self_test_step
from .sequential_capture import Needed, SequentialPlan, needed_at, plan_for, plan_record
from .settings import StationConfig
from .time_budget import BoardCounts, FloorInputs, TimeBudget, board_budget, finish, floor_parts
from .uncertainty_step import uncertainty_step
from .verdict import Stage
from .verification import verification_poses

# a verification capture: (mean counts, expected output in g, temperature)
Check = tuple[np.ndarray, np.ndarray, float | None]
# a burn step as it happens: (event kind, the burn outcome's record)
BurnLog = Callable[[str, JsonObject], None]


class BoardSteps:
    """The steps of one board's run, and what they count (samples, the operator's waiting)."""

    def __init__(self, config: StationConfig, *, echo: Callable[[str], None] = print,
                 progress: Callable[[str, float], None] | None = None, ui: OperatorUI | None = None,
                 live_reading: bool = True) -> None:
        self.cfg = config
        self.ui = ui  # the operator's front end (terminal or browser), for an operator jig
        self.echo = echo
        self.progress = progress
        self.live_reading = live_reading  # an operator jig may show the live reading (FlowPolicy.live_reading)
        # how the chip sits on the board: the jig and the words place the board, the chip reads mount @ r
        # (a panel's board: its own, set by panel.Panel.build)
        self.mount = config.device.mount_p()
        # the site's gravity in standard g: the force a pose puts on the board (config/site.py)
        self.g_site = config.site.gravity_g
        self._seen: list[tuple[np.ndarray, np.ndarray]] = []  # (pose's r in board axes, mean reading) so far
        self.samples_read = 0
        self.samples_used = 0
        self.operator_wait_s = 0.0
        self.warmup_s = 0.0  # the warm-up hold before the self-test (station/warmup.py, the flow's)
        # the time budget's counts (time_budget.py): samples by phase, the jig's moves, the fit's wall time
        self.warmup_read = self.self_test_read = 0  # warmup_read: set by the flow's hold (flow._warm_up)
        self.fit_read: int | None = None  # samples read when the fit poses were done (None: not yet)
        self.fit_used = 0
        self.fit_wall_s = 0.0
        self.verify_device_s = 0.0  # the verification poses' moves and captures, device clock
        # host wall time inside sampling (captures, warm-up, self-test): the host works on the samples as they
        # arrive, under the device's sampling time (a simulator's draws stand in for the chip's work there)
        self.sampling_wall_s = 0.0
        self.eeprom_device_s = 0.0  # the burn and read-back on the device's clock (None: the wall)
        self.jig_moves_s = 0.0
        # records each burn step in the store as it happens (FlowPolicy.burn_steps_recorded)
        self.burn_log: BurnLog | None = None
        self.presented: list[PoseSpec] = []  # the design's poses captured, in the order the jig presented them
        self.plan: SequentialPlan | None = None  # the sequential plan of the fit poses (sequential_plan)
        self.verify_taken: list[PoseSpec] = []  # the verification poses, as verification.py chose them

    # -- pieces -----------------------------------------------------------------------
    def _capture_sink(self, label: str) -> CaptureSink:
        """Where a capture's progress goes: the operator's front end, or nowhere."""
        return NoCaptureProgress() if self.ui is None else self.ui.capture(label)

    def _live(self, driver: Driver, gate: StillnessGate) -> LiveReading:
        n = max(8, int(round(0.2 * driver.odr_hz)))

        def live() -> tuple[np.ndarray, bool]:
            counts, t, _ = driver.read_samples(n)
            self.samples_read += len(counts)
            still = gate.update(counts.astype(float), float(t[-1]))
            return counts.mean(axis=0) / driver.counts_per_g, still
        return live

    def capture_pose(self, driver: Driver, jig: Jig, pose: PoseSpec, floor: np.ndarray | None,
                      report: RunReport, settings: CaptureSettings | None = None, needed: Needed | None = None,
                      move: bool = True) -> tuple[GatedCapture, int]:
        """Present and capture one pose; operator jigs retry a wrong pose, others fail.  ``needed``: the
        sequential plan's count for it; ``move`` False: the jig already holds the pose (a reused fit pose)."""
        s = settings or self.cfg.capture
        attempts = 0
        while True:
            attempts += 1
            live = jig.shows_live_reading and self.live_reading
            if move or attempts > 1:
                jig.present(pose, self._live(driver, StillnessGate(s, floor, driver.noise_lag1())) if live else None)
            bar = self._capture_sink(f"  capturing {pose.name}")
            try:
                t0 = time.perf_counter()
                try:
                    gc = gated_capture(driver, s, self.mount @ pose.reference_g, floor, progress=bar, needed=needed)
                finally:
                    self.sampling_wall_s += time.perf_counter() - t0
            except WrongPose as e:
                e = self._mounting(pose, e)
                report.events.append(f"{pose.name}: {e}")
                if isinstance(e, MountMismatch) or not jig.places_again or attempts > s.max_recaptures:
                    raise e from None
                self.echo(f"  refused: {e}")
                continue
            finally:
                bar.close()
            self.samples_read += gc.samples_read
            self.samples_used += gc.capture.n
            self._seen.append((pose.reference_g, gc.capture.mean_counts))
            for ev in gc.events + driver.take_events():
                report.events.append(f"{pose.name}: {ev}")
                self.echo(f"  {ev}")
            return gc, attempts - 1

    def defer(self, jig: Jig, pose: PoseSpec, e: WrongPose, deferred: WrongPose | None) -> WrongPose:
        """A wrong pose another mounting may explain, on a jig that cannot place again: keep its reading
        and go on to the next pose, which may single the mounting out (a MountMismatch); else raise."""
        if e.hint is None or jig.places_again or isinstance(e, MountMismatch):
            raise e
        self._seen.append((pose.reference_g, e.measured))
        self.echo(f"  {e}")
        return deferred or e

    def expected_g(self, pose: PoseSpec) -> np.ndarray:
        """What the chip reads at ``pose`` in standard g: its reference turned by the mounting and scaled
        to the site's gravity, so the fit maps counts to standard g (station.site)."""
        return np.asarray(self.mount @ pose.reference_g * self.g_site, dtype=float)

    def chip_angles(self, pose: PoseSpec) -> tuple[float, float]:
        """The AN4399 angles of what the chip is expected to read (the pose's own unless device.mount
        turns it), so that files and the store re-derive the same reference from them."""
        if np.array_equal(self.mount, np.eye(3)):
            return pose.pitch_deg, pose.roll_deg
        pitch, roll = reference_to_angles(self.mount @ pose.reference_g)
        return round(float(pitch), 9), round(float(roll), 9)

    def _mounting(self, pose: PoseSpec, e: WrongPose) -> WrongPose:
        """A wrong pose, with the mounting that fits it and the poses captured so far (capture.with_mounting)."""
        return with_mounting(self._seen, pose.reference_g, e, self.mount, self.cfg.capture.pose_tolerance_deg)

    # -- the steps -------------------------------------------------------------------
    def self_test_step(self, driver: Driver, rep: RunReport) -> bool:
        """The chip's built-in self-test once, before the poses (station/self_test_step.py).  True: the
        poses may follow.  Device errors propagate."""
        t0 = time.perf_counter()
        try:
            ok, read = self_test_step(driver, self.cfg, rep, self.echo)
            self.samples_read += read
            self.self_test_read = read
            return ok
        finally:
            self.sampling_wall_s += time.perf_counter() - t0

    def mark_fit_done(self) -> None:
        """The fit poses are captured: what was read and averaged so far is the fit's (time_budget.py)."""
        self.fit_read, self.fit_used = self.samples_read, self.samples_used

    def sequential_plan(self, driver: Driver, design: list[PoseSpec]) -> SequentialPlan | None:
        """This board's sequential plan for ``design`` (None: the per-pose SEM rule alone)."""
        self.plan = plan_for(self.cfg.model, self.cfg.capture, [self.expected_g(p) for p in design],
                             driver.counts_per_g, driver.odr_hz)
        return self.plan

    def run_poses(self, driver: Driver, jig: Jig, design: list[PoseSpec], records: list[PoseRecord],
                   retries: list[int], rep: RunReport) -> None:
        floor = None
        deferred: WrongPose | None = None  # a wrong pose another mounting may explain: read on to tell which
        plan = self.sequential_plan(driver, design)
        self.presented = []
        for i, pose in enumerate(design):
            self.echo(f"[{i + 1}/{len(design)}] {pose.name}")
            try:
                gc, tries = self.capture_pose(driver, jig, pose, floor, rep, needed=needed_at(plan, i))
                self.presented.append(pose)
            except PoseSkipped:
                rep.skipped.append(pose.name)
                self.echo("  skipped")
                continue
            except WrongPose as e:
                deferred = self.defer(jig, pose, e, deferred)
                continue
            floor = gc.floor_counts
            c = gc.capture
            pose_record = plan_record(plan, i, c)
            pitch, roll = self.chip_angles(pose)
            records.append(PoseRecord(pose.name, c.mean_counts, c.std_counts, c.n, self.expected_g(pose),
                                      pitch, roll, c.temp_c, c.dropped, c.t_start, c.t_end, c.n_eff))
            retries.append(tries + gc.recaptures)
            sem_mg = c.sem_counts / driver.counts_per_g * 1e3
            rep.poses.append({"pose": pose.name, "n": c.n, "mean_counts": c.mean_counts.tolist(),
                              "sem_mg": sem_mg.tolist(), "n_eff": _n_eff(c), "retries": tries + gc.recaptures,
                              "reached_target": gc.reached_target, **pose_record})
            self.echo(f"  n={c.n} sem={np.max(sem_mg):.3f} mg" + ("" if gc.reached_target else " (time limit)"))
            if self.progress:
                self.progress("poses", (i + 1) / len(design))
        self.mark_fit_done()
        if deferred is not None:
            raise deferred

    def fit_judge_write(self, driver: Driver, jig: Jig, session: Session, rep: RunReport) -> None:
        cal = self.fit_judge(driver, session, rep)
        if cal is None:
            return
        checks = self.verify_captures(driver, jig, rep)
        if self.judge_verified(cal, checks, rep):
            self.burn(driver, cal, checks, rep)

    def fit_judge(self, driver: Driver, session: Session, rep: RunReport) -> Calibration | None:
        """Fit and judge before any verification capture; the calibration to verify, or None (FAIL)."""
        t0 = time.perf_counter()
        try:
            return self._fit_judge(driver, session, rep)
        finally:
            self.fit_wall_s = time.perf_counter() - t0

    def _fit_judge(self, driver: Driver, session: Session, rep: RunReport) -> Calibration | None:
        cfg = self.cfg
        try:
            fit = fit_session(session, cfg.model)
        except UnderdeterminedError as e:
            rep.record(Stage.FIT, Reason("fit", str(e)))
            return None
        fit.calibration.metadata["site"] = cfg.site.to_metadata()  # the calibration file says which gravity
        rep.fit = fit
        rep.calibration = fit.calibration
        planned = len(get_design(cfg.design))
        verdict = judge(fit, cfg.limits, planned_poses=planned)
        rep.measured = verdict.measured
        guarded = uncertainty_step(cfg, session, fit, rep, session.counts_per_g)  # the decision rule's reasons
        for w in rep.warnings:
            self.echo(f"warning: {w}")
        if not verdict.passed or guarded:
            rep.record(Stage.ACCEPTANCE, *verdict.reasons, *guarded)
            self.echo("FAIL before writing: " + "; ".join([*verdict.reasons, *guarded]))
            return None
        cal: Calibration | None = fit.calibration
        if cfg.offset_trim:
            last = session.poses[-1].reference_g if session.poses else None
            cal = self._trim_offsets(driver, fit.calibration, last, rep)
            if cal is not None:
                rep.calibration = cal
        return cal

    def judge_verified(self, cal: Calibration, checks: list[Check], rep: RunReport) -> bool:
        """Judge again with the verification captures (when there are any); True: PASS so far."""
        if checks:
            assert rep.fit is not None, "verification captures are judged after the fit"
            err = self._verify_error(cal, checks)
            rep.verify_error_max_mg = err
            verdict = judge(rep.fit, self.cfg.limits, err, planned_poses=len(get_design(self.cfg.design)))
            rep.measured = verdict.measured
            if not verdict.passed:
                rep.record(Stage.ACCEPTANCE, *verdict.reasons)
                return False
        rep.record(Stage.JUDGED)
        return True

    def burn(self, driver: Driver, cal: Calibration, checks: list[Check], rep: RunReport) -> None:
        """Burn NVM, read back, and check the calibration read back does what the fitted one did (the time it
        takes on the device's clock is the time budget's eeprom_s)."""
        clock = clock_of(driver)
        t0 = None if clock is None or clock.realtime else clock.now()
        try:
            self._burn(driver, cal, checks, rep)
        finally:
            if clock is not None and t0 is not None:
                self.eeprom_device_s += clock.now() - t0

    def _burn(self, driver: Driver, cal: Calibration, checks: list[Check], rep: RunReport) -> None:
        cfg = self.cfg
        if not cfg.nvm_write:
            return
        nvm = driver.nvm
        if nvm is None:
            rep.record(Stage.NVM, Reason("nvm", "the device has no NVM to write; set nvm.write: false"))
            return
        writer = CalibrationWriter(nvm, cfg.slot_size)
        log = self.burn_log or (lambda kind, data: None)
        try:
            # recorded (committed) before the first byte: a crash mid-burn still says what may be on the board
            outcome = writer.burn(cal, rep.serial, cfg.station_id,
                                  before_write=lambda o: log("nvm_burning", o.to_dict()))
        except BurnError as e:
            rep.nvm = e.outcome.to_dict()
            log("nvm_burn_failed", rep.nvm)
            rep.record(Stage.NVM, Reason("nvm", str(e)))
            return
        rep.nvm = outcome.to_dict()
        log("nvm_burned", rep.nvm)
        # closed loop through NVM: the calibration read back (two reads alike) must do what the fitted one did
        try:
            back = writer.read_newest(rep.serial, settled=True)
        except NVMError as e:
            back, why = None, str(e)
        else:
            why = "no valid calibration readable after writing"
        stored = None if back is None else back[0]
        same = False
        if stored is not None:
            why = "calibration read back from NVM differs from the fitted one"
            same = bool(all(np.allclose(stored.apply(c, units="counts", temp_c=t),
                                        cal.apply(c, units="counts", temp_c=t), atol=1e-9) for c, _, t in checks)
                        if checks else np.allclose(stored.W, cal.W) and np.allclose(stored.V, cal.V))
        rep.nvm_verified = same
        if not rep.nvm_verified:  # a FAIL never leaves the unverified calibration as the board's newest
            writer.revert(outcome)
            rep.nvm = outcome.to_dict()
            log("nvm_reverted", rep.nvm)
            rep.record(Stage.NVM, Reason("nvm", f"{why}; {holds_text(outcome)}"))
            return
        self.echo(f"NVM: slot {outcome.slot}, generation {outcome.generation}, {outcome.length} bytes, verified")

    def _trim_offsets(self, driver: Driver, cal: Calibration, reference_g: np.ndarray | None,
                      rep: RunReport) -> Calibration | None:
        """Move the zero-g offset into the chip's offset registers and shift V by the change MEASURED.

        The trimmed output is G_f' = G_f + t, so G = W (G_f' - t) + V: V' = V - W t, with t the change
        measured at the board's last pose (a still capture before writing, one after), not the change the
        driver's trim unit promises.  It must agree with the promised one per axis within
        ``acceptance.offset_trim_tolerance`` of it or 4 standard errors of the difference, whichever is
        larger: a trim unit a little off is measured and used; a wrong sign, register or unit
        (docs/self-test.md) fails ``offset_trim`` and the registers get their old values back.
        None: FAIL.  The registers are volatile: the trim is reported so ``device.offset_trim_lsb`` can
        restore it at power-up.
        """
        if not driver.supports_offset_trim:
            raise ConfigError(f"nvm.offset_trim: the {driver.name} driver has no offset-trim registers; "
                              "set nvm.offset_trim: false")
        offset_g = -np.linalg.solve(cal.W, cal.V)  # zero-g output of the untrimmed chip
        lsb_g = driver.offset_trim_lsb_g
        old = np.asarray(driver.get_offset_trim(), dtype=float)
        total = np.clip(np.round(old - offset_g / lsb_g), -128, 127).astype(int)
        cpg = driver.counts_per_g
        before = self._still_capture(driver, reference_g, "before the offset trim")
        driver.set_offset_trim(tuple(int(v) for v in total))
        after = self._still_capture(driver, reference_g, "after the offset trim")
        expected_g = (total - old) * lsb_g
        measured_g, sigma_g, tol_g, ok = trim_change(expected_g, before, after, cpg,
                                                     self.cfg.limits.offset_trim_tolerance)
        rep.offset_trim_lsb = total.tolist()
        rep.offset_trim = trim_record(total, old, lsb_g, expected_g, measured_g, sigma_g, tol_g, ok)
        if not ok.all():
            driver.set_offset_trim(tuple(int(v) for v in old))  # the chip as it was: nothing of this run kept
            why = trim_failure(lsb_g, expected_g, measured_g, tol_g, ok)
            rep.record(Stage.OFFSET_TRIM, Reason("offset_trim", why))
            self.echo(f"FAIL: offset trim: {why}")
            return None
        rep.record(Stage.OFFSET_TRIM)
        self.echo(f"offset trim {total.tolist()} LSB ({lsb_g * 1e3:.2f} mg each), measured change "
                  f"{np.round(measured_g * 1e3, 2).tolist()} mg: add device.offset_trim_lsb to the config to "
                  "restore it at power-up")
        return trimmed(cal, total, old, measured_g)

    def _still_capture(self, driver: Driver, reference_g: np.ndarray | None, label: str) -> Capture:
        """One gated capture of the board where it stands (its events kept with the run's)."""
        bar = self._capture_sink(f"  capturing {label}")
        try:
            t0 = time.perf_counter()
            gc = gated_capture(driver, self.cfg.capture, reference_g, None, progress=bar)
            self.sampling_wall_s += time.perf_counter() - t0
        finally:
            bar.close()
        self.samples_read += gc.samples_read
        return gc.capture

    def verify_captures(self, driver: Driver, jig: Jig, rep: RunReport) -> list[Check]:
        """Fresh captures at the verification poses (verification.py: the last fit poses, the first
        without a move, or independent ones): (mean counts, expected g, temp)."""
        vp = verification_poses(self.cfg.verify_poses, self.cfg.schema.verify, self.cfg.design, self.presented)
        if not vp.poses:
            return []
        rep.verify_mode = vp.mode
        self.verify_taken = vp.poses
        out = []
        moved, read = jig.moves_s, self.samples_read
        # fit-poses: back along the path the jig took; independent poses: the shortest path from the last fit pose
        poses = visit_order(jig, vp.poses) if vp.first_moves else vp.poses
        for k, pose in enumerate(poses):
            self.echo(f"verify {pose.name}" + (" (where the jig stands)" if k == 0 and not vp.first_moves else ""))
            gc, _ = self.capture_pose(driver, jig, pose, None, rep, verify_settings(self.cfg),
                                      move=k > 0 or vp.first_moves)
            out.append((gc.capture.mean_counts, self.expected_g(pose), gc.capture.temp_c))
        self.verify_device_s = jig.moves_s - moved + (self.samples_read - read) / driver.odr_hz
        return out

    def _verify_error(self, cal: Calibration, checks: list[Check]) -> float:
        errs = [np.max(np.abs(cal.apply(c, units="counts", temp_c=t if cal.temperature is not None else None) - ref))
                for c, ref, t in checks]
        return float(np.max(errs)) * 1e3

    def timing(self, driver: Driver, clock: Clock | None, clock0: float | None, wall0: float) -> Timing:
        odr = driver.odr_hz
        t: Timing = {
            "odr_hz": odr,
            "samples_averaged": self.samples_used,
            "samples_read": self.samples_read,
            "sampling_floor_s": self.samples_used / odr,
            "sampling_s": self.samples_read / odr,
            "wall_s": time.perf_counter() - wall0,
        }
        t["operator_wait_s"] = self.operator_wait_s
        t["warmup_s"] = self.warmup_s
        # host compute: wall time not spent waiting for the operator (nor, on a real-time
        # board, sleeping through sampling and moves)
        t["host_compute_s"] = max(0.0, t["wall_s"] - self.operator_wait_s)
        # a panel's board that opened but did not identify has no start time: no device time
        if clock is not None and clock0 is not None:
            t["device_time_s"] = clock.now() - clock0  # moves, waits, EEPROM cycles, sampling
            t["board_time_s"] = t["device_time_s"] + (0.0 if clock.realtime else t["host_compute_s"])
        return t

    def time_budget(self, driver: Driver, clock: Clock | None, records: list[PoseRecord], t: Timing) -> TimeBudget:
        """Where this board's time went and its floor (time_budget.py), from its counts and its ``timing``."""
        real = clock is None or clock.realtime  # the wall holds sampling, moves and compute alike
        counts = BoardCounts(driver.odr_hz, self.warmup_read, self.self_test_read,
                             self.samples_read if self.fit_read is None else self.fit_read,
                             self.samples_used if self.fit_read is None else self.fit_used, self.samples_read,
                             None if real else t.get("device_time_s"), t["wall_s"], self.operator_wait_s,
                             self.jig_moves_s, self.fit_wall_s, self.verify_device_s, self.sampling_wall_s,
                             self.eeprom_device_s)
        budget = board_budget(counts, 0.0)
        cfg = self.cfg
        verify = self.verify_taken or (verification_poses(cfg.verify_poses, cfg.schema.verify, cfg.design,
                                                          self.presented).poses if cfg.verify_poses else [])
        sem = cfg.capture.target_sem_mg
        fit_n = None if self.plan is None else self.plan.floor_samples()
        inputs = FloorInputs(get_design(cfg.design), verify, jig_motion(cfg.jig),
                             DEFAULT_SEM_MG if sem is None else sem, driver.counts_per_g, driver.odr_hz, records,
                             verify_settings(cfg).target_sem_mg, fit_n)
        sampling, jig, eeprom = floor_parts(inputs, budget["eeprom_s"])
        out = finish(budget, sampling + jig + eeprom)
        out.update(floor_sampling_s=round(sampling, 6), floor_jig_s=round(jig, 6), floor_eeprom_s=round(eeprom, 6))
        return out


def verify_settings(cfg: StationConfig) -> CaptureSettings:
    """The capture settings of a verification pose: the capture's, averaged to ``verify.target_sem_mg`` when set."""
    target = cfg.schema.verify.target_sem_mg if cfg.schema.verify is not None else None
    return cfg.capture if target is None else replace(cfg.capture, target_sem_mg=target)


def _n_eff(c: Capture) -> list[float]:
    """A capture's effective sample count per axis for the report (n when it was not measured)."""
    return [float(c.n)] * 3 if c.n_eff is None else np.round(c.n_eff, 1).tolist()
