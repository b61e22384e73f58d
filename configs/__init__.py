"""Station configurations in YAML (``sim.yaml`` is the default station); data, no code, so
nothing imports from here: ``config.sections.default_config_path`` finds ``sim.yaml`` as
package data. (This folder sits at the top of the repository and installs as
``accelcal_station.configs``.)
"""
