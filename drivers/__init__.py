"""Sensor drivers: MMA8451 over I2C (smbus2), MPU6050 behind a serial bridge (pyserial), a
simulated board with the same interface, the TCA9548A multiplexer and the boards' EEPROM.
``factory.make_driver(config)`` builds a driver by name, like python-can's
``Bus(interface=...)``; ``emulated`` builds the register-level or serial emulators and hands
them to the real drivers as their bus or port.

May import ``sim`` (the simulated board's sensor model), ``config`` and the foundation; a
driver never imports its emulator.  (This folder sits at the top of the repository and
installs as ``accelcal_station.drivers``.)
"""
