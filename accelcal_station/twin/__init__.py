"""The population twin: a lot's boards summarised as the simulator's population, checked against it.

stream.py reads a lot in chunks (fits, measures, a reservoir sample, block sums along the
lot); mixture.py fits Gaussian / Student-t mixtures by EM (components chosen by BIC);
changes.py finds steps and trends along the lot; physics.py chooses the simulator physics
(implicit | forward) from the lot's residuals; fit.py writes the twin config;
compare.py holds the two-sample tests; check.py and whatif.py simulate lots from a config.

A middle layer beside lot and diagnosis: may import models, sim, data, fixtures, lot, store,
acceptance, config and the foundation; never the CLI.
"""
