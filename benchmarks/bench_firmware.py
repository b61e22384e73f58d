"""The bridge firmware on the simulated ATmega328P (simavr): stream rate and RAM, measured in one run.

For each sample rate 1000 / (1 + SMPLRT_DIV) Hz, streams N samples at 115200 baud and checks
the firmware's own timestamps (micros(), 4 us steps) and the SAMPLE index, which counts the
chip's samples: the stream is drop-free when no index is missing, no gap between stamps reaches
1.5 sample periods and the delivered rate is the requested one within 0.1 %.  A SAMPLE frame is
24 bytes = 240 bit times = 2.083 ms at 115200 baud, so the link bounds the rate at 480 Hz; the
driver refuses the rates above it (shown as refused).  Then prints flash/RAM use (avr-size) and
the free RAM at the deepest stack (stack painting and the lowest stack pointer, read back by the
harness).

    python benchmarks/bench_firmware.py [--n 200]
"""
from __future__ import annotations

import argparse
import subprocess
import sys

import numpy as np

from accelcal_station.drivers.mpu6050 import MPU6050Bridge
from accelcal_station.drivers.mpu6050_simavr import ELF, SimavrBridge, unavailable_reason
from accelcal_station.errors import ConfigError

RATES_HZ = [1000.0 / (1 + k) for k in range(6)]
FRAME_BITS = (2 + 8 + 12 + 2) * 10  # SAMPLE frame: sync, header, index + 8 data bytes, CRC; 10 bits a byte


def stream_rates(dev: MPU6050Bridge, n: int) -> list[tuple[float, float, float, bool]]:
    rows = []
    for rate in RATES_HZ:
        try:
            dev.configure(odr_hz=rate, dlpf=1)
        except ConfigError:  # beyond what the link carries: refused before streaming
            rows.append((rate, float("nan"), float("nan"), False))
            continue
        cap = dev.capture(n, keep=True)
        dt = np.diff(cap.timestamps)
        got = len(dt) / (cap.timestamps[-1] - cap.timestamps[0])
        ok = bool(cap.dropped == 0 and dt.max() < 1.5 / rate and abs(got / rate - 1) < 1e-3)
        rows.append((rate, got, float(dt.max() * 1e3), ok))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="samples per rate")
    a = ap.parse_args(argv)
    why = unavailable_reason()
    if why:
        print(f"skipped: {why}")
        return 0
    with SimavrBridge(seed=1) as b:
        with MPU6050Bridge(b.port, timeout_s=1.0, retries=2, boot_wait_s=3.0) as dev:
            rows = stream_rates(dev, a.n)
            # every other path once, so the deepest stack covers them: registers, NVM, RESET
            dev.read_register(0x3B, 16)
            dev.write_register(0x06, bytes(6))
            dev.nvm.write(0, bytes(range(64)))
            dev.reset()
        s = b.stats()
    print(f"{'requested_hz':>12}  {'delivered_hz':>12}  {'max_gap_ms':>10}  {'drop_free':>9}")
    print(f"{'-' * 12}  {'-' * 12}  {'-' * 10}  {'-' * 9}")
    for rate, got, gap, ok in rows:
        row = f"{'refused':>12}" if np.isnan(got) else f"{got:12.1f}  {gap:10.3f}  {str(ok):>9}"
        print(f"{rate:12.1f}  {row}")
    best = max((r for r, _, _, ok in rows if ok), default=0.0)
    print(f"\nhighest drop-free rate at 115200 baud: {best:.1f} Hz "
          f"(link bound {115200 / FRAME_BITS:.0f} Hz; ratio {best / (115200 / FRAME_BITS):.2f})")
    size = subprocess.run(["avr-size", "--mcu=atmega328p", "-C", str(ELF)], capture_output=True, text=True).stdout
    print("\n".join(ln for ln in size.splitlines() if ln.startswith(("Program", "Data"))))
    print(f"free RAM at deepest stack: {s['free_ram_min']} bytes by stack painting, {s['min_sp_free']} by lowest SP "
          f"(static {s['static_ram']} bytes, stack {2048 - s['static_ram'] - s['free_ram_min']} bytes; "
          f"simulated {s['sim_us'] / 1e6:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
