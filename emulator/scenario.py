"""Scenario files (TOML): the world, its radio models and the devices the host will see.

A scenario is a preset name (``s0-open``, ``s2-c`` …, shipped in ``emulator/scenarios/``) or
a path to a TOML file of the same shape. Random target positions are drawn from the seed, so
a (scenario, seed) pair always builds the same world.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, cast

import numpy as np

from rfhoming.emulator.arrival import TARGET_CLEARANCE_M, clearance
from rfhoming.emulator.links import not_plain
from rfhoming.emulator.radio import AoaModel, PathLossModel
from rfhoming.emulator.world import Obstacle, Pose, Target, World
from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error
from rfhoming.protocol.rssi_profile import RssiProfile
from rfhoming.protocol.radio_profile import IDEAL, ProfileError, RadioProfile, resolve
from rfhoming.protocol.textfile import parse_toml, read_toml



class ScenarioError(Error, ValueError):
    """A scenario that cannot be built; the message says what to fix."""


@dataclass
class DeviceSpec:
    name: str
    type: str
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """A device's name is its link's file name in the link folder: a plain name only."""
        why = not_plain(self.name)
        if why is not None:
            raise ScenarioError(f"device name {self.name!r} is not a plain name ({why}): it names the device's link "
                                f"in --link-dir; rename [devices.{json.dumps(self.name)}] (e.g. to letters, digits, - and _)")


@dataclass
class Scenario:
    name: str
    description: str
    world: World
    path_loss: PathLossModel
    aoa: AoaModel
    devices: list[DeviceSpec]
    robot_radius: float = 0.25
    robot_tag: str | None = None
    robot_tag_interval_ms: float = 20.0
    robot_height: float | None = None  # its receivers' height above ground (a copter's); None: planar radio
    vehicle: dict[str, Any] | None = None  # the base as a MAVLink vehicle (``[robot.mavlink]``), as --robot mavlink
    rssi: dict[str, RssiProfile] = field(default_factory=dict)
    """Measured RSSI by radio (a profile's ``[rssi.NAME]``); a radio left out keeps ``path_loss`` (ideal)."""
    radio: RadioProfile | None = None  # the measured radios (``--radio``); None: the scenario's idealised noise
    room_seed: int = 0  # seeds what the room holds still across runs (a profile's error field)

    @property
    def radio_name(self) -> str:
        """What ``--radio`` named: ``ideal``, or the profile's name."""
        return IDEAL if self.radio is None else self.radio.name


def presets() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("rfhoming.emulator.scenarios").iterdir() if p.name.endswith(".toml"))


def _read(name_or_path: str) -> dict[str, Any]:
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.is_file():  # a directory named like a preset is not a scenario
        return read_toml(path, "scenario", ScenarioError)
    resource = resources.files("rfhoming.emulator.scenarios") / f"{name_or_path}.toml"
    if not resource.is_file():
        raise ScenarioError(f"no scenario {name_or_path!r}; presets: {', '.join(presets())}, or a .toml path")
    return parse_toml(resource.read_text(), f"scenario {name_or_path}", ScenarioError)


def _model(cls: type, table: dict[str, Any], where: str) -> Any:
    known = {f.name for f in fields(cls)}
    unknown = set(table) - known - {"preset"}
    if unknown:
        raise ScenarioError(f"[{where}] has unknown keys {sorted(unknown)}; known: {sorted(known)}")
    return cls(**{k: v for k, v in table.items() if k in known})


def _point(p: Any) -> tuple[float, float]:
    """A TOML ``[x, y]`` as floats (its length is the scenario's to get right, as before)."""
    return cast("tuple[float, float]", tuple(map(float, p)))


def _timetable(rows: Any, where: str) -> list[tuple[float, float, float]]:
    """``timetable = [[t, x, y], ...]``: a walk on the clock (seconds, metres), times rising."""
    out = [cast("tuple[float, float, float]", tuple(map(float, row))) for row in rows]
    if any(len(row) != 3 for row in out) or any(b[0] <= a[0] for a, b in zip(out, out[1:])):
        raise ScenarioError(f"{where}: timetable must be [[t, x, y], ...] with the times rising")
    return out


def _random_free_point(bounds: tuple[float, ...], obstacles: list[Obstacle], rng: np.random.Generator,
                       margin: float = 1.0, clear_m: float = TARGET_CLEARANCE_M) -> tuple[float, float]:
    """A point ``margin`` inside the bounds and ``clear_m`` from every obstacle
    (:mod:`rfhoming.emulator.arrival`: a robot can stand beside it, in its line of sight)."""
    x0, y0, x1, y1 = bounds
    polygons = [o.polygon for o in obstacles]
    for _ in range(1000):
        p = (float(rng.uniform(x0 + margin, x1 - margin)), float(rng.uniform(y0 + margin, y1 - margin)))
        if clearance(p, polygons) >= clear_m:
            return p
    raise ScenarioError(f"no free point for a random target: nowhere in the bounds is {clear_m} m from every obstacle")


BLE_RECEIVERS = tuple(name for name, (kind, _) in devices.BOARDS.items() if "ble" in kind.roles)
"""Interchangeable BLE RSSI receivers: ``receiver=`` puts one in place of the scenario's."""


def load(name_or_path: str, seed: int = 0, target: tuple[float, ...] | None = None,
         aoa_preset: int | None = None, receiver: str | None = None, radio: str | RadioProfile = IDEAL,
         room_seed: int | None = None) -> Scenario:
    """Build a scenario; ``target`` overrides the first target's position, ``aoa_preset`` the
    AoA noise with S0's configuration 1–5, ``receiver`` the type of every BLE RSSI receiver,
    ``radio`` the radios' errors: ``ideal`` (the scenario's own noise, each paper's set-up),
    ``measured`` (the project's profile, fitted to real recordings) or a profile file or object
    (docs/emulator.md, "Radio profiles"); ``room_seed`` (default ``seed``) what stays put in the
    room from run to run under a profile (its error field)."""
    profile = _radio(receiver, aoa_preset, radio)
    raw = _read(name_or_path)
    rng = np.random.default_rng(seed)
    try:
        bounds = tuple(float(v) for v in raw["bounds"])
        robot = raw.get("robot", {})
        start = Pose(*map(float, robot.get("start", (0.0, 0.0, 0.0))))
        obstacles = [Obstacle.rect(*map(float, o["rect"])) if "rect" in o else Obstacle([_point(p) for p in o["polygon"]])
                     for o in raw.get("obstacles", [])]
        targets = [_target(t, _point(target) if i == 0 and target is not None else None, bounds, obstacles, rng)
                   for i, t in enumerate(raw.get("targets", []))]
        aoa_table = dict(raw.get("aoa", {}))
        preset = aoa_preset if aoa_preset is not None else aoa_table.get("preset")
        aoa = AoaModel.s0_preset(int(preset)) if preset is not None else _model(AoaModel, aoa_table, "aoa")
        specs = [_device(name, spec, receiver) for name, spec in raw.get("devices", {}).items()]
    except KeyError as exc:
        raise ScenarioError(f"scenario {name_or_path} lacks {exc}") from None
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ScenarioError):
            raise
        raise ScenarioError(f"scenario {name_or_path}: {exc}") from None
    path_loss = _model(PathLossModel, raw.get("radio", {}), "radio")
    if path_loss.reflections is None:  # walls reflect where there are walls (docs/emulator.md)
        path_loss = replace(path_loss, reflections=bool(obstacles))
    return Scenario(
        name=str(raw.get("name", name_or_path)),
        description=str(raw.get("description", "")),
        world=World(start, targets, obstacles, bounds),  # type: ignore[arg-type]
        path_loss=path_loss,
        aoa=aoa,
        devices=specs,
        robot_radius=float(robot.get("radius", 0.25)),
        robot_tag=robot.get("tag"),
        robot_tag_interval_ms=float(robot.get("tag_interval_ms", 20.0)),
        robot_height=None if robot.get("height") is None else float(robot["height"]),
        vehicle=_vehicle(robot, name_or_path),
        radio=profile,
        rssi={} if profile is None else dict(profile.rssi),
        room_seed=seed if room_seed is None else room_seed,
    )


def _radio(receiver: str | None, aoa_preset: int | None, radio: str | RadioProfile) -> RadioProfile | None:
    """load's choices checked, and the radio profile they name (None: each paper's own noise)."""
    if receiver is not None and receiver not in BLE_RECEIVERS:
        raise ScenarioError(f"receiver must be one of {BLE_RECEIVERS}, not {receiver!r}")
    if aoa_preset is not None and radio != IDEAL:
        raise ScenarioError("--aoa-preset is S0's idealised noise: give it with --radio ideal, or leave it out")
    if aoa_preset is not None and aoa_preset not in range(1, 6):
        raise ScenarioError("AoA preset must be 1..5 (S0 Table 2)")
    try:
        return radio if isinstance(radio, RadioProfile) else resolve(radio)
    except ProfileError as exc:
        raise ScenarioError(str(exc)) from None


def _target(t: dict[str, Any], forced: tuple[float, float] | None, bounds: tuple[float, ...],
            obstacles: list[Obstacle], rng: np.random.Generator) -> Target:
    """One ``[[targets]]`` entry; ``forced``: its position given on the command line."""
    if forced is not None:
        position = forced
    elif t.get("position", "random") == "random":
        position = _random_free_point(bounds, obstacles, rng)
    else:
        position = _point(t["position"])
    return Target(
        id=str(t["id"]), kind=str(t["kind"]), position=position,
        height=float(t.get("height", 0.0)),
        path=[_point(p) for p in t.get("path", [])], speed=float(t.get("speed", 0.0)),
        interval_ms=float(t.get("interval_ms", 20.0)), jitter_ms=float(t.get("jitter_ms", 0.0)),
        tx_power_dbm=float(t.get("tx_power_dbm", 0.0)), heading=float(t.get("heading", 0.0)),
        timetable=_timetable(t.get("timetable", []), f"[[targets]] {t['id']}"),
    )


def _device(name: str, spec: dict[str, Any], receiver: str | None) -> DeviceSpec:
    """One ``[devices.NAME]``: its type checked against the device table (read now, so a kind
    added to the table is known at once); ``receiver`` replaces every BLE receiver's type."""
    options = dict(spec)
    kind = options.pop("type", None)
    if kind not in devices.BOARDS:
        served = devices.KINDS[kind].emulated_as if isinstance(kind, str) and kind in devices.KINDS else None
        raise ScenarioError(f"[devices.{name}] type must be one of {tuple(devices.BOARDS)}, not {kind!r}"
                            + (f"; a {kind} is served by {served}" if served else ""))
    if receiver is not None and kind in BLE_RECEIVERS:
        kind = receiver
    return DeviceSpec(name, kind, options)


def _vehicle(robot: dict[str, Any], where: str) -> dict[str, Any] | None:
    """``[robot.mavlink]``: the scenario's base is an emulated MAVLink vehicle (the options of
    ``--robot mavlink``); a copter flies at the robot's ``height``."""
    options = robot.get("mavlink")
    if options is None:
        return None
    if not isinstance(options, dict):
        raise ScenarioError(f"scenario {where}: [robot.mavlink] must be a table of the vehicle's options")
    options = dict(options)
    if options.get("vehicle") == "copter" and "height" in robot:
        options.setdefault("altitude", float(robot["height"]))
    return {"kind": "mavlink", "gcs": None, "options": options}

