"""Calibration models: fit a pose set, one board or a stack of boards.  AN4399's 6, 12 and
15 parameter least squares (``linear``), the 9 parameter gravity-norm model by Gauss-Newton
(``gravity_norm``), the stacked fitters of a lot (``stacked``, ``stacked_norm``, with
``boardwise`` 9x9 algebra and ``heap`` settings), the entry points (``fitting``), the result
(``result``), the refusal of absurd fits (``sanity``) and hand-placed faces (``handplaced``).

May import only the foundation (calibration, identifiability, session, conventions, errors);
nothing above it.
"""
