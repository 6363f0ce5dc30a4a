"""The device table: every device kind's facts in one record, as gpsd keeps its drivers.

Each layer reads what it needs from here -- the port spec's kinds and each kind's settings
with their parsers (host/portspec.py, protocol/settings.py), the driver to build and the kinds
to sniff (host/session.py), the USB bridge ``auto`` looks for (host/discovery.py), the set-up
deadline (host/supervise.py), the roles a kind may fill in a homing run (host/homing/assembly.py),
the capture's link type and the recorded kind (host/capture.py, host/session.py), the emulator's
boards, their firmware models and the runners that build them (emulator/runtime.py). What a
kind does -- its run options, its sniffing test, the items it yields -- is its driver's
(host/drivers/common.py ``Driver``; host/drivers/driver_proto.py is the template).

The table lives in the protocol layer, which every other layer may import; what belongs to a
higher layer (a driver, a firmware model, a runner) is named by its ``module:attribute`` path
and loaded by that layer with :func:`load`.
``tests/test_devices.py`` walks the table and checks every record is complete.

Old spellings (``ublox-aoa``, ``rss``, ...) are accepted as aliases with a one-line notice;
docs/architecture.md, "Adding a device", is the checklist for a new kind.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from rfhoming.protocol import pcapng
from rfhoming.protocol import settings as s
from rfhoming.protocol.errors import Error
from rfhoming.protocol.settings import Parser

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WireProtocol:
    """How a device kind's bytes look on the wire, and the sans-IO decoder that reads them."""

    name: str
    title: str
    decoder: str  # module:class of its decoder (feed(bytes) -> items)
    linktype: int  # the pcapng interface's link type (docs/protocol.md §5)
    aliases: tuple[str, ...] = ()


PROTOCOLS: dict[str, WireProtocol] = {p.name: p for p in (
    WireProtocol("uconnect", "u-connectLocate AT commands and +UUDF events (text)",
                 "rfhoming.protocol.uconnect:UConnectDecoder", pcapng.LINKTYPE_UCONNECT, ("ublox-aoa",)),
    WireProtocol("frames", "rfhoming's COBS-framed binary records (nodes and the robot base)",
                 "rfhoming.protocol.frames:FrameDecoder", pcapng.LINKTYPE_FRAMES, ("rss",)),
    WireProtocol("esp-at", "Espressif ESP-AT commands and +BLESCAN reports (text)",
                 "rfhoming.protocol.espat:EspAtDecoder", pcapng.LINKTYPE_ESP_AT),
    WireProtocol("h4", "Bluetooth HCI over UART (H4) packets",
                 "rfhoming.protocol.h4:H4Splitter", pcapng.LINKTYPE_H4_STREAM, ("hci",)),
    WireProtocol("ros2", "ROS 2 messages over DDS: one sample record (topic, type, CDR) per packet",
                 "rfhoming.protocol.ros2:SampleDecoder", pcapng.LINKTYPE_ROS2_SAMPLES),
    WireProtocol("mavlink", "MAVLink 2 (and 1) packets, as each datagram or read carried them",
                 "rfhoming.protocol.mavlink:MavlinkDecoder", pcapng.LINKTYPE_MAVLINK),
)}


@dataclass(frozen=True)
class Board:
    """One emulated board of a kind: the name scenarios give as ``type``, and its firmware model."""

    name: str
    firmware: str  # module:class in rfhoming.firmware
    runner: str  # module:class of its emulator runner (rfhoming.emulator), built by its ``build`` classmethod
    radio: str | None = None  # its RSSI's table in a radio profile, ``[rssi.NAME]`` (protocol/rssi_profile.py)


@dataclass(frozen=True)
class Reports:
    """What a kind's readings carry (``rfhoming devices --kinds``): a new AoA board's record says
    which azimuths it reports, whether elevation and RSSI, and how often."""

    readings: str  # what its driver puts out, in words
    azimuth_deg: tuple[float, float] | None = None  # an AoA board's azimuths (degrees, REP 103)
    elevation: bool = False
    rssi: bool = False
    rate: str = ""  # how often, with its source


@dataclass(frozen=True)
class Role:
    """A place a device takes in a homing run: its command-line option and the kind it defaults to."""

    name: str
    title: str
    default_kind: str


ROLES: dict[str, Role] = {r.name: r for r in (
    Role("aoa", "the XPLR-AOA on the robot (S0) or at the dock (S1)", "xplr-aoa"),
    Role("rss", "the four-dish AT86RF212 node (S2)", "rss-node"),
    Role("ble", "the BLE RSSI receiver (S3)", "rss-node"),
    Role("anchor", "a fixed XPLR-AOA anchor of a site", "xplr-aoa"),
    Role("base", "the robot base: velocity commands out, odometry and scans in", "base"),
)}


@dataclass(frozen=True)
class UsbBridge:
    """A USB-serial bridge a kind sits behind, for ``auto`` (host/discovery.py): its name, and
    each USB vendor id it enumerates with and what that vendor's chip is."""

    name: str
    vendors: tuple[tuple[int, str], ...]


FTDI = 0x0403
USB_XPLR_AOA = UsbBridge("xplr-aoa", ((FTDI, "FTDI USB-UART (the XPLR-AOA's bridge)"),))
USB_ESP32 = UsbBridge("esp32", ((0x10C4, "Silicon Labs CP210x (common on ESP32 boards)"),
                                (0x1A86, "WCH CH340/CH9102 (common on ESP32 boards)"),
                                (0x303A, "Espressif native USB (ESP32-S3/C3)")))
USB_STM32 = UsbBridge("stm32", ((0x0483, "STMicroelectronics virtual COM port (STM32 + AT86RF212 node)"),))


@dataclass(frozen=True)
class DeviceKind:
    """One record of the device table: the facts the layers read (docs/architecture.md lists
    each field and its readers)."""

    name: str  # the canonical name: port spec kind, capture kind, driver kind
    title: str
    protocol: str  # a key of PROTOCOLS
    settings: Mapping[str, Parser] = field(hash=False)  # port spec key -> its parser (protocol/settings.py)
    driver: str  # module:class of its host driver
    boards: tuple[Board, ...]  # the emulator's boards of this kind
    roles: tuple[str, ...]  # keys of ROLES
    setup_timeout_s: float  # how long it may take to open and be set up
    usb: UsbBridge | None  # the USB bridge host/discovery.py looks for, for ``auto`` (None: no auto)
    sniff: int = 0  # 0: never sniffed; else it can be told from what a port says (a spec without KIND:) by
    # its driver's ``speaks``, tried in this order (lowest first: the stricter test, a checksum before a text line)
    rtscts: bool = False  # RTS/CTS flow control by default (flow=auto)
    commanded: bool = False  # its writes come from the homing loop, not its driver (a replay without
    # the loop does not wait for them)
    extra: str | None = None  # the pip extra its driver needs
    aliases: tuple[str, ...] = ()
    emulated_as: str | None = None  # how the emulator serves a kind that is no board of a scenario
    default_where: str | None = None  # a kind reached by settings, not a path: WHERE when none is given
    reports: Reports = Reports("")  # what its readings carry
    brakes: bool = False  # a base with a brake mode (emergency deceleration) the loop can switch on; a base
    # without one sheds speed at its normal deceleration, so the loop bounds its speed (host/homing/loop.py)

    @property
    def wire(self) -> WireProtocol:
        return PROTOCOLS[self.protocol]


EMULATOR = "rfhoming.emulator.devices"

KINDS: dict[str, DeviceKind] = {k.name: k for k in (
    DeviceKind("xplr-aoa", "u-blox XPLR-AOA direction-finding kit (u-connectLocate)", "uconnect",
               {**s.SERIAL, "tags": s.tags}, "rfhoming.host.drivers.aoa:AoaDriver",
               (Board("xplr-aoa", "rfhoming.firmware.xplr_aoa:XplrAoaFirmware", f"{EMULATOR}:AoaRunner", "xplr"),),
               ("aoa", "anchor"), 20.0, USB_XPLR_AOA, sniff=20, rtscts=True, aliases=("ublox-aoa",),
               reports=Reports("bearings (+UUDF)", (-90.0, 90.0), elevation=True, rssi=True,
                               rate="one per tag advertisement: 20 ms (1.x tags, assumed) or 50-1000 ms (2.x); "
                                    "at most about 180 a second on a 115200 Bd link (docs/hardware.md, section 6)")),
    DeviceKind("rss-node", "rfhoming node firmware: ESP32 BLE scanner or STM32 + AT86RF212 four-dish node",
               "frames", s.SERIAL, "rfhoming.host.drivers.rss:RssDriver",
               (Board("esp32", "rfhoming.firmware.esp32_scanner:Esp32ScannerFirmware", f"{EMULATOR}:Esp32Runner", "ble"),
                Board("at86rf212", "rfhoming.firmware.at86rf212_node:At86rf212NodeFirmware", f"{EMULATOR}:RssRunner", "subghz")),
               ("rss", "ble"), 5.0, USB_ESP32, sniff=10, aliases=("rss",),
               reports=Reports("BLE RSSI (ESP32) or four dishes' sub-GHz RSSI (AT86RF212)", rssi=True,
                               rate="one per advertisement heard, or per antenna set")),
    DeviceKind("esp-at", "ESP32 with Espressif's ESP-AT firmware (BLE scan)", "esp-at", {**s.SERIAL, **s.SCAN},
               "rfhoming.host.drivers.espat:EspAtDriver",
               (Board("esp-at", "rfhoming.firmware.esp_at:EspAtFirmware", f"{EMULATOR}:EspAtRunner", "ble"),),
               ("ble",), 5.0, USB_ESP32,
               reports=Reports("BLE RSSI (+BLESCAN)", rssi=True, rate="one per advertisement heard in a scan window")),
    DeviceKind("hci", "Bluetooth controller through a bumble transport (HCI advertising reports)", "h4",
               {"name": s.name, "timeout": s.seconds, **s.SCAN, **s.HCI_SCAN}, "rfhoming.host.drivers.hci:HciDriver",
               (Board("hci", "rfhoming.firmware.hci_controller:HciControllerFirmware", f"{EMULATOR}:HciRunner", "ble"),),
               ("ble",), 5.0, None, extra="hci",
               reports=Reports("BLE RSSI (HCI advertising reports)", rssi=True,
                               rate="one per advertisement heard in a scan window")),
    DeviceKind("base", "rfhoming robot base (velocity commands, odometry, range scans)", "frames", s.SERIAL,
               "rfhoming.host.drivers.robot_base:BaseDriver",
               (Board("base", "rfhoming.firmware.robot_base:RobotBaseFirmware", f"{EMULATOR}:BaseRunner"),),
               ("base",), 5.0, USB_STM32, commanded=True, aliases=("robot-base",), brakes=True,
               reports=Reports("odometry and range scans; takes velocity commands")),
    DeviceKind("ros2", "a ROS 2 robot base over DDS (nav_msgs/Odometry, sensor_msgs/LaserScan in; "
               "geometry_msgs/Twist out); WHERE is its namespace", "ros2",
               {"name": s.name, "timeout": s.seconds, **s.ROS2},
               "rfhoming.host.drivers.ros2_base:Ros2BaseDriver", (), ("base",), 10.0, None,
               commanded=True, extra="ros2", emulated_as="rfhoming emulate SCENARIO --robot ros2", default_where="/",
               reports=Reports("odometry and laser scans; takes velocity commands")),
    DeviceKind("mavlink", "a MAVLink vehicle (ArduPilot Rover or Copter, PX4) in GUIDED/OFFBOARD; WHERE is a "
               "pymavlink connection string (udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, a serial device)",
               "mavlink", {"name": s.name, "timeout": s.seconds, "baud": s.baud, **s.MAVLINK},
               "rfhoming.host.drivers.mavlink_base:MavlinkBaseDriver", (), ("base",), 10.0, None,
               commanded=True, extra="mavlink",
               emulated_as="rfhoming emulate SCENARIO --robot mavlink",  # brakes: no (docs/protocol.md)
               reports=Reports("the vehicle's position and attitude; takes guided setpoints")),
)}

BOARDS: dict[str, tuple[DeviceKind, Board]] = {b.name: (k, b) for k in KINDS.values() for b in k.boards}
"""Emulated board name (a scenario's ``type``) -> its kind and board record."""

_ALIASES = {a: k.name for k in KINDS.values() for a in k.aliases}
_PROTOCOL_ALIASES = {a: p.name for p in PROTOCOLS.values() for a in p.aliases}
_told: set[str] = set()


class UnknownKind(Error, ValueError):
    """A device kind or protocol name that is in no record; the message lists the names."""


def _canonical(name: str, names: dict[str, Any], aliases: dict[str, str], what: str, notice: bool) -> str:
    if name in names:
        return name
    if name in aliases:
        if notice and name not in _told:
            _told.add(name)
            log.warning("%s %r is now called %r; the old name still works", what, name, aliases[name])
        return aliases[name]
    raise UnknownKind(f"unknown {what} {name!r}; the {what}s are {', '.join(names)}")


def kind(name: str, *, notice: bool = True) -> DeviceKind:
    """The record for a kind's canonical name or alias (an alias logs a one-line notice once)."""
    return KINDS[_canonical(name, KINDS, _ALIASES, "device kind", notice)]


def protocol(name: str, *, notice: bool = True) -> WireProtocol:
    return PROTOCOLS[_canonical(name, PROTOCOLS, _PROTOCOL_ALIASES, "protocol", notice)]


def is_kind(name: str) -> bool:
    return name in KINDS or name in _ALIASES


def recorded_kind(fields: dict[str, str], linktype: int | None) -> DeviceKind:
    """The kind of a capture's interface: its ``kind=`` (canonical since captures record it,
    or an older capture's driver or board name), else the one kind of its link type."""
    named = fields.get("kind")
    if named is not None:
        if is_kind(named):
            return kind(named, notice=False)
        if named in BOARDS:
            return BOARDS[named][0]
        if named == "stm32":
            return KINDS["rss-node"]
    by_link = [k for k in KINDS.values() if k.wire.linktype == linktype]
    if not by_link:
        raise UnknownKind(f"link type {linktype} is none of rfhoming's devices (kind={named!r})")
    return by_link[0]  # frames: an older capture with no kind= is a node's; the base always said kind=base


def by_linktype(linktype: int) -> WireProtocol | None:
    """The protocol of a pcapng interface's link type (None: not one of ours)."""
    return next((p for p in PROTOCOLS.values() if p.linktype == linktype), None)


def load(path: str) -> Any:
    """``module:attribute`` -> the object (a driver or firmware class of a higher layer)."""
    module, _, attribute = path.partition(":")
    return getattr(importlib.import_module(module), attribute)


def with_role(role: str) -> list[DeviceKind]:
    return [k for k in KINDS.values() if role in k.roles]


