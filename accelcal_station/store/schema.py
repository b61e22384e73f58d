"""The results store's schema constants: the allowed statuses and verdicts, the pose columns,
the JSON columns and the schema version this station needs.

The tables are SQLAlchemy Core objects in tables.py, created and upgraded by the Alembic
revisions in ``migrations/versions`` (migrate.py); ``SCHEMA_VERSION`` names the newest
revision (revisions are numbered ``0001``, ``0002``, ...).  Failure reasons are typed
(reasons.Reason): the ``reasons`` column holds a JSON list of ``{"code", "message"}``
objects and summaries group by the code.  Rows written before schema 3 held bare text;
revision 0003 gives each its code once.
"""
from __future__ import annotations

STATUSES = ("running", "complete", "interrupted", "error")
VERDICTS = ("PASS", "FAIL")
POSE_COLS = ("idx", "name", "pitch_deg", "roll_deg", "ref_x", "ref_y", "ref_z", "mean_x", "mean_y", "mean_z",
             "std_x", "std_y", "std_z", "n", "dropped", "temp_c", "t_start", "t_end", "retries")
SCHEMA_VERSION = 6  # the Alembic revision this station needs: "0006"
# text columns holding JSON
JSON_COLUMNS = ("reasons", "nvm_outcome", "calibration", "fit_summary", "limits", "site", "uncertainty")
