"""Temperature calibration at the station: a thermal plan run in a chamber (AN4399 section 9).

For each set point (ascending, calibration and verification set points together, so the
chamber travels one way): set the chamber, soak until the board's temperature is stable,
run the pose design with the configured jig and record every pose with its temperature.
Then fit one calibration per calibration temperature, judge each, build the temperature
table (AN4399 Eqns 83-92, piecewise ``linear`` or ``quadratic``), verify it on the poses
captured at the verification set points (temperatures not used in the fit), judge the table,
burn it (A/B slot, CRC) and read it back.  A chamber that never reaches its set point, an
alarm, a door opened during a capture, or a board that drifts out of its band during the
poses ends the run with a recorded FAIL verdict and its reason; nothing is burned.

The soak rule: the chamber air is within ``band_c`` of the set point and the board
temperature (the chip's die temperature; the chamber air for a chip without a sensor, the
MMA8451) has stayed within ``tolerance_c`` (max - min) for ``hold_s``; else ``timeout_s``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .acceptance import judge
from .calibration import Calibration, TemperatureTable
from .config import check_keys, choice, number
from .errors import AccelcalError, ConfigError, UnderdeterminedError
from .fixtures.designs import get_design
from .instruments import ChamberError, make_chamber
from .models import fit_session
from .reasons import Reason, wrap
from .session import PoseRecord, Session
from .station import RunReport, Station, StationConfig, board_of, make_jig
from .store import Store
from .writer import BurnError, CalibrationWriter

SOAK_KEYS = ("tolerance_c", "band_c", "hold_s", "timeout_s", "poll_s")
PLAN_KEYS = ("set_points_c", "verify_set_points_c", "method", "soak", "capture_band_c", "reference_c")


class ChamberFault(AccelcalError):
    """The thermal environment failed the plan: a recorded FAIL, not a crash.  ``kind`` says which."""

    def __init__(self, kind: str, message: str, soak_s: float = 0.0) -> None:
        super().__init__(message)
        self.kind = kind
        self.soak_s = soak_s  # a soak that timed out: the time it took, still counted as soak


@dataclass(frozen=True)
class SoakRule:
    tolerance_c: float = 0.2
    band_c: float = 2.0
    hold_s: float = 300.0
    timeout_s: float = 5400.0
    poll_s: float = 10.0


@dataclass(frozen=True)
class ThermalPlan:
    """``thermal:`` of a station config, checked (errors name the key path)."""

    set_points_c: tuple[float, ...]
    verify_set_points_c: tuple[float, ...]
    method: str
    soak: SoakRule
    capture_band_c: float
    reference_c: float  # the single-temperature calibration "without the table" is the one nearest this

    @classmethod
    def from_config(cls, d: Any, model: str, path: str = "thermal") -> "ThermalPlan":
        d = check_keys(d, PLAN_KEYS, path)
        sps = _temps(d, "set_points_c", path, required=True)
        if len(sps) < 3:
            raise ConfigError(f"{path}.set_points_c: {len(sps)} set points; allowed: 3 or more")
        if min(np.diff(sorted(sps))) < 5.0:
            raise ConfigError(f"{path}.set_points_c: {sps}; set points must be 5 C or more apart")
        ver = _temps(d, "verify_set_points_c", path, required=True)
        for v in ver:
            if not sps[0] < v < sps[-1] or min(abs(v - s) for s in sps) < 2.5:
                raise ConfigError(f"{path}.verify_set_points_c: {v:g} C; allowed: between {sps[0]:g} and "
                                  f"{sps[-1]:g} C and 2.5 C or more from every calibration set point")
        if model == "9":
            raise ConfigError(f"{path}: model 9 has no pose references to verify against; allowed plan.model: 6, 12, 15")
        s = check_keys(d.get("soak"), SOAK_KEYS, f"{path}.soak")
        sp = f"{path}.soak"
        soak = SoakRule(number(s, "tolerance_c", sp, 0.2, 0.001, 10.0), number(s, "band_c", sp, 2.0, 0.01, 20.0),
                        number(s, "hold_s", sp, 300.0, 0.0, 86400.0), number(s, "timeout_s", sp, 5400.0, 1.0, 604800.0),
                        number(s, "poll_s", sp, 10.0, 0.01, 3600.0))
        return cls(tuple(sps), tuple(ver), choice(d, "method", path, ("linear", "quadratic"), "linear"), soak,
                   number(d, "capture_band_c", path, 1.0, 0.01, 20.0), number(d, "reference_c", path, 25.0, -70.0, 180.0))

    def visits(self) -> list[tuple[float, str]]:
        """(set point, 'calibrate' | 'verify') in ascending temperature: the chamber travels one way."""
        return sorted([(t, "calibrate") for t in self.set_points_c] + [(t, "verify") for t in self.verify_set_points_c])


def _temps(d: dict, key: str, path: str, required: bool) -> list[float]:
    v = d.get(key)
    if v is None:
        if required:
            raise ConfigError(f"{path}.{key}: required (a list of temperatures in C)")
        return []
    if not isinstance(v, list) or not v:
        raise ConfigError(f"{path}.{key}: {v!r}; allowed: a list of temperatures in C")
    out = [number({key: x}, key, f"{path}.{key}", lo=-70.0, hi=180.0) for x in v]
    if len(set(out)) != len(out):
        raise ConfigError(f"{path}.{key}: {v}; each temperature once")
    return sorted(out)


def soak_until(rule: SoakRule, sp: float, chamber, clock, read, check_alarms, echo
               ) -> tuple[float, np.ndarray, float, float]:
    """Wait for the soak rule at ``sp`` (module docstring) over every temperature ``read(status)`` gives
    (one per board: the rule holds when each board's max - min over the hold is within tolerance).

    Returns (soak time, the temperatures, the air temperature, the time soaked), all on ``clock``;
    ChamberFault on timeout or alarm.
    """
    t0 = next_note = clock.now()
    window: list[tuple[float, np.ndarray]] = []
    while True:
        st = chamber.status()
        check_alarms(st, f"during the soak at {sp:g} C")
        temps = np.asarray(read(st), dtype=float)
        now = clock.now()
        if abs(st.air_c - sp) > rule.band_c:
            window = []
        else:
            window.append((now, temps))
            while np.max(np.ptp(np.stack([x for _, x in window]), axis=0)) > rule.tolerance_c:
                window.pop(0)
            if now - window[0][0] >= rule.hold_s:
                return now - t0, temps, st.air_c, now
        if now >= next_note + 600.0:  # a soak takes most of an hour: say where it is every 10 minutes
            next_note = now
            held = now - window[0][0] if window else 0.0
            echo(f"  soaking {now - t0:.0f} s: air {st.air_c:.1f} C, board {_span(temps)} C, stable for {held:.0f} s")
        if now - t0 >= rule.timeout_s:
            if abs(st.air_c - sp) > rule.band_c:
                raise ChamberFault("set point not reached", f"set point {sp:g} C not reached within "
                                   f"{rule.timeout_s:g} s (air {st.air_c:.1f} C, band +-{rule.band_c:g} C)", now - t0)
            raise ChamberFault("not stable", f"board temperature not stable within {rule.tolerance_c:g} C for "
                               f"{rule.hold_s:g} s at {sp:g} C within {rule.timeout_s:g} s (board {_span(temps)} C)",
                               now - t0)
        clock.sleep(rule.poll_s)


def _span(temps: np.ndarray) -> str:
    return f"{temps[0]:.2f}" if len(temps) == 1 else f"{temps.min():.2f}..{temps.max():.2f}"


class WallClock:
    """Real time, for a station with real hardware (the simulated board brings its virtual clock)."""

    realtime = True

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, dt: float) -> None:
        if dt > 0:
            time.sleep(dt)


@dataclass
class SetPointResult:
    """What one set point gave: soak, poses, temperatures, time split (s, on the station's clock)."""

    set_point_c: float
    role: str
    temp_source: str = ""
    soak_s: float = 0.0
    board_temp_c: float | None = None
    air_temp_c: float | None = None
    sampling_floor_s: float = 0.0
    poses_s: float = 0.0
    poses: int = 0
    fit: dict | None = None
    verdict: str | None = None
    reasons: list[Reason] = field(default_factory=list)
    verify_error_max_mg: float | None = None
    without_table_error_max_mg: float | None = None
    t_start_s: float = 0.0
    t_soaked_s: float | None = None
    t_end_s: float | None = None

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class ThermalRunReport(RunReport):
    thermal: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "thermal": self.thermal}


class ThermalStation(Station):
    """Runs a thermal plan for one board (module docstring); ``run()`` returns a ThermalRunReport."""

    def __init__(self, config: StationConfig, **kw) -> None:
        super().__init__(config, **kw)
        raw = config.raw
        if "thermal" not in raw or "chamber" not in raw:
            raise ConfigError(f"{config.path}: a thermal plan needs both thermal: and chamber: sections")
        if config.offset_trim:
            raise ConfigError("nvm.offset_trim: not with a thermal plan (the offset moves with temperature); "
                              "allowed: false")
        self.plan = ThermalPlan.from_config(raw["thermal"], config.model)
        self.results: list[SetPointResult] = []
        self.soak_s = 0.0
        self.report_events: list[str] = []
        self.verify: list[dict] = []
        self.table_verdict: dict | None = None

    # -- the run --------------------------------------------------------------------
    def run(self) -> ThermalRunReport:
        from .drivers import make_driver

        cfg = self.cfg
        rep = ThermalRunReport(station_id=cfg.station_id, model=cfg.model, design=cfg.design, store=str(cfg.store_file))
        wall0 = time.perf_counter()
        if self.driver is None:
            self.driver = make_driver(cfg.raw["device"])
        driver = self.driver
        with Store(cfg.store_file) as store:
            store.mark_stale_interrupted()
            with driver:
                ident = driver.identify()
                rep.serial, rep.chip = self.serial_override or ident.serial, ident.chip
                dev = cfg.raw["device"]
                driver.configure(dev.get("range_g"), dev.get("odr_hz"))
                board = board_of(driver)
                clock = board.clock if board is not None else WallClock()
                t0 = clock.now()
                run_id = rep.run_id = store.start_run(
                    device_serial=rep.serial, chip=ident.chip, station_id=cfg.station_id, operator=self.operator,
                    lot=self.lot, config_text=cfg.text, model=cfg.model, units="counts", counts_per_g=driver.counts_per_g)
                records: list[PoseRecord] = []
                retries: list[int] = []
                session = Session(records, units="counts", counts_per_g=driver.counts_per_g, device=rep.serial)
                try:
                    with make_chamber(cfg.raw["chamber"], board) as chamber, \
                            make_jig(cfg.raw.get("jig") or {"type": "simulated"}, driver, self.echo) as jig:
                        self._plan(driver, chamber, jig, clock, records, retries, rep)
                except (AccelcalError, KeyboardInterrupt) as e:
                    if isinstance(e, ChamberFault):
                        rep.verdict, rep.reasons = "FAIL", [Reason("chamber", str(e))]
                        self.echo(f"FAIL: chamber: {e} (nothing burned)")
                    else:
                        where = self._where()
                        why = "interrupted" if isinstance(e, KeyboardInterrupt) else str(e)
                        store.interrupt_run(run_id, f"{why} ({where})", session=session if records else None,
                                            status="interrupted" if isinstance(e, KeyboardInterrupt) else "error",
                                            retries=retries if records else None, nvm_outcome=rep.nvm)
                        raise
                rep.events.extend(self.report_events)
                rep.timing = self._thermal_timing(driver, clock, t0, wall0)
                rep.thermal = self._summary(rep)
                store.finish_run(run_id, session=session, calibration=rep.calibration,
                                 verdict=rep.verdict, reasons=rep.reasons, nvm_outcome=rep.nvm,
                                 fit_summary={"measured": rep.measured, "verify_error_max_mg": rep.verify_error_max_mg,
                                              "design": cfg.design, "timing": rep.timing, "thermal": rep.thermal,
                                              "nvm_verified": rep.nvm_verified},
                                 model=cfg.model, retries=retries)
        return rep

    def _where(self) -> str:
        if not self.results:
            return "before the first set point"
        r = self.results[-1]
        return f"at set point {r.set_point_c:g} C ({len(self.results)}/{len(self.plan.visits())}), " \
               f"{sum(x.poses for x in self.results)} poses captured"

    def _plan(self, driver, chamber, jig, clock, records, retries, rep) -> None:
        try:
            self._visit_all(driver, chamber, jig, clock, records, retries, rep)
        except BaseException:
            try:
                chamber.standby()  # leave the chamber safe; the original error is what matters
            except AccelcalError:
                pass
            raise

    def _visit_all(self, driver, chamber, jig, clock, records, retries, rep) -> None:
        visits = self.plan.visits()
        groups: dict[float, list[PoseRecord]] = {}
        for i, (sp, role) in enumerate(visits):
            self.echo(f"[set point {i + 1}/{len(visits)}] {sp:g} C ({role})")
            res = SetPointResult(sp, role, t_start_s=clock.now())
            self.results.append(res)
            chamber.set_point(sp)
            self._soak(driver, chamber, clock, res)
            # calibration poses go to the run's session as they come: an interrupted run keeps them
            sink = (records, retries) if role == "calibrate" else None
            groups[sp] = self._capture_set_point(driver, chamber, jig, clock, self._poses_for(role), res, rep, sink)
            if self.progress:
                self.progress("set points", (i + 1) / len(visits))
        chamber.standby()
        self._fit_table_burn(driver, groups, rep)

    def _poses_for(self, role: str):
        if role == "calibrate":
            return get_design(self.cfg.design)
        design = get_design(self.cfg.verify_design or self.cfg.design)
        return design[:max(self.cfg.verify_poses, 1)]

    # -- soak and capture --------------------------------------------------------------
    def _check_alarms(self, st, context: str) -> None:
        if st.door_open:
            raise ChamberFault("door open", f"door opened {context} (alarm {st.alarm_text()})")
        if st.alarms:
            raise ChamberFault("alarm", f"alarm {st.alarm_text()} {context}")
        if st.mode != "CONSTANT":
            raise ChamberFault("stopped", f"the chamber left constant mode ({st.mode}) {context}")

    def _soak(self, driver, chamber, clock, res: SetPointResult) -> None:
        """Wait until the soak rule holds (module docstring); ChamberFault on timeout or alarm."""
        has_sensor = driver.temperature_c() is not None
        res.temp_source = "die" if has_sensor else "chamber_air"
        if not has_sensor and len(self.results) == 1:
            note = (f"{driver.name}: the chip has no temperature sensor; the soak and every pose use the "
                    "chamber air temperature (the board is taken to be at the air temperature after the soak)")
            self.echo(f"  note: {note}")
            self.report_events.append(note)
        read = (lambda st: np.array([driver.temperature_c()])) if has_sensor else (lambda st: np.array([st.air_c]))
        try:
            soak_s, temps, air_c, now = soak_until(self.plan.soak, res.set_point_c, chamber, clock, read,
                                                   self._check_alarms, self.echo)
        except ChamberFault as e:
            res.soak_s = e.soak_s
            self.soak_s += e.soak_s
            raise
        self.soak_s += soak_s
        res.soak_s, res.board_temp_c, res.air_temp_c, res.t_soaked_s = soak_s, float(temps[0]), air_c, now
        self.echo(f"  soaked in {soak_s:.0f} s: board {temps[0]:.2f} C ({res.temp_source}), air {air_c:.1f} C")

    def _capture_set_point(self, driver, chamber, jig, clock, poses, res: SetPointResult, rep,
                           sink: tuple[list, list] | None) -> list[PoseRecord]:
        used0, t0, floor, out = self.samples_used, clock.now(), None, []
        sp = res.set_point_c
        for k, pose in enumerate(poses):
            self.echo(f"  [{k + 1}/{len(poses)}] {pose.name}")
            gc, tries = self._capture_pose(driver, jig, pose, floor, rep)
            st = chamber.status()
            self._check_alarms(st, f"during the capture of {pose.name} at {sp:g} C; the capture is discarded")
            floor, c = gc.floor_counts, gc.capture
            temp = c.temp_c if res.temp_source == "die" else st.air_c
            if abs(temp - res.board_temp_c) > self.plan.capture_band_c:
                raise ChamberFault("temperature moved", f"board temperature {temp:.2f} C during {pose.name} at {sp:g} C "
                                   f"left the band +-{self.plan.capture_band_c:g} C around {res.board_temp_c:.2f} C")
            rec = PoseRecord(f"{pose.name}@{sp:g}C", c.mean_counts, c.std_counts, c.n, pose.reference_g,
                             pose.pitch_deg, pose.roll_deg, temp, c.dropped, c.t_start, c.t_end)
            out.append(rec)
            if sink is not None:
                sink[0].append(rec)
                sink[1].append(tries + gc.recaptures)
            rep.poses.append({"pose": rec.name, "set_point_c": sp, "role": res.role, "temp_c": temp, "n": c.n,
                              "sem_mg": (c.sem_counts / driver.counts_per_g * 1e3).tolist(),
                              "retries": tries + gc.recaptures})
            res.poses += 1
        res.sampling_floor_s = (self.samples_used - used0) / driver.odr_hz
        res.t_end_s = clock.now()
        res.poses_s = res.t_end_s - t0
        return out

    # -- fit, table, verify, burn ----------------------------------------------------------
    def _fit_each(self, groups, cpg, rep) -> tuple[list[tuple[float, Any]], list[str]]:
        fits, reasons = [], []
        for res in (r for r in self.results if r.role == "calibrate"):
            sp = res.set_point_c
            temps = [p.temp_c for p in groups[sp]]
            try:
                fit = fit_session(Session(groups[sp], "counts", cpg, device=rep.serial), self.cfg.model)
            except UnderdeterminedError as e:
                res.verdict, res.reasons = "FAIL", [Reason("fit", str(e))]
                reasons.append(wrap(Reason("fit", str(e)), f"at {sp:g} C: "))
                continue
            v = judge(fit, self.cfg.limits)
            res.fit = {"residual_rms_mg": fit.residual_rms_g * 1e3, "V_mg": (fit.V * 1e3).tolist(), **v.measured}
            res.verdict, res.reasons = v.label, v.reasons
            reasons += [wrap(r, f"at {sp:g} C: ") for r in v.reasons]
            fits.append((float(np.mean(temps)), fit))
        return fits, reasons

    def _fit_table_burn(self, driver, groups, rep) -> None:
        cfg, plan, cpg = self.cfg, self.plan, driver.counts_per_g
        fits, reasons = self._fit_each(groups, cpg, rep)
        if len(fits) < len(plan.set_points_c):
            rep.verdict, rep.reasons = "FAIL", reasons
            return
        table = TemperatureTable([t for t, _ in fits], [f.W for _, f in fits], [f.V for _, f in fits],
                                 [f.Gamma for _, f in fits], plan.method)
        cal = Calibration(cfg.model, table.W[0], table.V[0], table.Gamma[0], "counts", cpg, temperature=table,
                          metadata={"thermal": {"set_points_c": list(plan.set_points_c), "method": plan.method}})
        ref_t, ref_fit = min(fits, key=lambda tf: abs(tf[0] - plan.reference_c))
        rep.calibration, rep.fit = cal, ref_fit
        rep.measured = judge(ref_fit, cfg.limits).measured
        limit = cfg.limits.values.get("verify_error_max_mg")
        self.verify = []
        for res in (r for r in self.results if r.role == "verify"):
            recs = groups[res.set_point_c]
            ref = np.array([p.reference_g for p in recs])
            x = np.array([p.mean for p in recs])
            t = np.array([p.temp_c for p in recs])
            try:
                with_table = float(np.max(np.abs(cal.apply(x, units="counts", temp_c=t) - ref))) * 1e3
            except AccelcalError as e:
                reasons.append(Reason.of("verify", f"verify at {res.set_point_c:g} C: {e}"))
                continue
            single = float(np.max(np.abs(ref_fit.calibration.apply(x, units="counts") - ref))) * 1e3
            res.verify_error_max_mg, res.without_table_error_max_mg = with_table, single
            res.verdict = "PASS" if limit is None or with_table <= limit else "FAIL"
            self.verify.append({"set_point_c": res.set_point_c, "board_temp_c": float(np.mean(t)),
                                "error_max_mg": with_table, "without_table_error_max_mg": single,
                                "without_table_calibration_c": ref_t, "limit_mg": limit,
                                "within_limit": limit is None or with_table <= limit,
                                "without_table_within_limit": limit is None or single <= limit})
            self.echo(f"verify at {res.set_point_c:g} C: {with_table:.3f} mg with the table, "
                      f"{single:.3f} mg with the {ref_t:.1f} C calibration alone (limit {limit} mg)")
            if limit is not None and not with_table <= limit:
                reasons.append(Reason.of("verify_error_max_mg", f"verify at {res.set_point_c:g} C: verify_error_max_mg "
                                          f"{with_table:.4g} > limit {limit:g}"))
        rep.verify_error_max_mg = max((v["error_max_mg"] for v in self.verify), default=None)
        if rep.verify_error_max_mg is not None:
            rep.measured["verify_error_max_mg"] = rep.verify_error_max_mg
        self.table_verdict = {"verdict": "FAIL" if reasons else "PASS", "reasons": [str(r) for r in reasons]}
        if reasons:
            rep.verdict, rep.reasons = "FAIL", reasons
            self.echo("FAIL before writing: " + "; ".join(reasons))
            return
        rep.verdict, rep.reasons = "PASS", []
        if cfg.nvm_write:
            self._burn(driver, cal, groups, rep)

    def _burn(self, driver, cal: Calibration, groups, rep) -> None:
        if driver.nvm is None:
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", "the device has no NVM to write; set nvm.write: false")]
            return
        writer = CalibrationWriter(driver.nvm, self.cfg.slot_size)
        try:
            outcome = writer.burn(cal, rep.serial, self.cfg.station_id)
        except BurnError as e:
            rep.nvm = e.outcome.to_dict()
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", str(e))]
            return
        rep.nvm = outcome.to_dict()
        back = writer.read_newest(rep.serial)
        if back is None or back[0].temperature is None:
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", "no temperature table readable after writing")]
            return
        stored = back[0]
        recs = [p for r in self.results if r.role == "verify" for p in groups.get(r.set_point_c, [])]
        x, t = np.array([p.mean for p in recs]), np.array([p.temp_c for p in recs])
        same = np.allclose(stored.apply(x, units="counts", temp_c=t), cal.apply(x, units="counts", temp_c=t), atol=1e-9) \
            and np.allclose(stored.temperature.temps_c, cal.temperature.temps_c)
        rep.nvm_verified = bool(same)
        if not same:
            rep.verdict, rep.reasons = "FAIL", [Reason("nvm", "the table read back from NVM differs from the fitted one")]
        self.echo(f"NVM: slot {outcome.slot}, generation {outcome.generation}, {outcome.length} bytes, "
                  f"{len(stored.temperature.temps_c)}-temperature table read back"
                  + (" and verified" if same else " DIFFERS"))

    # -- report ----------------------------------------------------------------------------
    def _thermal_timing(self, driver, clock, t0: float, wall0: float) -> dict[str, float]:
        """Time per board: soak, the sampling floor (samples averaged / ODR) and the rest (moves, gating, I/O)."""
        total = clock.now() - t0
        floor = self.samples_used / driver.odr_hz
        return {"odr_hz": driver.odr_hz, "samples_averaged": self.samples_used, "samples_read": self.samples_read,
                "board_time_s": total, "soak_s": self.soak_s, "sampling_floor_s": floor,
                "sampling_s": self.samples_read / driver.odr_hz, "rest_s": total - self.soak_s - floor,
                "boards": 1, "per_board_s": total, "clock": "real" if getattr(clock, "realtime", False) else "virtual",
                "host_compute_s": time.perf_counter() - wall0}

    def _summary(self, rep) -> dict:
        p = self.plan
        table = rep.calibration.temperature if rep.calibration is not None else None
        return {"set_points_c": list(p.set_points_c), "verify_set_points_c": list(p.verify_set_points_c),
                "method": p.method, "soak": p.soak.__dict__,
                "temp_source": self.results[0].temp_source if self.results else None,
                "visits": [r.to_dict() for r in self.results],
                "table": None if table is None else {"temps_c": table.temps_c.tolist(), "method": table.method,
                                                     **(self.table_verdict or {})},
                "verify": self.verify, "panel": None}
