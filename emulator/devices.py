"""Adapters that connect each firmware model to the world and to its link.

A device runner turns world geometry into what its radio or motors would sense (through the
channel models), feeds its firmware, and pumps the firmware's bytes through the link's faults.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Iterator, Mapping
from typing import Any, NamedTuple

import numpy as np

from rfhoming.emulator import draws
from rfhoming.emulator.aoa_error import MeasuredAoa
from rfhoming.emulator.faults import ByteFaults, scramble
from rfhoming.emulator.links import Link, TcpLink
from rfhoming.emulator.measured_rssi import channel
from rfhoming.emulator.radio import (
    AoaModel,
    PathLossModel,
    RadioChannel,
    idealised_rssi,
    measure_azimuth,
    power_sum_dbm,
    seen_azimuth,
)
from rfhoming.emulator.scenario import Scenario, ScenarioError
from rfhoming.emulator.world import Target, World
from rfhoming.firmware.at86rf212_node import At86rf212NodeFirmware
from rfhoming.firmware.esp32_scanner import Esp32ScannerFirmware, ScanConfig
from rfhoming.firmware.esp_at import EspAtFirmware
from rfhoming.firmware.robot_base import RobotBaseFirmware, Slip
from rfhoming.firmware.xplr_aoa import C209_NAMESPACE, Advertisement, XplrAoaFirmware
from rfhoming.protocol import devices
from rfhoming.protocol.rssi_profile import RssiProfile
from rfhoming.protocol.uconnect import Dialect

BOARD_HEIGHT_M = 0.2
DEFAULT_BAUD = 115200


class DeviceRunner:
    """One device: firmware + link + faults. Subclasses sense the world in :meth:`step`."""

    board = "device"  # its name in the device table's boards (rfhoming.protocol.devices.BOARDS)

    def __init__(self, name: str, make_firmware: Callable[[], Any], link: Link, faults: ByteFaults,
                 rng: np.random.Generator) -> None:
        self.name = name
        self.make_firmware = make_firmware
        self.firmware = make_firmware()
        self.link = link
        self.faults = faults
        self.rng = rng
        self.forced_baud: int | None = None
        self.baud = DEFAULT_BAUD  # the UART rate the device was set to (scenario option ``baud``)
        link.on_receive = self.on_host_bytes

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        """The runner of a scenario's device of this board (the device table's ``Board.runner``
        names the class); ``k``: its place among the scenario's devices, ``options``: its table's."""
        raise NotImplementedError(f"{cls.__name__} is no board's runner")

    def describe(self) -> dict[str, Any]:
        """What ``rfhoming emulate`` prints of it: its board, the device kind a host names it
        by in a port spec, its wire protocol, and where its link is."""
        record = devices.BOARDS[self.board][0]
        return {"device": self.name, "type": self.board, "kind": record.name, "protocol": record.protocol,
                **self.link.describe()}

    def device_baud(self) -> int:
        return self.forced_baud or self.baud

    def mismatched(self) -> bool:
        host = self.link.host_baud()
        return host is not None and host != self.device_baud()

    def on_host_bytes(self, data: bytes) -> None:
        data = self.faults.apply(data)
        if self.mismatched():
            data = scramble(data, self.rng)
        self.firmware.receive(data)

    def pump(self, t: float) -> None:
        data = self.firmware.read() + self.faults.bursts(t)
        if not data:
            return
        data = self.faults.apply(data)
        if self.mismatched():
            data = scramble(data, self.rng)
        self.link.send(data)

    def step(self, world: World, t0: float, t1: float) -> None:
        self.firmware.tick(int(t1 * 1e6))

    offset = (0.0, 0.0)
    """Where the device sits on the robot (m, x ahead, y left: REP 103)."""
    height: float | None = None
    """Its height above ground (a copter's receivers): distances in 3-D; None: in the plane."""

    def mounted(self, options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        """Its place on the robot: the device's ``offset = [x, y]`` and the robot's ``height``."""
        self.offset = _point(options.get("offset", (0.0, 0.0)))
        self.height = scenario.robot_height
        return self

    def antenna(self, world: World) -> tuple[float, float]:
        """Where it is in the world: on the robot at its ``offset``."""
        r = world.robot
        if self.offset == (0.0, 0.0):
            return r.x, r.y
        c, s = math.cos(r.theta), math.sin(r.theta)
        return r.x + c * self.offset[0] - s * self.offset[1], r.y + s * self.offset[0] + c * self.offset[1]

    def transmissions(self, world: World, kind: str, t0: float, t1: float) -> Iterator[tuple[Target, float, tuple[float, float], float, int]]:
        """(source, time, position, distance to the device, obstacles crossed) of every
        transmission of a ``kind`` source in (t0, t1]."""
        x, y = self.antenna(world)
        for source in (s for s in world.targets if s.kind == kind):
            for t in self.schedule.due(source.id, source.interval_ms / 1000, source.jitter_ms / 1000, t0, t1):
                pos = source.position_at(t)
                distance = (math.hypot(pos[0] - x, pos[1] - y) if self.height is None
                            else math.hypot(pos[0] - x, pos[1] - y, self.height - source.height))
                yield source, t, pos, distance, world.obstacles_crossed((x, y), pos)

    schedule: _Schedule
    channel: RadioChannel
    """Its radio (the scenario's, or measured: emulator/measured_rssi.py), for a board that hears one."""

    def beacon_receptions(self, world: World, t0: float, t1: float) -> Iterator[tuple[Target, float, int, int, float]]:
        """(beacon, time, k, channel, dBm) of every advertisement heard in (t0, t1] on 37, 38 and
        39 in turn (k = 0, 1, 2): what a BLE scanner's radio hands its firmware."""
        here = self.antenna(world)
        for beacon, t, pos, distance, walls in self.transmissions(world, "ble_beacon", t0, t1):
            link = (beacon.id, self.name)
            if self.channel.lost(link, t):
                continue
            for k, ch in enumerate((37, 38, 39)):
                power = self.channel.received_dbm(link, distance, beacon.tx_power_dbm, walls, t=t, ends=(pos, here))
                if power is not None:
                    yield beacon, t, k, ch, power

    def reboot(self, t: float) -> None:
        """Power-cycle: fresh firmware, all state lost (binary nodes restart their counters)."""
        self.firmware = self.make_firmware()


def arrivals(world: World, model: PathLossModel, source: tuple[float, float], receiver: tuple[float, float],
             tx_power_dbm: float, walls: int) -> list[tuple[float, float]]:
    """(world direction toward the arrival, mean dBm) of each path from source to receiver: the
    direct one first (``walls`` crossed), then each wall reflection if the radio has them."""
    direct = (math.atan2(source[1] - receiver[1], source[0] - receiver[0]),
              model.mean_dbm(math.dist(source, receiver), tx_power_dbm, walls))
    if not model.reflections:
        return [direct]
    return [direct] + [(p.direction_rad, model.path_dbm(p.distance_m, tx_power_dbm, p.walls, p.reflections))
                       for p in world.reflected_paths(source, receiver, model.reflect_bounds)]


class _Schedule:
    """Next transmission time per source: interval plus uniform jitter, random phase."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.next: dict[str, float] = {}
        self.sent: dict[str, int] = {}
        """Transmissions per source so far (a tag's periodic-advertising event counter)."""

    def due(self, source: str, interval_s: float, jitter_s: float, t0: float, t1: float) -> list[float]:
        t = self.next.get(source)
        if t is None:
            t = t0 + draws.uniform(self.rng, 0, interval_s)
        times = []
        while t <= t1:
            times.append(t)
            t += interval_s + draws.uniform(self.rng, 0, jitter_s)
        self.next[source] = t
        return times


class Heard(NamedTuple):
    """A tag an XPLR-AOA hears: where it is at a time, how often it sends, and the way it faces."""

    id: str
    position: tuple[float, float]
    height: float
    interval_s: float
    tx_power_dbm: float
    heading: float


class AoaRunner(DeviceRunner):
    """An XPLR-AOA board on the robot (``mount_yaw_deg``) or fixed (``mount = [x, y, θ]``).

    Its angle errors are the scenario's idealised ``[aoa]`` model, or, under a radio profile
    (``--radio``), the profile's measured process (emulator/aoa_error.py); a board carried on the
    robot takes the fixed anchors' figures (*assumed*: no recording of a carried board)."""

    board = "xplr-aoa"

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        """A fixed anchor in 3-D where the device gives a ``position`` (emulator/anchors.py)."""
        from rfhoming.emulator.anchors import FixedAnchorRunner  # a subclass: imported here

        tag = (scenario.robot_tag, scenario.robot_tag_interval_ms) if scenario.robot_tag else None
        runner = FixedAnchorRunner if "position" in options else AoaRunner
        profile = scenario.radio.aoa if scenario.radio is not None else None
        measured = MeasuredAoa(profile, name, rng, scenario.room_seed) if profile is not None else None
        return runner(name, link, faults, rng, options, scenario.aoa, scenario.path_loss, tag, measured, scenario.rssi)

    def __init__(self, name: str, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 options: dict[str, Any], aoa: AoaModel, path_loss: PathLossModel,
                 robot_tag: tuple[str, float] | None, measured: MeasuredAoa | None = None,
                 rssi: Mapping[str, RssiProfile] | None = None) -> None:
        dialect = Dialect(str(options.get("dialect", "1.2")))
        mac = str(options.get("mac", "CCF9578E0D89"))
        baud = int(options.get("baud", DEFAULT_BAUD))
        # hardships no source shows are options, off by default (docs/protocol.md, "The emulated board")
        torn = bool(options.get("torn_answers", False))
        deaf_ms = int(options.get("deaf_after_boot_ms", 0))
        super().__init__(name, lambda: XplrAoaFirmware(mac, dialect, baud, paced=True, torn_answers=torn,
                                                       deaf_after_boot_ms=deaf_ms), link, faults, rng)
        self.namespace = str(options.get("tag_namespace", C209_NAMESPACE)).upper()
        self.aoa = aoa
        self.path_loss = path_loss
        self.channel = channel(self.board, path_loss, rng, rssi or {})
        self.mount = options.get("mount")
        self.yaw = math.radians(float(options.get("mount_yaw_deg", 0.0)))
        self.upside_down = bool(options.get("upside_down", False))
        self.observe_robot = options.get("observe", "targets") == "robot"
        self.robot_tag = robot_tag
        self.measured = measured
        self.schedule = _Schedule(rng)
        self._tag_ids: list[str] | None = None

    def device_baud(self) -> int:
        return self.forced_baud or self.firmware.baud

    def reboot(self, t: float) -> None:
        self.firmware.boot(int(t * 1000))

    def board_pose(self, world: World) -> tuple[float, float, float]:
        if self.mount is not None:
            x, y, th = map(float, self.mount)
            return x, y, th
        r = world.robot
        return r.x, r.y, r.theta + self.yaw

    def _quiet_until(self, world: World) -> float:
        """The next transmission time of any tag this board hears (-inf before each has one)."""
        if self._tag_ids is None:  # who is heard never changes
            self._tag_ids = [s.id for s in self.sources(world, 0.0)]
        nexts = self.schedule.next
        return min((nexts.get(tag_id, -math.inf) for tag_id in self._tag_ids), default=math.inf)

    def sources(self, world: World, t: float) -> list[Heard]:
        """Every tag this board hears."""
        if self.observe_robot:
            if self.robot_tag is None:
                return []
            tag_id, interval_ms = self.robot_tag
            r = world.robot
            return [Heard(tag_id, (r.x, r.y), 0.1, interval_ms / 1000, 0.0, r.theta)]
        return [Heard(t_.id, t_.position_at(t), t_.height, t_.interval_ms / 1000, t_.tx_power_dbm, t_.heading_at(t))
                for t_ in world.targets if t_.kind == "aoa_tag"]

    def step(self, world: World, t0: float, t1: float) -> None:
        fw: XplrAoaFirmware = self.firmware
        if self._quiet_until(world) > t1:  # no tag sends in this step (most steps)
            fw.tick(int(t1 * 1000))
            return
        for tag_id, pos, height, interval, tx, heading in self.sources(world, t1):
            for t in self.schedule.due(tag_id, interval, interval * 0.1, t0, t1):
                fw.tick(int(t * 1000))
                # the tag's own event counter counts what it sent, whatever the board hears
                counter = self.schedule.sent[tag_id] = (self.schedule.sent.get(tag_id, 0) + 1) & 0xFFFF
                link = (tag_id, self.name)
                if self.channel.lost(link, t):
                    continue
                bx, by, bth = self.board_pose(world)
                distance = math.hypot(pos[0] - bx, pos[1] - by)
                walls = world.obstacles_crossed((bx, by), pos)
                paths = arrivals(world, self.path_loss, pos, (bx, by), tx, walls)
                # NLOS: the board reads the strongest path's bearing (docs/emulator.md)
                direction = max(paths, key=lambda p: p[1])[0] if len(paths) > 1 else paths[0][0]
                if self.aoa.idealised_rssi and self.measured is None:  # S0's presets: idealised distance noise
                    rssi = idealised_rssi(self.aoa, self.path_loss, distance, tx, self.rng)
                else:
                    if distance > self.path_loss.max_range_m:
                        continue
                    rssi = self.channel.sample(link, power_sum_dbm([p for _, p in paths]), t=t, ends=(pos, (bx, by)),
                                               distance_m=distance)
                    if rssi < -100:
                        continue
                relative = math.degrees(direction - bth)
                elevation = math.degrees(math.atan2(height - BOARD_HEIGHT_M, max(distance, 0.05)))
                if self.measured is not None:
                    true_az = -seen_azimuth(relative, self.aoa.fold)
                    got = self.measured.report(tag_id, t, true_az, elevation, (bx, by, BOARD_HEIGHT_M, bth),
                                               (pos[0], pos[1], height, heading))
                    if got is None:
                        continue
                    azimuth, elevation = got
                else:
                    azimuth = measure_azimuth(self.aoa, relative, self.rng)
                    elevation += draws.normal(self.rng, 0, self.aoa.angle_deg)
                if self.upside_down:
                    azimuth = -azimuth
                fw.on_advertisement(Advertisement(tag_id, self.namespace, azimuth, elevation, rssi,
                                                  self.channel.second_dbm(link, rssi), counter))
        fw.tick(int(t1 * 1000))


def _point(p: Any) -> tuple[float, float]:
    x, y = map(float, p)
    return x, y


def _address(target_id: str) -> bytes:
    """A 12-hex-digit id as the 6 address bytes on the air (LSB first)."""
    return bytes.fromhex(target_id.rjust(12, "0")[-12:])[::-1]


class Esp32Runner(DeviceRunner):
    """The robot's ESP32 scanner; every beacon advertises on 37, 38, 39 in turn."""

    board = "esp32"

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        return cls(name, k + 1, link, faults, rng, scenario.path_loss, options, scenario.rssi).mounted(options, scenario)

    def __init__(self, name: str, node_id: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 path_loss: PathLossModel, options: dict[str, Any], rssi: Mapping[str, RssiProfile] | None = None) -> None:
        # a duty-cycled scan is a hardship no source shows for rfhoming's node: an option, off by
        # default (docs/protocol.md, "The ESP32 scanner node")
        default = ScanConfig()
        interval_ms = float(options.get("scan_interval_ms", default.interval_us / 1000))
        window_ms = float(options.get("scan_window_ms", min(default.window_us / 1000, interval_ms)))
        config = ScanConfig(round(interval_ms * 1000), round(window_ms * 1000))
        if not 2_500 <= config.window_us <= config.interval_us <= 10_240_000:
            raise ScenarioError(f"[devices.{name}] needs 2.5 <= scan_window_ms <= scan_interval_ms <= 10240, "
                                f"not {window_ms:g} and {interval_ms:g}")
        super().__init__(name, lambda: Esp32ScannerFirmware(node_id, config), link, faults, rng)
        self.channel = channel(self.board, path_loss, rng, rssi or {})
        self.schedule = _Schedule(rng)

    def step(self, world: World, t0: float, t1: float) -> None:
        fw: Esp32ScannerFirmware = self.firmware
        for beacon, t, k, ch, power in self.beacon_receptions(world, t0, t1):
            fw.on_advertisement(int(t * 1e6) + 400 * k, ch, _address(beacon.id), power, BEACON_AD)
        fw.tick(int(t1 * 1e6))


BEACON_AD = b"\x02\x01\x06\x03\x03\xaa\xfe"
"""What the emulated beacons advertise: flags, and the Eddystone service UUID."""


class EspAtRunner(DeviceRunner):
    """An ESP32 with Espressif's ESP-AT firmware on the robot, scanning when the host says so."""

    board = "esp-at"

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        return cls(name, link, faults, rng, scenario.path_loss, options, scenario.rssi).mounted(options, scenario)

    def __init__(self, name: str, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 path_loss: PathLossModel, options: dict[str, Any], rssi: Mapping[str, RssiProfile] | None = None) -> None:
        version = str(options.get("version", "3.2"))  # which ESP-AT documentation the board follows
        super().__init__(name, lambda: EspAtFirmware(version), link, faults, rng)
        self.baud = int(options.get("baud", DEFAULT_BAUD))
        self.channel = channel(self.board, path_loss, rng, rssi or {})
        self.schedule = _Schedule(rng)

    def step(self, world: World, t0: float, t1: float) -> None:
        fw: EspAtFirmware = self.firmware
        for beacon, t, k, ch, power in self.beacon_receptions(world, t0, t1):
            fw.on_advertisement(int(t * 1e6) + 400 * k, ch, beacon.id.rjust(12, "0")[-12:], power, BEACON_AD)
        fw.tick(int(t1 * 1e6))


class HciRunner(DeviceRunner):
    """A Bluetooth controller in HCI-UART mode on the robot (H4, 1 Mbaud by default), scanning
    when the host's HCI commands say so. Its model needs bumble (the ``hci`` extra)."""

    board = "hci"

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        return cls(name, link, faults, rng, scenario.path_loss, options, scenario.rssi).mounted(options, scenario)

    def __init__(self, name: str, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 path_loss: PathLossModel, options: dict[str, Any], rssi: Mapping[str, RssiProfile] | None = None) -> None:
        from rfhoming.firmware.hci_controller import (
            HciControllerFirmware,  # bumble only where used
        )

        address = str(options.get("address", "C0:FF:EE:00:00:01"))
        # extended reports in fragments of this many bytes (and the last lost: truncate), as a BT5
        # controller sends what does not fit one event; off by default (the beacons' data fit)
        fragment = options.get("fragment_bytes")
        truncate = bool(options.get("truncate", False))
        super().__init__(name, lambda: HciControllerFirmware(address, fragment_bytes=int(fragment) if fragment else None,
                                                             truncate=truncate), link, faults, rng)
        self.baud = int(options.get("baud", 1_000_000))
        if isinstance(link, TcpLink):  # HCI over TCP (bumble's tcp-client) has no baud rate to get wrong
            link.assumed_host_baud = self.baud
        self.channel = channel(self.board, path_loss, rng, rssi or {})
        self.schedule = _Schedule(rng)

    def step(self, world: World, t0: float, t1: float) -> None:
        fw = self.firmware
        for beacon, t, k, ch, power in self.beacon_receptions(world, t0, t1):
            hex_id = beacon.id.rjust(12, "0")[-12:].upper()
            address = ":".join(hex_id[i : i + 2] for i in range(0, 12, 2))
            fw.on_advertisement(int(t * 1e6) + 400 * k, ch, address, power, BEACON_AD)
        fw.tick(int(t1 * 1e6))


class RssRunner(DeviceRunner):
    """The four-dish AT86RF212 node on the robot, hearing 915 MHz emitters."""

    board = "at86rf212"

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        return cls(name, k + 1, link, faults, rng, scenario.path_loss, options, scenario.rssi)

    def __init__(self, name: str, node_id: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 path_loss: PathLossModel, options: dict[str, Any], rssi: Mapping[str, RssiProfile] | None = None) -> None:
        offsets = tuple(float(v) for v in options.get("chip_offsets_db", rng.uniform(-5, 5, 4)))
        kwargs: dict[str, Any] = {"chip_offsets_db": offsets, "dish_diameter_m": float(options.get("dish_diameter_m", 0.3))}
        super().__init__(name, lambda: At86rf212NodeFirmware(node_id, **kwargs), link, faults, rng)
        self.channel = channel(self.board, path_loss, rng, rssi or {})
        self.schedule = _Schedule(rng)
        self.emitter_seq: dict[str, int] = {}

    def step(self, world: World, t0: float, t1: float) -> None:
        fw: At86rf212NodeFirmware = self.firmware
        r = world.robot
        m = self.channel.model
        for emitter, t, pos, distance, walls in self.transmissions(world, "rf_emitter", t0, t1):
            if distance > m.max_range_m:
                continue
            seq = self.emitter_seq[emitter.id] = (self.emitter_seq.get(emitter.id, 0) + 1) & 0xFFFF
            if self.channel.lost((emitter.id, self.name), t):  # the whole frame: the chips measure the one frame
                continue
            bearing = math.atan2(pos[1] - r.y, pos[0] - r.x) - r.theta
            paths = arrivals(world, m, pos, (r.x, r.y), emitter.tx_power_dbm, walls)
            ends = (pos, (r.x, r.y))
            if len(paths) == 1:
                incident = [self.channel.received_dbm((emitter.id, f"{self.name}.{i}"), distance,
                                                      emitter.tx_power_dbm, walls, t=t, ends=ends) for i in range(4)]
                fw.on_frame(int(t * 1e6), seq, bearing, incident)  # type: ignore[arg-type]
                continue
            noise = [self.channel.sample((emitter.id, f"{self.name}.{i}"), 0.0, t=t, ends=ends, distance_m=distance)
                     for i in range(4)]
            fw.on_paths(int(t * 1e6), seq, [(d - r.theta, p) for d, p in paths], noise)
        fw.tick(int(t1 * 1e6))


class BaseRunner(DeviceRunner):
    """The robot base: its applied velocity moves the true pose; scans come from the world."""

    board = "base"
    SCAN_PERIOD_S = 0.1
    SCAN_BEAMS = 181
    SCAN_RANGE_M = 8.0

    @classmethod
    def build(cls, name: str, k: int, link: Link, faults: ByteFaults, rng: np.random.Generator,
              options: dict[str, Any], scenario: Scenario) -> DeviceRunner:
        r = scenario.world.robot
        return cls(name, link, faults, rng, options, (r.x, r.y, r.theta), scenario.robot_radius)

    def __init__(self, name: str, link: Link, faults: ByteFaults, rng: np.random.Generator,
                 options: dict[str, Any], start: tuple[float, float, float], radius: float) -> None:
        slip = Slip(*map(float, options.get("slip", (0.0, 0.0, 0.0))))  # odometry: v scale, ω scale, yaw drift rad/s
        super().__init__(name, lambda: RobotBaseFirmware(0, start_pose=start, slip=slip), link, faults, rng)
        self.baud = int(options.get("baud", DEFAULT_BAUD))
        self.scan = bool(options.get("scan", False))
        self.scan_noise_m = float(options.get("scan_noise_m", 0.0))  # σ of each range
        self.radius = radius
        self.commanded = asyncio.Event()
        self._next_scan = 0.0
        self._beams = np.linspace(-math.pi / 2, math.pi / 2, self.SCAN_BEAMS)  # robot frame, made once
        self._commands_seen = 0
        # a link that drives the firmware itself (a MAVLink vehicle) says when the host commanded
        self._link_commands = hasattr(link, "on_command")
        if self._link_commands:
            link.on_command = self.commanded.set  # type: ignore[attr-defined]

    def on_host_bytes(self, data: bytes) -> None:
        super().on_host_bytes(data)
        if not self._link_commands and self.firmware.counters["commands"] != self._commands_seen:
            self._commands_seen = self.firmware.counters["commands"]
            self.commanded.set()

    def reboot(self, t: float) -> None:
        """The motor controller restarts: it stops and its clock restarts at 0 (t_us from 0, as
        an MCU reset does); its odometry (kept in RAM here) survives."""
        self.firmware.reset(round(t * 1e6))

    def step(self, world: World, t0: float, t1: float) -> None:
        fw: RobotBaseFirmware = self.firmware
        # rounded, not truncated: a sum of 10 ms steps is often a hair under the step's time, and a
        # truncated microsecond put odometry one step late, after a lockstep period's end, where the
        # emulator waited for a command the host had no odometry to send (CI, 2026-12-05)
        v, w = fw.step(round(t1 * 1e6))
        r = world.robot
        before = (r.x, r.y, r.theta)
        r.advance(v, w, t1 - t0)
        fw.contact = world.collides(r.x, r.y, self.radius)
        if fw.contact:  # bumped: the wheels slip, the robot stays where it was
            r.x, r.y, _ = before
        if self.scan and t1 >= self._next_scan:
            self._next_scan = t1 + self.SCAN_PERIOD_S
            ranges = world.cast((r.x, r.y), self._beams + r.theta, self.SCAN_RANGE_M)
            if self.scan_noise_m > 0:
                ranges = np.maximum(ranges + self.rng.normal(0, self.scan_noise_m, len(ranges)), 0.0)
            fw.send_scan_mm(-math.pi / 2, math.pi / 2, self.SCAN_RANGE_M, scan_mm(ranges))


def scan_mm(ranges_m: np.ndarray) -> tuple[int, ...]:
    """Ranges (metres, inf = no return) in the base's wire form, all at once: what
    :meth:`RobotBaseFirmware.send_scan` makes of them one by one (mm rounded half to even, 0 =
    no return, at least 1, at most 65535; the first 255)."""
    r = ranges_m[:255]
    finite = np.isfinite(r)
    mm = np.clip(np.rint(np.where(finite, r, 0.0) * 1000), 1, 65535)
    return tuple(np.where(finite, mm, 0).astype(np.int64).tolist())


def target_positions(world: World, t: float) -> list[dict[str, Any]]:
    out = []
    for target in world.targets:
        x, y = target.position_at(t)
        out.append({"id": target.id, "kind": target.kind, "x": round(x, 4), "y": round(y, 4)})
    return out

