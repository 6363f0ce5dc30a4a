"""One run assembly: roles and port specs (or ports already made) -> drivers, a controller,
sinks, supervision and the loop. ``rfhoming run``, ``rfhoming demo``, the campaigns' closed
loop, the benches and the tests all build their homing runs here, so a run is wired one way.

A :class:`Homing` says what to run: the controller, each device by its role (``aoa``, ``rss``,
``ble``, ``anchor``, ``base``; rfhoming.protocol.devices.ROLES) and either a port spec to open
or a port already made (the campaigns' in-process pipe, a replay). :func:`build` makes the
drivers -- each handing its readings to the loop's one input stream from the start -- and the
loop; :func:`run` resolves the specs first (``auto`` found, each kind fixed by its role), then runs the loop
while :func:`~rfhoming.host.supervise.supervise` watches every driver on a real port: one that
fails, or is not ready by its kind's deadline, ends the run with an Error naming its port.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from rfhoming.host import losses
from rfhoming.host import site as sites
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.common import BoundedStream, Driver, Wiring
from rfhoming.host.drivers.robot import RobotBase
from rfhoming.host.homing.anchors import AnchorsController
from rfhoming.host.homing.config import Config, from_tables, to_tables
from rfhoming.host.homing.loop import (
    HomingLoop,
    Outcome,
    RunLog,
)
from rfhoming.host.homing.planner import Planner
from rfhoming.host.homing.s0_aoa import AoaController
from rfhoming.host.homing.s1_dock import DockController
from rfhoming.host.homing.s2_rss import RssController
from rfhoming.host.homing.s3_trilat import TrilatController
from rfhoming.host.homing.s4_air import SurveyController
from rfhoming.host.homing.types import Controller
from rfhoming.host.ports import HostPort, Tap
from rfhoming.host.portspec import PortSpec, PortSpecError
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.host.replay import ReplayPort, Sequencer, notes, read_capture
from rfhoming.host.replay import describe as describe_interface
from rfhoming.host.session import driver_class, names_of, recorded_kind, resolve, serve_driver
from rfhoming.host.sink import Sink
from rfhoming.host.site import Site
from rfhoming.host.supervise import deadline, supervise
from rfhoming.protocol import devices
from rfhoming.protocol.pcapng import CaptureFormatError

CHOOSE_TAG_S = 2.0
"""Live runs with no tag chosen listen this long, then home on the only tag in view."""
INPUT_QUEUE = 4000
"""Items the loop's one input stream holds (odometry, scans and readings, in arrival order)."""


@dataclass(frozen=True)
class Method:
    """A homing method: the role its sensor fills and how to make its controller."""

    title: str
    role: str
    make: Callable[[Config, Site | None], Controller]


def _anchors(config: Config, site: Site | None) -> Controller:
    if site is None:
        raise PortSpecError("--controller anchors needs --site SITE.toml (anchors, and tags with role = "
                            "\"robot\" / \"target\")")
    return AnchorsController(site)


METHODS: dict[str, Method] = {
    "aoa": Method("S0: XPLR-AOA bearings and RSSI ranges", "aoa",
                  lambda c, s: AoaController(c.s0, c.mounting.to_robot, c.calibration.model)),
    "dock": Method("S1: docking on the station's AoA/RSSI of the robot's tag", "aoa", lambda c, s: DockController(c.s1)),
    "rss": Method("S2: four dishes and a particle filter", "rss", lambda c, s: RssController(c.s2)),
    "trilat": Method("S3: trilateration on BLE beacons at known places", "ble", lambda c, s: TrilatController(c.trilat)),
    "survey": Method("S4: lawn-mower survey, EKF beacon localisation, hold over one", "ble",
                     lambda c, s: SurveyController(c.s4)),
    "anchors": Method("fixed anchors locate the robot's tag and the target's", "anchor", _anchors),
}


SENSORS = {"dock_aoa": ("dock", "aoa"), "aoa": ("aoa", "aoa"), "rss": ("rss", "rss"), "ble": ("trilat", "ble"),
           "survey_ble": ("survey", "ble")}
"""The emulator's scenarios name each sensor device for what it is for: such a name -> the
homing method it calls for and the role its device fills (the demo and the campaigns). Several
devices of one method are numbered: survey_ble1, survey_ble2 ..."""


def sensors_of(names: Sequence[str]) -> tuple[str, str, list[str]]:
    """A scenario's device names -> the homing method they call for, the role its sensors fill,
    and those sensors' names (one, or several numbered alike); KeyError if none."""
    for key, (controller, role) in SENSORS.items():
        found = [n for n in names if n == key or (n.startswith(key) and n[len(key):].isdigit())]
        if found:
            return controller, role, found
    raise KeyError(f"no sensor among {list(names)}")


@dataclass(frozen=True)
class Device:
    """One device of a run: its role, and a port spec to open or a port already made (with
    ``kind``, its device kind; by default the role's)."""

    role: str
    spec: PortSpec | str | None = None
    port: Any = None  # HostPort-shaped: open, read, write, close, name, taps, counters
    kind: str | None = None


@dataclass
class Homing:
    """Everything a homing run is made of. ``controller`` is a METHODS name or a controller
    object (a campaign's calibration recorder)."""

    controller: str | Controller
    devices: list[Device]
    config: Config = field(default_factory=Config)
    site: Site | None = None
    runlog: RunLog | None = None
    sinks: Sequence[Sink] = ()
    capture: CaptureWriter | None = None
    tags: tuple[str, ...] = ()  # the XPLR-AOA tags to home on (besides a spec's tags=)
    choose_tag_s: float | None = None  # no tag chosen: listen this long, then home on the only one heard
    probe_baud: bool = False  # an XPLR-AOA sending garbage is probed at every documented rate
    baud: int | None = None  # defaults for specs that give none
    flow: str | None = None
    planner: Planner | None = None  # the grid's path planner (host/homing/planner.py); None: libtcod's A*
    plans_taken: dict[float, float] = field(default_factory=dict)  # a replay: when the live run's late plans took effect
    odometry_stale_at: frozenset[tuple[float, int]] = frozenset()  # a replay: where the live run's odometry watchdog fired


def sensor_role(plan: Homing) -> str | None:
    return METHODS[plan.controller].role if isinstance(plan.controller, str) else None


def check(plan: Homing) -> None:
    """The plan's shape: a known method, one base, its sensor role(s) filled; PortSpecError says
    what is missing."""
    if isinstance(plan.controller, str) and plan.controller not in METHODS:
        raise PortSpecError(f"unknown controller {plan.controller!r}; the controllers are {', '.join(METHODS)}")
    roles = [d.role for d in plan.devices]
    if roles.count("base") != 1:
        raise PortSpecError("a homing run needs one robot base (--base PORT, or [devices.base] in the config)")
    role = sensor_role(plan)
    if role is not None and role not in roles:
        raise PortSpecError(f"--controller {plan.controller} needs --{role} PORT (or [devices.{role}] in the config)")
    if plan.tags and role != "aoa":
        raise PortSpecError(f"--tag chooses an XPLR-AOA tag; --controller {plan.controller} has none")


def _kind_for(device: Device, spec: PortSpec) -> PortSpec:
    """The spec with its kind fixed by its role: a spec without KIND: is the role's default
    kind, one with a kind must be able to fill the role."""
    role = devices.ROLES[device.role]
    if spec.kind is None:
        return spec.with_kind(role.default_kind)
    if spec.kind in ("capture", "serve"):
        return spec
    if device.role not in devices.kind(spec.kind).roles:
        takes = ", ".join(k.name for k in devices.with_role(device.role))
        raise PortSpecError(f"{spec} is a {spec.kind} port where {role.title} is wanted ({takes})")
    return spec


async def resolve_devices(plan: Homing) -> Homing:
    """The plan with every spec made concrete (``auto`` found, the kind fixed by the role);
    the capture, if any, is told what each port is and the role it fills."""
    taps: list[Tap] = [plan.capture.tap] if plan.capture else []
    out = []
    for device in plan.devices:
        describe = None if plan.capture is None else _describing(plan.capture, device.role)

        if device.spec is None:
            out.append(device)
            continue
        spec = _kind_for(device, parse_spec(device.spec))
        if spec.kind == "capture":  # its recorded device, wired below with the others of its file
            out.append(replace(device, spec=spec))
            continue
        if spec.kind == "serve":
            if device.role != "aoa":
                raise PortSpecError(f"--{device.role} {spec}: only the XPLR-AOA (--aoa) can come from "
                                    "`rfhoming serve` yet")
            out.append(replace(device, spec=spec))
            continue
        spec = await resolve(spec, baud=plan.baud, flow=plan.flow, taps=taps, kind=spec.kind, describe=describe)
        out.append(replace(device, spec=spec))
    return replace(plan, devices=_recorded(out, plan.capture))


def _recorded(devices_: list[Device], capture: CaptureWriter | None) -> list[Device]:
    """Devices given as ``capture:FILE[,device=NAME]`` -> their recorded ports, released in the
    file's recorded global order: ``device=`` names one (a path, label or role `rfhoming replay`
    lists); without it, the one recorded in the device's role, or the one whose kind fills it."""
    files: dict[str, list[int]] = {}
    for i, device in enumerate(devices_):
        spec = parse_spec(device.spec) if device.spec is not None else None
        if spec is not None and spec.kind == "capture":
            files.setdefault(spec.where, []).append(i)
    out = list(devices_)
    for path, indexes in files.items():
        interfaces, packets, _torn, _ = read_capture(path)
        picked = [_pick(path, interfaces, devices_[i]) for i in indexes]
        for i, k in zip(indexes, picked):
            kind = recorded_kind(interfaces[k])
            if devices_[i].role not in kind.roles or picked.count(k) > 1:
                why = "is taken twice" if picked.count(k) > 1 else f"is a {kind.name}"
                raise PortSpecError(f"{path}: {interfaces[k].name} {why}; it cannot be the "
                                    f"{devices.ROLES[devices_[i].role].title}")
        sequencer = Sequencer({interfaces[k].name: packets[k] for k in picked})
        for i, k in zip(indexes, picked):
            port = ReplayPort(interfaces[k].name, packets[k], sequencer=sequencer,
                              description=describe_interface(interfaces[k]))
            recorded = recorded_kind(interfaces[k]).name
            if capture is not None:  # a run on recorded devices is a run: its capture replays too
                port.taps.append(capture.tap)
                capture.describe(port.name, kind=recorded, role=devices_[i].role)
            out[i] = replace(devices_[i], spec=None, port=port, kind=recorded)
    return out


def _pick(path: str, interfaces: list[Any], device: Device) -> int:
    wanted = parse_spec(device.spec or "").settings.get("device")
    for test in ((lambda i: wanted in names_of(i)) if wanted else None,
                 lambda i: describe_interface(i).get("role") == device.role,
                 lambda i: device.role in recorded_kind(i).roles):
        found = [k for k, iface in enumerate(interfaces) if test is not None and test(iface)]
        if len(found) == 1 or (wanted and found):
            return found[0]
        if wanted or len(found) > 1:
            held = "; ".join(" = ".join(names_of(i)) for i in interfaces)
            what = f"no device {wanted!r}" if wanted else f"{len(found)} devices that can be the {device.role}"
            raise PortSpecError(f"{path} has {what}; name one with capture:{path},device=NAME (it holds: {held})")
    raise PortSpecError(f"{path} holds no device for the {device.role} role (it holds: "
                        f"{'; '.join(' = '.join(names_of(i)) for i in interfaces)})")


def _describing(capture: CaptureWriter, role: str) -> Callable[..., None]:
    """The capture's describe, adding the role the device fills in the run."""
    def describe(name: str, **fields: str) -> None:
        capture.describe(name, role=role, **fields)
    return describe


def _driver(plan: Homing, device: Device, inputs: BoundedStream[Any]) -> tuple[Driver, float | None]:
    """The device's driver, handing its items to ``inputs``, with its spec's settings (also on a
    port already made: a replay keeps the live run's tags= and scan settings); and its set-up
    deadline (None: a port that needs none, the in-process pipe or a replay)."""
    taps: list[Tap] = [plan.capture.tap] if plan.capture else []
    spec = parse_spec(device.spec) if device.spec is not None else None
    if spec is not None and spec.kind == "serve":
        served = serve_driver(spec, out=inputs)
        return served, deadline(served, spec.timeout)
    record = spec.device if spec is not None and device.port is None else devices.kind(
        device.kind or devices.ROLES[device.role].default_kind)
    assert record is not None, device
    if spec is None or spec.kind != record.name:  # a port made without a spec: the kind's defaults
        spec = PortSpec(record.name, getattr(device.port, "name", "port"), spec.settings if spec else {})
    if plan.tags and device.role == "aoa":
        spec = replace(spec, settings={**spec.settings, "tags": tuple(dict.fromkeys((*spec.tags, *plan.tags)))})
    cls = driver_class(record)
    wiring = Wiring(device.role, plan.config, plan.choose_tag_s, plan.probe_baud)
    driver = cls.from_spec(spec, taps, port=device.port, out=inputs, **cls.options(wiring))
    if device.port is not None and not isinstance(device.port, HostPort):
        return driver, None
    return driver, deadline(driver, spec.timeout)


RUN_RECORD = "rfhoming-run"
"""The key of a homing run's record in its capture's section comment."""


def run_record(plan: Homing, site_text: str | None = None) -> str:
    """What a run's capture keeps of its plan, so that :func:`replay_plan` runs the same loop on
    its bytes: the controller, the whole config as used, the tags, every device's spec (its
    settings: tags=, scan timing ...) in the order of the capture's interfaces of its role, and
    the site file's text."""
    if not isinstance(plan.controller, str):
        raise PortSpecError("only a run of one of the METHODS can be recorded for replay")
    specs = [[d.role, str(parse_spec(d.spec)) if d.spec is not None else None] for d in plan.devices]
    return json.dumps({RUN_RECORD: 1, "controller": plan.controller, "config": to_tables(plan.config),
                       "tags": list(plan.tags), "choose_tag_s": plan.choose_tag_s, "probe_baud": plan.probe_baud,
                       "devices": specs, "site": site_text})


def replay_plan(path: Path | str, *, controller: str | None = None, config: Config | None = None) -> Homing:
    """The homing run a capture recorded, on its bytes: every device's inbound chunks in their
    recorded global order, the loop's writes matched against the recorded ones. ``controller``
    and ``config`` replace the recorded ones (the replay then reports where it diverged). A replay
    runs on the recorded bytes, not the wall clock, so the wall-clock odometry watchdog is off
    (``Config.for_lockstep``): a loaded machine must not change it. Where the live run's watchdog
    fired (the capture holds the bytes, not their silence: it notes the robot time and the items
    taken after that odometry), the replay's fires too. A plan that took effect late in the live
    run (on the wall clock) takes effect at the same robot time in the replay: the capture notes when."""
    interfaces, packets, _torn, comments = read_capture(path)
    record = _record(path, comments)
    specs: dict[str, list[str | None]] = {}
    for role, text in record["devices"]:
        specs.setdefault(role, []).append(text)
    roles, ports, descriptions = [], {}, {}
    for i, iface in enumerate(interfaces):
        role = describe_interface(iface).get("role")
        if role is None:  # bytes sniffed or recorded for no device of the run
            continue
        ports[iface.name] = packets[i]
        descriptions[iface.name] = describe_interface(iface)
        text = specs.get(role, []).pop(0) if specs.get(role) else None
        roles.append(Device(role, spec=text, kind=recorded_kind(iface).name, port=iface.name))
    sequencer = Sequencer(ports)
    roles = [replace(d, port=ReplayPort(d.port, ports[d.port], sequencer=sequencer, description=descriptions[d.port]))
             for d in roles]
    try:
        site = sites.parse(tomllib.loads(record["site"]), f"{path}: the recorded site") if record["site"] else None
    except tomllib.TOMLDecodeError as exc:
        raise CaptureFormatError(0, f"{path}: its run record's site file is not TOML ({exc})") from None
    noted = notes(path)
    try:
        taken = {float(n["plan_asked"]): math.inf if n["plan_taken"] is None else float(n["plan_taken"])
                 for n in noted if "plan_asked" in n}  # the last note of each
        stale = frozenset((float(n["odometry_stale"]), int(n["after_items"])) for n in noted if "odometry_stale" in n)
    except (KeyError, TypeError, ValueError) as exc:
        raise CaptureFormatError(0, f"{path}: a host note in the capture is malformed ({exc!r})") from None
    return Homing(controller or record["controller"], roles,
                  (config if config is not None else from_tables(record["config"], f"{path}: the recorded config"))
                  .for_lockstep(),
                  site=site, tags=tuple(record["tags"]), choose_tag_s=record["choose_tag_s"],
                  probe_baud=record["probe_baud"], plans_taken=taken, odometry_stale_at=stale)


RECORD_KEYS: dict[str, type | tuple[type, ...]] = {"controller": str, "config": dict, "tags": list, "choose_tag_s": (float, int, type(None)),
               "probe_baud": bool, "devices": list, "site": (str, type(None))}


def recorded_site(path: Path | str) -> Site | None:
    """The site file a run's capture recorded (``--controller anchors``), or None: a capture of
    another run or of no run. For an export, which places the anchors' frames from it."""
    _interfaces, _packets, _torn, comments = read_capture(path)
    try:
        record = _record(path, comments)
        return sites.parse(tomllib.loads(record["site"]), f"{path}: the recorded site") if record["site"] else None
    except (CaptureFormatError, tomllib.TOMLDecodeError):
        return None


def _record(path: Path | str, comments: list[str]) -> dict[str, Any]:
    """The capture's run record, checked; CaptureFormatError says what is missing or wrong."""
    text = next((c for c in comments if c.startswith(f'{{"{RUN_RECORD}"')), None)
    if text is None:
        raise CaptureFormatError(0, f"{path} holds no homing run's record (a capture of `rfhoming listen` or "
                                    "`capture`, or of a run before rfhoming recorded them): replay its devices with "
                                    "rfhoming replay CAPTURE, without --run")
    try:
        record: dict[str, Any] = json.loads(text)
    except ValueError as exc:
        raise CaptureFormatError(0, f"{path}: its run record is not JSON ({exc})") from None
    if record.get(RUN_RECORD) != 1:
        raise CaptureFormatError(0, f"{path}: a run record of version {record.get(RUN_RECORD)!r}; this rfhoming "
                                    "reads version 1")
    bad = [k for k, kind in RECORD_KEYS.items() if not isinstance(record.get(k), kind)]
    if bad or record["controller"] not in METHODS:
        raise CaptureFormatError(0, f"{path}: its run record lacks or mangles {', '.join(bad) or 'controller'}")
    return record


@dataclass
class Assembled:
    """A built run: the loop, and the deadline of every driver on a real port."""

    loop: HomingLoop
    deadlines: dict[Driver, float]


def build(plan: Homing) -> Assembled:
    """The drivers, the controller, the sinks and the loop (specs must be resolved)."""
    check(plan)
    inputs = BoundedStream[Any](INPUT_QUEUE)
    built = [(device, *_driver(plan, device, inputs)) for device in plan.devices]
    base = next(driver for device, driver, _ in built if device.role == "base")
    assert isinstance(base, RobotBase)
    sensors = [driver for device, driver, _ in built if device.role != "base"]
    controller = (METHODS[plan.controller].make(plan.config, plan.site) if isinstance(plan.controller, str)
                  else plan.controller)
    runlog = plan.runlog or RunLog(None)
    runlog.listeners += [sink.on_runlog for sink in plan.sinks]
    for _, driver, _ in built:
        driver.listeners += [sink.on_item for sink in plan.sinks]
    loop = HomingLoop(base, sensors, controller, plan.config, runlog, inputs, plan.planner, plan.plans_taken,
                      plan.odometry_stale_at)
    if plan.capture is not None:
        capture, port = plan.capture, base.port.name
        loop.note = lambda record: capture.note(port, time.time(), record)
    for sink in plan.sinks:
        sink.watch(loop)
        sink.show_anchors(plan.config.trilat.anchors if plan.controller == "trilat" else {})
    return Assembled(loop, {driver: limit for _, driver, limit in built if limit is not None})


async def run(plan: Homing) -> Outcome:
    """Resolve, build and run to the end; an Error (PortError, DeviceNotReady, PortSpecError)
    when a device cannot be used, naming its port."""
    check(plan)
    assembled = build(await resolve_devices(plan))
    drivers: list[Driver | RobotBase] = [*assembled.loop.sensors, assembled.loop.base]
    homing = asyncio.create_task(assembled.loop.run())
    watch = asyncio.create_task(supervise(assembled.deadlines))  # at once done for in-process ports and replays
    lost = asyncio.create_task(losses.watch(lambda: [d.health() for d in drivers]))
    try:
        done, _ = await asyncio.wait({homing, watch}, return_when=asyncio.FIRST_COMPLETED)
        if watch in done:
            watch.result()  # raises: the run cannot go on
            await homing  # or there was nothing to watch
        return homing.result()
    finally:
        for task in (homing, watch, lost):
            task.cancel()
        await asyncio.gather(homing, watch, lost, return_exceptions=True)
