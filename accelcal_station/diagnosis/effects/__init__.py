"""The diagnosis's catalog of effects: one module per effect (DESIGN.md's names), each a
deterministic effect (design columns fitted on held-out folds) or a stochastic one (judged by
its own signature); ``catalog`` lists them in the design's column order, ``design`` builds the
static view's design from them, and ``jig_rotation`` fits a fixed jig rotation on that design.

May import the rest of ``diagnosis`` below the held-out evaluation (gap_data, noise_floor,
evaluation, least_squares), ``identifiability`` and numpy/scipy; never gap_effects, the views,
the engine, the report or anything above the diagnosis.
"""
