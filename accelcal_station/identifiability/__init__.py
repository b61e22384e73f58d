"""Whether poses determine a model, before any fit: ``determined`` (assess, assess_batch, require,
worst_parameter: the models 6, 9, 12, 15), ``orientations`` (distinct orientations of the poses) and
``terms`` (describe_terms: which terms of any effects design are confounded, for diagnose).

Imports only numpy and the errors (errors is below it in the layers); the models, the diagnosis, the
lot flows and the CLI import it.  The names below are its interface.
"""
from .determined import (
    COEFFS,
    PARAMS,
    REL_SV_MIN,
    SPREAD_MIN_G,
    Identifiability,
    _design,
    assess,
    assess_batch,
    require,
    worst_parameter,
)
from .orientations import DISTINCT_TOL_DEG, SMALL_P, _centre, distinct_count, first_of_orientation
from .terms import TERM_REL_SV_MIN, TermsCounts, TermsDescription, describe_terms

__all__ = ["COEFFS", "DISTINCT_TOL_DEG", "PARAMS", "REL_SV_MIN", "SMALL_P", "SPREAD_MIN_G", "TERM_REL_SV_MIN",
           "Identifiability", "TermsCounts", "TermsDescription", "_centre", "_design", "assess", "assess_batch",
           "describe_terms", "distinct_count", "first_of_orientation", "require", "worst_parameter"]
