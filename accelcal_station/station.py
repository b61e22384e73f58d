"""The station: calibrate one board end to end (DESIGN.md, "The flow of one board").

identify -> plan poses -> for each pose: jig.present, gated capture -> fit -> judge ->
closed-loop verify (fresh captures, calibration applied in software) -> judge again ->
burn NVM (A/B slot, read-back) -> re-verify through the calibration read back from
NVM -> record everything in the store.  A board that fails is never written.
"""
from __future__ import annotations

import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .acceptance import Limits, judge
from .calibration import MODELS, Calibration
from .capture import CaptureSettings, StillnessGate, WrongPose, gated_capture
from .config import check_keys, choice, load_yaml, number
from .drivers import Driver, make_driver
from .errors import AccelcalError, ConfigError, UnderdeterminedError
from .fixtures.base import Jig, PoseSpec
from .fixtures.designs import get_design
from .fixtures.factory import board_of, make_jig  # noqa: F401  (re-exported: the jig factory lives there)
from .fixtures.operator_jig import OperatorAbort, OperatorJig, PoseSkipped
from .models import check_model, fit_session
from .models.result import FitResult
from .reasons import Reason, codes
from .run_identity import IDENTITY_KEYS, identity_options
from .session import PoseRecord, Session
from .store import Store, store_path, store_target
from .writer import BurnError, CalibrationWriter

TOP_KEYS = ("station", "store", "device", "jig", "plan", "capture", "acceptance", "nvm", "verify",
            "thermal", "chamber")  # thermal plans: accelcal_station/thermal.py
JIG_TYPES = ("simulated", "operator", "motorized")


def default_config_path() -> Path:
    """configs/sim.yaml, wherever the package is installed."""
    from . import configs

    return Path(configs.__file__).parent / "sim.yaml"


@dataclass
class StationConfig:
    """A checked station configuration (every error names its key path)."""

    raw: dict
    text: str
    path: Path
    station_id: str
    design: str
    model: str
    capture: CaptureSettings
    limits: Limits
    nvm_write: bool
    slot_size: int | None
    offset_trim: bool
    verify_poses: int
    verify_design: str | None
    store_file: Path | str  # a file, or a store URL (postgresql://...)

    @classmethod
    def load(cls, path: str | Path | None = None, store_override: str | Path | None = None,
             port: str | None = None, jig_port: str | None = None) -> "StationConfig":
        """Read and check a station config; ``port``/``jig_port`` override the device's
        port (or MMA8451 bus) and the motorized jig's port."""
        default = path is None
        p = default_config_path() if default else Path(path)
        raw = load_yaml(p)
        if port is not None:
            from .cli.probe import _with_port

            raw["device"] = _with_port(dict(raw.get("device") or {}), port)
        if jig_port is not None:
            jig = dict(raw.get("jig") or {})
            if jig.get("type") != "motorized":
                raise ConfigError(f"--jig-port {jig_port}: the config's jig is not motorized (jig.type: motorized)")
            raw["jig"] = {**jig, "port": jig_port}
        check_keys(raw, TOP_KEYS, str(p.name))
        if "device" not in raw:
            raise ConfigError(f"{p}: device: required (a mapping with a 'driver' key)")
        st = check_keys(raw.get("station"), ["id", *IDENTITY_KEYS], "station")
        identity_options(raw)
        plan = check_keys(raw.get("plan"), ["design", "model"], "plan")
        design = str(plan.get("design", "an4399-8"))
        get_design(design)  # unknown names fail now, not mid-run
        try:
            model = check_model(plan.get("model", "12"))
        except AccelcalError:
            raise ConfigError(f"plan.model: {plan.get('model')!r}; allowed: {', '.join(MODELS)}") from None
        cap = check_keys(raw.get("capture"), CaptureSettings.__dataclass_fields__, "capture")
        defaults = CaptureSettings()
        settings = CaptureSettings(**{
            k: number(cap, k, "capture", getattr(defaults, k), lo=0.0,
                      integer=isinstance(getattr(defaults, k), int)) for k in cap})
        for k in ("block_s", "max_s", "settle_timeout_s", "min_samples"):
            if getattr(settings, k) <= 0:
                raise ConfigError(f"capture.{k}: {getattr(settings, k)!r}; allowed: a positive number")
        if settings.k_leave < settings.k_enter:
            raise ConfigError("capture.k_leave must be >= capture.k_enter (hysteresis)")
        nvm = check_keys(raw.get("nvm"), ["write", "slot_size", "offset_trim"], "nvm")
        write, trim = nvm.get("write", True), nvm.get("offset_trim", False)
        for key, v in (("write", write), ("offset_trim", trim)):
            if not isinstance(v, bool):
                raise ConfigError(f"nvm.{key}: {v!r}; allowed: true, false")
        if trim and model == "15":
            raise ConfigError("nvm.offset_trim: the 15-parameter model's cubic term cannot be moved into "
                              "offset registers; allowed with models 6, 9, 12")
        slot = nvm.get("slot_size")
        slot = None if slot is None else number(nvm, "slot_size", "nvm", lo=64, integer=True)
        ver = check_keys(raw.get("verify"), ["poses", "design"], "verify")
        vdesign = ver.get("design")
        if vdesign is not None:
            get_design(str(vdesign))
        jig = raw.get("jig") or {"type": "simulated"}
        check_keys(jig, list(jig), "jig")
        choice(jig, "type", "jig", JIG_TYPES)
        # a relative store path is taken from the current directory: the station's
        # working folder, never the (possibly installed, read-only) config folder
        store_file = store_target(store_override) if store_override else store_path(raw, Path.cwd())
        limits = Limits.from_config(raw.get("acceptance"))
        verify_poses = number(ver, "poses", "verify", 3, 0, 64, integer=True)
        if verify_poses == 0 and "verify_error_max_mg" in limits.values:
            # without verification captures this limit would never be judged: a board would pass unchecked
            raise ConfigError("acceptance.verify_error_max_mg: needs verification captures (verify.poses: 0); "
                              "allowed: verify.poses of 1 or more, or remove the limit")
        return cls(raw, p.read_text(), p, str(st.get("id", "station-1")), design, model, settings,
                   limits, write, slot, trim, verify_poses,
                   None if vdesign is None else str(vdesign), store_file)


@dataclass
class RunReport:
    """What one run did; ``to_dict`` is the `accelcal run --json` object."""

    run_id: int | None = None
    serial: str = ""
    chip: str = ""
    station_id: str = ""
    verdict: str = "FAIL"
    reasons: list[Reason] = field(default_factory=list)
    model: str = ""
    design: str = ""
    fit: FitResult | None = None
    measured: dict[str, float] = field(default_factory=dict)
    verify_error_max_mg: float | None = None
    nvm: dict | None = None
    nvm_verified: bool = False
    offset_trim_lsb: list[int] | None = None
    calibration: Calibration | None = None  # what was (or would be) written: the fit's, trim applied
    poses: list[dict] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)
    store: str = ""

    def to_dict(self) -> dict[str, Any]:
        f, c = self.fit, self.calibration
        return {
            "run_id": self.run_id, "serial": self.serial, "chip": self.chip, "station_id": self.station_id,
            "verdict": self.verdict, "reasons": [str(r) for r in self.reasons], "reason_codes": codes(self.reasons),
            "model": self.model, "design": self.design,
            "W": None if c is None else c.W.tolist(), "V": None if c is None else c.V.tolist(),
            "Gamma": None if c is None else c.Gamma.tolist(),
            "residual_rms_mg": None if f is None else f.residual_rms_g * 1e3,
            "crossval_rms_mg": None if f is None or f.crossval_rms_g is None else f.crossval_rms_g * 1e3,
            "measured": self.measured, "verify_error_max_mg": self.verify_error_max_mg,
            "nvm": self.nvm, "nvm_verified": self.nvm_verified, "offset_trim_lsb": self.offset_trim_lsb,
            "poses": self.poses, "skipped": self.skipped,
            "events": self.events, "timing": self.timing, "store": self.store,
        }


class CaptureProgress:
    """A progress bar (stderr) for any capture that takes longer than a moment of wall time.

    Virtual-clock captures finish in milliseconds and never show one; a real board at
    100 Hz averaging for seconds does.
    """

    def __init__(self, label: str, after_s: float = 0.5):
        self.label, self.after_s = label, after_s
        self.t0 = time.monotonic()
        self.bar = None
        self.done = 0

    def __call__(self, fraction: float) -> None:
        if self.bar is None:
            if time.monotonic() - self.t0 < self.after_s:
                return
            import click

            self.bar = click.progressbar(length=1000, label=self.label, file=sys.stderr)
            self.bar.__enter__()
        step = int(1000 * min(max(fraction, 0.0), 1.0)) - self.done
        if step > 0:
            self.bar.update(step)
            self.done += step

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


class Station:
    """Runs the flow for one board at a time."""

    def __init__(self, config: StationConfig, *, operator: str | None = None, serial: str | None = None,
                 lot: str | None = None, echo: Callable[[str], None] = print,
                 progress: Callable[[str, float], None] | None = None, driver: Driver | None = None):
        self.cfg = config
        self.driver = driver  # default: built from the config's device section at run()
        self.operator = operator
        self.serial_override = serial
        self.lot = lot
        self.echo = echo
        self.progress = progress
        self.samples_read = 0
        self.samples_used = 0
        self.operator_wait_s = 0.0

    # -- pieces -----------------------------------------------------------------------
    def _live(self, driver: Driver, gate: StillnessGate):
        n = max(8, int(round(0.2 * driver.odr_hz)))

        def live():
            counts, t, _ = driver.read_samples(n)
            self.samples_read += len(counts)
            still = gate.update(counts.astype(float), float(t[-1]))
            return counts.mean(axis=0) / driver.counts_per_g, still
        return live

    def _capture_pose(self, driver: Driver, jig: Jig, pose: PoseSpec, floor, report: RunReport):
        """Present and capture one pose; operator jigs retry a wrong pose, others fail."""
        s = self.cfg.capture
        attempts = 0
        while True:
            attempts += 1
            jig.present(pose, self._live(driver, StillnessGate(s, floor)) if isinstance(jig, OperatorJig) else None)
            bar = CaptureProgress(f"  capturing {pose.name}")
            try:
                gc = gated_capture(driver, s, pose.reference_g, floor, progress=bar)
            except WrongPose as e:
                report.events.append(f"{pose.name}: {e}")
                if not isinstance(jig, OperatorJig) or attempts > s.max_recaptures:
                    raise
                self.echo(f"  refused: {e}")
                continue
            finally:
                bar.close()
            self.samples_read += gc.samples_read
            self.samples_used += gc.capture.n
            for ev in gc.events:
                report.events.append(f"{pose.name}: {ev}")
                self.echo(f"  {ev}")
            return gc, attempts - 1

    # -- the run ---------------------------------------------------------------------
    def run(self) -> RunReport:
        cfg = self.cfg
        rep = RunReport(station_id=cfg.station_id, model=cfg.model, design=cfg.design, store=str(cfg.store_file))
        wall0 = time.perf_counter()
        design = get_design(cfg.design)
        if self.driver is None:
            self.driver = make_driver(cfg.raw["device"])
        driver = self.driver
        with Store(cfg.store_file) as store:
            store.mark_stale_interrupted()
            if cfg.limits.defaults_line():
                self.echo(cfg.limits.defaults_line())
                rep.events.append(cfg.limits.defaults_line())
            with ExitStack() as stack:
                try:
                    stack.enter_context(driver)  # opening a port that nobody answers on is recorded too
                    ident = driver.identify()
                    dev = cfg.raw["device"]
                    driver.configure(dev.get("range_g"), dev.get("odr_hz"))
                except AccelcalError as e:
                    self._record_unreachable(store, e)
                    raise
                rep.serial = self.serial_override or ident.serial
                rep.chip = ident.chip
                board = board_of(driver)
                clock0 = board.clock.now() if board is not None else None
                run_id = store.start_run(device_serial=rep.serial, chip=ident.chip, station_id=cfg.station_id,
                                         operator=self.operator, lot=self.lot, config_text=cfg.text,
                                         model=cfg.model, units="counts", counts_per_g=driver.counts_per_g)
                rep.run_id = run_id
                self._burn_log = lambda kind, data, r=run_id: store.record_burn(r, kind, data)
                records: list[PoseRecord] = []
                retries: list[int] = []
                session = Session(records, units="counts", counts_per_g=driver.counts_per_g, device=rep.serial)
                try:
                    with make_jig(cfg.raw.get("jig") or {"type": "simulated"}, driver, self.echo) as jig:
                        try:
                            self._run_poses(driver, jig, design, records, retries, rep)
                            self._fit_judge_write(driver, jig, session, rep)
                        finally:
                            self.operator_wait_s = float(getattr(jig, "wait_s", 0.0))
                except (AccelcalError, KeyboardInterrupt) as e:
                    why = "interrupted (Ctrl-C)" if isinstance(e, KeyboardInterrupt) else str(e)
                    store.interrupt_run(run_id, why, session=session if records else None,
                                        status="interrupted" if isinstance(e, (OperatorAbort, KeyboardInterrupt))
                                        else "error", retries=retries if records else None,
                                        nvm_outcome=rep.nvm)
                    raise
                rep.timing = self._timing(driver, board, clock0, wall0)
                try:
                    store.finish_run(run_id, session=session, calibration=rep.calibration,
                                     verdict=rep.verdict, reasons=rep.reasons, nvm_outcome=rep.nvm,
                                     fit_summary={**fit_figures(rep.fit), "reason_codes": codes(rep.reasons),
                                                  "measured": rep.measured,
                                                  "verify_error_max_mg": rep.verify_error_max_mg,
                                                  "offset_trim_lsb": rep.offset_trim_lsb,
                                                  "design": cfg.design, "skipped": rep.skipped,
                                                  "timing": rep.timing, "nvm_verified": rep.nvm_verified},
                                     model=cfg.model, retries=retries)
                except AccelcalError as e:
                    # never leave the run 'running': record it as an error (finish_run rolled back)
                    store.interrupt_run(run_id, f"could not record the result: {e}", status="error",
                                        nvm_outcome=rep.nvm)
                    raise
        return rep

    def _record_unreachable(self, store: Store, err: AccelcalError) -> None:
        """A device that does not answer still leaves a record: status error, with the reason."""
        cfg = self.cfg
        rid = store.start_run(device_serial=self.serial_override, station_id=cfg.station_id,
                              operator=self.operator, lot=self.lot, config_text=cfg.text, model=cfg.model)
        store.interrupt_run(rid, f"device: {err}", status="error")

    def _run_poses(self, driver, jig, design, records, retries, rep) -> None:
        floor = None
        for i, pose in enumerate(design):
            self.echo(f"[{i + 1}/{len(design)}] {pose.name}")
            try:
                gc, tries = self._capture_pose(driver, jig, pose, floor, rep)
            except PoseSkipped:
                rep.skipped.append(pose.name)
                self.echo("  skipped")
                continue
            floor = gc.floor_counts
            c = gc.capture
            records.append(PoseRecord(pose.name, c.mean_counts, c.std_counts, c.n, pose.reference_g,
                                      pose.pitch_deg, pose.roll_deg, c.temp_c, c.dropped, c.t_start, c.t_end))
            retries.append(tries + gc.recaptures)
            sem_mg = c.sem_counts / driver.counts_per_g * 1e3
            rep.poses.append({"pose": pose.name, "n": c.n, "mean_counts": c.mean_counts.tolist(),
                              "sem_mg": sem_mg.tolist(), "retries": tries + gc.recaptures,
                              "reached_target": gc.reached_target})
            self.echo(f"  n={c.n} sem={np.max(sem_mg):.3f} mg" + ("" if gc.reached_target else " (time limit)"))
            if self.progress:
                self.progress("poses", (i + 1) / len(design))

    def _fit_judge_write(self, driver, jig, session: Session, rep: RunReport) -> None:
        cal = self._fit_judge(driver, session, rep)
        if cal is None:
            return
        checks = self._verify_captures(driver, jig, rep)
        if self._judge_verified(cal, checks, rep):
            self._burn(driver, cal, checks, rep)

    def _fit_judge(self, driver, session: Session, rep: RunReport) -> Calibration | None:
        """Fit and judge before any verification capture; the calibration to verify, or None (FAIL)."""
        cfg = self.cfg
        try:
            fit = fit_session(session, cfg.model)
        except UnderdeterminedError as e:
            rep.verdict, rep.reasons = "FAIL", [Reason("fit", str(e))]
            return None
        rep.fit = fit
        rep.calibration = fit.calibration
        planned = len(get_design(cfg.design))
        verdict = judge(fit, cfg.limits, planned_poses=planned)
        rep.measured = verdict.measured
        if not verdict.passed:
            rep.verdict, rep.reasons = "FAIL", verdict.reasons
            self.echo("FAIL before writing: " + "; ".join(verdict.reasons))
            return None
        cal = fit.calibration
        if cfg.offset_trim:
            cal = rep.calibration = self._trim_offsets(driver, cal, rep)
        return cal

    def _judge_verified(self, cal: Calibration, checks, rep: RunReport) -> bool:
        """Judge again with the verification captures (when there are any); True: PASS so far."""
        if checks:
            err = self._verify_error(cal, checks)
            rep.verify_error_max_mg = err
            verdict = judge(rep.fit, self.cfg.limits, err, planned_poses=len(get_design(self.cfg.design)))
            rep.measured = verdict.measured
            if not verdict.passed:
                rep.verdict, rep.reasons = "FAIL", verdict.reasons
                return False
        rep.verdict, rep.reasons = "PASS", []
        return True

    def _burn(self, driver, cal: Calibration, checks, rep: RunReport) -> None:
        """Burn NVM, read back, and check the calibration read back does what the fitted one did."""
        cfg = self.cfg
        if not cfg.nvm_write:
            return
        nvm = driver.nvm
        if nvm is None:
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", "the device has no NVM to write; set nvm.write: false")]
            return
        writer = CalibrationWriter(nvm, cfg.slot_size)
        log = getattr(self, "_burn_log", None) or (lambda kind, data: None)
        try:
            # recorded (committed) before the first byte: a crash mid-burn still says what may be on the board
            outcome = writer.burn(cal, rep.serial, cfg.station_id,
                                  before_write=lambda o: log("nvm_burning", o.to_dict()))
        except BurnError as e:
            rep.nvm = e.outcome.to_dict()
            log("nvm_burn_failed", rep.nvm)
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", str(e))]
            return
        rep.nvm = outcome.to_dict()
        log("nvm_burned", rep.nvm)
        # closed loop through NVM: the calibration read back must do what the fitted one did
        back = writer.read_newest(rep.serial)
        if back is None:
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", "no valid calibration readable after writing")]
            return
        stored = back[0]
        if checks:
            same = all(np.allclose(stored.apply(c, units="counts", temp_c=t), cal.apply(c, units="counts", temp_c=t),
                                   atol=1e-9) for c, _, t in checks)
        else:
            same = np.allclose(stored.W, cal.W) and np.allclose(stored.V, cal.V)
        rep.nvm_verified = bool(same)
        if not same:
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", "calibration read back from NVM differs from the fitted one")]
        self.echo(f"NVM: slot {outcome.slot}, generation {outcome.generation}, {outcome.length} bytes, verified")

    def _trim_offsets(self, driver, cal: Calibration, rep: RunReport) -> Calibration:
        """Move the zero-g offset into the chip's offset registers and shift V to match.

        The trimmed output is G_f' = G_f + t, so G = W (G_f' - t) + V: V' = V - W t.
        The registers are volatile: the trim is reported (and recorded) so the device
        config's ``offset_trim_lsb`` can restore it at power-up.
        """
        lsb_g = getattr(driver, "offset_trim_lsb_g", None)
        if lsb_g is None or not hasattr(driver, "set_offset_trim"):
            raise ConfigError(f"nvm.offset_trim: the {driver.name} driver has no offset-trim registers; "
                              "set nvm.offset_trim: false")
        offset_g = -np.linalg.solve(cal.W, cal.V)  # zero-g output of the untrimmed chip
        old = np.asarray(driver.get_offset_trim(), dtype=float) if hasattr(driver, "get_offset_trim") else 0.0
        total = np.clip(np.round(old - offset_g / lsb_g), -128, 127).astype(int)
        driver.set_offset_trim(tuple(int(v) for v in total))
        t = (total - old) * lsb_g
        rep.offset_trim_lsb = total.tolist()
        self.echo(f"offset trim {total.tolist()} LSB ({lsb_g * 1e3:.2f} mg each): "
                  "add device.offset_trim_lsb to the config to restore it at power-up")
        return Calibration(cal.model, cal.W, cal.V - cal.W @ t, cal.Gamma, cal.input_units, cal.input_per_g,
                           cal.temperature, dict(cal.metadata, offset_trim_lsb=total.tolist()))

    def _verify_captures(self, driver, jig, rep) -> list[tuple[np.ndarray, np.ndarray, float | None]]:
        """Fresh captures at the verification poses: (mean counts, expected g, temp)."""
        n = self.cfg.verify_poses
        if n == 0:
            return []
        poses = get_design(self.cfg.verify_design) if self.cfg.verify_design else get_design(self.cfg.design)
        out = []
        for pose in poses[:n]:
            self.echo(f"verify {pose.name}")
            gc, _ = self._capture_pose(driver, jig, pose, None, rep)
            out.append((gc.capture.mean_counts, pose.reference_g, gc.capture.temp_c))
        return out

    def _verify_error(self, cal: Calibration, checks) -> float:
        errs = [np.max(np.abs(cal.apply(c, units="counts", temp_c=t if cal.temperature is not None else None) - ref))
                for c, ref, t in checks]
        return float(np.max(errs)) * 1e3

    def _timing(self, driver, board, clock0, wall0) -> dict[str, float]:
        odr = driver.odr_hz
        t = {
            "odr_hz": odr,
            "samples_averaged": self.samples_used,
            "samples_read": self.samples_read,
            "sampling_floor_s": self.samples_used / odr,
            "sampling_s": self.samples_read / odr,
            "wall_s": time.perf_counter() - wall0,
        }
        t["operator_wait_s"] = self.operator_wait_s
        # host compute: wall time not spent waiting for the operator (nor, on a real-time
        # board, sleeping through sampling and moves)
        t["host_compute_s"] = max(0.0, t["wall_s"] - self.operator_wait_s)
        if board is not None:
            t["device_time_s"] = board.clock.now() - clock0  # moves, waits, EEPROM cycles, sampling
            t["board_time_s"] = t["device_time_s"] + (0.0 if board.clock.realtime else t["host_compute_s"])
        return t


def fit_figures(fit: FitResult | None) -> dict[str, float | None]:
    """The fit's scalar figures as the store keeps them (report list/export columns)."""
    if fit is None:
        return {}
    return {"residual_rms_g": fit.residual_rms_g, "residual_max_g": fit.residual_max_g,
            "crossval_rms_g": fit.crossval_rms_g, "condition_number": fit.condition_number}
