"""`accelcal poses NAME`: show a pose design and the standard errors it would give."""
from __future__ import annotations

import json
import math

import click
import numpy as np

from ..calibration import MODELS
from ..conventions import up_direction
from ..errors import DataError
from ..fixtures.designs import describe, design_model, get_design, min_separation, predict_stderr, references
from ..fixtures.operator_jig import pose_words
from ._common import Finite

# Display scale and unit per parameter family: gains and cubic terms are dimensionless
# (shown in 1e-3), offsets are in g (shown in mg).
_SCALE = {"W": (1e3, "1e-3"), "M": (1e3, "1e-3"), "Gamma": (1e3, "1e-3"), "V": (1e3, "mg"), "B": (1e3, "mg")}


def _clean(v: np.ndarray) -> list[float]:
    """Round away cos(90 deg) ~ 6e-17 so faces print as 0, not -0.0000."""
    return (np.round(np.asarray(v, dtype=float), 12) + 0.0).tolist()


@click.command("poses")
@click.argument("name")
@click.option("--model", type=click.Choice(MODELS), default=None,
              help="Model to predict for (default: the one the design was drawn up for).")
@click.option("--noise-mg", type=Finite(-math.inf, math.inf), default=1.0, show_default=True,
              help="Per-axis standard error of each pose's averaged reading, in mg.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def command(name: str, model: str | None, noise_mg: float, as_json: bool) -> None:
    """Show pose design NAME (AN4399 pitch/roll, where the board goes) and its predicted standard errors.

    Each pose's expected output (AN4399 Eqn 22) points up: a chip reads +1 g on the axis
    pointing away from the Earth (docs/conventions.md); --json gives it as ``up`` with ``words``.

    NAME: an4399-2, an4399-3, an4399-4, an4399-6, an4399-8, six-face, nine-position,
    or optimal-N.  Standard errors scale linearly with --noise-mg.
    """
    poses = get_design(name)
    if not np.isfinite(noise_mg) or noise_mg <= 0 or noise_mg > 1e6:  # click's float lets nan and inf through
        raise DataError(f"--noise-mg {noise_mg:g}: must be a positive number of mg, at most 1e+06")
    model = model or design_model(name)
    pred = predict_stderr(name, model, noise_mg * 1e-3)
    ref = references(poses)
    sep = min_separation(poses)
    description = describe(name)
    if as_json:
        click.echo(json.dumps({
            "design": name, "description": description, "convention": "AN4399 pitch/roll (Eqn 22) give "
            "expected_g; the board is placed with expected_g pointing up (a chip reads +1 g on the axis "
            "pointing away from the Earth): up is that board-frame unit vector (docs/conventions.md)",
            "poses": [{"name": p.name, "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg, "expected_g": _clean(r),
                       "up": _clean(up_direction(r)), "words": pose_words(p).split(" (")[0]}
                      for p, r in zip(poses, ref, strict=True)],
            "min_separation_g": sep, "model": model, "noise_g": pred["noise_g"],
            "stderr": {"param_names": pred["param_names"], "params": pred["params"].tolist(),
                       "W": pred["W"].tolist(), "V_g": pred["V"].tolist(), "Gamma": pred["Gamma"].tolist()},
            "condition_number": pred["condition_number"],
        }))
        return
    click.echo(f"design {name}: {description}")
    click.echo("pose        pitch_deg  roll_deg     x_g      y_g      z_g   (expected output, AN4399 Eqn 22)  "
               "placement (that direction up)")
    for p, r in zip(poses, [_clean(row) for row in np.round(ref, 4)], strict=True):
        click.echo(f"{p.name:<10} {p.pitch_deg:10.2f} {p.roll_deg:9.2f}  {r[0]:+.4f}  {r[1]:+.4f}  {r[2]:+.4f}  "
                   f"{pose_words(p).split(' (')[0]}")
    click.echo(f"minimum channel separation: {sep:.4f} g (AN4399 section 5)")
    click.echo(f"predicted standard errors, model {model}, noise {noise_mg:g} mg per axis on each pose mean:")
    for pname, se in zip(pred["param_names"], pred["params"], strict=True):
        scale, unit = _SCALE[pname.split("_")[0]]
        click.echo(f"  {pname:<9} {se * scale:9.4f} {unit}")
    click.echo(f"condition number: {pred['condition_number']:.3g}")
