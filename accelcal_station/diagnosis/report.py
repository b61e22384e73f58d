"""What `accelcal diagnose` says: the human summary, the self-test table, figures and markdown.

Figures need matplotlib (the ``report`` extra) and use the Agg backend; every file
is written to a temporary name and renamed, so a report directory never holds a
half-written file.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from ..atomic import atomic_write
from ..errors import AccelcalError, DataError
from ..sim.sensor_model import EffectValue
from .evaluation import Evaluation
from .gap_data import time_data
from .result import Diagnosis, DiagnosisJson
from .selection import MIN_GAP_SHRINK, Fitted

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .selftest import SelfTestResult  # type only: the self-test's simulation is not imported for a report

FIGURES = {"sphere": "residuals over the sphere of orientations", "level": "residual against input level",
           "temperature": "residual against temperature", "time": "residual against time in capture"}


# -- text ---------------------------------------------------------------------------------------------

def _g(x: float | None) -> str:
    return "n/a" if x is None or not np.isfinite(x) else (f"{x:.3g}" if x < 100 else f"{x:.0f}")


def config_hint(effect: str, fitted: Fitted) -> dict[str, EffectValue | None] | None:
    """The fitted effect as simulator-configuration parameters (approximate where W is not I)."""
    f = fitted

    def n(key: str) -> float:  # a fitted number (a per-axis list where one is named is the caller's error)
        v = f[key]
        if isinstance(v, list):
            raise TypeError(f"fitted {key}: a list where a number was fitted")
        return v

    try:
        if effect == "cubic":
            return {"cubic_per_g2": [-n(f"Gamma_{a}") for a in "xyz"]}  # AN4399 Eqn 67: Gamma = -c
        if effect == "quadratic":
            return {"quadratic_per_g": [-n(f"Q_{a}") for a in "xyz"]}
        if effect == "offset":
            return {"offset_mg": [-1e3 * n(f"V_{a}") for a in "xyz"]}
        if effect == "gain":
            return {"gain": [1.0 / n(f"W_{a}{a}") for a in "xyz"]}
        if effect == "temperature":
            return {"offset_mg_per_c": [-1e3 * n(f"offset_{a}_per_25C") / 25.0 for a in "xyz"],
                    "gain_ppm_per_c": [-1e6 * n(f"gain_{a}_per_25C") / 25.0 for a in "xyz"]}
        if effect == "noise":
            return {"density_ug_per_rthz": f["density_ug_per_rthz"]}
        if effect == "quantization":
            return {"lsb_counts": int(round(n("lsb_counts")))}
        if effect == "pose_error":
            return {"scatter_deg": f["scatter_deg"]}
        if effect == "settling":
            return {"tau_s": f["settling_tau_s"]}
        if effect == "drift":
            return {"warmup_mg": [1e3 * n(f"warmup_{a}") for a in "xyz"], "warmup_tau_s": f["drift_tau_s"]} \
                if "drift_tau_s" in f else {"warmup_tau_s": f.get("drift_tau_s_time")}
    except KeyError:
        return None
    return None


def _yaml_inline(d: Mapping[str, object]) -> str:
    def v(x: Any) -> str:
        if isinstance(x, list):
            return "[" + ", ".join(v(y) for y in x) + "]"
        return f"{x:.4g}" if isinstance(x, float) else str(x)
    return "{" + ", ".join(f"{k}: {v(x)}" for k, x in d.items()) + "}"


def _where_lines(d: Diagnosis) -> list[str]:
    """Where the baseline's held-out gap lies (where.breakdown) as text."""
    data = d.data
    out = ["WHERE (held-out ratio to the floor, baseline model)"]
    w = d.where
    if "by_axis" in w:
        out.append("  by axis: " + ", ".join(f"{a} {_g(v)}" for a, v in w["by_axis"].items()))
    if "by_pose" in w:
        odd = [p for p in w["by_pose"] if p["stands_out"]][:4]
        out.append("  poses that stand out (standardised held-out residual): "
                   + (", ".join(f"{p['pose']} {_g(p['z_rms'])}" for p in odd) if odd else "none"))
    if w.get("by_level"):
        rows: dict[str, list[str]] = {}
        for r in w["by_level"]:
            rows.setdefault(r["axis"], []).append(f"{r['level_g'][0]:+.1f}..{r['level_g'][1]:+.1f} g: "
                                                  f"{r['mean_residual_mg']:+.3g} mg")
        label = "channel" if not data.norm_only else "norm residual vs channel"
        for a, rr in rows.items():
            out.append(f"  by input level ({label} {a}, mean residual): " + "; ".join(rr))
    if w.get("by_temperature"):
        out.append("  by temperature: " + ", ".join(f"{t['temp_c']:.0f} C {_g(t['gap'])}" for t in w["by_temperature"]))
    if w.get("by_time_in_capture"):
        tt = w["by_time_in_capture"]
        out.append("  by time in capture: " + ", ".join(f"{t['t_s']:.1f} s {_g(t['gap'])}" for t in tt)
                   + f" (first block leans {tt[0]['toward_step_mg']:+.3g} mg along the last move)")
    if "noise" in w:
        nz = w["noise"]
        out.append("  noise: per-sample sigma " + "/".join(f"{x:.3g}" for x in nz["sigma_mg"]) + " mg against the "
                   f"simulator's {np.mean(nz['simulator_sigma_mg']):.3g} mg (ratio "
                   + "/".join(_g(x) for x in nz["ratio"]) + ")")
    if "allan" in w:
        al = w["allan"]
        out.append(f"  Allan deviation at {al['tau_s'][-1]:.3g} s: "
                   + "/".join(_g(x) for x in al["ratio_at_longest_tau"])
                   + " x white noise (x, y, z; 1 = white, more = drift or flicker)")
    return out


def summary_lines(d: Diagnosis) -> list[str]:
    """The human summary: gap, where, which, how far, and what to do."""
    out = _gap_lines(d) + [""] + _where_lines(d) + [""] + _which_lines(d)
    out += _stochastic_lines(d) + _verdict_lines(d)
    return out


def _gap_lines(d: Diagnosis) -> list[str]:
    """The data, the simulator and its floor, and the headline gap."""
    data, sim, b = d.data, d.sim, d.base
    kind = ("references" if not data.norm_only else "norm only (no references)") + \
        (f", raw captures at {data.rate_hz:g} Hz" if data.captures is not None else "")
    n_txt = f"{np.median(data.n):.0f} samples/pose" + ("" if data.n_known else " (assumed)")
    temps = "" if data.temp_c is None else f", {data.n_temps} temperature(s)"
    fl = d.floor
    out = [f"accelcal diagnose: {data.P} poses from {', '.join(data.sources)} ({kind}; {n_txt}{temps})",
           f"simulator {sim.source}: {', '.join(sim.enabled) or 'no effects'}; fitted baseline: "
           f"{', '.join(sim.baseline) or 'nothing (W = I)'}; floor from the {fl.source}: "
           f"{1e3 * float(np.mean(fl.sigma_g)):.3g} mg/sample at {data.rate_hz or sim.odr_hz:g} Hz"
           f" and a {1e3 * fl.q_g:.3g} mg LSB"]
    out += [f"note: {n}" for n in data.notes]
    if not d.static_ok:
        out.append(f"note: no static view: {d.static_why}")
    out.append("")
    h = d.headline
    if h is not None and h["held_out_rms_mg"] is not None:
        out.append(f"GAP  held-out residual {h['held_out_rms_mg']:.4g} mg RMS ({h['source']}): {_g(h['gap'])} x the "
                   f"floor of a pose mean ({h['floor_mg']:.3g} mg RMS, fixed before any candidate; 1.0 = at the floor)")
        out.append(f"     at the floor with this design's own fit uncertainty it would be {h['expected_mg']:.4g} mg; "
                   f"{h['note']}")
    else:
        out.append(f"GAP  held-out gap {_g(d.gap_before)} x the floor fixed before any candidate (time view; "
                   f"held-out residual {1e3 * b.rms_g:.4g} mg RMS)")
    w = d.where.get("views", {})
    views = [f"{v} view {_g(g)}" for v, g in w.items() if g is not None]
    if len(views) > 1:
        out.append("     selection's held-out gap by view: " + "; ".join(views) + f" (their RMS {_g(d.gap_before)} is "
                   "the gap the selection below judges)")
    return out


def _which_lines(d: Diagnosis) -> list[str]:
    """Every candidate's held-out gap and p, the untestable ones with why, and how far the gap fell."""
    out: list[str] = []
    out.append(f"WHICH (each candidate added to the model, refitted on training folds, scored on held-out poses;\n"
               f"       selected while a one-sided paired test (t or Wilcoxon, doubled) on per-pose held-out log "
               "density\n"
               f"       beats alpha = {d.alpha:g} / candidates, the held-out RMS shrinks, some view loses "
               f"{MIN_GAP_SHRINK:.0%} of its log gap,\n       the gap is outside its chance range, and it beats a "
               "change over the session (the order trend)\n       in the same test; when the best fails a rule the "
               "next is tried)")
    for i, r in enumerate(d.ranking):
        mark = "  <- selected" if r["effect"] in d.selected else ""
        out.append(f"  {i + 1:2d}. {r['effect']:<13} held-out gap {_g(r['held_out_gap']):>7}   "
                   f"p {r['p_value']:.2g}{mark}")
    if not d.ranking:
        out.append("  (no catalog effect can be tested on these data)")
    for e, why in d.untestable.items():
        out.append(f"  not testable: {e}: {why}")
    out.append("")
    out.append("HOW FAR (held-out gap; held-out residual RMS)")
    txt = f"  baseline {_g(d.gap_before)} ({1e3 * d.base.rms_g:.3g} mg)"
    for s in d.steps:
        txt += f" -> + {s['added']} {_g(s['gap_after'])} ({s['rms_mg_after']:.3g} mg)"
    out.append(txt)
    ot = d.order_trend
    if ot is not None:
        out.append(f"  order trend (a change over the session) on the baseline: {_g(ot['held_out_gap'])} "
                   f"({_g(ot['rms_mg'])} mg)" if ot["fitted"] else f"  order trend: not fitted ({ot['why_not']})")
    out.append("")
    return out


def _stochastic_lines(d: Diagnosis) -> list[str]:
    """Each stochastic effect's signature test, and the jig rotation."""
    out: list[str] = []
    out.append("STOCHASTIC (each judged by its own signature; never lowers the gap)")
    for name, st in d.stochastic.items():
        if st.get("testable"):
            out.append(f"  {name}: {'NAMED' if st['passed'] else 'no'}: {st['reason']}")
        else:
            out.append(f"  {name}: not testable: {st['reason']}")
    jig = d.stochastic.get("pose_error", {}).get("jig_rotation")
    if jig and isinstance(jig, dict):  # engine.diagnose: jig_rotation's report under pose_error
        state = ("FITTED" if jig["passed"] else "no") if jig["testable"] else "not testable"
        out.append(f"  jig rotation (deterministic, 3 parameters): {state}: {jig['reason']}")
    out.append("")
    return out


def _verdict_lines(d: Diagnosis) -> list[str]:
    """The verdict and the configuration hints that follow from it."""
    data = d.data
    out: list[str] = []
    out.append(f"VERDICT: {d.verdict}: {d.verdict_text}")
    if d.steps and d.verdict in ("explained", "partly explained"):  # only what the selection kept
        out.append("  add to the simulator configuration:")
        for s in d.steps:
            hint = config_hint(s["added"], s["fitted"])
            out.append(f"  {s['added']}: {_yaml_inline(hint)}" if hint else f"  {s['added']}: (see --json steps)")
    if not data.n_known:
        out.append(f"  (the floor assumes {np.median(data.n):.0f} sample(s) per pose: with more, the true gap is "
                   "larger)")
    return out


def selftest_lines(r: SelfTestResult) -> list[str]:
    out = [f"accelcal diagnose --selftest: {r['design']} boards ({r['physics']}), seed {r['seed']}, "
           f"alpha {r['alpha']:g}",
           f"{'case':<19}{'expect':<12}{'named':<26}{'verdict':<19}{'rms mg before':>14}{'after':>8}  result"]
    for c in r["cases"]:
        res = "ok" if c["pass"] else "FAIL"
        if not c["revealable"]:
            res += " (not revealable: see below)"
        out.append(f"{c['case']:<19}{c['kind']:<12}{', '.join(c['selected']) or '-':<26}{c['verdict']:<19}"
                   f"{c['rms_mg_before']:>14.3g}{c['rms_mg_after']:>8.3g}  {res}")
    if "coverage" in r:
        out.append("")
        out.append("effects the data cannot reveal, and why:")
        for effect, row in r["coverage"].items():
            for kind, st in row.items():
                if not st.startswith("testable"):
                    out.append(f"  {effect} / {kind}: {st}")
    out.append("")
    out.append("self-test " + ("passed" if r["passed"] else "FAILED"))
    return out


# -- figures ------------------------------------------------------------------------------------------

def _pyplot() -> ModuleType:
    try:
        import matplotlib
    except ImportError:
        raise AccelcalError("--report needs matplotlib for its figures: pip install 'accelcal-station[report]'") \
            from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


SYSTEM_DIRS = ("/", "/bin", "/boot", "/dev", "/etc", "/lib", "/lib64", "/opt", "/proc", "/root", "/run",
               "/sbin", "/srv", "/sys", "/tmp", "/usr", "/var", "/home")


def is_system_dir(p: Path) -> bool:
    """/ and the system's own folders (and anything under /proc, /sys, /dev, /etc, /usr...)."""
    r = p.expanduser().resolve()
    if str(r) in SYSTEM_DIRS or r == Path.home().resolve():
        return True
    return any(r.is_relative_to(d) for d in ("/proc", "/sys", "/dev", "/etc", "/boot", "/bin", "/sbin",
                                              "/lib", "/usr"))


REPORT_FILES = ("sphere.png", "level.png", "temperature.png", "time.png", "allan.png", "summary.md")  # what it writes


def check_report_dir(path: str | Path) -> Path:
    """The report directory, checked before any analysis runs (write_report creates it, so a
    run that fails leaves no empty directory behind)."""
    _pyplot()
    p = Path(path)
    if is_system_dir(p):
        raise DataError(f"--report {path}: refusing a system folder; allowed: a folder of your own "
                        "(e.g. ./diagnosis)")
    if p.is_symlink() or (p.exists() and not p.is_dir()):
        raise DataError(f"--report {path}: exists and is not a directory")
    if not p.parent.is_dir():
        raise DataError(f"--report {path}: cannot create it (no such directory {p.parent})")
    if not os.access(p if p.exists() else p.parent, os.W_OK | os.X_OK):
        raise DataError(f"--report {path}: not writable")
    return p


def _save(fig: Figure, files: list[Path], path: Path) -> None:
    """Write one figure whole (temporary file, rename), list it, and free it."""
    import matplotlib.pyplot as plt

    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
    finally:
        plt.close(fig)
    files.append(path)  # only files this run wrote are ever removed on a later failure


def _z_pose(e: Evaluation) -> np.ndarray | None:
    """Each pose's held-out residual over its predicted spread (RMS over the axes); None without a static view."""
    if e.r_static is None or e.v_static is None:
        return None
    return np.sqrt(np.mean(e.r_static**2 / e.v_static, axis=1))


def _empty(ax: Axes, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", wrap=True, transform=ax.transAxes)
    ax.set_axis_off()


def write_report(d: Diagnosis, out_dir: str | Path, json_obj: DiagnosisJson) -> list[Path]:
    """PNG figures and summary.md (which embeds them) in out_dir; returns the files written.

    On any failure the files written so far (and out_dir, if this call created it) are removed.
    """
    plt = _pyplot()
    out = Path(out_dir)
    created = not out.exists()
    out.mkdir(exist_ok=True)
    files: list[Path] = []
    try:
        return _write_report(plt, d, out, json_obj, files)
    except BaseException:
        for f in files:
            f.unlink(missing_ok=True)
        if created:
            with contextlib.suppress(OSError):  # something else was put in it meanwhile: it stays
                out.rmdir()
        raise


def _write_report(plt: ModuleType, d: Diagnosis, out: Path, json_obj: DiagnosisJson,
                  files: list[Path]) -> list[Path]:
    """Every figure of the report, then summary.md linking them; ``files``: what was written so far."""
    after = " + ".join(d.selected) if d.selected else "no effect added"
    for plot in (_plot_sphere, _plot_level, _plot_temperature, _plot_time, _plot_allan):
        plot(plt, d, after, out, files)
    _write_summary(d, out, json_obj, files)
    return files


def _plot_sphere(plt: ModuleType, d: Diagnosis, after: str, out: Path, files: list[Path]) -> None:
    """Direction of each pose (reference, or reading when norm-only), coloured by held-out z."""
    data = d.data
    fig = plt.figure(figsize=(11, 4.2))
    u = data.ref if data.ref is not None else data.g
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    lon, lat = np.arctan2(u[:, 1], u[:, 0]), np.arcsin(np.clip(u[:, 2], -1, 1))
    z_base = _z_pose(d.base)  # one colour scale for both panels
    for k, (e, title) in enumerate(((d.base, "baseline"), (d.final, after))):
        ax = fig.add_subplot(1, 2, k + 1, projection="mollweide")
        z = _z_pose(e)
        if z is None or z_base is None:
            ax.set_title(f"{title}: no static view")
            continue
        sc = ax.scatter(lon, lat, c=np.log10(np.maximum(z, 1e-3)), cmap="viridis", s=40, vmin=-0.5,
                        vmax=max(1.0, float(np.log10(max(z_base.max(), 1.0)))))
        ax.set_title(f"{title}: held-out gap {_g(e.view_gap('static'))}", fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.set_xticklabels([])
        fig.colorbar(sc, ax=ax, shrink=0.7, label="log10 residual / floor")
    fig.suptitle("Residuals over the sphere of orientations (direction of gravity in the sensor frame)")
    _save(fig, files, out / "sphere.png")


def _plot_level(plt: ModuleType, d: Diagnosis, after: str, out: Path, files: list[Path]) -> None:
    """Held-out residual against input level, per channel."""
    data = d.data
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for c, ax in enumerate(axes):
        if d.base.r_static is None:
            _empty(ax, "no static view")
            continue
        col = 0 if data.norm_only else c
        for e, lab, st in ((d.base, "baseline", {"color": "0.6", "marker": "o", "s": 14}),
                           (d.final, after, {"color": "C3", "marker": "x", "s": 18})):
            if e.r_static is not None:  # the final model has a static view whenever the baseline has
                ax.scatter(data.g[:, c], 1e3 * e.r_static[:, col], label=lab, **st)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(f"reading {'xyz'[c]} (g)")
        ax.set_title(f"{'norm residual' if data.norm_only else 'channel ' + 'xyz'[c]}", fontsize=10)
    axes[0].set_ylabel("held-out residual (mg)")
    if d.base.r_static is not None:
        axes[0].legend(fontsize=8)
    fig.suptitle("Residual against input level")
    _save(fig, files, out / "level.png")


def _plot_temperature(plt: ModuleType, d: Diagnosis, after: str, out: Path, files: list[Path]) -> None:
    """Held-out residual over its floor against temperature."""
    data = d.data
    fig, ax = plt.subplots(figsize=(6, 3.6))
    if data.temp_c is None or data.n_temps < 2 or d.base.r_static is None:
        _empty(ax, "all poses at one temperature (or no temp_c): nothing to plot against temperature"
               if d.base.r_static is not None else "no static view")
    else:
        for e, lab, st in ((d.base, "baseline", {"color": "0.6", "marker": "o"}),
                           (d.final, after, {"color": "C3", "marker": "x"})):
            ax.scatter(data.temp_c, _z_pose(e), label=lab, **st)
        ax.set_yscale("log")
        ax.axhline(1, color="k", lw=0.5)
        ax.set_xlabel("temperature (C)")
        ax.set_ylabel("held-out residual / floor")
        ax.legend(fontsize=8)
    ax.set_title("Residual against temperature")
    _save(fig, files, out / "temperature.png")


def _plot_time(plt: ModuleType, d: Diagnosis, after: str, out: Path, files: list[Path]) -> None:
    """Block residuals against time within the capture: RMS per tenth of the capture and expected."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    td = None if d.base.r_time is None else time_data(d.data)
    if td is None or d.base.r_time is None:
        _empty(ax, "no raw samples: time within a capture needs raw logs (--raw)")
    else:
        edges = np.linspace(0.0, float(td.t_in.max()) + 1e-9, 11)
        k = np.digitize(td.t_in, edges[1:-1])
        mid = 0.5 * (edges[1:] + edges[:-1])
        has = np.array([np.any(k == i) for i in range(10)])
        for e, lab, col in ((d.base, "baseline", "0.4"), (d.final, after, "C3")):
            if e.r_time is None or e.v_time is None:  # the final model has a time view whenever the baseline has
                continue
            rms = np.array([np.sqrt(np.mean(e.r_time[k == i] ** 2)) if has[i] else np.nan for i in range(10)])
            exp = np.array([np.sqrt(np.mean(e.v_time[k == i])) if has[i] else np.nan for i in range(10)])
            ax.plot(mid[has], 1e3 * rms[has], "o-", color=col, lw=2, label=f"{lab}: RMS")
            ax.plot(mid[has], 1e3 * exp[has], "--", color=col, lw=1, label=f"{lab}: expected")
        ax.plot(td.t_in, 1e3 * np.abs(d.base.r_time), ".", color="0.6", alpha=0.2, ms=2)
        ax.set_yscale("log")
        ax.set_xlabel("time since the capture started (s)")
        ax.set_ylabel("|block mean - capture mean| (mg)")
        ax.legend(fontsize=8)
    ax.set_title("Residual against time in capture")
    _save(fig, files, out / "time.png")


def _plot_allan(plt: ModuleType, d: Diagnosis, after: str, out: Path, files: list[Path]) -> None:
    """Allan deviation of the longest capture against the simulator's white noise (raw data only)."""
    al = d.where.get("allan")
    if not al:
        return
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for c in range(3):
        ax.loglog(al["tau_s"], al["adev_mg"][c], "-o", ms=3, label=f"{'xyz'[c]} data")
        ax.loglog(al["tau_s"], al["white_mg"][c], ":", color=f"C{c}")
    sim_sig = 1e3 * float(np.mean(d.floor.sigma_g))
    ax.loglog(al["tau_s"], sim_sig / np.sqrt(np.array(al["tau_s"]) * (d.data.rate_hz or 1)), "k--",
              label="simulator white noise")
    ax.set_xlabel("tau (s)")
    ax.set_ylabel("Allan deviation (mg)")
    ax.legend(fontsize=7)
    ax.set_title("Noise: Allan deviation of the longest capture")
    _save(fig, files, out / "allan.png")


def _write_summary(d: Diagnosis, out: Path, json_obj: DiagnosisJson, files: list[Path]) -> None:
    """summary.md: the text summary, the ranking and every figure written."""
    md = ["# Sim-to-real gap diagnosis", "", "```", *summary_lines(d), "```", ""]
    md += ["| effect | held-out gap | p |", "|---|---|---|"]
    md += [f"| {r['effect']}{' (selected)' if r['effect'] in d.selected else ''} | {_g(r['held_out_gap'])} | "
           f"{r['p_value']:.2g} |" for r in json_obj["ranking"]]
    md.append("")
    for f in files:
        title = FIGURES.get(f.stem, "noise: Allan deviation")
        md += [f"## {title[0].upper() + title[1:]}", "", f"![{title}]({f.name})", ""]
    atomic_write(out / "summary.md", "\n".join(md) + "\n")
    files.append(out / "summary.md")

