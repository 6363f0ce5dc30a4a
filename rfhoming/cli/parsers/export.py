"""``rfhoming export``: a run's files -> an MCAP log of ROS 2 messages."""

from __future__ import annotations

import argparse

from rfhoming.cli.args import output_file, path
from rfhoming.cli.parsers import command

EXPORT_HELP = """\
Write a run as ROS 2 messages in an MCAP file that Foxglove, rosbags and `ros2 bag` read:
/tf and /tf_static (REP 105 frames: map, odom, base_link, and the sensors' frames from the
--config's [mounting]), /odom (nav_msgs/Odometry), /scan (sensor_msgs/LaserScan), the loop's
commands on /rfhoming/cmd_vel (geometry_msgs/Twist; not /cmd_vel, which a played log would drive a
robot with), /rfhoming/target (geometry_msgs/PointStamped), and rfhoming_msgs' AoaAngle, RssiReading,
AntennaSet and Bearing (their .msg files ship in rfhoming/host/export/rfhoming_msgs). Give the
run log and its capture for everything; a capture alone gives the devices' own streams and the
commands sent to the base; a run log alone gives commands, estimates and bearings.
It prints the message count per topic as one JSON object.

examples:
  rfhoming export run.jsonl --capture run.pcapng -o run.mcap
  rfhoming export run.jsonl --capture run.pcapng --config robot.toml -o run.mcap
  rfhoming export rfhoming-demo/capture.pcapng -o devices.mcap
  rfhoming export run.jsonl -o decisions.mcap
"""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("export", help="a run log and/or capture -> MCAP with ROS 2 messages",
                       description=EXPORT_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", type=path, metavar="RUN", help="the run log (run.jsonl), or a pcapng capture alone")
    p.add_argument("--capture", type=path, help="the run's pcapng capture (odometry, scans, raw readings)")
    p.add_argument("-o", "--output", type=output_file, required=True, help="MCAP file to write (as FILE.part, renamed to FILE once whole)")
    p.add_argument("--config", type=path, help="the run's TOML config, for where the sensors sit on the robot "
                   "([mounting]; default: all at its centre)")
    p.set_defaults(func=command("export"))
