"""A Gage R&R study from stored runs: which runs form it, the parameters studied, the result per parameter.

Parts are the serials with more than one complete calibrated run; appraisers are the runs' operators
(or stations); trials are the repeats of a part by an appraiser.  The study must be balanced (every
part measured by every appraiser the same number of times, >= 2): an unbalanced one is refused with
the cells that are short, never analysed by a method that would silently weight some parts more
(docs/msa.md, "Unbalanced studies").
"""
from __future__ import annotations

import random
from collections import Counter, defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..jsontypes import JsonValue
from ..store.records import RunRecord, RunSummary
from .msa import Anova, AverageRange, Figures, anova, average_range, figures

AXES = "xyz"
Getter = Callable[[RunRecord], float | None]


def _cal(i: int, j: int | None, scale: float, offset: float) -> Getter:
    def get(rec: RunRecord) -> float | None:
        cal = rec.calibration or {}
        try:
            v = cal["V"][i] if j is None else cal["W"][i][j]  # type: ignore[index]
            return (float(v) - offset) * scale  # type: ignore[arg-type]
        except (KeyError, IndexError, TypeError, ValueError):
            return None
    return get


def _fit(key: str, scale: float) -> Getter:
    def get(rec: RunRecord) -> float | None:
        v = (rec.fit_summary or {}).get(key)
        return float(v) * scale if isinstance(v, int | float) and not isinstance(v, bool) else None
    return get


@dataclass(frozen=True)
class Parameter:
    """A studied parameter: its name, unit, how it is read from a run, and the stored limit that gives
    its tolerance (limit key, tolerance = factor x limit: 2 for a symmetric +-limit, 1 for 0..limit)."""

    name: str
    unit: str
    get: Getter
    limit_key: str | None
    factor: float


PARAMETERS: list[Parameter] = (
    [Parameter(f"V_{AXES[i]}", "mg", _cal(i, None, 1e3, 0.0), "offset_max_mg", 2.0) for i in range(3)]
    + [Parameter(f"W_{AXES[i]}{AXES[i]}", "1 (gain error W_ii - 1)", _cal(i, i, 1.0, 1.0), "gain_error_max", 2.0)
       for i in range(3)]
    + [Parameter(f"W_{AXES[i]}{AXES[j]}", "1", _cal(i, j, 1.0, 0.0), "cross_axis_max", 2.0)
       for i in range(3) for j in range(3) if i != j]
    + [Parameter("residual_rms_mg", "mg", _fit("residual_rms_g", 1e3), "residual_rms_mg", 1.0),
       Parameter("verify_error_max_mg", "mg", _fit("verify_error_max_mg", 1.0), "verify_error_max_mg", 1.0)])


@dataclass(frozen=True)
class Study:
    """The balanced runs of a study: ``cells[(part, appraiser)]`` the runs in trial order."""

    parts: list[str]
    appraisers: list[str]
    trials: int
    cells: dict[tuple[str, str], list[RunRecord]]
    excluded: dict[str, int]
    by: str

    def values(self, prm: Parameter) -> np.ndarray | None:
        """parts x appraisers x trials of one parameter; None when any run lacks it."""
        x = np.empty((len(self.parts), len(self.appraisers), self.trials))
        for a, part in enumerate(self.parts):
            for b, appr in enumerate(self.appraisers):
                for t, rec in enumerate(self.cells[(part, appr)]):
                    v = prm.get(rec)
                    if v is None or not np.isfinite(v):
                        return None
                    x[a, b, t] = v
        return x


def _who(rec: RunRecord, by: str) -> str | None:
    return rec.operator if by == "operator" else rec.station_id


def build_study(recs: Sequence[RunRecord], by: str = "operator", left_out: int = 0) -> Study:
    """The study of the complete calibrated runs in ``recs`` (oldest first); DataError naming what is
    missing when there are no repeats, fewer than two parts or appraisers, or unequal trials.
    ``left_out``: runs of serials listed once, already left out by the caller (counted, said)."""
    usable = [r for r in recs if r.status == "complete" and r.calibration and not r.damaged and r.device_serial]
    excluded = {"not_complete_or_no_calibration": len(recs) - len(usable)}
    who = [r for r in usable if _who(r, by)]
    excluded[f"no_{by}"] = len(usable) - len(who)
    n_serial = Counter(r.device_serial for r in who)
    done = [r for r in who if n_serial[r.device_serial] > 1]
    excluded["serials_measured_once"] = len(who) - len(done) + left_out
    if not done:
        raise DataError(f"no serial measured more than once among {len(who) + left_out} run(s) "
                        f"(complete, calibrated, with a{'n' if by == 'operator' else ''} {by}): "
                        "a study needs repeats")
    cells: dict[tuple[str, str], list[RunRecord]] = defaultdict(list)
    for r in done:
        cells[(str(r.device_serial), str(_who(r, by)))].append(r)
    parts = sorted({p for p, _ in cells})
    appraisers = sorted({a for _, a in cells})
    if len(parts) < 2:
        raise DataError(f"one part ({parts[0]}) measured more than once: a study needs >= 2 parts")
    if len(appraisers) < 2:
        raise DataError(f"one {by} ({appraisers[0]}) among the repeated serials: a study needs >= 2 "
                        f"appraisers{' (--by station for stations)' if by == 'operator' else ''}")
    counts = {(p, a): len(cells.get((p, a), [])) for p in parts for a in appraisers}
    trials = max(counts.values())
    short = [f"{p}/{a} has {n}" for (p, a), n in counts.items() if n != trials]
    if short:
        more = f" (+{len(short) - 5} more)" if len(short) > 5 else ""
        raise DataError(f"unbalanced study: every part x {by} needs {trials} trial(s); "
                        f"{', '.join(short[:5])}{more} (rerun them, or filter the runs: --since, --lot)")
    if trials < 2:
        raise DataError(f"every part x {by} has 1 run: a study needs >= 2 trials per part and {by}")
    return Study(parts, appraisers, trials, {k: cells[k] for k in counts}, excluded, by)


def _tolerance(study: Study, prm: Parameter, given: Mapping[str, float]) -> tuple[float | None, str | None]:
    """The tolerance: --tolerance, else factor x the stored limit when every run was judged by the same."""
    if prm.name in given:
        return given[prm.name], "--tolerance"
    if prm.limit_key is None:
        return None, None
    limits = {(r.limits or {}).get(prm.limit_key) for runs in study.cells.values() for r in runs}
    if len(limits) != 1 or (lim := limits.pop()) is None or lim <= 0:
        return None, None
    return prm.factor * lim, f"{prm.factor:g} x stored limit {prm.limit_key} = {lim:g}"


def _ar_dict(ar: AverageRange, tol: float | None) -> dict[str, JsonValue]:
    if ar.ev is None or ar.av is None or ar.pv is None:
        return {"available": False, "reason": ar.unavailable}
    f = figures(ar.ev, ar.av, 0.0, ar.pv, tol)
    return {"available": True, "r_bar": ar.r_bar, "x_diff": ar.x_diff, "r_part": ar.r_part,
            **{k: v for k, v in f.to_dict().items() if k != "interaction"}}


def analyse(study: Study, tolerances: Mapping[str, float] | None = None) -> list[dict[str, JsonValue]]:
    """One result per parameter present in every run of the study (ANOVA, then average and range)."""
    given = dict(tolerances or {})
    out: list[dict[str, JsonValue]] = []
    for prm in PARAMETERS:
        x = study.values(prm)
        if x is None:
            continue
        a: Anova = anova(x)
        tol, source = _tolerance(study, prm, given)
        f: Figures = figures(a.ev, a.av, a.interaction, a.pv, tol)
        out.append({"parameter": prm.name, "unit": prm.unit, **f.to_dict(), "tolerance": tol,
                    "tolerance_source": source, "boards": len(study.parts), "appraisers": len(study.appraisers),
                    "trials": study.trials, "interaction_pooled": a.pooled, "p_interaction": a.p_interaction,
                    "anova": {"ss_part": a.ss_part, "ss_appraiser": a.ss_appraiser,
                              "ss_interaction": a.ss_interaction, "ss_error": a.ss_error,
                              "df": [a.df_part, a.df_appraiser, a.df_interaction, a.df_error]},
                    "average_range": _ar_dict(average_range(x), tol)})
    return out


def plan(parts: Sequence[str], appraisers: Sequence[str], trials: int, seed: int) -> list[dict[str, JsonValue]]:
    """A study's run order (MSA 4th ed. III-B "Conducting the study"): trial by trial, each appraiser
    measures every part in a fresh random order, so no one remembers a reading; a fixed seed."""
    rng = random.Random(seed)
    out: list[dict[str, JsonValue]] = []
    for t in range(1, trials + 1):
        for a in appraisers:
            order = list(parts)
            rng.shuffle(order)
            start = len(out) + 1
            out += [{"order": start + k, "trial": t, "appraiser": a, "part": p} for k, p in enumerate(order)]
    return out


def recent(runs: Sequence[RunSummary], by: str, n_parts: int, n_appraisers: int) -> tuple[list[str], list[str]]:
    """The newest distinct serials and appraisers of complete runs (``Store.list_runs``, oldest first),
    padded with placeholders when the store has fewer."""
    done = [r for r in reversed(runs) if r["status"] == "complete"]
    serials = list(dict.fromkeys(str(r["device_serial"]) for r in done if r["device_serial"]))[:n_parts]
    names = (r["operator"] if by == "operator" else r["station_id"] for r in done)
    who = list(dict.fromkeys(str(w) for w in names if w))[:n_appraisers]
    serials += [f"board-{k}" for k in range(len(serials) + 1, n_parts + 1)]
    who += [f"{by}-{chr(ord('A') + k)}" if k < 26 else f"{by}-{k + 1}" for k in range(len(who), n_appraisers)]
    return serials, who
