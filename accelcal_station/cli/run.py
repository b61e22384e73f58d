"""`accelcal run`: calibrate one board end to end."""
from __future__ import annotations

import json

import click

from ..station import Station, StationConfig
from ._common import jsonable


@click.command("run")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Station config YAML (default: the simulated station, configs/sim.yaml).")
@click.option("--serial", default=None, help="Board serial number (default: the device's own).")
@click.option("--operator", default=None, help="Operator name, recorded with the run.")
@click.option("--lot", default=None, help="Production lot, recorded with the run.")
@click.option("--store", "store_file", type=click.Path(dir_okay=False), default=None,
              help="Results store file (default: the config's store.path).")
@click.option("--port", default=None, help="Override the device's serial port (or the MMA8451's I2C bus).")
@click.option("--jig-port", default=None, help="Override the motorized jig's serial port.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (human lines go to stderr).")
def command(config_path, serial, operator, lot, store_file, port, jig_port, as_json):
    """Calibrate one board: identify, present each pose, capture, fit, judge, write NVM, verify, record.

    Exit status: 0 PASS, 1 FAIL, 2 bad input or configuration, 3 device error,
    4 NVM error, 5 operator abort.
    """
    cfg = StationConfig.load(config_path, store_file, port, jig_port)

    def echo(text: str) -> None:
        click.echo(text, err=as_json)

    echo(f"station {cfg.station_id}: design {cfg.design}, model {cfg.model}, config {cfg.path}")
    if "thermal" in cfg.raw or "chamber" in cfg.raw:  # ThermalStation refuses one without the other
        from ..thermal import ThermalStation

        rep = ThermalStation(cfg, operator=operator, serial=serial, lot=lot, echo=echo).run()
    else:
        rep = Station(cfg, operator=operator, serial=serial, lot=lot, echo=echo).run()
    if as_json:
        click.echo(json.dumps(jsonable(rep.to_dict()), indent=2, allow_nan=False))
    else:
        t = rep.timing
        f = rep.fit
        if f is not None:
            click.echo(f"fit: model {rep.model}, {f.pose_count} poses, residual RMS {f.residual_rms_g * 1e3:.3f} mg"
                       + ("" if f.crossval_rms_g is None else f", cross-validated {f.crossval_rms_g * 1e3:.3f} mg"))
        table = (getattr(rep, "thermal", None) or {}).get("table")
        if table:
            click.echo(f"table: {len(table['temps_c'])} temperatures ("
                       + ", ".join(f"{t:.1f}" for t in table["temps_c"]) + f" C), {table['method']}; "
                       f"the fit above is the one at the temperature nearest {cfg.raw['thermal'].get('reference_c', 25)} C")
        if rep.verify_error_max_mg is not None:
            click.echo(f"verify: max error {rep.verify_error_max_mg:.3f} mg after calibration")
        colour = "green" if rep.verdict == "PASS" else "red"
        click.secho(f"{rep.verdict} board {rep.serial} (run {rep.run_id}, store {rep.store})", fg=colour, bold=True)
        for r in rep.reasons:
            click.secho(f"  - {r}", fg=colour)
        if t and "soak_s" in t:
            click.echo(f"time per board: soak {t['soak_s']:.0f} s, sampling floor {t['sampling_floor_s']:.1f} s, "
                       f"rest {t['rest_s']:.1f} s of {t['board_time_s']:.0f} s ({t['clock']} clock)")
        elif t and "board_time_s" in t:
            click.echo(f"time: sampling floor {t['sampling_floor_s']:.1f} s of {t['board_time_s']:.1f} s "
                       f"board time at {t['odr_hz']:g} Hz (simulated clock); host compute {t['host_compute_s']:.2f} s")
        elif t:
            click.echo(f"time: sampling floor {t['sampling_floor_s']:.1f} s at {t['odr_hz']:g} Hz; "
                       f"wall time {t['host_compute_s']:.1f} s")
    if rep.verdict != "PASS":
        raise click.exceptions.Exit(1)
