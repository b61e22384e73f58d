"""The sim-to-real gap diagnosis: where real data leave the simulator, which catalog effect
explains it, by how much the held-out residuals shrink once it is added, and what is left.

Holds ``loading`` (the simulator and the data as GapData), ``gap_data``, ``noise_floor``,
``effects/`` (one class per catalog effect: design columns or a stochastic signature;
``effects.design`` the static design and its rank), the held-out fits (``gap_effects.evaluate``
over ``folds``, ``least_squares``, ``static_view``, ``time_view``, giving an ``evaluation``),
``engine`` (diagnose: floor, gap, stochastic signatures) with ``candidates``, ``selection``,
``where``, ``verdict`` and ``result`` (the Diagnosis and its JSON), ``shape`` (what is left),
``report`` (words), ``figures`` (--report's files), ``request`` (what to diagnose) and
``selftest`` (forward-physics boards).  May import ``data``, ``sim``, ``drivers`` (the simulated
board), ``fixtures`` (designs, the simulated jig), ``models``, ``config`` and the
foundation; never the station, the lot flows or the CLI.
"""
