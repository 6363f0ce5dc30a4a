"""Wire formats of the devices rfhoming talks to.

This package is the bottom layer: it imports nothing from ``firmware_py``, ``emulator`` or
``host``. Every decoder here is sans-IO -- ``feed(bytes) -> list of items`` with no clock and no
file or port -- so one object serves a serial port, a pty, a TCP socket, a file and a replay.

- :mod:`rfhoming.protocol.uconnect` -- the u-blox XPLR-AOA u-connectLocate AT/URC text protocol.
- :mod:`rfhoming.protocol.frames` -- rfhoming's COBS-framed binary records (RSS nodes, robot base).
"""
