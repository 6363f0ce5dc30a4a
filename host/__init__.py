"""The stack that runs on the robot: port specs, ports, drivers, estimation, homing, capture.

It imports :mod:`rfhoming.protocol` only and reaches devices -- real dongles, the emulator, a
replayed capture -- through port specs and transports. The application layer (:mod:`rfhoming`:
the API, the command line, the demo) is what wires the emulator in.
"""
