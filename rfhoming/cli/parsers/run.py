"""``rfhoming run``, ``demo`` and ``config``: homing against real devices or the emulator."""

from __future__ import annotations

import argparse
from pathlib import Path

from rfhoming.cli.args import nonempty, output_file, output_folder, path, seed, speed, xy
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import (
    GROWING,
    MEASURED,
    add_foxglove_option,
    add_port_defaults,
    add_radio_option,
    add_ros2_option,
    add_watch_options,
)
from rfhoming.cli.parsers.io import CONTROLLERS

MCAP_HELP = ("also record the run as ROS 2 messages (odometry, scans, commands, estimates, readings) in "
             "this MCAP file, for Foxglove, rosbags or ros2 bag (needs the ros extra)" + GROWING)

DEMO_HELP = """\
Start the emulator in its own process on pseudo-terminals (in lockstep: its world waits
for the host), run the host's homing loop against it until arrival or failure, and print
a summary. It writes the trajectory plot, the capture, the run log and the truth file to
--out; `rfhoming replay OUT/capture.pcapng --run` runs the same loop again on its bytes.

What varies from run to run with the same seed: on ptys the XPLR-AOA's and the base's bytes
reach the host in whatever order the operating system delivers two ports, so a reading
can meet a different odometry record and the simulated time and errors move by a few
hundredths; the latencies are wall-clock figures. --in-process joins the emulator and the
host by the emulator's in-process byte pipe (as the campaigns run) and gives the same
summary, line for line, for the same seed, without the latency lines -- except s4-air, whose
MAVLink copter talks to the host over UDP on 127.0.0.1 even in process: its datagrams meet the
readings in the order the sockets deliver them.

examples:
  rfhoming demo
  rfhoming demo --seed 7 --json
  rfhoming demo --in-process               # the same summary for the same seed, every time
  rfhoming demo --scenario s0-open --target=-6,4 --out /tmp/demo
  rfhoming demo --scenario s0-house                    (radios as bad as real ones: docs/emulator.md)
  rfhoming demo --radio ideal              # the paper's idealised noise instead
  rfhoming demo --scenario s3-arena --receiver hci     (S3 on HCI advertising reports)
  rfhoming demo --scenario s4-air --in-process  (S4: a copter surveys ten beacons; limit >= 600 s)
  rfhoming demo --mcap run.mcap            # and a ROS 2 log of the run
  rfhoming demo --foxglove                 # watch it live at robot time: Foxglove -> ws://127.0.0.1:8765
"""

RUN_HELP = """\
Home on a tag with real devices or emulator endpoints. The XPLR-AOA gives bearings; the base
takes velocity commands and gives odometry. The robot stops when data goes stale, on
arrival, on any error and on Ctrl-C. Exit status: 0 arrived, 1 did not, 2 usage/port errors
(a port that cannot be opened, a device not set up within its timeout=, several tags in view
and none chosen with --tag).

examples:
  rfhoming run --aoa /dev/ttyUSB0 --base /dev/ttyACM0 --log run.jsonl --capture run.pcapng
  rfhoming run --aoa /dev/ttyUSB0 --base /dev/ttyACM0 --tag CCF9578E0D8A
  rfhoming run --aoa /dev/ttyUSB0,baud=1000000,tags=CCF9578E0D8A --base /dev/ttyACM0,baud=115200
  rfhoming run --aoa socket://127.0.0.1:40123 --base socket://127.0.0.1:40124 --config robot.toml
  rfhoming run --config robot.toml          # ports from its [devices.aoa] and [devices.base]
  rfhoming run --config robot.toml --mcap run.mcap   # and a ROS 2 log for Foxglove / rosbags
  rfhoming run --config robot.toml --foxglove        # and a live view in Foxglove
  rfhoming run --controller rss --rss /dev/ttyACM1 --base /dev/ttyACM0
  rfhoming run --controller anchors --site site.toml --base /dev/ttyACM0
  rfhoming run --aoa serve://127.0.0.1:2948 --base /dev/ttyACM0   # share the XPLR-AOA with viewers
  rfhoming run --aoa /dev/ttyUSB0 --base mavlink:udpin:127.0.0.1:14550,arm=1   # ArduPilot/PX4: arms it, ends in HOLD
"""

NODE_HELP = """\
The homing run as a ROS 2 node (rclpy: the system's ROS 2, or pip install 'rfhoming[ros2node]'),
on ROS_DOMAIN_ID, with the same devices as run. Services ~/home (start homing on the tag
parameter; empty: the only tag in view) and ~/cancel (stop the robot), both std_srvs/Trigger;
~/feedback and ~/result (diagnostic_msgs/DiagnosticStatus), ~/estimate
(PoseWithCovarianceStamped); /diagnostics at 1 Hz; each tag a TF frame FRAME -> tag_<id> on /tf.
Parameter mode=nav2 hands the estimate to Nav2 on goal_pose instead of driving /cmd_vel.
A ros2: base without domain= is on ROS_DOMAIN_ID. docs/usage.md, "rfhoming node".

examples:
  rfhoming node --aoa /dev/ttyUSB0 --base ros2:
  rfhoming node --aoa /dev/ttyUSB0 --base ros2: --ros-args -r __ns:=/robot1 -p mode:=nav2
  ros2 param set /rfhoming tag CCF9578E0D8A && ros2 service call /rfhoming/home std_srvs/srv/Trigger
"""


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("demo", help="emulator + host: a full homing run, a summary and a plot",
                       description=DEMO_HELP, formatter_class=raw)
    p.add_argument("--scenario", type=nonempty, default="s0-open", help="scenario preset (default s0-open)")
    p.add_argument("--seed", type=seed, default=1, help="seed of the world (default 1)")
    p.add_argument("--target", type=xy, help="tag position X,Y, e.g. --target=-6,4 (default: random per seed)")
    p.add_argument("--out", type=output_folder, default=Path("rfhoming-demo"), help="output folder (default ./rfhoming-demo)")
    p.add_argument("--config", type=path, help="TOML config (see rfhoming config --print-default)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--receiver", choices=("esp32", "esp-at", "hci"),
                   help="s3-arena: the robot's BLE RSSI receiver -- esp32 (rfhoming frames, default), esp-at "
                   "(ESP32 with Espressif's AT firmware) or hci (a Bluetooth controller, needs rfhoming[hci])")
    p.add_argument("--mcap", type=output_file, metavar="FILE", help=MCAP_HELP)
    p.add_argument("--in-process", action="store_true",
                   help="the emulator in this process on its byte pipe: the same summary for the same seed")
    p.add_argument("--speed", type=speed, metavar="N", help="simulated seconds per wall second (0: lockstep, as "
                   "fast as the host answers); default 1 with --foxglove, else 0")
    add_radio_option(p, MEASURED, MEASURED)
    add_foxglove_option(p)
    add_watch_options(p)
    p.set_defaults(func=command("demo"))

    p = sub.add_parser("run", help="home on a tag with real devices or emulator endpoints",
                       description=RUN_HELP, formatter_class=raw)
    add_device_options(p)
    p.add_argument("--log", type=output_file, help="JSON-lines run log of every measurement, estimate and command" + GROWING)
    p.add_argument("--capture", type=output_file, help="pcapng capture of every byte" + GROWING)
    p.add_argument("--mcap", type=output_file, metavar="FILE", help=MCAP_HELP)
    add_ros2_option(p, "what the run senses (a ROS 2 base's own /odom, /scan and /tf are left to it)")
    add_foxglove_option(p)
    p.set_defaults(func=command("run"))

    p = sub.add_parser("node", help="the homing run as a ROS 2 node: services, parameters, diagnostics, tags on /tf",
                       description=NODE_HELP, formatter_class=raw)
    add_device_options(p)
    p.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[], metavar="ARG",
                   help="the rest goes to ROS 2 as a node's --ros-args: -r __ns:=/robot1, -r __node:=NAME, "
                        "-r FROM:=TO, -p NAME:=VALUE, --params-file FILE")
    p.set_defaults(func=command("node"))

    p = sub.add_parser("config", help="print the default config, or check a config file")
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--print-default", action="store_true", help="print the commented default TOML")
    group.add_argument("--check", type=path, metavar="FILE", help="check a config file")
    p.set_defaults(func=command("config"))


def add_device_options(p: argparse.ArgumentParser) -> None:
    """The devices of a homing run (run and node): each role's port spec, the controller, the
    tag, the site, the config and the ports' defaults."""
    p.add_argument("--aoa", type=nonempty, metavar="SPEC", help="the XPLR-AOA, for --controller aoa and dock: a port spec "
                   "WHERE[,baud=,flow=,tags=] (e.g. /dev/ttyUSB0,baud=1000000); settings it leaves out come "
                   "from the config's [devices.aoa]")
    p.add_argument("--rss", type=nonempty, metavar="SPEC", help="the four-dish AT86RF212 node, for --controller rss")
    p.add_argument("--ble", type=nonempty, metavar="SPEC", action="append",
                   help="the BLE RSSI receiver, for --controller trilat and survey: an ESP32 "
                   "scanner (rss-node:PATH), an ESP32 with ESP-AT (esp-at:PATH) or an HCI controller (hci:usb:0); "
                   "survey takes one --ble per receiver the vehicle carries")
    p.add_argument("--base", type=nonempty, metavar="SPEC", help="the robot base (e.g. /dev/ttyACM0,baud=115200)")
    p.add_argument("--controller", choices=CONTROLLERS, default="aoa",
                   help="homing method: aoa (S0, XPLR-AOA bearings), dock (S1, the station's AoA/RSSI of "
                        "the robot's tag, given with --aoa), rss (S2, four dishes + particle filter), "
                        "trilat (S3, BLE beacons at the places in [trilat.anchors], to [trilat] goal), "
                        "survey (S4, a vehicle carrying --ble receivers flies a lawn-mower over [s4] area, "
                        "localises the beacons and holds over [s4] home_on), "
                        "anchors (fixed XPLR-AOA anchors of --site locate the robot's own tag and the target's)")
    p.add_argument("--tag", type=nonempty, action="append", default=[], metavar="ID",
                   help="the tag to home on (12 hex digits; repeat or join with + for several ids of one "
                        "target). Without it, run listens for 2 s and homes on the only tag in view, or "
                        "stops and lists the tags it hears. Same as tags= in the --aoa spec")
    p.add_argument("--site", type=path, help="site file for --controller anchors (see rfhoming locate --help)")
    p.add_argument("--config", type=path, help="TOML config (see rfhoming config --print-default)")
    add_port_defaults(p)
