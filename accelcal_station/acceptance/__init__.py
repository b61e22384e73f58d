"""Acceptance: the limits a calibrated board must meet, the PASS/FAIL verdict with every
reason, and the typed reasons themselves (a code and a message) that runs and lot results store.

Holds ``rules`` (limits and judging a fit) and ``reasons``.  May import ``models`` (the fit
result it judges), ``config`` and the foundation (errors, calibration, session); never the
flows above it (station, lot, diagnosis), the store or the CLI.
"""
