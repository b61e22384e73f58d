"""Same answers before and after a change: a fixed list of commands run by this checkout and by
another revision, outputs compared byte for byte apart from times, run ids and CRCs.

    python benchmarks/same_answers.py REV          # e.g. the commit before a refactor

REV is checked out in a temporary git worktree with a virtual environment of its own
(``pip install -e .[test]``, about a minute); this checkout's ``accelcal`` is the one on PATH (installed with
the same extra, since pyarrow, when present, writes the results tables). Every
command runs in a fresh folder per side, on seeded copies of configs/ (``seed: 1`` in sim.yaml),
a 300-board lot file written once and read by both, and the data in tests/data and examples/.
What is masked: ISO times, durations, run and panel ids, pids, and each blob's CRC (it covers the burn
time); a `run`'s stderr (what the station said) is compared too, and the stored runs through
`report show`.  The 16-board thermal panel has every number masked: its boards' threads share the
chamber's time, so its figures differ in the last digits from run to run (a thermal panel of one
is compared whole).  Written files (results tables, pose tables, truths, raw logs) are compared whole.
Prints one line per command that differs and ``N of N commands identical``; exit 1 on a difference.
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MASKED = ("started_at", "finished_at", "heartbeat_at", "time", "at", "timestamp", "duration_s", "elapsed_s",
          "wall_s", "seconds", "run_id", "panel_id", "id", "first_run", "last_run", "since", "until", "boards_per_s",
          "host_compute_s", "operator_wait_s", "board_time_s", "crc32", "panel_time_s", "per_board_s", "pid", "t")
RAW = "--raw --columns -,-,x,y,z,-,-,- --rate 204.8 {D}/imucal_annotated_session.csv"
COMMANDS = [
    "run --config {C}/sim.yaml --serial SN1 --store store.sqlite --json",
    "run --config {C}/sim.yaml --serial SN2 --lot L1 --store store.sqlite --json",
    "run --config {C}/panel-sim.yaml --store store.sqlite --json",
    "run --config {C}/thermal-sim.yaml --store store.sqlite --json",
    "run --config {C}/mma8451-emulated.yaml --store store.sqlite --json",  # Enter at every prompt
    "fit {D}/calibraxis_set_1.csv --model 9 --json",
    "fit {D}/calibraxis_set_2.csv --model 9 --json",
    "fit {D}/nine_position_paper_faces.csv --model 6 --json",
    "fit {D}/nine_position_paper_faces.csv --model 12 --json",
    "fit {E}/poses.csv --model 12 --json",
    "fit {E}/poses.csv --model 15 --json",
    f"fit {RAW} --model 9 --json",
    "poses an4399-8 --model 12 --noise-mg 0.05 --json",
    "simulate --config {C}/sim.yaml --poses an4399-8 --out s.csv --truth-out t.json",
    "fit s.csv --model 12 --json",
    "batch {E}/poses.csv s.csv --model 12 --json",
    "batch {LOT} --model 12 --out results12.csv --json",
    "batch {LOT} --model 9 --out results9.csv --json",
    "diagnose {E}/poses.csv --json",
    f"diagnose {RAW} --json",
    "diagnose {D}/calibraxis_set_1.csv --json",
    "report summary --db store.sqlite --json",
    "report list --db store.sqlite --json",
    "batch --from-store store.sqlite --model 12 --json",
    "fit {E}/poses.csv --model 12",
    "diagnose {E}/poses.csv",
    f"fit {RAW} --model 6",
    "simulate --config {C}/sim.yaml --poses six-face --raw --temps 0,25 --out r.csv --truth-out rt.json --json",
    "fit r.csv --raw --model 9 --json",
    "fit s.csv --model 6 --hand-placed --json",
    "simulate --config {C}/sim.yaml --poses an4399-8 --temps 0,40 --out tt.csv",
    "fit tt.csv --model 12 --json",
    "fit tt.csv --model 12",
    "fit {D}/nine_position_paper_faces.csv --model 12 --temp-method cubic --json",
    "twin fit {LOT} -o tw.yaml --json",
    "twin fit {LOT} -o tw2.yaml",
    "twin check {LOT} --config tw.yaml --seed 1 --json",
    "twin check {LOT} --config tw.yaml --seed 1",
    "twin whatif {LOT} --config tw.yaml --seed 1 --boards 2000 --limit offset_max_mg=60 --limit cubic_max=0.01 --json",
    "twin whatif {LOT} --config tw.yaml --seed 1 --boards 2000 --limit offset_max_mg=60",
    f"diagnose {RAW}",
    "diagnose {D}/nine_position_paper_faces.csv --json",
    "diagnose --selftest --json",
    "fit s.csv --model 12 -o cal12.json --json",
    "fit tt.csv --model 12 -o caltt.json",
    "report show 1 --db store.sqlite --json",
    "report check --db store.sqlite --json",
    # the four flows (one board, a panel, a thermal plan, a thermal panel), panels of one and shifts,
    # with what they say on stderr and what the store keeps of them (report show)
    "run --config {C}/panel-mma8451-emulated.yaml --store flows.sqlite --json",
    "run --config {C}/panel-one.yaml --store flows.sqlite --json",
    "run --config {C}/thermal-panel-one.yaml --store flows.sqlite --json",
    "run --config {C}/sim.yaml --serial SN3 --store flows.sqlite --json",
    "run --config {C}/thermal-sim.yaml --serial SN4 --store flows.sqlite --json",
    "run --shift --config {C}/sim.yaml --store flows.sqlite --json",
    "run --shift --config {C}/thermal-sim.yaml --store flows.sqlite --json",
    "run --config {C}/sim.yaml --serial SN5 --store flows.sqlite",
    "run --config {C}/panel-sim.yaml --store flows.sqlite",
    "run --config {C}/thermal-sim.yaml --serial SN6 --store flows.sqlite",
    "run --config {C}/thermal-panel-one.yaml --store flows.sqlite",
    "run --config {C}/mma8451-emulated.yaml --store flows.sqlite",
    "report list --db flows.sqlite --json",
    *[f"report show {n} --db flows.sqlite --json" for n in (1, 8, 9, 10, 11, 12, 13, 16, 19, 20, 35, 36, 37, 38)],
    # 16 boards in one chamber: their threads share the chamber's time, so the figures vary from run
    # to run (in the last digits); every number is masked, the rest (keys, verdicts, words) compared
    "run --config {C}/thermal-panel-sim.yaml --store tp16.sqlite --json",
    "run --config {C}/thermal-panel-sim.yaml --store tp16.sqlite",
]
NUMBERS_MASKED = ("tp16.sqlite",)
SHIFT_INPUT = "SN10\nSN11\n\nSN10\n"  # a blank line (ignored) and a retest; end of input ends the shift
FILES = ("results12.csv", "results9.csv", "s.csv", "t.json", "r.csv", "rt.json", "tt.csv", "tw.yaml", "tw2.yaml",
         "cal12.json", "caltt.json")


def normalise(text: str, repo: Path) -> str:
    """Mask what differs from run to run (times, ids, CRCs over a time stamp) and the checkout's path."""
    text = text.replace(str(repo), "REPO")
    text = re.sub(r'"\d{4}-\d{2}-\d{2}[T ][0-9:.+Z-]+"', '"TIME"', text)
    text = re.sub(r"\S+-\d{8}T\d{6}-[0-9a-f]{6}", "PANEL_ID", text)
    text = re.sub(r"CRC-32 0x[0-9a-f]{8}", "CRC-32 X", text)
    text = re.sub(r"(wall|compute|station) \d+\.\d+ s", r"\1 T s", text)  # host times in text
    text = re.sub(r"\d+\.\d+ s (board time|per board)", r"T s \1", text)
    return re.sub(r'"(' + "|".join(MASKED) + r')": *[^,}]+', r'"\1": X', text)


def run_all(accelcal: str, repo: Path, work: Path, configs: Path, lot: Path) -> list[str]:
    """Each command's stdout and exit status (and a run's stderr: what the station said), run in
    ``work`` by ``accelcal``."""
    out = []
    for cmd in COMMANDS:
        args = cmd.format(C=configs, D=repo / "tests" / "data", E=repo / "examples", LOT=lot).split()
        stdin = SHIFT_INPUT if "--shift" in args else "\n" * 64  # Enter at every operator prompt
        r = subprocess.run([accelcal, *args], cwd=work, input=stdin, capture_output=True, text=True, timeout=600)
        said = normalise(r.stderr, repo) if args[0] == "run" else ""
        text = normalise(r.stdout, repo) + f"\nexit {r.returncode}\n" + said
        if any(m in cmd for m in NUMBERS_MASKED):
            text = re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "N", text)
        out.append(text)
    return out


def prepare(rev: str, tmp: Path) -> tuple[Path, str]:
    """REV in a worktree with its own editable install: its repository and its ``accelcal``."""
    repo, venv = tmp / "checkout", tmp / "venv"
    subprocess.run(["git", "worktree", "add", "--detach", "-f", str(repo), rev], cwd=ROOT, check=True,
                   capture_output=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    # the [test] extra, as here: pyarrow, when installed, writes the results CSV (same rows, other quoting)
    subprocess.run([str(venv / "bin" / "pip"), "install", "-q", "-e", f"{repo}[test]"], check=True)
    return repo, str(venv / "bin" / "accelcal")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the revision to compare with (a commit, tag or branch)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder (to look at a difference)")
    a = ap.parse_args()
    from accelcal_station.lot.synthetic import write_lot

    tmp = Path(tempfile.mkdtemp(prefix="same-answers-"))
    try:
        repo, before = prepare(a.rev, tmp)
        configs = tmp / "configs"
        shutil.copytree(ROOT / "configs", configs)
        sim = configs / "sim.yaml"
        sim.write_text(sim.read_text().replace("  # seed: 1 ", "  seed: 1   ", 1))
        for panel in ("panel-sim", "thermal-panel-sim"):  # panels of one: device.boards 1
            text = (configs / f"{panel}.yaml").read_text()
            one = text.replace("  boards: 16", "  boards: 1 ", 1)
            (configs / f"{panel.replace('sim', 'one')}.yaml").write_text(one)
        lot = tmp / "lot.csv"
        write_lot(lot, 300, design="optimal-12", seed=7)
        sides = {}
        for name, exe, src in (("before", before, repo), ("after", shutil.which("accelcal") or "accelcal", ROOT)):
            (tmp / name).mkdir()
            sides[name] = (run_all(exe, src, tmp / name, configs, lot), tmp / name)
            if a.keep:  # each command's normalised output, to diff
                (tmp / name / "outputs.txt").write_text("".join(f"$ {c}\n{o}" for c, o in zip(COMMANDS, sides[name][0],
                                                                                             strict=True)))
        (b, bdir), (c, cdir) = sides["before"], sides["after"]
        diff = [cmd for cmd, x, y in zip(COMMANDS, b, c, strict=True) if x != y]
        diff += [f for f in FILES if (bdir / f).read_bytes() != (cdir / f).read_bytes()]
        for d in diff:
            print(f"differs: {d}")
        same = len(COMMANDS) + len(FILES) - len(diff)
        print(f"{same} of {len(COMMANDS) + len(FILES)} commands and written files identical (against {a.rev})")
        return 1 if diff else 0
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(tmp / "checkout")], cwd=ROOT, capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True) if not a.keep else print(f"kept {tmp}")


if __name__ == "__main__":
    raise SystemExit(main())
