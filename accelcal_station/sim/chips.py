"""The accelerometer chips' data-sheet figures (ChipSpec) the simulator and its checks use:
ranges, sensitivity, noise density, output data rates, the MPU6050's DLPF bandwidths and delays,
the MMA8451's oversampling ratios (sensor_model.py stage 7 uses them)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

# -- chips ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ChipSpec:
    """Datasheet figures of a real accelerometer chip.

    ``odr_hz``: the discrete output data rates (MMA8451 CTRL_REG1 DR bits); None
    means ``odr_base_hz / (1 + divider)`` for divider 0..255 (MPU6050 SMPLRT_DIV;
    ``odr_base_dlpf0_hz`` with DLPF_CFG 0), at most ``odr_max_hz``.
    ``dlpf_hz``: accelerometer bandwidth per DLPF_CFG setting (MPU6050), or None.
    """

    name: str
    chip_id: int  # WHO_AM_I
    bits: int
    ranges_g: tuple[int, ...]
    counts_per_g_at_2g: float
    noise_ug_per_rthz: float
    has_temperature: bool
    odr_hz: tuple[float, ...] | None = None
    odr_base_hz: float | None = None
    odr_base_dlpf0_hz: float | None = None
    odr_max_hz: float = 1000.0
    dlpf_hz: tuple[float, ...] | None = None
    dlpf_delay_ms: tuple[float, ...] | None = None
    # MMA8451 CTRL_REG2 MODS: oversampling ratio per mode at each odr_hz (same order)
    oversampling: dict[str, tuple[int, ...]] | None = None
    default_range_g: int = 2
    default_odr_hz: float = 100.0
    default_dlpf: int | None = None

    def counts_per_g(self, range_g: int) -> float:
        """Nominal sensitivity: the full code range spans +-range_g."""
        return self.counts_per_g_at_2g * 2.0 / range_g

    @property
    def code_limits(self) -> tuple[int, int]:
        """Smallest and largest output code (two's complement, ``bits`` wide)."""
        return -(2 ** (self.bits - 1)), 2 ** (self.bits - 1) - 1

    def check(self, range_g: int, odr_hz: float, dlpf: int | None, path: str) -> tuple[int, float, int | None]:
        """Validate a configuration against the datasheet; ConfigError names the key."""
        if range_g not in self.ranges_g:
            raise ConfigError(f"{path}.range_g: {range_g!r}; allowed for {self.name}: "
                              f"{', '.join(map(str, self.ranges_g))}")
        if isinstance(odr_hz, bool) or not isinstance(odr_hz, (int, float)) or not np.isfinite(odr_hz):
            raise ConfigError(f"{path}.odr_hz: {odr_hz!r} is not a number")
        if self.dlpf_hz is None:
            if dlpf is not None:
                raise ConfigError(f"{path}.dlpf: {dlpf!r}; {self.name} has no digital low-pass filter; "
                                  "allowed: none (leave it out)")
        else:
            dlpf = self.default_dlpf if dlpf is None else dlpf
            if isinstance(dlpf, bool) or dlpf not in range(len(self.dlpf_hz)):
                raise ConfigError(f"{path}.dlpf: {dlpf!r}; allowed for {self.name}: 0..{len(self.dlpf_hz) - 1} "
                                  f"({', '.join(f'{b:g}' for b in self.dlpf_hz)} Hz)")
        if self.odr_hz is not None:
            ok = [r for r in self.odr_hz if abs(r - odr_hz) <= 1e-6 * r]
            if not ok:
                raise ConfigError(f"{path}.odr_hz: {odr_hz:g}; allowed for {self.name}: "
                                  f"{', '.join(f'{r:g}' for r in self.odr_hz)}")
            odr_hz = ok[0]
        else:
            # MPU6050: SMPLRT_DIV divides 8 kHz with DLPF_CFG 0, else 1 kHz; accelerometer data is 1 kHz at most
            base = self.odr_base_dlpf0_hz if dlpf == 0 and self.odr_base_dlpf0_hz else self.odr_base_hz
            assert base is not None, f"{self.name}: a ChipSpec gives odr_hz or odr_base_hz"
            div = base / odr_hz - 1.0 if odr_hz > 0 else -1.0
            if not (0 <= round(div) <= 255 and abs(div - round(div)) < 1e-6 and odr_hz <= self.odr_max_hz):
                raise ConfigError(f"{path}.odr_hz: {odr_hz:g}; allowed for {self.name} with dlpf {dlpf}: "
                                  f"{base:g} / (1 + divider), divider 0..255, at most {self.odr_max_hz:g} "
                                  "(e.g. 1000, 500, 200, 100, 50)")
        return int(range_g), float(odr_hz), dlpf

    def enbw_hz(self, odr_hz: float, dlpf: int | None = None) -> float:
        """Equivalent noise bandwidth of one output sample, Hz: Nyquist (ODR / 2) without a DLPF;
        with the MPU6050's DLPF the one-pole filter's (pi / 2) f_c, f_c the data sheet's DLPF_CFG
        bandwidth (integral of |H(f)|^2 = 1 / (1 + (f / f_c)^2) over f >= 0).  The filter runs
        ahead of the output-rate decimation, so the ODR does not narrow it: a sample below
        2 f_c carries the filter's whole noise (aliased), not Nyquist's."""
        if self.dlpf_hz is not None and dlpf is not None:
            return float(np.pi / 2.0 * self.dlpf_hz[dlpf])
        return odr_hz / 2.0

    def noise_lag1(self, odr_hz: float, dlpf: int | None = None) -> float:
        """Lag-1 autocorrelation of the output noise: a one-pole low-pass of bandwidth f_c sampled
        every 1/ODR has rho_1 = exp(-2 pi f_c / ODR) (the DLPF); 0 without a DLPF."""
        if self.dlpf_hz is None or dlpf is None:
            return 0.0
        return float(np.exp(-2.0 * np.pi * self.dlpf_hz[dlpf] / odr_hz))

    def delay_s(self, dlpf: int | None = None) -> float:
        """The DLPF's signal delay (MPU-6000/6050 register map, CONFIG table), s; 0 without one."""
        if self.dlpf_delay_ms is None or dlpf is None:
            return 0.0
        return 1e-3 * self.dlpf_delay_ms[dlpf]

    def noise_scale(self, odr_hz: float, mode: str | None) -> float:
        """Noise density relative to normal mode at this ODR: sqrt(OSR_normal / OSR_mode)
        (averaging OSR conversions divides the noise variance by OSR); 1 without modes."""
        if self.oversampling is None or mode is None or self.odr_hz is None:
            return 1.0
        if mode not in self.oversampling:
            raise ConfigError(f"oversampling: {mode!r}; allowed: {', '.join(self.oversampling)}")
        i = int(np.argmin([abs(r - odr_hz) for r in self.odr_hz]))
        return float(np.sqrt(self.oversampling["normal"][i] / self.oversampling[mode][i]))


CHIPS: dict[str, ChipSpec] = {
    # MMA8451Q datasheet: 14-bit, 4096 counts/g at 2 g, 99 ug/sqrt(Hz), no temperature sensor
    "mma8451": ChipSpec("mma8451", 0x1A, 14, (2, 4, 8), 4096.0, 99.0, False,
                        odr_hz=(800.0, 400.0, 200.0, 100.0, 50.0, 12.5, 6.25, 1.5625),
                        # data sheet, CTRL_REG2 MODS oversampling ratios per ODR (800 .. 1.56 Hz)
                        oversampling={"normal": (2, 4, 4, 4, 4, 4, 4, 4),
                                      "low_noise_low_power": (2, 4, 4, 4, 4, 4, 4, 4),
                                      "high_resolution": (2, 4, 8, 16, 32, 128, 256, 1024),
                                      "low_power": (2, 4, 2, 2, 2, 2, 2, 2)},
                        default_odr_hz=100.0),
    # MPU-6050 datasheet: 16-bit, 16384 LSB/g at 2 g, 400 ug/sqrt(Hz), DLPF_CFG 0..6
    "mpu6050": ChipSpec("mpu6050", 0x68, 16, (2, 4, 8, 16), 16384.0, 400.0, True,
                        odr_base_hz=1000.0, odr_base_dlpf0_hz=8000.0,
                        dlpf_hz=(260.0, 184.0, 94.0, 44.0, 21.0, 10.0, 5.0),
                        dlpf_delay_ms=(0.0, 2.0, 3.0, 4.9, 8.5, 13.8, 19.0),
                        default_odr_hz=100.0, default_dlpf=3),
}


def get_chip(name: str, path: str = "chip") -> ChipSpec:
    if name not in CHIPS:
        raise ConfigError(f"{path}: {name!r}; allowed: {', '.join(CHIPS)}")
    return CHIPS[name]
