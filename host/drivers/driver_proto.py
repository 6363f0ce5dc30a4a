"""A template for a new device kind, in the spirit of gpsd's ``driver_proto.c``: copy this file
to ``host/drivers/<yours>.py``, rename, and fill in every hook; then copy :data:`RECORD` into
``KINDS`` in protocol/devices.py. docs/architecture.md, "Adding a device", is the checklist of
every other place a kind touches; tests/test_new_kind.py adds this kind from this file alone.

The example is a working kind: ``proto-node``, a BLE RSSI receiver on an ESP32 that speaks
rfhoming's frames (protocol/frames) and reports only advertisements at least ``min_rssi`` strong.
Its emulated board runs the ESP32 scanner's firmware model, so it needs no firmware or runner
of its own. A kind with a new wire protocol also needs a sans-IO decoder in protocol/ and a
``WireProtocol`` in ``PROTOCOLS``; a board with a new firmware model needs the model in
firmware_py/ and a runner in emulator/devices.py (a ``DeviceRunner`` with ``board`` and ``build``).
"""

from __future__ import annotations

from typing import Any

from rfhoming.host.drivers.common import BoundedStream, Driver, Wiring, serial_port
from rfhoming.host.drivers.rss import FRAME_ITEMS, BleRssi
from rfhoming.host.ports import HostPort, Tap
from rfhoming.host.portspec import PortSpec
from rfhoming.protocol import settings
from rfhoming.protocol.devices import USB_ESP32, Board, DeviceKind
from rfhoming.protocol.frames import AdvReport, FrameDecoder


def min_rssi(text: str) -> int:
    """The kind's own setting: a parser from text, whose ValueError says what is allowed (the
    port spec's one-line error quotes it). Shared ones are in protocol/settings.py."""
    if not text.lstrip("-").isdigit() or not -127 <= int(text) <= 20:
        raise ValueError("dBm from -127 to 20, e.g. min_rssi=-90")
    return int(text)


RECORD = DeviceKind(
    "proto-node",  # its name: port spec KIND, a capture's kind=, the driver's ``kind``
    "template: an ESP32 BLE receiver speaking rfhoming's frames (host/drivers/driver_proto.py)",
    "frames",  # its wire protocol: a key of PROTOCOLS (decoder, pcapng link type)
    {**settings.SERIAL, "min_rssi": min_rssi},  # the port spec settings it takes, each with its parser
    "rfhoming.host.drivers.driver_proto:ProtoDriver",  # its driver, loaded when a port of it is opened
    (Board("proto-node", "rfhoming.firmware.esp32_scanner:Esp32ScannerFirmware",  # a scenario's type =
           "rfhoming.emulator.devices:Esp32Runner"),),  # its firmware model and the runner that builds it
    ("ble",),  # the roles it can fill in a homing run (ROLES)
    5.0,  # seconds it may take to open and be set up before the run gives up on it
    USB_ESP32,  # the USB bridge ``auto`` looks for (None: it cannot be found by auto)
    sniff=5,  # tried before rss-node (10) when a spec has no KIND: its test (one AdvReport) is stricter
)
"""The template's record; a real kind's lives in protocol/devices.py KINDS. Fields left at their
defaults here: ``rtscts`` (flow=auto turns RTS/CTS on), ``commanded`` (the homing loop writes to
it: a robot base), ``extra`` (the pip extra its driver needs), ``aliases``, ``emulated_as`` (how
the emulator serves a kind that is no scenario board), ``default_where``, ``brakes`` (a base with
a brake mode)."""


class ProtoDriver(Driver):
    """Every hook a kind fills; the base class (host/drivers/common.py) does the rest: the
    port kept open with back-off, chunks read and timed, health and counters."""

    kind = "proto-node"  # = RECORD.name
    sets_up = False  # True: ready only once set-up commands succeeded (then extend ``session``)
    items = FRAME_ITEMS  # every type it shows listeners: each must be in rfhoming.api.Item
    poke = b""  # what to say to a silent port while sniffing (the XPLR-AOA's is AT)

    @classmethod
    def speaks(cls, data: bytes) -> bool:
        """Sniffing (RECORD.sniff > 0): whether bytes from a port of unknown kind are this kind's."""
        return any(isinstance(r, AdvReport) for r in FrameDecoder().feed(data))

    @classmethod
    def options(cls, wiring: Wiring) -> dict[str, Any]:
        """The constructor options it takes from a homing run (wiring.config, wiring.role) or a
        listen; none here."""
        return {}

    @classmethod
    def describe_spec(cls, spec: PortSpec) -> dict[str, str]:
        """What a capture's interface records of its spec for a replay; here the threshold."""
        return {"min_rssi": str(spec.settings["min_rssi"])} if "min_rssi" in spec.settings else {}

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> Driver:
        """The spec's own settings into constructor options; ``port``: one already made (a replay)."""
        threshold = spec.settings.get("min_rssi", -127)
        return cls(port or serial_port(spec, taps), min_rssi=threshold, **options)

    def __init__(self, port: HostPort, *, min_rssi: int = -127, reconnect: bool = True,
                 out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=1000)
        self.decoder = FrameDecoder()  # sans-IO: bytes in, items out, drops counted
        self.min_rssi = min_rssi
        self.counters.update(weak=0)

    def on_chunk(self, data: bytes, t_host: float) -> None:
        """Decode; show every item to the listeners (capture, MCAP, listen); put the readings a
        homing run uses on ``self.out``."""
        for record in self.decoder.feed(data):
            self.emit(t_host, record)
            if not isinstance(record, AdvReport) or record.rssi_dbm == 127:  # 127: no RSSI
                continue
            if record.rssi_dbm < self.min_rssi:
                self.counters["weak"] += 1
                continue
            self.out.put(BleRssi(t_host, record.node_id, record.addr[::-1].hex().upper(), record.rssi_dbm))

    def sent(self, data: bytes) -> list[Any]:
        """What the host wrote to it, decoded, for an export (a base's commands); none here."""
        return []
