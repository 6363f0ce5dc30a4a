"""rfhoming: radio homing for mobile robots.

The application layer: the public Python API (docs/api.md) and the command line sit here, above
the layers they wire together -- :mod:`rfhoming.protocol`, :mod:`rfhoming.firmware`,
:mod:`rfhoming.emulator`, :mod:`rfhoming.host` and :mod:`rfhoming.campaigns`. The API's names are
imported on first use, so ``import rfhoming.protocol`` stays as light as the decoders.
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("rfhoming")
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"

_API = {  # public name -> the module that holds it
    "open": "rfhoming.api", "read": "rfhoming.api", "Devices": "rfhoming.api", "Received": "rfhoming.api",
    "parse_spec": "rfhoming.host.portspec:parse", "PortSpec": "rfhoming.host.portspec",
    "PortSpecError": "rfhoming.host.portspec", "PortError": "rfhoming.host.ports",
    "UConnectDecoder": "rfhoming.protocol.uconnect", "FrameDecoder": "rfhoming.protocol.frames",
    "AngleEvent": "rfhoming.protocol.uconnect", "Error": "rfhoming.protocol.errors",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    where = _API.get(name)
    if where is None:
        raise AttributeError(f"module 'rfhoming' has no attribute {name!r}")
    module, _, attribute = where.partition(":")
    return getattr(import_module(module), attribute or name)
