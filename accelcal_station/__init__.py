"""accelcal-station: calibration station for three-axis MEMS accelerometers."""
__version__ = "0.1.0"
