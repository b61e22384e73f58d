"""The results store: every station run in one database, an SQLite file (the default) or a
line's PostgreSQL server.  ``runs`` holds the ``Store`` (recording, queries), ``schema``
the migrations, statuses and columns, ``records`` a stored run as Python values
(``RunRecord``, conversions, ``StoreError``), ``exports`` the JSON/CSV exports and the lot
summary, ``location`` where a store is (config path, URL, identity) and ``database`` the
connection over SQLAlchemy.

May import ``acceptance`` (typed reasons), ``config`` and the foundation (calibration,
session, errors, atomic); never the station, the lot flows or the CLI.
"""
