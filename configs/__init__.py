"""Station configurations in YAML (``sim.yaml`` is the default station); no code.
(This folder sits at the top of the repository and installs as ``accelcal_station.configs``.)
"""
