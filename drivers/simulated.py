"""The simulated board: a SensorModel with state (orientation, clock, temperature, EEPROM).

:class:`SimulatedBoard` is the physical board; :class:`SimulatedDriver` is the
:class:`Driver` that talks to it (python-can's ``virtual`` interface in spirit), and
the register-level emulators of the real chips are fed by a board through
``configure()`` and ``read()`` only.

Time is a :class:`VirtualClock`: reading n samples advances it by n / ODR (the
samples sit on the chip's ODR grid) without waiting, so a whole calibration takes
milliseconds; ``realtime: true`` also sleeps the wall time, for demonstrations.
One ``seed`` drives three independent random streams (noise, drift, pose scatter),
so switching one effect on does not change the draws of the others.

Board configuration (YAML mapping; the ``device`` section of a station config
with ``driver: simulated``)::

    chip: mma8451         # datasheet defaults: mma8451 | mpu6050
    range_g: 2            # full scale, g (chip's allowed ranges)
    odr_hz: 100           # output data rate, Hz
    dlpf: 3               # MPU6050 DLPF_CFG 0..6 (MPU6050 only)
    seed: 1               # reproducible runs (default: fresh entropy, kept in .seed)
    serial: SIM-0001      # board serial (default: from the seed)
    realtime: false       # sleep wall time as the virtual clock advances
    ambient_c: 25         # ambient temperature, C
    self_heating_c: 0     # die temperature above ambient, C
    eeprom: {size_bytes: 4096, page_bytes: 32, write_cycle_ms: 5, fail_at_write: null}
    simulator: FILE.yaml  # or an inline mapping {effects: {...}}; or `effects:` here directly
"""
from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np
from numpy.typing import ArrayLike

from ..calibration import Calibration
from ..config.kinds import SimEepromSection, SimulatedBoardSection
from ..config.parts import parse
from ..conventions import WORLD_UP, attitude_for_up, pose_attitude
from ..errors import ConfigError, DeviceError
from ..sim.chip_noise import FilteredNoise
from ..sim.sensor_model import SensorModel, get_chip, rotation_matrix
from .base import Driver, Identity
from .eeprom import EEPROM24
from .simulated_section import draw_board, load_physics, load_simulator


class Pose(Protocol):
    """What the board needs of a commanded pose (a fixtures PoseSpec): its name and reference output."""

    @property
    def name(self) -> str: ...

    @property
    def reference_g(self) -> np.ndarray: ...


class Environment(Protocol):
    """Surroundings that set the board's temperature (an emulated chamber's physics)."""

    def board_temperature_c(self) -> float: ...


class VirtualClock:
    """Simulated time in seconds; ``realtime`` also sleeps the wall time."""

    def __init__(self, start: float = 0.0, realtime: bool = False) -> None:
        self.t = float(start)
        self.realtime = realtime

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        if dt > 0:
            if self.realtime:
                time.sleep(dt)
            self.t += dt

    def advance_to(self, t: float) -> None:
        self.sleep(t - self.t)


def pose_placement(pose: Pose) -> np.ndarray:
    """Board-to-world rotation that places ``pose`` physically: from its AN4399 angles when it has
    them (the jig's own turn), else the smallest turn putting its expected output up."""
    pitch, roll = getattr(pose, "pitch_deg", None), getattr(pose, "roll_deg", None)
    if pitch is not None and roll is not None:
        return pose_attitude(pitch, roll)
    return attitude_for_up(pose.reference_g)


class SimulatedBoard:
    """A simulated accelerometer board (see module docstring and sensor_model)."""

    def __init__(self, model: SensorModel, seed: int | None = None, serial: str | None = None,
                 realtime: bool = False, ambient_c: float = 25.0, self_heating_c: float = 0.0,
                 eeprom: EEPROM24 | None = None, clock: VirtualClock | None = None) -> None:
        self.model = model
        self.chip = model.chip
        ss = np.random.SeedSequence(seed)
        self.seed = int(cast(int, ss.entropy))  # an int: the seed given, or fresh entropy for None
        self._rng_noise, self._rng_drift, self._rng_pose = (np.random.default_rng(s) for s in ss.spawn(3))
        self.serial = serial if serial is not None else f"SIM-{self.seed % 10**8:08d}"
        self.clock = clock if clock is not None else VirtualClock(realtime=realtime)
        self.eeprom = eeprom if eeprom is not None else EEPROM24(clock=self.clock)
        self.eeprom.clock = self.clock
        self.ambient_c = float(ambient_c)
        self.self_heating_c = float(self_heating_c)
        # e.g. an emulated chamber's physics: then the board's temperature follows it
        self.environment: Environment | None = None
        self._t_power = self.clock.now()
        self.pose: Pose | None = None
        self.true_rotation = np.eye(3)  # R_err of the current pose
        # how the board sits in the world (board-to-world rotation; flat, component side up) and how
        # the chip sits on the board: row i of ``mount`` is the chip axis i in board axes
        self.attitude = np.eye(3)
        self.mount = np.eye(3)
        self._dir = np.array([0.0, 0.0, 1.0])  # true output direction, chip axes (flat board: +z up)
        self._f = model.gravity_g() * self._dir
        self._settle = np.zeros(3)  # settling transient at time _t_settle
        self._t_settle = self._t_power
        self._walk = np.zeros(3)  # drift random-walk state at time _t_walk
        self._t_walk = self._t_power
        self._noise = FilteredNoise()  # the DLPF's noise state
        self._f_prev, self._t_change = self._f.copy(), -np.inf  # the force before the last change (DLPF delay)
        self.oversampling: str | None = None  # MMA8451 CTRL_REG2 MODS (None: normal)
        self._disturbances: list[tuple[float, float, float, np.ndarray]] = []
        c = self.chip
        self.configure(c.default_range_g, c.default_odr_hz, c.default_dlpf)

    def powered_for(self, seconds: float) -> None:
        """The board has been powered ``seconds`` already (a line powers boards ahead of placement):
        the warm-up of the drift effect (stage 5) runs from that earlier power-up."""
        self._t_power = self.clock.now() - float(seconds)

    @classmethod
    def from_config(cls, cfg: Mapping[str, object] | None = None, chip: str | None = None, seed: int | None = None,
                    path: str = "simulator") -> SimulatedBoard:
        """A board from a mapping of board keys (a test's, a simulator file's), validated once against
        SimulatedBoardSection, then built as :meth:`from_section`.

        ``cfg=None`` is an ideal chip of its datasheet: noise, quantization and
        saturation only (configs/sim.yaml is the realistic default board).
        """
        return cls.from_section(parse(cfg, SimulatedBoardSection, path), chip, seed, path)

    @classmethod
    def from_section(cls, m: SimulatedBoardSection, chip: str | None = None, seed: int | None = None,
                     path: str = "simulator") -> SimulatedBoard:
        """Build a board from its validated section; ``chip``/``seed`` arguments override it."""
        spec = get_chip(chip or m.chip or "mma8451", f"{path}.chip")
        effects, epath, population = load_simulator(m, path)
        model = SensorModel.from_config(effects, spec, epath, forward=load_physics(m, path))
        if seed is None:
            seed = m.seed
        if population is not None:
            seed = int(cast(int, np.random.SeedSequence(seed).entropy))  # fixed here: the draw depends on it
            model = draw_board(model, population, seed, epath.rsplit(".", 1)[0] + ".population")
        board = cls(model, seed, None if m.serial is None else str(m.serial), m.realtime, m.ambient_c,
                    m.self_heating_c, sim_eeprom(m.eeprom or SimEepromSection(), f"{path}.eeprom"))
        if m.true_mount is not None:  # the chip sits turned on this board (the station may not know)
            board.mount = m.true_mount_p()
            board.place(board.attitude)
        board.configure(spec.default_range_g if m.range_g is None else m.range_g,
                        spec.default_odr_hz if m.odr_hz is None else m.odr_hz, m.dlpf, path)
        return board

    # -- configuration ----------------------------------------------------------------------
    def configure(self, range_g: int, odr_hz: float, dlpf: int | None = None, path: str = "configure",
                  oversampling: str | None = None) -> None:
        """Set full scale (g), output data rate (Hz) and, on the MPU6050, DLPF_CFG; on the MMA8451 the
        oversampling mode (CTRL_REG2 MODS; None keeps the current one)."""
        range_g, odr_hz, dlpf = self.chip.check(range_g, odr_hz, dlpf, path)
        self.model.check_range(range_g)
        if oversampling is not None:
            self.chip.noise_scale(odr_hz, oversampling)  # refuses a mode the chip does not have
            self.oversampling = oversampling
        self.range_g, self.odr_hz, self.dlpf = range_g, odr_hz, dlpf
        self._grid0 = self.clock.now()  # the ODR grid restarts with the new setting

    @property
    def counts_per_g(self) -> float:
        return self.chip.counts_per_g(self.range_g)

    @property
    def identity(self) -> Identity:
        return Identity(self.chip.name, self.chip.chip_id, self.serial, "simulated")

    @property
    def temperature_c(self) -> float:
        """True die temperature, C (ambient, or the board's temperature in its environment, plus self-heating)."""
        if self.environment is not None:
            return self.environment.board_temperature_c() + self.self_heating_c
        return self.ambient_c + self.self_heating_c

    def set_temperature(self, ambient_c: float) -> None:
        self.ambient_c = float(ambient_c)

    @property
    def noise_sigma_counts(self) -> np.ndarray:
        """Per-sample noise standard deviation in counts at the current setting."""
        return self.noise_sigma_g * self.counts_per_g

    @property
    def noise_sigma_g(self) -> np.ndarray:
        """Per-sample noise standard deviation in g: density (scaled by the oversampling mode) * sqrt(ENBW)."""
        return self.model.noise_sigma_g(self.odr_hz, self.dlpf) * self.chip.noise_scale(self.odr_hz, self.oversampling)

    noise_lag1 = property(lambda self: self.chip.noise_lag1(self.odr_hz, self.dlpf), doc="noise rho_1 (stage 7)")

    def truth(self, temp_c: float | None = None) -> Calibration:
        """The exact AN4399 calibration at temp_c (default: the die temperature now)."""
        return self.model.truth(self.temperature_c if temp_c is None else temp_c, self.counts_per_g)

    # -- orientation -------------------------------------------------------------------------
    @property
    def true_direction(self) -> np.ndarray:
        """Unit vector of the true ideal output, chip axes: the chip axis pointing up reads +."""
        return self._dir.copy()

    def pose_error_rotation(self) -> np.ndarray:
        """R_err = R_jig R_scatter for one presentation (a fresh scatter draw)."""
        if not self.model.has("pose_error"):
            return np.eye(3)
        p = self.model.effects["pose_error"]
        scatter = self._rng_pose.normal(0.0, p["scatter_deg"], 3) if p["scatter_deg"] > 0 else np.zeros(3)
        return rotation_matrix(p["jig_rotation_deg"]) @ rotation_matrix(scatter)

    def force_direction(self, attitude: ArrayLike) -> np.ndarray:
        """Unit specific force in chip axes with the board at ``attitude`` (board-to-world):
        ``mount @ attitude.T @ up``, +1 g on the axis pointing away from the Earth (MMA8451Q
        data sheet "Product orientation"; MPU-6050 product specification)."""
        return self.mount @ (np.asarray(attitude, dtype=float).T @ WORLD_UP)

    def place(self, attitude: ArrayLike) -> None:
        """Hold the board physically at ``attitude`` (board-to-world rotation); starts a settling transient."""
        R = np.asarray(attitude, dtype=float).reshape(3, 3)
        if not np.all(np.isfinite(R)) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
            raise DeviceError(f"board attitude {R.tolist()} must be a rotation matrix")
        self.attitude = R
        self._set_direction(self.force_direction(R))

    def set_pose(self, pose: Pose, rotation: ArrayLike | None = None, attitude: ArrayLike | None = None) -> None:
        """Bring the board to a commanded PoseSpec: placed with its expected output pointing up
        (conventions.pose_attitude), turned by the jig's error, so the true output is R_err @ reference_g.

        ``rotation``: an R_err already drawn with :meth:`pose_error_rotation` (a jig
        that moves there first); by default a fresh one is drawn.  ``attitude``: the nominal
        board-to-world rotation a machine's own axes reached (the jig emulator's gimbal);
        by default the pose's placement.
        """
        R = self.pose_error_rotation() if rotation is None else np.asarray(rotation, dtype=float)
        self.pose, self.true_rotation = pose, R
        nominal = pose_placement(pose) if attitude is None else np.asarray(attitude, dtype=float)
        self.place(nominal @ R.T)

    def set_gravity_direction(self, direction: ArrayLike) -> None:
        """Place the board so its chip reads along ``direction`` (chip axes; the axis pointing up reads +):
        the smallest turn from flat that puts that direction up (no pose error)."""
        d = np.asarray(direction, dtype=float).reshape(3)
        n = np.linalg.norm(d)
        if not np.isfinite(n) or n == 0:
            raise DeviceError(f"gravity direction {d.tolist()} must be a finite non-zero vector")
        self.place(attitude_for_up(self.mount.T @ (d / n)))

    def _set_direction(self, d: np.ndarray) -> None:
        n = np.linalg.norm(d)
        f_new = self.model.gravity_g() * d / n
        now = self.clock.now()
        self._f_prev, self._t_change = self._f.copy(), now
        self._settle = self._settling_at(np.array([now]))[0] + self._settle_fraction() * (f_new - self._f)
        self._t_settle = now
        self._dir, self._f = d / n, f_new

    # -- samples -------------------------------------------------------------------------------
    def _settle_fraction(self) -> float:
        return float(self.model.effects["settling"]["fraction"]) if self.model.has("settling") else 0.0

    def _settling_at(self, t: np.ndarray) -> np.ndarray:
        if not self.model.has("settling"):
            return np.zeros((len(t), 3))
        tau = self.model.effects["settling"]["tau_s"]
        return self._settle * np.exp(-(t - self._t_settle) / tau)[:, None]

    def _drift(self, t: np.ndarray) -> np.ndarray:
        """Offset drift (g) at sample times t: warm-up plus random walk (state carried on)."""
        if not self.model.has("drift"):
            return np.zeros((len(t), 3))
        p = self.model.effects["drift"]
        warm = 1e-3 * p["warmup_mg"] * (1.0 - np.exp(-(t - self._t_power) / p["warmup_tau_s"]))[:, None]
        dts = np.diff(np.concatenate([[self._t_walk], t]))
        steps = self._rng_drift.standard_normal((len(t), 3)) * np.sqrt(dts)[:, None]
        walk = self._walk + np.cumsum(steps * 1e-6 * p["random_walk_ug_per_rts"], axis=0)
        self._walk, self._t_walk = walk[-1].copy(), float(t[-1])
        return warm + walk

    def _times(self, n: int) -> np.ndarray:
        """The next n instants of the ODR grid after now; the clock advances to the last."""
        if n < 1:
            raise DeviceError(f"read of {n} samples; need at least 1")
        m0 = np.floor((self.clock.now() - self._grid0) * self.odr_hz + 1e-6) + 1
        t = self._grid0 + (m0 + np.arange(n)) / self.odr_hz
        self.clock.advance_to(float(t[-1]))
        return t

    def _noise_at(self, t: np.ndarray) -> np.ndarray:
        """Noise (g) at sample times t (sim/chip_noise.py; white, the same draws, without a DLPF)."""
        e = self._rng_noise.standard_normal((len(t), 3)) * self.noise_sigma_g
        return self._noise.draw(e, t, self.noise_lag1, self.odr_hz)

    def _sample(self, t: np.ndarray, G: np.ndarray, settle: np.ndarray) -> np.ndarray:
        x = G + self._drift(t) + settle
        if self.model.has("noise"):
            x = x + self._noise_at(t)
        return self.model.to_counts(x, self.counts_per_g)

    def read(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n samples at the current pose: counts (n, 3) and timestamps t_s (n,).

        Counts are int64 when quantization is enabled (always for a real chip), else
        float64 unrounded counts.  The virtual clock advances by n / ODR.
        """
        t = self._times(int(n))
        f = self._f[None]
        if self._disturbances:
            f = self._disturbed(t)
        late = t < self._t_change + self.chip.delay_s(self.dlpf)  # the DLPF's delay: still the old force
        if late.any():
            f = np.where(late[:, None], self._f_prev[None], np.broadcast_to(f, (len(t), 3)))
        G = self.model.response_g(f, self.temperature_c)
        return self._sample(t, G, self._settling_at(t)), t

    def disturb(self, after_s: float, duration_s: float, amplitude_deg: float) -> None:
        """Someone bumps the board: from ``after_s`` (virtual clock, from now) for
        ``duration_s`` it tips by up to ``amplitude_deg`` (a half-sine) and comes back."""
        d = self._dir
        axis = np.cross(d, np.eye(3)[int(np.argmin(np.abs(d)))])
        t0 = self.clock.now() + float(after_s)
        self._disturbances.append((t0, t0 + float(duration_s), float(amplitude_deg), axis / np.linalg.norm(axis)))

    def _disturbed(self, t: np.ndarray) -> np.ndarray:
        f = np.repeat(self._f[None], len(t), axis=0)
        for t0, t1, amp, axis in self._disturbances:
            m = (t >= t0) & (t < t1)
            if m.any():
                ang = amp * np.sin(np.pi * (t[m] - t0) / (t1 - t0))
                f[m] = rotation_matrix(axis * ang[:, None]) @ self._f
        self._disturbances = [d for d in self._disturbances if d[1] > t[-1]]
        return f

    def read_motion(self, directions: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """One sample per row of ``directions`` (n, 3) while the true output follows them.

        The board rotates about its sensor (no centripetal force); each change of
        the true force feeds the settling transient.  The board ends at the last row.
        """
        d = np.asarray(directions, dtype=float)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        f = self.model.gravity_g() * d
        t = self._times(len(d))
        settle = np.zeros_like(f)
        if self.model.has("settling"):
            tau = self.model.effects["settling"]["tau_s"]
            steps = self._settle_fraction() * np.diff(np.vstack([self._f, f]), axis=0)
            x0 = self._settling_at(t[:1])[0] + steps[0]
            a = np.exp(-1.0 / (self.odr_hz * tau))  # s_k = a s_{k-1} + step_k on the ODR grid
            settle[0] = x0
            if len(t) > 1:
                from scipy.signal import lfilter  # on first use: keeps start-up fast

                settle[1:] = lfilter([1.0], [1.0, -a], steps[1:], axis=0, zi=(a * x0)[None])[0]
            self._settle, self._t_settle = settle[-1].copy(), float(t[-1])
        self._dir, self._f = d[-1].copy(), f[-1].copy()
        return self._sample(t, self.model.response_g(f, self.temperature_c), settle), t


class SimulatedDriver(Driver):
    """The driver of a SimulatedBoard: the same interface as the hardware drivers."""

    name = "simulated"
    board: SimulatedBoard

    def __init__(self, board: SimulatedBoard) -> None:
        self.board = board
        self._open = False

    def open(self) -> None:
        self._open = True

    def close(self) -> None:
        self._open = False

    def _check_open(self) -> None:
        if not self._open:
            raise DeviceError("simulated device is not open (use it as a context manager)")

    def identify(self) -> Identity:
        self._check_open()
        return self.board.identity

    def configure(self, range_g: int | None = None, odr_hz: float | None = None, **options: Any) -> None:
        self._check_open()
        unknown = set(options) - {"dlpf"}
        if unknown:
            raise ConfigError(f"configure: unknown option {sorted(unknown)[0]!r}; allowed: dlpf")
        b = self.board
        b.configure(b.range_g if range_g is None else range_g, b.odr_hz if odr_hz is None else odr_hz,
                    options.get("dlpf", b.dlpf))

    @property
    def range_g(self) -> int:
        return self.board.range_g

    @property
    def odr_hz(self) -> float:
        return self.board.odr_hz

    @property
    def counts_per_g(self) -> float:
        return self.board.counts_per_g

    def read_samples(self, n: int) -> tuple[np.ndarray, np.ndarray, int]:
        self._check_open()
        counts, t = self.board.read(n)
        return counts, t, 0

    def temperature_c(self) -> float | None:
        return self.board.temperature_c if self.board.chip.has_temperature else None

    def noise_lag1(self) -> float:
        return float(self.board.noise_lag1)

    @property
    def nvm(self) -> EEPROM24:
        return self.board.eeprom


def sim_eeprom(e: SimEepromSection, ep: str) -> EEPROM24:
    """A simulated board's EEPROM from its section (its size a whole number of pages, its image file
    a regular file in an existing folder)."""
    if e.size_bytes % e.page_bytes:
        raise ConfigError(f"{ep}.size_bytes: {e.size_bytes} must be a multiple of page_bytes ({e.page_bytes})")
    if e.image is not None and not e.image.strip():
        raise ConfigError(f"{ep}.image: {e.image!r}; allowed: a file path (relative: the current directory)")
    if e.image is not None:
        _check_image_path(e.image, f"{ep}.image")
    return EEPROM24(e.size_bytes, e.page_bytes, e.write_cycle_ms / 1000.0, fail_at_write=e.fail_at_write,
                    image_path=e.image)


def _check_image_path(image: str, where: str) -> None:
    """Up front, not at burn time: the image's folder exists and the image is a regular file."""
    from ..atomic import check_target

    p = Path(image)
    if not p.parent.is_dir():
        raise ConfigError(f"{where}: {image}: folder {p.parent} does not exist; allowed: a file in an existing folder")
    try:
        check_target(p)
    except OSError as e:
        raise ConfigError(f"{where}: {image} {e.strerror}") from None
