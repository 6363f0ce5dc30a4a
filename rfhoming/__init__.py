"""rfhoming: radio homing for mobile robots.

The application layer: the public Python API (docs/api.md) and the command line sit here, above
the layers they wire together -- :mod:`rfhoming.protocol`, :mod:`rfhoming.firmware`,
:mod:`rfhoming.emulator`, :mod:`rfhoming.host` and :mod:`rfhoming.campaigns`.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("rfhoming")
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
