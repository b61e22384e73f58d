"""The results store: every station run in one database, an SQLite file (the default) or a
line's PostgreSQL server.  ``runs`` holds the ``Store`` (recording, queries), ``tables``
the SQLAlchemy Core tables, ``schema`` the statuses, columns and schema version,
``migrate`` the Alembic upgrade run at open (revisions in ``migrations/versions``, package
data), ``records`` a stored run as Python values (``RunRecord``, conversions,
``StoreError``), ``rowcheck`` the checks every read row passes (``damaged_row``),
``exports`` the JSON/CSV exports and the lot summary, ``outbox`` and ``replay`` the local
outbox of a line store whose server went away, ``location`` where a store is (config path,
URL, identity) and ``database`` the connection over SQLAlchemy; ``celltext`` decodes text
cells one by one (a bad byte damages its cell), ``liveness`` reads a running run whose
process is gone as ``stale``, ``integrity`` names damaged rows and unreadable pages.

May import ``acceptance`` (typed reasons), ``config`` and the foundation (calibration,
session, errors, atomic); never the station, the lot flows or the CLI.
"""
