"""The station: calibrate boards end to end.  One flow for boards x conditions (``flow``:
StationFlow, built by make_flow; what a single board does differently in ``policy``), with its
parts: the boards on one jig (``panel``, its device sections in ``panel_config``, the jig's
per-pose rotation estimated jointly in ``jig_pose``), room temperature (``room``) or a thermal
plan in a chamber (``thermal``, ``thermal_panel``, ``thermal_table``, the plan and soak rule in
``thermal_plan``), a board's steps (``board``), configured by ``settings`` and reported by
``report``; the gated capture (``capture``), who and what a run is about (``identity``), a
shift of boards (``shift``) and a finished run recorded, or kept in the outbox with the truth
said when the store fails (``recording``).

May import the parts below it: ``store``, ``nvm``, ``data``, ``fixtures``, ``instruments``,
``drivers``, ``acceptance``, ``models``, ``config`` and the foundation; never the lot flows,
the diagnosis or the CLI.
"""
