"""The station: calibrate boards end to end.  One board (``board``, configured by ``settings``,
reported by ``report``), a panel of boards on one jig (``panel``, its device sections in
``panel_config``, the jig's per-pose rotation estimated jointly in ``jig_pose``), a thermal
plan in a chamber (``thermal``, ``thermal_panel``, the plan and soak rule in ``thermal_plan``),
the gated capture (``capture``), who and what a run is about (``identity``) and a finished
run recorded, or kept in the outbox with the truth said when the store fails (``recording``).

May import the parts below it: ``store``, ``nvm``, ``data``, ``fixtures``, ``instruments``,
``drivers``, ``acceptance``, ``models``, ``config`` and the foundation; never the lot flows,
the diagnosis or the CLI.
"""
