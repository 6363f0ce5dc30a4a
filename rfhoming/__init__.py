"""rfhoming: radio homing for mobile robots.

The application layer: the public Python API (docs/api.md) and the command line sit here, above
the layers they wire together -- :mod:`rfhoming.protocol`, :mod:`rfhoming.firmware`,
:mod:`rfhoming.emulator`, :mod:`rfhoming.host` and :mod:`rfhoming.campaigns`. The API's names are
imported on first use, so ``import rfhoming.protocol`` stays as light as the decoders.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

from rfhoming import _links

_links.check()  # a checkout without symlinks: one line saying what to set

if TYPE_CHECKING:  # what _API loads on first use, for type checkers (tests/test_typing.py holds them equal)
    from rfhoming.api import Devices as Devices
    from rfhoming.api import Item as Item
    from rfhoming.api import Reader as Reader
    from rfhoming.api import Received as Received
    from rfhoming.api import open as open  # noqa: A004 - the API's verb
    from rfhoming.api import read as read
    from rfhoming.host.capture import CaptureWriter as CaptureWriter
    from rfhoming.host.portspec import PortSpec as PortSpec
    from rfhoming.host.portspec import PortSpecError as PortSpecError
    from rfhoming.host.portspec import parse as _parse
    from rfhoming.host.ports import PortError as PortError
    from rfhoming.protocol.errors import Error as Error
    from rfhoming.protocol.frames import FrameDecoder as FrameDecoder
    from rfhoming.protocol.uconnect import AngleEvent as AngleEvent
    from rfhoming.protocol.uconnect import UConnectDecoder as UConnectDecoder

    parse_spec = _parse

__version__: str  # read on first use (_version): the package metadata is not free


def _version() -> str:
    """The installed version, read when first asked for (``rfhoming.__version__``): the package
    metadata costs a command that never shows it about as much as the decoders do."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rfhoming")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "0+unknown"


_API = {  # public name -> the module that holds it
    "open": "rfhoming.api", "read": "rfhoming.api", "Devices": "rfhoming.api", "Received": "rfhoming.api",
    "Item": "rfhoming.api", "Reader": "rfhoming.api", "CaptureWriter": "rfhoming.host.capture",
    "parse_spec": "rfhoming.host.portspec:parse", "PortSpec": "rfhoming.host.portspec",
    "PortSpecError": "rfhoming.host.portspec", "PortError": "rfhoming.host.ports",
    "UConnectDecoder": "rfhoming.protocol.uconnect", "FrameDecoder": "rfhoming.protocol.frames",
    "AngleEvent": "rfhoming.protocol.uconnect", "Error": "rfhoming.protocol.errors",
}

__all__ = ["__version__", *_API]


if not TYPE_CHECKING:  # hidden from type checkers, so that they flag a misspelt name

    def __getattr__(name: str) -> Any:
        if name == "__version__":
            globals()["__version__"] = found = _version()
            return found
        where = _API.get(name)
        if where is None:
            raise AttributeError(f"module 'rfhoming' has no attribute {name!r}")
        module, _, attribute = where.partition(":")
        return getattr(import_module(module), attribute or name)
