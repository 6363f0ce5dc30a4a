"""Driver for any Bluetooth LE controller spoken to over HCI (a USB dongle, an nRF52840 or
ESP32 in HCI-UART mode, the computer's own adapter), as a BLE RSSI receiver.

bumble (a well-kept Bluetooth stack in Python) encodes the commands and decodes the events;
this driver does the rest: after every open it resets the controller, reads its LE features,
sets the event masks and scans -- with the extended commands where the controller has LE
Extended Advertising (``extended=auto``), the legacy ones otherwise -- and turns every legacy
or extended advertising report into the same :class:`~rfhoming.host.drivers.rss.BleRssi`
reading the rfhoming ESP32 scanner gives, timed by the host's arrival time, filtered by
address, local name, iBeacon or Eddystone content.

Where the controller is: ``serial:PATH[,BAUD]`` and ``tcp-client:HOST:PORT`` are opened as
rfhoming ports (captured and replayed like the others, H4 bytes); every other bumble
transport name (``usb:0``, ``hci-socket:0``, ...) is opened by bumble, and its packets pass
the same taps.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, NamedTuple

from bumble import hci

from rfhoming.host.drivers.common import BoundedStream, CommandFailed, Driver, scan_settings
from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.ports import Disconnected, HostPort, Port, PortError, Tap
from rfhoming.host.portspec import PortSpec, PortSpecError
from rfhoming.protocol import ad as adv
from rfhoming.protocol import h4
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.h4 import H4Splitter

log = logging.getLogger(__name__)
UNIT_MS = 0.625
EVENT_MASK = (1 << 61) | 0x00001FFFFFFFFFFF  # the spec's default, plus LE Meta events
LE_EVENT_MASK = (1 << 1) | (1 << 12)  # LE Advertising Report, LE Extended Advertising Report
RSSI_NOT_AVAILABLE = 127
HARDWARE_ERROR_EVENT = 0x10  # the controller lost its state: set it up again
CONTENT_FILTERS = {"ibeacon": adv.is_ibeacon, "eddystone": adv.is_eddystone}
DATA_STATUS_SHIFT, MORE_TO_COME, TRUNCATED = 5, 1, 2  # extended report event type bits 5-6 (7.7.65.13)
MAX_PARTIAL = 64  # advertisers with a fragment pending; the oldest is dropped beyond
MAX_AD = 1650  # the longest extended advertising data (Core v5.4 Vol 4 Part E 7.8.54)


class _Advertisement(NamedTuple):
    address: str  # 12 hex digits, MSB first
    address_type: int
    rssi_dbm: int  # 127 = not available
    extended: bool
    data: bytes


class Advertisement(_Advertisement):
    """One advertising report, as ``listen`` shows it (and as listeners get it)."""

    __slots__ = ()
    kind: ClassVar[Literal["advertisement"]] = "advertisement"


class _HciPacket(NamedTuple):
    name: str
    raw: bytes


class HciPacket(_HciPacket):
    """Any other HCI packet: bumble's name for it and its bytes (H4 indicator included)."""

    __slots__ = ()
    kind: ClassVar[Literal["hci"]] = "hci"


@dataclass(frozen=True)
class HciSetup:
    """How to scan (physical units) and which reports to keep."""

    active: bool = False
    interval_ms: float = 100.0
    window_ms: float = 100.0
    extended: str = "auto"  # auto: the extended commands if the controller has them; on; off
    filter_duplicates: bool = False  # the controller's: True keeps one report per address per scan
    addresses: frozenset[str] = field(default_factory=frozenset)  # 12 hex digits, MSB first
    name: str | None = None  # advertised local name
    content: str | None = None  # "ibeacon" or "eddystone"
    node_id: int = 0
    command_timeout: float = 2.0
    silence_timeout: float = 10.0
    """Scanning without one advertising report this long: say why that may be."""

    def __post_init__(self) -> None:
        if not 2.5 <= self.window_ms <= self.interval_ms <= 10_240:
            raise ValueError("need 2.5 ms <= window_ms <= interval_ms <= 10240 ms")
        if self.extended not in ("auto", "on", "off"):
            raise ValueError("extended is auto, on or off")
        if self.content not in (None, *CONTENT_FILTERS):
            raise ValueError(f"content filter is one of {', '.join(CONTENT_FILTERS)}")

    def keeps(self, address: str, data: bytes) -> bool:
        return ((not self.addresses or address in self.addresses)
                and (self.name is None or adv.local_name(data) == self.name)
                and (self.content is None or CONTENT_FILTERS[self.content](data)))


def address_text(address: hci.Address) -> str:
    """bumble's address (bytes LSB first) -> 12 upper-case hex digits, MSB first."""
    return bytes(address.address_bytes)[::-1].hex().upper()


def setup_from_spec(spec: PortSpec, setup: HciSetup | None = None) -> HciSetup:
    """The spec's scan settings over ``setup`` (default settings if None)."""
    setup = setup or HciSetup()
    s = spec.settings
    scanning: HciSetup = scan_settings(spec, setup, extended=s.get("extended", setup.extended),
                                         filter_duplicates=s.get("dedup", setup.filter_duplicates),
                                         addresses=frozenset([s["mac"].replace(":", "")]) if "mac" in s else setup.addresses,
                                         name=s.get("adname", setup.name), content=s.get("content", setup.content))
    return scanning


class HciDriver(Driver):
    kind = "hci"
    sets_up = True
    items = (Advertisement, HciPacket, Drop)

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> HciDriver:
        """WHERE is a bumble transport name (serial:PATH,SPEED, usb:0, tcp-client:H:P ...)."""
        if port is None:
            try:
                port = open_port(spec.where, name=spec.name, taps=taps)
            except ValueError as exc:
                raise PortSpecError(str(exc)) from None
        return cls(port, setup_from_spec(spec, options.pop("setup", None)), **options)

    def __init__(self, port: Port, setup: HciSetup = HciSetup(), *, queue_size: int = 4000,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.setup = setup
        self.splitter = H4Splitter(h4.TO_HOST)
        self.counters.update(setups=0, silent=0, reports=0, filtered=0, no_rssi=0, bad_packets=0, hardware_errors=0,
                             fragments=0, truncated=0, partial_dropped=0,
                             **{"drop.not_event": 0, "drop.malformed": 0, "drop.error": 0})
        self._partial: dict[tuple[Any, ...], tuple[Any, bytearray]] = {}  # fragments of extended reports, by advertiser
        self.extended: bool | None = None
        self._pending: tuple[int, asyncio.Future[Any]] | None = None

    def on_chunk(self, data: bytes, t_host: float) -> None:
        """Split, parse and route; whatever goes wrong with one packet is that packet's drop,
        never the end of the driver's task (which would stop the receiver for good)."""
        for item in self.splitter.feed(data):
            if not isinstance(item, bytes):
                self.emit(t_host, item)
                continue
            try:
                self._on_packet(item, t_host)
            except Exception as exc:  # noqa: BLE001 -- one bad packet must not end the driver
                self._drop("error", f"{type(exc).__name__} handling a packet: {exc}", item, t_host)

    def _on_packet(self, raw: bytes, t_host: float) -> None:
        if raw[0] != h4.EVENT:  # a scanning host opens no connection, so it expects no data
            self._drop("not_event", f"an H4 packet of type 0x{raw[0]:02x}; a receiver expects only events",
                       raw, t_host)
            return
        try:
            packet = hci.HCI_Packet.from_bytes(raw)
        except Exception as exc:  # bumble raises several types on a malformed packet  # noqa: BLE001
            self._drop("malformed", f"bumble cannot parse it: {exc}", raw, t_host)
            return
        extended = isinstance(packet, hci.HCI_LE_Extended_Advertising_Report_Event)
        if isinstance(packet, (hci.HCI_LE_Extended_Advertising_Report_Event, hci.HCI_LE_Advertising_Report_Event)):
            for report in packet.reports:
                whole: tuple[Any, bytes] | None = self._reassemble(report) if extended else (report, bytes(report.data))
                if whole is not None:
                    self._report(*whole, extended, t_host)
            return
        self.emit(t_host, HciPacket(packet.name, raw))
        if isinstance(packet, (hci.HCI_Command_Complete_Event, hci.HCI_Command_Status_Event)):
            if self._pending is not None and packet.command_opcode == self._pending[0] and not self._pending[1].done():
                self._pending[1].set_result(packet)
        elif isinstance(packet, hci.HCI_Event) and packet.event_code == HARDWARE_ERROR_EVENT:
            self.counters["hardware_errors"] += 1
            log.warning("%s: controller hardware error; setting it up again", self.port.name)
            self._needs_setup.set()

    def _drop(self, reason: str, detail: str, raw: bytes, t_host: float) -> None:
        """A packet the driver cannot use: counted (``bad_packets`` and ``drop.<reason>``),
        logged the first time for each reason, shown to the listeners."""
        key = "drop." + reason
        if not self.counters[key]:
            log.warning("%s: dropping an HCI packet (%s); counting such drops as %s", self.port.name, detail, key)
        self.counters[key] += 1
        self.counters["bad_packets"] += 1
        self.emit(t_host, Drop(reason, detail, raw[:64]))

    def _reassemble(self, report: Any) -> tuple[Any, bytes] | None:
        """An extended report's fragments joined by their data status: (first fragment, data)
        once complete or truncated, None while more is to come."""
        status = (report.event_type >> DATA_STATUS_SHIFT) & 0x3
        key = (bytes(report.address), report.address_type, report.advertising_sid,
               report.event_type & 0x1F)
        first, data = self._partial.pop(key, (report, bytearray()))
        data += bytes(report.data)
        del data[MAX_AD:]
        if status == MORE_TO_COME:
            self.counters["fragments"] += 1
            if len(self._partial) >= MAX_PARTIAL:
                self._partial.pop(next(iter(self._partial)))
                self.counters["partial_dropped"] += 1
            self._partial[key] = (first, data)
            return None
        if status == TRUNCATED:
            self.counters["truncated"] += 1
        return first, bytes(data)

    def _report(self, report: Any, data: bytes, extended: bool, t_host: float) -> None:
        self.counters["reports"] += 1
        self.last_item = time.monotonic()
        address = address_text(report.address)
        self.emit(t_host, Advertisement(address, report.address_type, report.rssi, extended, data))
        if report.rssi == RSSI_NOT_AVAILABLE:
            self.counters["no_rssi"] += 1
        elif not self.setup.keeps(address, data):
            self.counters["filtered"] += 1
        else:
            self.out.put(BleRssi(t_host, self.setup.node_id, address, report.rssi))

    async def command(self, command: hci.HCI_Command) -> Any:
        """Send one command; its Command Complete return parameters (CommandFailed otherwise)."""
        future = asyncio.get_running_loop().create_future()
        self._pending = (command.op_code, future)
        self.port.write(bytes(command))
        try:
            async with asyncio.timeout(self.setup.command_timeout):
                event = await future
        except TimeoutError:
            raise CommandFailed(f"{command.name}: no answer in {self.setup.command_timeout:g} s; "
                                f"{self.silent_hint()}") from None
        finally:
            self._pending = None
        params = getattr(event, "return_parameters", event)
        status = getattr(params, "status", hci.HCI_SUCCESS)
        if status != hci.HCI_SUCCESS:
            raise CommandFailed(f"{command.name} failed: {hci.HCI_Constant.error_name(status)}")
        return params

    async def session(self) -> None:
        """Set the controller up after every open and every reset; say so when nothing arrives."""
        quiet = asyncio.create_task(self.watch_quiet(self.setup.silence_timeout, "advertising report", self._quiet_hint))
        try:
            await self.keep_set_up()
        finally:
            quiet.cancel()

    def silent_hint(self) -> str:
        return getattr(self.port, "firmware_hint", None) or "is this an HCI controller (H4) at this baud rate?"

    def _quiet_hint(self) -> str:
        return getattr(self.port, "firmware_hint", None) or (
            "no Bluetooth LE advertiser in range (mac=, adname= and content= filter on the host: they do not "
            "silence the controller); a USB dongle whose vendor firmware was not loaded may scan without hearing "
            "(docs/hardware.md)")

    async def _set_up(self) -> None:
        s = self.setup
        self.state = "setting_up"
        await self.command(hci.HCI_Reset_Command())
        features = await self.command(hci.HCI_LE_Read_Local_Supported_Features_Command())
        has_extended = bool(int.from_bytes(features.le_features, "little") & hci.LeFeatureMask.LE_EXTENDED_ADVERTISING)
        if s.extended == "on" and not has_extended:
            raise CommandFailed("extended=on, but this controller has no LE Extended Advertising")
        self.extended = has_extended and s.extended != "off"
        await self.command(hci.HCI_Set_Event_Mask_Command(event_mask=EVENT_MASK.to_bytes(8, "little")))
        await self.command(hci.HCI_LE_Set_Event_Mask_Command(le_event_mask=LE_EVENT_MASK.to_bytes(8, "little")))
        interval, window, kind = round(s.interval_ms / UNIT_MS), round(s.window_ms / UNIT_MS), int(s.active)
        if self.extended:
            await self.command(hci.HCI_LE_Set_Extended_Scan_Parameters_Command(
                own_address_type=0, scanning_filter_policy=0, scanning_phys=1,  # LE 1M
                scan_types=[kind], scan_intervals=[interval], scan_windows=[window]))
            await self.command(hci.HCI_LE_Set_Extended_Scan_Enable_Command(
                enable=1, filter_duplicates=int(s.filter_duplicates), duration=0, period=0))
        else:
            await self.command(hci.HCI_LE_Set_Scan_Parameters_Command(
                le_scan_type=kind, le_scan_interval=interval, le_scan_window=window,
                own_address_type=0, scanning_filter_policy=0))
            await self.command(hci.HCI_LE_Set_Scan_Enable_Command(
                le_scan_enable=1, filter_duplicates=int(s.filter_duplicates)))
        self.counters["setups"] += 1
        self.state, self.problem, self.streaming_at = "streaming", None, time.monotonic()

    def health(self) -> dict[str, Any]:
        return {**super().health(), "extended": self.extended, "queued": len(self.out),
                "queue_dropped": self.out.dropped, "problem": self.problem,
                **{f"h4.{k}": v for k, v in self.splitter.counters.items()}}


def explain_open_error(spec: str, exc: BaseException) -> str:
    """What bumble (libusb, via usb1) raised when opening ``spec`` -> one line that says what to do."""
    text = str(exc)
    if "LIBUSB_ERROR_ACCESS" in text:
        return (f"no permission to open the USB Bluetooth dongle {spec} ({text}): give your user access with a udev "
                "rule (docs/hardware.md, USB Bluetooth dongles), or try once with sudo")
    if "LIBUSB_ERROR_BUSY" in text or "LIBUSB_ERROR_OTHER" in text:
        return (f"the USB Bluetooth dongle {spec} is held by another driver ({text}): usually the kernel's btusb; "
                "release it (sudo rmmod btusb, or unbind the one dongle) or use hci-socket:0 instead "
                "(docs/hardware.md, USB Bluetooth dongles)")
    if "LIBUSB_ERROR_NO_DEVICE" in text or "LIBUSB_ERROR_NOT_FOUND" in text or "device not found" in text:
        return (f"no USB Bluetooth dongle at {spec} ({text}): is it plugged in? `bumble-usb-probe` lists the ones "
                "bumble sees")
    return f"bumble could not open {spec}: {text}"


VENDOR_FIRMWARE = {
    "rtk": ("Realtek", "BUMBLE_RTK_FIRMWARE_DIR", "/lib/firmware/rtl_bt", "bumble-rtk-fw-download", "bumble-rtk-util"),
    "intel": ("Intel", "BUMBLE_INTEL_FIRMWARE_DIR", "/lib/firmware/intel", "bumble-intel-fw-download",
              "bumble-intel-util"),
}


def firmware_hint(spec: str, vendor_id: int | None, product_id: int | None) -> str | None:
    """For a USB dongle whose chip runs only once its vendor firmware is loaded (Realtek, Intel:
    bumble's driver tables), how to load it; None for any other."""
    from bumble.drivers import intel, rtk

    ids = (vendor_id, product_id)
    vendor = "rtk" if ids in rtk.RTK_USB_PRODUCTS else "intel" if ids in intel.INTEL_USB_PRODUCTS else None
    if vendor is None:
        return None
    name, env, linux_dir, download, util = VENDOR_FIRMWARE[vendor]
    return (f"{spec} is a {name} dongle ({vendor_id:04X}:{product_id:04X}), which needs its vendor firmware loaded "
            f"before it scans: `{download}` fetches it (bumble looks in ${env}, its data folder and {linux_dir}), "
            f"then `{util} load {spec}` loads it (docs/hardware.md)")


class BumbleTransportPort(HostPort):
    """A controller bumble opens itself (``usb:0``, ``hci-socket:0`` ...), presented as a port:
    each HCI packet it delivers is one inbound chunk (H4 indicator included), and the
    driver's writes, each one whole command packet, go to the controller."""

    def __init__(self, spec: str, *, name: str | None = None, taps: list[Tap] | None = None) -> None:
        super().__init__(spec, name=name, taps=taps)
        self._bumble: Any = None
        self.firmware_hint: str | None = None

    async def open(self) -> None:
        from bumble.transport import open_transport

        try:
            self._bumble = await open_transport(self.spec)
        except Exception as exc:  # bumble raises per-transport types  # noqa: BLE001
            raise PortError(explain_open_error(self.spec, exc)) from None
        self._transport = self._bumble  # is_open and _lost() look at it
        metadata = getattr(self._bumble.source, "metadata", None) or {}
        self.firmware_hint = firmware_hint(self.spec, metadata.get("vendor_id"), metadata.get("product_id"))
        if self.firmware_hint:
            log.warning("%s", self.firmware_hint)
        self._gone = asyncio.Event()
        self._queue = asyncio.Queue()
        self._backlog = 0
        self._bumble.source.set_packet_sink(self)
        self.counters["opens"] += 1

    def on_packet(self, packet: bytes) -> None:
        self._received(bytes(packet))

    def write(self, data: bytes) -> None:
        if self._bumble is None:
            raise Disconnected(f"{self.name} is not open")
        now = self.clock()
        for tap in self.taps:
            tap(self.name, "out", now, data)
        self.counters["bytes_out"] += len(data)
        self._bumble.sink.on_packet(data)

    async def close(self) -> None:
        transport, self._bumble, self._transport = self._bumble, None, None
        if transport is not None:
            await transport.close()
            self._queue.put_nowait(None)


def open_port(where: str, *, name: str | None = None, taps: list[Tap] | None = None) -> HostPort:
    """The port for a bumble-style transport name (see the module docstring)."""
    if where.startswith("serial:") or where.startswith("/"):
        path, *options = where.removeprefix("serial:").split(",")
        baud, rtscts = 1_000_000, False  # bumble's defaults
        for option in options:
            if option.isdigit():
                baud = int(option)
            elif option == "rtscts":
                rtscts = True
            else:
                raise ValueError(f"{where}: after the path come SPEED and rtscts, e.g. serial:/dev/ttyACM0,1000000,rtscts")
        return HostPort(path, baud=baud, rtscts=rtscts, name=name or path, taps=taps)
    if where.startswith("tcp-client:"):
        host_port = where.removeprefix("tcp-client:")
        return HostPort(f"socket://{host_port}", name=name or where, taps=taps)
    return BumbleTransportPort(where, name=name or where, taps=taps)
