"""A thermal plan over a panel: every board of the panel captured at each pose at each set point.

The panel sits in one chamber on one jig (panel.Panel captures a pose on every board at once;
thermal_table.BoardPlan gives each board's fits, temperature table, verdicts, burn and
read-back).  At each set point the soak holds when every board's temperature (its die's; the
chamber air for a chip without a sensor) is stable (thermal_plan.soak_until); then the pose
design runs once for the whole panel.  Each board gets its own per-temperature fits and table,
verified at the unused set points, its own burn with read-back and its own run in the store,
all sharing one ``panel_id``.  Each board is fitted against references turned by its own
mounting (device.mount, device.boards[i].mount: panel_mount.py), as at room temperature.

A board that fails (a NACK, a wrong face, its temperature leaving the capture band, a fit
beyond its limits) is named with its own reason and dropped; it never stops the others.
A chamber fault (set point not reached, alarm, door opened) ends every board's run with a
recorded FAIL verdict and the reason; nothing is burned (burning comes after the last set
point).  Simulated boards each keep their own clock (captures run at once); the chamber
runs on the first board's clock and every clock is brought to the latest after each step.
"""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ..acceptance.reasons import Reason
from ..config.schema import ChamberSection
from ..drivers.base import Clock
from ..fixtures.base import Jig, PoseSpec
from ..fixtures.factory import board_of, clock_of, sync_clocks
from ..instruments.chamber import Chamber, ChamberStatus
from ..instruments.factory import make_chamber
from ..session import PoseRecord
from .capture import GatedCapture
from .panel import PanelBoard, PanelTiming
from .policy import FlowView
from .thermal_plan import ChamberFault, ThermalPlan, WallClock, check_alarms, soak_until, standby
from .thermal_table import BoardPlan, SetPointResult, poses_for
from .verdict import Stage


class ThermalPanel:
    """The panel's part of a thermal plan: its shared soaks and captures, its clock and its time."""

    def __init__(self, plan: ThermalPlan, chamber_section: ChamberSection, of: Callable[[PanelBoard], BoardPlan],
                 flow: FlowView) -> None:
        self.plan, self.chamber_section, self.flow = plan, chamber_section, flow
        self.of = of  # each board's part of the plan (thermal.ThermalConditions.of)
        self.echo = flow.echo
        self.soak_s = 0.0
        self.floor_s = 0.0  # the panel's sampling floor: per pose, the longest board's averaged samples / ODR
        self.clock: Clock = WallClock()  # the panel's clock and its start, set when the boards are open
        self.t0 = 0.0

    def calibrate(self, boards: list[PanelBoard]) -> None:
        live = [b for b in boards if b.active]
        clock = self.clock = next((c for c in (clock_of(b.driver) for b in live) if c is not None), None) \
            or WallClock()
        self.t0 = clock.now()
        if live:
            self._in_chamber(live, clock)

    def _in_chamber(self, live: list[PanelBoard], clock: Clock) -> None:
        sims = [board_of(b.driver) for b in live]
        # every board of the panel sits in the same chamber air (coupled by the factory)
        with make_chamber(self.chamber_section, sims[0], others=sims[1:]) as chamber, \
                self.flow.panel.make_jig(live) as jig:
            try:
                self._visit_all(live, chamber, jig, clock)
            except ChamberFault as e:
                self._chamber_fault(live, chamber, e)
                return
            except BaseException:
                standby(chamber)
                raise
        for b in live:
            if b.active:
                self.of(b).fit_table_burn(b.driver, b.rep)
                b.cal = b.rep.calibration

    def _chamber_fault(self, live: list[PanelBoard], chamber: Chamber, e: ChamberFault) -> None:
        standby(chamber)
        self.echo(f"FAIL: chamber: {e} (every board; nothing burned)")
        for b in live:
            b.rep.record(Stage.CHAMBER, Reason("chamber", str(e)))

    # -- set points ------------------------------------------------------------------------
    def _sync(self, boards: list[PanelBoard]) -> None:
        """Bring every simulated board's clock to the latest: the panel shares one chamber's time."""
        sync_clocks([b.driver for b in boards])

    def _visit_all(self, live: list[PanelBoard], chamber: Chamber, jig: Jig, clock: Clock) -> None:
        visits = self.plan.visits()
        for i, (sp, role) in enumerate(visits):
            active = [b for b in live if b.active]
            if not active:
                break
            self.echo(f"[set point {i + 1}/{len(visits)}] {sp:g} C ({role}), {len(active)} boards")
            res = {b.index: SetPointResult(sp, role, t_start_s=clock.now()) for b in active}
            for b in active:
                self.of(b).results.append(res[b.index])
            chamber.set_point(sp)
            self._soak(active, chamber, clock, res)
            self._capture_set_point(active, chamber, jig, clock, poses_for(self.flow.cfg, role), res)
        standby(chamber)

    def _soak(self, active: list[PanelBoard], chamber: Chamber, clock: Clock,
              res: dict[int, SetPointResult]) -> None:
        """Every board soaked together: the rule holds over all their temperatures (thermal_plan.soak_until)."""
        die = {b.index: b.driver.temperature_c() is not None for b in active}
        for b in active:
            res[b.index].temp_source = "die" if die[b.index] else "chamber_air"

        def read(st: ChamberStatus) -> np.ndarray:
            return np.array([b.driver.temperature_c() if die[b.index] else st.air_c for b in active])

        sp = next(iter(res.values())).set_point_c
        try:
            soak_s, temps, air_c, now = soak_until(self.plan.soak, sp, chamber, clock, read, check_alarms, self.echo)
        except ChamberFault as e:
            self._soaked(active, res, e.soak_s)  # a soak that timed out still counts as soak time
            raise
        self._soaked(active, res, soak_s, temps, air_c, now)
        self.echo(f"  soaked in {soak_s:.0f} s: boards {temps.min():.2f}..{temps.max():.2f} C, air {air_c:.1f} C")

    def _soaked(self, active: list[PanelBoard], res: dict[int, SetPointResult], soak_s: float,
                temps: np.ndarray | None = None, air_c: float | None = None, now: float | None = None) -> None:
        """Record a soak (ended or timed out) for the panel and each board, and bring the clocks together."""
        self.soak_s += soak_s
        for k, b in enumerate(active):
            r = res[b.index]
            self.of(b).soak_s += soak_s
            r.soak_s, r.air_temp_c, r.t_soaked_s = soak_s, air_c, now
            r.board_temp_c = None if temps is None else float(temps[k])
        self._sync(active)

    def _capture_set_point(self, active: list[PanelBoard], chamber: Chamber, jig: Jig, clock: Clock,
                           poses: list[PoseSpec], res: dict[int, SetPointResult]) -> None:
        sp = next(iter(res.values())).set_point_c
        t0 = clock.now()
        for k, pose in enumerate(poses):
            self.echo(f"  [{k + 1}/{len(poses)}] {pose.name}")
            todo = [b for b in active if b.active]
            caps = self.flow.panel.present_and_capture(todo, jig, pose, {b.index: b.floor for b in todo},
                                                       read_on=True)
            self._sync(todo)
            st = chamber.status()
            check_alarms(st, f"during the capture of {pose.name} at {sp:g} C; the capture is discarded")
            if caps:
                self.floor_s += max(gc.capture.n / todo[0].driver.odr_hz for gc in caps.values())
            for b in todo:
                if b.index in caps:
                    self._keep(b, pose, caps[b.index], st, res[b.index])
        self.flow.panel.end_design(active)  # a board read on past a wrong pose: named with its mounting
        for b in active:
            r = res[b.index]
            r.sampling_floor_s = sum(p["n"] for p in b.rep.poses if p["set_point_c"] == sp) / b.driver.odr_hz
            r.t_end_s = clock.now()
            r.poses_s = r.t_end_s - t0

    def _keep(self, b: PanelBoard, pose: PoseSpec, gc: GatedCapture, st: ChamberStatus, res: SetPointResult) -> None:
        """One board's capture at one pose and set point; its temperature leaving the band fails that board."""
        sp, c = res.set_point_c, gc.capture
        temp = res.pose_temp_c(c.temp_c, st.air_c)
        band = self.plan.capture_band_c
        if res.moved_c(temp) > band:
            b.fail(Stage.CAPTURE, Reason("temperature", f"board temperature {temp:.2f} C during {pose.name} at "
                                         f"{sp:g} C left the band +-{band:g} C around {res.board_temp_c:.2f} C"))
            self.echo(f"  {b.name}: {b.rep.reasons[-1]}")
            return
        b.floor = gc.floor_counts
        rec = PoseRecord(f"{pose.name}@{sp:g}C", c.mean_counts, c.std_counts, c.n, b.steps.expected_g(pose),
                         *b.steps.chip_angles(pose), temp, c.dropped, c.t_start, c.t_end, c.n_eff)
        self.of(b).groups.setdefault(sp, []).append(rec)
        if res.role == "calibrate":  # the run's session: calibration poses, kept if the run is interrupted
            b.records.append(rec)
            b.retries.append(gc.recaptures)
        b.steps.samples_read += gc.samples_read
        b.steps.samples_used += c.n
        b.rep.poses.append({"pose": rec.name, "set_point_c": sp, "role": res.role, "temp_c": temp, "n": c.n,
                            "sem_mg": (c.sem_counts / b.driver.counts_per_g * 1e3).tolist(),
                            "retries": gc.recaptures})
        res.poses += 1

    # -- report ----------------------------------------------------------------------------
    def timing(self, boards: list[PanelBoard], wall0: float) -> None:
        """Each board's split as a single board reports it, and the panel's: the boards share the soak
        and are captured at once, so the per-board figure is the panel's time / boards."""
        clock, t0 = self.clock, self.t0
        opened = [b for b in boards if b.open_]
        self._sync(opened)  # the burns ran on each board's own clock (own EEPROM): the panel waits for the last
        for b in opened:
            b.rep.timing = self.of(b).timing(b.driver, clock, t0, wall0)
            b.rep.timing["boards"] = len(boards)
        total = clock.now() - t0
        n = len(boards)
        rest = total - self.soak_s - self.floor_s
        timing: PanelTiming = {
            "boards": n, "panel_time_s": total, "soak_s": self.soak_s, "sampling_floor_s": self.floor_s,
            "rest_s": rest, "board_time_s": total,
            "per_board": {"soak_s": self.soak_s / n, "sampling_floor_s": self.floor_s / n,
                          "rest_s": rest / n, "board_time_s": total / n},
            "clock": "real" if clock.realtime else "virtual", "host_compute_s": time.perf_counter() - wall0}
        self.flow.panel.timing = timing
        timing["per_board_s"] = total / n
