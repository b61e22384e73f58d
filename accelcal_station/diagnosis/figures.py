"""The files `accelcal diagnose --report DIR` writes: figures (matplotlib, Agg backend; the ``report``
extra) and summary.md, each written to a temporary name and renamed, so a report directory never holds a
half-written file; and the check of DIR before any analysis runs.  The words are report.py's.
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..atomic import atomic_write
from ..errors import AccelcalError, DataError
from .evaluation import Evaluation
from .gap_data import time_data
from .report import FIGURES, fmt_g, summary_lines
from .result import Diagnosis, DiagnosisJson

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


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
        ax.set_title(f"{title}: held-out gap {fmt_g(e.view_gap('static'))}", fontsize=10)
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
    md += [f"| {r['effect']}{' (selected)' if r['effect'] in d.selected else ''} | {fmt_g(r['held_out_gap'])} | "
           f"{r['p_value']:.2g} |" for r in json_obj["ranking"]]
    md.append("")
    for f in files:
        title = FIGURES.get(f.stem, "noise: Allan deviation")
        md += [f"## {title[0].upper() + title[1:]}", "", f"![{title}]({f.name})", ""]
    atomic_write(out / "summary.md", "\n".join(md) + "\n")
    files.append(out / "summary.md")

