"""Lot-scale batch: recalibrate many boards with one model, vectorised (pose tables or the
store), stream a whole lot file in chunks into one results table with verdicts, the lot
report (HTML with figures) and synthetic lot files for benchmarks and tests.

Holds ``batch``, ``streaming``, ``report`` and ``synthetic``.  May import ``store``,
``data``, ``acceptance``, ``models``, ``fixtures`` (pose designs), ``config`` and the
foundation; never the station, the diagnosis or the CLI.
"""
