"""`accelcal fit`: fit a calibration model to a pose table or a raw sample log."""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, NotRequired, TypeAlias, TypedDict

import click
import numpy as np
from numpy.typing import ArrayLike

from ..api import Fit, check_temp_method, fit, hand_placed_fit
from ..calibration import CalibrationDict
from ..config.site import SiteJson
from ..data.loader import Loaded, load
from ..data.rawlog import RawLog
from ..data.static_poses import StaticDetection
from ..errors import AccelcalError, DataError
from ..identifiability import assess, worst_parameter
from ..models.choice import ModelChoice, ModelChoiceJson, choose_model, with_face_references
from ..models.handplaced import norm_faces, opposite_face
from ..models.result import FitCore, FitJson, FitResult, PoseRow
from ..session import Session
from ._common import check_model_units, force_option, parse_int
from ._common import jsonable as _clean
from ._common import parse_number as _number
from ._outputs import refuse_output
from ._text import clean


class FaceFitJson(TypedDict):
    """A hand-placed fit's gain and offset per axis (and, for the norm fit, each pose's misplacement)."""

    gain: np.ndarray
    offset_g: np.ndarray


class NormFitJson(FaceFitJson):
    misplacement_deg: np.ndarray | None


class HandPlacedJson(TypedDict):
    """``hand_placed`` of fit --json: both fits and their held-out norm errors (None: a face seen once)."""

    opposite_face: FaceFitJson
    norm: NormFitJson
    held_out_norm_rms_g: dict[str, float] | None
    distinct_orientations: int
    note: str


class SegmentJson(TypedDict):
    """A static interval found in a raw log: its samples, times and mean and spread per axis."""

    pose: str
    start: int
    stop: int
    n: int
    ranges: list[list[int]]
    t_start: float
    t_end: float
    mean: np.ndarray
    std: np.ndarray


class SegmentationJson(TypedDict):
    """``segmentation`` of fit --raw --json: the log and the static intervals found in it."""

    samples: int
    rate_hz: float | None
    columns: list[str]
    window_samples: int
    noise_sigma: np.ndarray
    threshold: np.ndarray
    min_samples: int
    count: int
    segments: list[SegmentJson]


class TemperatureFitJson(FitJson):
    """One temperature's fit in a table fit's ``temperatures``."""

    temp_c: float | None


class FaceJson(TypedDict):
    """A hand-placed pose and the face it was taken as."""

    pose: str
    face: str
    angle_deg: float


class TableFitJson(FitCore):
    """A fit at several temperatures (one table, AN4399 section 9): the fits' figures pooled, the
    table's calibration and each temperature's own fit."""

    temperature_method: str | None
    calibration: CalibrationDict
    temperatures: list[TemperatureFitJson]


class ReadJson(TypedDict):
    """What reading the file inferred (and, for a raw log, the static intervals found in it)."""

    inferred: dict  # data/loader.Loaded.to_json's own mapping (untyped there)
    segmentation: NotRequired[SegmentationJson]


class SourceJson(TypedDict):
    """The file fitted and the units its readings were in."""

    source: str
    units: str
    site: SiteJson | None  # the site's gravity the references were scaled to (config/site.py Site.to_json)


class OptionsJson(TypedDict, total=False):
    """What the options add: the model chosen (no --model), --hand-placed, -o."""

    model_choice: ModelChoiceJson
    faces: list[FaceJson]
    hand_placed: HandPlacedJson
    output: str


class OneFitReport(ReadJson, FitJson, SourceJson, OptionsJson):
    """fit --json at one temperature.  Made JSON-safe by ``jsonable``."""


class TableFitReport(ReadJson, TableFitJson, SourceJson, OptionsJson):
    """fit --json at several temperatures.  Made JSON-safe by ``jsonable``."""


FitReport: TypeAlias = OneFitReport | TableFitReport  # fit --json


def _load(path: str, raw: bool, model: str | None, units: str | None, cpg: float | None, gravity: float | None,
          columns: str | None, skip_rows: int | None, rate: float | None) -> Loaded:
    if rate is not None and not raw:
        raise DataError(f"--rate is for raw sample logs; add --raw to read {path} as one")
    loaded = load(path, raw, units=units, counts_per_g=cpg, gravity_mps2=gravity, columns=columns,
                  skip_rows=skip_rows, rate_hz=rate, references=model is not None and model != "9")
    have = [p.reference_g is not None for p in loaded.session.poses]
    if model is None and any(have) and not all(have):  # some rows give references: the reader names the row
        load(path, raw, units=units, counts_per_g=cpg, gravity_mps2=gravity, references=True)
    return loaded


def _vec(v: ArrayLike, fmt: str = "+.6f") -> str:
    return "[" + " ".join(f"{x:{fmt}}" for x in np.asarray(v, dtype=float)) + "]"


def _scale_text(session: Session, fit: FitResult) -> str:
    u = session.units
    if u == "counts" and session.counts_per_g is None:
        return (f"counts, 1 g = {fit.calibration.input_per_g:.6g} counts estimated from the data "
                "(no counts_per_g or --units given)")
    if u == "counts":
        return f"counts at {fit.calibration.input_per_g:.6g} counts/g (given)"
    if u == "mps2":
        return f"m/s^2 at {fit.calibration.input_per_g:.6g} m/s^2 per g"
    return "g"


def _fit_text(fit: FitResult, names: list[str]) -> list[str]:
    out = [f"W     = {_vec(fit.W[0])}"] + [f"        {_vec(r)}" for r in fit.W[1:]]
    out += [f"V     = {_vec(fit.V)} g", f"Gamma = {_vec(fit.Gamma)}",
            f"residual RMS {fit.residual_rms_g * 1e3:.3f} mg, max {fit.residual_max_g * 1e3:.3f} mg; "
            f"{_crossval_text(fit)}; condition number {fit.condition_number:.3g}"]
    if fit.message:
        out.append(f"note: {fit.message}")
    out += [f"held: {h.text}" for h in fit.held]
    out += [f"freed: {h.reason}" for h in fit.freed]
    out += _barely_text(fit) if not fit.held else []
    w = max(4, *(len(n) for n in names))
    out.append(f"{'pose':<{w}}  {'x_g':>9} {'y_g':>9} {'z_g':>9}  {'res_x_mg':>9} {'res_y_mg':>9} "
               f"{'res_z_mg':>9}  {'norm_err_mg':>11}")
    for n, g, r, e in zip(names, fit.readings_g, fit.residuals_g * 1e3, fit.norm_error_g * 1e3, strict=True):
        out.append(f"{n:<{w}}  {g[0]:+9.5f} {g[1]:+9.5f} {g[2]:+9.5f}  {r[0]:+9.3f} {r[1]:+9.3f} {r[2]:+9.3f}  "
                   f"{e:+11.3f}")
    return out


def _crossval_text(fit: FitResult) -> str:
    """Both held-out figures, and which one acceptance judges (models/crossval.py)."""
    def mg(v: float | None, what: str) -> str:
        return f"n/a (a left-out {what} leaves the model undetermined)" if v is None else f"{v * 1e3:.3f} mg"

    loo = f"leave-one-pose-out RMS {mg(fit.crossval_rms_g, 'pose')}"
    if not fit.orientations_repeat:
        return loo + " (no orientation revisited: acceptance judges this)"
    return (f"{loo}; leave-one-orientation-out RMS {mg(fit.crossval_by_orientation_rms_g, 'orientation')} "
            f"({fit.distinct_orientations} distinct orientations among {fit.pose_count} poses: "
            "acceptance judges by orientation)")


def _barely_text(fit: FitResult) -> list[str]:
    """A barely determined fit, flagged with its degrees of freedom and least certain parameter."""
    ident = assess(fit.readings_g, fit.model)
    if not ident.barely:
        return []
    per = " per channel" if fit.model != "9" else ""
    worst = worst_parameter(fit.stderr, fit.model)
    se = (f"; least certain: {worst[0]} +- {worst[1]} (1 sigma)" if worst
          else "; standard errors unknown (no per-pose noise and no spare orientation)")
    return [f"warning: barely determined: {ident.distinct} distinct orientations for {ident.coefficients} "
            f"coefficients{per} ({ident.dof} degree{'s' if ident.dof != 1 else ''} of freedom){se}; "
            "add poses in new orientations"]


def _hand_placed(session: Session, fr: FitResult) -> tuple[HandPlacedJson, list[str]]:
    """The norm fit of hand-placed faces against the opposite-face estimate (handplaced module)."""
    x, ref = fr.readings_g, session.references_g
    if ref is None:  # model 6 was fitted, so references exist; say so plainly if that ever changes
        raise DataError("--hand-placed needs the faces' references (an 'axis up' pose table)")
    try:
        norm, classic = norm_faces(x, ref), opposite_face(x, ref)
    except AccelcalError as e:
        raise type(e)(f"--hand-placed: {e}") from None
    ax = np.argmax(np.abs(ref), axis=1)
    sign = np.sign(ref[np.arange(len(ref)), ax])
    once = [f"{'+-'[s < 0]}{'xyz'[a]}" for a in range(3) for s in (1, -1) if np.sum((ax == a) & (sign == s)) < 2]
    held = None
    if not once:  # every face seen twice or more: each pose can be left out of both fits
        held = {m: float(np.sqrt(np.mean([f(np.delete(x, i, 0), np.delete(ref, i, 0)).norm_error_g(x[i:i + 1])[0]
                                          ** 2 for i in range(len(x))])))
                for m, f in (("norm", norm_faces), ("opposite_face", opposite_face))}
    tilt = norm.misplacement_deg if norm.misplacement_deg is not None else np.full(len(x), np.nan)  # norm fit: always
    lines = [f"hand-placed faces: {len(x)} poses, {norm.distinct} distinct orientations",
             f"  opposite-face: gain {_vec(classic.gain)}  offset {_vec(classic.offset_g * 1e3, '+.3f')} mg",
             f"  norm fit:      gain {_vec(norm.gain)}  offset {_vec(norm.offset_g * 1e3, '+.3f')} mg",
             "  held-out norm error RMS (each pose left out of both fits): " +
             (f"norm fit {held['norm'] * 1e3:.3f} mg, opposite-face {held['opposite_face'] * 1e3:.3f} mg" if held
              else f"cannot hold poses out: face{'s' if len(once) > 1 else ''} {', '.join(once)} "
                   f"{'have' if len(once) > 1 else 'has'} one pose (revisit every face to check the fits)"),
             "  misplacement (deg): " + ", ".join(f"{n} {m:.2f}" for n, m in zip(session.names, tilt, strict=True)),
             f"  note: {norm.note}"]
    js: HandPlacedJson = {"opposite_face": {"gain": classic.gain, "offset_g": classic.offset_g},
          "norm": {"gain": norm.gain, "offset_g": norm.offset_g, "misplacement_deg": norm.misplacement_deg},
          "held_out_norm_rms_g": held, "distinct_orientations": norm.distinct, "note": norm.note}
    return js, lines


def _segmentation(log: RawLog, det: StaticDetection, names: list[str]) -> tuple[SegmentationJson, list[str]]:
    rate = f"{log.rate_hz:.6g} Hz" if log.rate_hz else "unknown rate (give --rate HZ for times in seconds)"
    lines = [f"raw log {log.source}: {len(log)} samples at {rate}; noise floor sigma {_vec(det.noise_sigma, '.4g')} "
             f"per sample; found {len(det.segments)} static intervals of {det.min_samples}+ samples "
             f"({int(det.still.sum())} samples used):"]
    segs: list[SegmentJson] = []
    for n, s in zip(names, det.segments, strict=True):
        parts = ", ".join(f"{a}-{b - 1}" for a, b in s.ranges)
        span = f", t {log.t[s.start]:.2f}-{log.t[s.stop - 1]:.2f} s" if log.rate_hz else ""
        lines.append(f"  {n}: samples {parts} ({s.n} used{span})")
        segs.append({"pose": n, "start": s.start, "stop": s.stop, "n": s.n, "ranges": [list(r) for r in s.ranges],
                     "t_start": float(log.t[s.start]), "t_end": float(log.t[s.stop - 1]),
                     "mean": s.mean, "std": s.std})
    info: SegmentationJson = {
        "samples": len(log), "rate_hz": log.rate_hz, "columns": log.columns, "window_samples": det.window,
        "noise_sigma": det.noise_sigma, "threshold": det.threshold, "min_samples": det.min_samples,
        "count": len(det.segments), "segments": segs}
    return info, lines


def _table_report(path: str, session: Session, result: Fit) -> tuple[TableFitJson, list[str]]:
    """The JSON and lines of a fit at several temperatures (one table, AN4399 section 9)."""
    fits, subs, cal, model = result.fits, result.sessions, result.calibration, result.model
    allres = np.concatenate([f.residuals_g for _, f in fits])
    cvs = [f.crossval_rms_g for _, f in fits]
    known = [c for c in cvs if c is not None]
    report: TableFitJson = {
        "model": model, "pose_count": len(session), "W": cal.W.tolist(), "V": cal.V.tolist(),
        "Gamma": cal.Gamma.tolist(), "P": np.sum([f.P for _, f in fits], axis=0).tolist(),
        "residual_rms_g": float(np.sqrt(np.mean(allres**2))), "residual_max_g": float(np.max(np.abs(allres))),
        "crossval_rms_g": None if len(known) < len(cvs) else float(np.sqrt(np.mean(np.square(known)))),
        "temperature_method": result.temp_method, "calibration": cal.to_dict(),
        "temperatures": [{"temp_c": t, **f.to_json_dict(s.names)} for (t, f), s in zip(fits, subs, strict=True)],
        "poses": [PoseRow(temp_c=t, **p) for (t, f), s in zip(fits, subs, strict=True) for p in f.pose_rows(s.names)],
    }
    text = [f"{path}: model {model}, {len(session)} poses at {len(fits)} temperatures "
            f"({', '.join(f'{t:g}' for t, _ in fits)} C), {result.temp_method} interpolation, "
            f"{_scale_text(session, fits[0][1])}"]
    for (t, f), s in zip(fits, subs, strict=True):
        text.append(f"-- at {t:g} C: {len(s)} poses")
        text += _fit_text(f, s.names)
    return report, text


def _echo_lines(text: list[str]) -> None:
    """Print the lines a block at a time (a 100,000-pose table is never one string); pose names come
    from the file: never raw escapes."""
    for i in range(0, len(text), 1000):
        click.echo("\n".join(clean(t) for t in text[i:i + 1000]))


def _report(path: str, loaded: Loaded, result: Fit) -> tuple[FitReport, list[str]]:
    """What `accelcal fit` prints: what reading the file inferred, its static intervals (raw logs), the fit.
    A single fit's per-pose JSON rows are a stand-in (_POSES) that _echo_json writes a block at a time
    (a 100,000-pose table: memory)."""
    session = loaded.session
    held = result.calibration.metadata.get("held")
    result.calibration.metadata = {"source": str(path), "pose_count": len(session), "device": session.device,
                                   "site": session.metadata.get("site")}
    if held:
        result.calibration.metadata["held"] = held
    read: ReadJson = {"inferred": loaded.to_json()}
    text = [f"read {path}: " + "; ".join(loaded.inferred)]
    if loaded.log is not None and loaded.detection is not None:
        read["segmentation"], seg_lines = _segmentation(loaded.log, loaded.detection, session.names)
        text += seg_lines
    source: SourceJson = {"source": str(path), "units": session.units, "site": session.metadata.get("site")}
    report: FitReport
    if len(result.fits) == 1:
        fr = result.result
        report = {**read, **fr.to_json_dict(session.names, poses=_POSES), **source}
        text.append(f"{path}: model {result.model}, {len(session)} poses, {_scale_text(session, fr)}")
        text += _fit_text(fr, session.names)
    else:
        table, lines = _table_report(path, session, result)
        report = {**read, **table, **source}
        text += lines
    return report, text


@click.command("fit")
@click.argument("path", metavar="FILE")
@click.option("--raw", is_flag=True, help="FILE is a raw sample log: find its static poses automatically.")
@click.option("--model", default=None, metavar="6|9|12|15",
              help="Parameters to fit (default: the richest model the poses determine: 15 or 12 with references; "
                   "without, the hand-placed faces' norm fit or 9).")
@click.option("--units", default=None, metavar="counts|g|mps2",
              help="Units of the readings (default: the table's '# units:' line, else counts).")
@click.option("--counts-per-g", "counts_per_g", default=None, metavar="N",
              help="Counts per g (needed for counts with models 6, 12, 15; model 9 estimates it).")
@click.option("--gravity", default=None, metavar="M_S2",
              help="The site's gravity in m/s^2 where the data were taken (default: the file's '# gravity_mps2:' "
                   "line, else standard 9.80665): references are scaled to it, the calibration maps to standard g.")
@click.option("--temp-method", default="linear", metavar="linear|quadratic",
              help="Interpolation between calibration temperatures (tables with temp_c at 2+ temperatures).")
@click.option("--columns", default=None, metavar="NAMES",
              help="Raw log columns, e.g. t,x,y,z or -,-,x,y,z (- ignores a column).")
@click.option("--skip-rows", default=None, metavar="N", help="Raw log: lines to skip at the top.")
@click.option("--rate", default=None, metavar="HZ", help="Raw log without a time column: sample rate in Hz.")
@click.option("--hand-placed", "hand_placed", is_flag=True,
              help="Six faces placed by hand ('axis up' references): fit gain and offset by the gravity norm, "
                   "estimate each pose's misplacement, compare with the opposite-face estimate on held-out poses; "
                   "-o writes the norm fit.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of the summary.")
@click.option("-o", "--output", default=None, metavar="FILE", help="Write the calibration JSON here (atomically).")
@force_option
def command(**opts: Any) -> None:
    """Fit a calibration to a pose table (CSV) or, with --raw, a raw sample log."""
    _fit_cmd(FitCommand.from_click(opts))


@dataclass(frozen=True)
class FitCommand:
    """`accelcal fit`'s options as typed: the numbers still as given (parsed with their option's name)."""

    path: str
    raw: bool
    model: str | None
    units: str | None
    counts_per_g: str | None
    gravity: str | None
    temp_method: str
    columns: str | None
    skip_rows: str | None
    rate: str | None
    hand_placed: bool
    as_json: bool
    output: str | None
    force: bool

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> FitCommand:
        return cls(path=o["path"], raw=o["raw"], model=o["model"], units=o["units"], counts_per_g=o["counts_per_g"],
                   gravity=o["gravity"], temp_method=o["temp_method"], columns=o["columns"], skip_rows=o["skip_rows"],
                   rate=o["rate"], hand_placed=o["hand_placed"], as_json=o["as_json"], output=o["output"],
                   force=o["force"])


def _fit_cmd(o: FitCommand) -> None:
    path, raw, model, units, output, hand_placed = o.path, o.raw, o.model, o.units, o.output, o.hand_placed
    temp_method, counts_per_g, gravity, force = o.temp_method, o.counts_per_g, o.gravity, o.force
    refuse_output([("-o", output, "json")], [("FILE", path)], force, has_config=False)
    model = "6" if model is None and hand_placed else model
    check_model_units(model or "12", units)  # no --model: the units still checked first
    check_temp_method(temp_method)
    cpg, grav = _number(counts_per_g, "--counts-per-g"), _number(gravity, "--gravity")
    loaded = _load(path, raw, model, units, cpg, grav, o.columns,
                   parse_int(o.skip_rows, "--skip-rows", positive=False), _number(o.rate, "--rate"))
    choice = None
    if model is None:
        loaded, choice = _choose(path, loaded)
        model, hand_placed = choice.model, choice.faces is not None
    result = fit(loaded, model, temp_method=temp_method, source=path)
    if hand_placed:
        if len(result.fits) != 1 or model != "6":
            raise DataError("--hand-placed fits model 6 at one temperature; give --model 6")
        hp = _hand_placed(loaded.session, result.result)
        result = hand_placed_fit(result, loaded.session)  # one calibration object: printed is saved
    report, text = _report(path, loaded, result)
    if choice is not None:
        report.update(_choice_json(choice, loaded.session.names))
    if hand_placed:
        report["hand_placed"], hp_lines = hp
        text += hp_lines
    if output:  # the very calibration printed above (one object from fit to file)
        result.calibration.save(output)
        report["output"] = str(output)
        text.append(f"calibration written to {output}")
    _print(report, text, result, loaded.session.names, o.as_json)


def _print(report: FitReport, text: list[str], result: Fit, names: list[str], as_json: bool) -> None:
    """The fit's report: one JSON line (--json), or its text lines."""
    if as_json:
        _echo_json(report, result.result if len(result.fits) == 1 else None, names)
    else:
        _echo_lines(text)


def _choice_json(choice: ModelChoice, names: list[str]) -> OptionsJson:
    """The model fit chose, and the face each pose was taken as (hand-placed faces)."""
    out: OptionsJson = {"model_choice": choice.to_json()}
    if choice.faces is not None:
        out["faces"] = [{"pose": n, "face": f, "angle_deg": float(a)} for n, f, a in
                        zip(names, choice.faces.names, choice.faces.angle_deg, strict=True)]
    return out


# stands for a fit's per-pose rows in the report until they are written, a block at a time: a
# 100,000-pose table's rows as Python dicts would be ~70 MB, twice over with their JSON-safe copy
_POSES = "\x00accelcal-poses\x00"
_BLOCK = 2000


def _echo_json(report: FitReport, fr: FitResult | None, names: list[str]) -> None:
    """The report as one JSON line, exactly ``json.dumps(report)`` with the rows in place of _POSES."""
    text = json.dumps(_clean(report), allow_nan=False)
    key = '"poses": ' + json.dumps(_POSES)  # a quote inside a JSON string is escaped: found only as the key
    if fr is None or key not in text:
        click.echo(text)
        return
    head, tail = text.split(key, 1)
    click.echo(head + '"poses": [', nl=False)
    for i in range(0, fr.pose_count, _BLOCK):
        rows = json.dumps(_clean(fr.pose_rows(names, i, i + _BLOCK)), allow_nan=False)
        click.echo((", " if i else "") + rows[1:-1], nl=False)
    click.echo("]" + tail)


def _choose(path: str, loaded: Loaded) -> tuple[Loaded, ModelChoice]:
    """No --model: the richest model the data determine (models/choice.py), said on the read line;
    hand-placed faces become the session's references."""
    session = loaded.session
    try:
        choice = choose_model(session)
    except AccelcalError as e:
        raise type(e)(f"{path}: {e}") from None
    inferred = list(loaded.inferred)
    if choice.faces is not None:
        f = choice.faces
        inferred.append(f"{f.text}: " + ", ".join(f"{n} {face}" for n, face in zip(session.names, f.names,
                                                                                    strict=True))
                        + "; taken as references")
        session = with_face_references(session, f)
    inferred.append(f"model: {choice.method} ({choice.reason}; --model N to choose)")
    return replace(loaded, session=session, inferred=inferred), choice
