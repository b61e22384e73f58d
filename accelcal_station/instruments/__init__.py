"""Instruments beside the device and the jig: the thermal chamber (``chamber``, ESPEC-style
ASCII over pyvisa), its emulator (``chamber_emulator``: physics on a pseudo-terminal) and the
factory that builds the configured one (``factory``, like ``drivers.factory``).

May import ``sim`` (the pty server of the emulator), ``config`` and the foundation; the
chamber driver never imports its emulator.
"""
