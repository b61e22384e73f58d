"""The results store's schema: the migrations, the allowed statuses and verdicts, the pose columns.

Schema versions live in ``PRAGMA user_version`` (SQLite; database.py keeps PostgreSQL's);
``MIGRATIONS[i]`` upgrades version i to i + 1.  Failure reasons are typed
(reasons.Reason): the ``reasons`` column holds a JSON list of ``{"code", "message"}``
objects and summaries group by the code.  Rows written before schema 3 held bare text;
migration 3 gives each its code once (_typed_reasons).
"""
from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from .database import Database
from .records import load_or

STATUSES = ("running", "complete", "interrupted", "error")
VERDICTS = ("PASS", "FAIL")
POSE_COLS = ("idx", "name", "pitch_deg", "roll_deg", "ref_x", "ref_y", "ref_z", "mean_x", "mean_y", "mean_z",
             "std_x", "std_y", "std_z", "n", "dropped", "temp_c", "t_start", "t_end", "retries")


def _legacy_code(text: str, typed: list[Any] | None, i: int) -> str:
    """The code of a reason stored as bare text before schema 3: the station's own
    ``reason_codes`` when it kept them, else the text's first word (acceptance.py starts
    each limit reason with its key).  Used by migration 3 only, once per row."""
    if typed is not None and i < len(typed) and isinstance(typed[i], str) and typed[i]:
        return typed[i]
    words = text.strip().split(None, 1)
    return words[0].split(":", 1)[0] if words else ""


def _typed_reasons(db: Database) -> None:
    """Migration 3: every stored reason becomes ``{"code", "message"}``; damaged rows stay as they are."""
    rows = db.execute("SELECT id, reasons, fit_summary FROM runs WHERE reasons IS NOT NULL").fetchall()
    updates = []
    for r in rows:
        old, fit = load_or(r["reasons"], None), load_or(r["fit_summary"], None)
        if not isinstance(old, list):
            continue
        typed = fit.get("reason_codes") if isinstance(fit, dict) and len(fit.get("reason_codes") or []) == len(old) \
            else None
        new = [x if isinstance(x, dict) else {"code": _legacy_code(str(x), typed, i), "message": str(x)}
               for i, x in enumerate(old)]
        updates.append((json.dumps(new), r["id"]))
    db.executemany("UPDATE runs SET reasons = ? WHERE id = ?", updates)


# statements are split at ';' (keep it out of comments and strings); a callable gets the connection
MIGRATIONS: list[str | Callable[[Database], None]] = [
    """
    CREATE TABLE runs (
        id INTEGER PRIMARY KEY,
        started_at REAL NOT NULL,
        finished_at REAL,
        status TEXT NOT NULL DEFAULT 'running'
            CHECK (status IN ('running', 'complete', 'interrupted', 'error')),
        status_reason TEXT,
        device_serial TEXT,
        chip TEXT,
        station_id TEXT,
        operator TEXT,
        lot TEXT,
        config_hash TEXT,
        config_text TEXT,
        model TEXT,
        units TEXT,
        counts_per_g REAL,
        gravity_mps2 REAL,
        verdict TEXT CHECK (verdict IN ('PASS', 'FAIL')),
        reasons TEXT,           -- JSON list of {"code", "message"} (text before schema 3)
        nvm_status TEXT,        -- written / failed / none
        nvm_outcome TEXT,       -- JSON (writer.BurnOutcome.to_dict)
        calibration TEXT,       -- JSON (Calibration.to_dict)
        fit_summary TEXT,       -- JSON (FitResult.to_json_dict or similar)
        host TEXT,
        pid INTEGER
    );
    CREATE INDEX runs_device ON runs (device_serial, started_at);
    CREATE INDEX runs_lot ON runs (lot, started_at);
    CREATE INDEX runs_started ON runs (started_at);
    CREATE TABLE poses (
        run_id INTEGER NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
        idx INTEGER NOT NULL,
        name TEXT NOT NULL,
        pitch_deg REAL, roll_deg REAL,
        ref_x REAL, ref_y REAL, ref_z REAL,          -- expected output, g
        mean_x REAL NOT NULL, mean_y REAL NOT NULL, mean_z REAL NOT NULL,  -- session units
        std_x REAL, std_y REAL, std_z REAL,          -- session units
        n INTEGER,
        dropped INTEGER NOT NULL DEFAULT 0,
        temp_c REAL,
        t_start REAL, t_end REAL,
        retries INTEGER NOT NULL DEFAULT 0,          -- rejected captures before this one
        PRIMARY KEY (run_id, idx)
    );
    CREATE TABLE events (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
        t REAL NOT NULL,
        kind TEXT NOT NULL,
        message TEXT,
        data TEXT                                    -- JSON
    );
    CREATE INDEX events_run ON events (run_id);
    """,
    """
    ALTER TABLE runs ADD COLUMN panel_id TEXT;   -- the boards calibrated together on one jig (panel.py)
    CREATE INDEX runs_panel ON runs (panel_id);
    """,
    _typed_reasons,
]
SCHEMA_VERSION = len(MIGRATIONS)
