"""``rfhoming emulate``: run a scenario and serve its devices on ptys or TCP until interrupted."""

from __future__ import annotations

import argparse
from collections.abc import Callable
import os
import re
from importlib.util import find_spec
from typing import Any

from rfhoming.cli.args import duration, fault, nonempty, output_file, path, seed, speed, xy
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import GROWING, IDEAL, MEASURED, add_radio_option

BLE_RECEIVERS = ("esp32", "at86rf212", "esp-at", "hci")
"""emulator/scenario.py's BLE_RECEIVERS, the device table's boards with the "ble" role (a test
holds them equal), named here so that building the parsers loads neither."""


def presets() -> list[str]:
    """emulator/scenario.py's presets (a test holds them equal), without loading the emulator or
    importlib.resources (which costs --version a fifth of its time)."""
    spec = find_spec("rfhoming.emulator.scenarios")
    folders = spec.submodule_search_locations if spec is not None else None
    return sorted(name[:-5] for folder in folders or () for name in os.listdir(folder) if name.endswith(".toml"))


HELP = """\
Run an emulated world and serve each device where a host opens it like real hardware:
a pseudo-terminal per device (default; a stable symlink path) or TCP on 127.0.0.1
(pyserial URL socket://127.0.0.1:PORT). One JSON line per device endpoint is printed,
then the world runs until Ctrl-C.

examples:
  rfhoming emulate s0-open --seed 3 --truth truth.jsonl
  rfhoming emulate s0-open --radio ideal          (the paper's idealised noise, not real boards' errors)
  rfhoming emulate s2-c --tcp --speed 10
  rfhoming emulate s3-arena --receiver esp-at     (the robot's scanner is an ESP32 with ESP-AT)
  rfhoming emulate s3-arena --receiver hci        (... a Bluetooth controller: hci:serial:PATH)
  rfhoming emulate s0-open --lockstep --fault unplug@aoa:at=5,for=2 --fault ber:rate=1e-5
  rfhoming emulate s0-open --pose-from ros2:/ground_truth/pose,domain=7   (the radios ride on a ROS 2 robot)

faults (repeatable): KIND[@DEVICE][:key=value,...]
  ber:rate=R  drop:rate=R  garbage:every=S,len=N  unplug:at=S,for=S  reboot:at=S  baud:at=S,rate=B
  after_bytes=N instead of at=S: once the host has written to the device (set it up) and the
  device has sent N bytes since, whatever the clock says -- e.g. unplug@aoa:after_bytes=4000,for=1
"""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("emulate", help="run an emulated world with devices on ptys or TCP",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", type=nonempty, help=f"a preset ({', '.join(presets())}) or a .toml file")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="a pseudo-terminal per device (default)")
    where.add_argument("--tcp", action="store_true", help="TCP on 127.0.0.1 per device")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=speed, default=1.0, help="simulated seconds per wall second (default 1; 0 = as fast as possible)")
    pace.add_argument("--lockstep", action="store_true", help="advance a control period only after the host's velocity command")
    p.add_argument("--seed", type=seed, default=0, help="seed of every random stream (default 0)")
    p.add_argument("--target", type=xy, help="first target's position X,Y in metres, e.g. --target=-3.5,2 "
                   "(default: the scenario's, random per seed)")
    p.add_argument("--receiver", choices=BLE_RECEIVERS,
                   help="serve every BLE RSSI receiver as this device: esp32 (rfhoming frames), esp-at "
                   "(Espressif's AT firmware) or hci (a Bluetooth controller over H4, needs rfhoming[hci])")
    p.add_argument("--aoa-preset", type=int, choices=range(1, 6), help="S0 Table 2 noise configuration 1-5 "
                   "(idealised noise: --radio ideal, the default with it)")
    add_radio_option(p, None, f"{MEASURED}; {IDEAL} with --aoa-preset")
    p.add_argument("--fault", type=fault, action="append", default=[], metavar="SPEC", help="inject a fault (see above)")
    p.add_argument("--truth", type=output_file, help="write the true robot pose and target positions as JSON lines" + GROWING)
    p.add_argument("--duration", type=duration, help="stop after this many simulated seconds")
    p.add_argument("--robot", type=robot_kind, metavar="ros2[:...] | mavlink[:udpout:HOST:PORT][,...]",
                   help="the robot base as a ROS 2 robot over DDS (ros2[:domain=N,ns=NS,discovery=subnet,stamped=1]: "
                        "/odom, /scan, /tf out, /cmd_vel in; this machine only unless discovery=subnet), or as a "
                        "MAVLink vehicle on UDP 127.0.0.1 (mavlink[:udpout:127.0.0.1:PORT][,autopilot=ardupilot|px4,"
                        "vehicle=rover|copter,mode=HOLD,armed=1,prearm=fail,timeout=S]), not a serial port "
                        "(docs/hardware.md, Robots)")
    p.add_argument("--pose-from", type=pose_source, metavar="ros2:TOPIC[,domain=N,frame=world,discovery=subnet,...]",
                   help="the robot is a ROS 2 robot of its own (a simulator's, a real one): the emulated receivers "
                        "ride on it, moved by its pose on TOPIC (nav_msgs/Odometry or geometry_msgs/PoseStamped, "
                        "e.g. a Gazebo robot's ground truth); the scenario's base is not served -- drive that robot "
                        "with run --base ros2:. frame=start (default): its first pose is the scenario's start pose; "
                        "frame=world: its poses are the scenario's coordinates. It warns when no pose comes within "
                        "wait=S (5), when poses stop for stale=S (1: the radios then hear nothing until they come "
                        "again), and of poses refused: not finite, or not in frame_id=ID (the first's) "
                        "(docs/emulator.md)")
    p.add_argument("--link-dir", type=path, help="directory for the pty symlinks (default: a new temp dir)")
    p.set_defaults(func=command("emulate"))


TOPIC = re.compile(r"/?[A-Za-z_~][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")
"""A ROS 2 topic name (design.ros2.org "Topic and Service names"), relative or absolute."""


def _seconds(text: str) -> float | None:
    """A positive, finite number of seconds, or None."""
    try:
        value = float(text)
    except ValueError:
        return None
    return value if 0 < value < float("inf") else None


POSE_SOURCE: dict[str, Callable[[str], Any]] = {
    "domain": lambda v: int(v) if v.isdigit() and int(v) <= 232 else None,
    "discovery": lambda v: v if v in ("localhost", "subnet") else None,
    "frame": lambda v: v if v in ("start", "world") else None,
    "wait": _seconds,
    "stale": _seconds,
    "frame_id": lambda v: v if TOPIC.fullmatch(v) else None,
}


def pose_source(text: str) -> dict[str, Any]:
    """``ros2:TOPIC[,domain=N,discovery=localhost|subnet,frame=start|world,wait=S,stale=S,frame_id=ID]``
    -> PoseFollower's arguments (emulator/ros2pose.py)."""
    head, *pairs = text.split(",")
    kind, _, topic = head.partition(":")
    if kind != "ros2" or not TOPIC.fullmatch(topic):
        raise argparse.ArgumentTypeError(f"{text!r}: give ros2:TOPIC, a ROS 2 topic of nav_msgs/Odometry or "
                                         "geometry_msgs/PoseStamped, e.g. ros2:/ground_truth/pose,domain=7")
    settings: dict[str, Any] = {"topic": topic}
    for pair in pairs:
        key, _, raw = pair.partition("=")
        if key not in POSE_SOURCE:
            raise argparse.ArgumentTypeError(f"{text!r}: --pose-from ros2: takes {', '.join(POSE_SOURCE)}")
        settings[key] = POSE_SOURCE[key](raw)
        if settings[key] is None:
            raise argparse.ArgumentTypeError(f"{text!r}: bad {key}={raw!r} (domain=0..232, "
                                             "discovery=localhost|subnet, frame=start|world, wait= and stale= "
                                             "seconds above 0, frame_id=a frame name)")
    return settings


def robot_kind(text: str) -> dict[str, Any]:
    """``--robot``: a ROS 2 robot or a MAVLink vehicle."""
    return mavlink_robot(text) if text.partition(":")[0].partition(",")[0] == "mavlink" else ros2_robot(text)


MAVLINK_ROBOT: dict[str, Callable[[str], Any]] = {"autopilot": str, "vehicle": str, "mode": str, "armed": lambda v: v in ("1", "yes", "true"),
                 "prearm": lambda v: v != "fail", "timeout": float}


def mavlink_robot(text: str) -> dict[str, Any]:
    """``mavlink[:udpout:HOST:PORT][,key=value...]`` -> MavlinkLink's arguments (emulator/mavlinkrobot.py)."""
    head, *pairs = text.split(",")
    where = head.partition(":")[2]
    gcs = None
    if where:
        host, _, port = where.removeprefix("udpout:").rpartition(":")
        if not where.startswith("udpout:") or host not in ("127.0.0.1", "localhost") or not port.isdigit():
            raise argparse.ArgumentTypeError(f"{text!r}: the emulated vehicle sends to udpout:127.0.0.1:PORT (where "
                                             "the ground station listens), or leave it out and connect to the vehicle")
        gcs = ("127.0.0.1", int(port))
    options: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        if key not in MAVLINK_ROBOT:
            raise argparse.ArgumentTypeError(f"{text!r}: --robot mavlink takes {', '.join(MAVLINK_ROBOT)}")
        try:
            options[{"prearm": "prearm_ok", "timeout": "command_timeout_s"}.get(key, key)] = MAVLINK_ROBOT[key](value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: bad {key}={value!r}") from None
    return {"kind": "mavlink", "gcs": gcs, "options": options}


def ros2_robot(text: str) -> dict[str, Any]:
    """``ros2[:domain=N,ns=NS,discovery=localhost|subnet,stamped=0|1]`` -> Ros2Link's arguments."""
    kind, _, rest = text.partition(":")
    if kind != "ros2":
        raise argparse.ArgumentTypeError(f"{text!r}: the robot can be ros2[:domain=N,ns=NS] or mavlink[:udpout:127.0.0.1:PORT][,autopilot=px4...]")
    from rfhoming.host import portspec

    try:
        spec = portspec.parse("ros2:" + rest)
    except portspec.PortSpecError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if set(spec.settings) - {"domain", "ns", "discovery", "stamped"}:
        raise argparse.ArgumentTypeError(f"{text!r}: --robot ros2 takes domain=, ns=, discovery= and stamped=")
    return {"domain": spec.settings.get("domain", 0), "ns": str(spec.settings.get("ns", spec.where)).strip("/"),
            "discovery": spec.settings.get("discovery", "localhost"),
            "stamped": spec.settings.get("stamped", False) in (True, "1")}
