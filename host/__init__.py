"""The stack that runs on the robot.

It imports :mod:`protocol` only and reaches devices -- real dongles, the emulator, a replayed
capture -- through transports. Only :mod:`rfhoming.host.cli` wires the emulator in, for ``rfhoming demo``
and ``rfhoming emulate``.
"""
