"""The simulator: the sensor as forward physics, true force to raw counts through the named
effects of the catalog (``sensor_model``), and the pseudo-terminal server that every emulator
answers a serial line on (``pty_server``).

May import ``config`` and the foundation (calibration, conventions, errors); never a driver,
a fixture or anything above.
"""
