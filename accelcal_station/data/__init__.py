"""Files in and out: the one loader every command reads measurements through (pose tables,
raw sample logs with their static poses found), lot files streamed in chunks, and the results
table of a lot.

Holds ``loader``, ``posetable``, ``rawlog`` (reading a log), ``static_poses`` (finding its
still intervals), ``lotfile`` and ``results_table``.  May import
``models`` (the nominal scale of counts), ``config`` and the foundation (session,
conventions, calibration, errors, atomic); never the station, the store, the lot flows, the
diagnosis or the CLI.
"""
