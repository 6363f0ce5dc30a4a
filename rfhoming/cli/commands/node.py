"""``rfhoming node``: the homing run as a ROS 2 node (rfhoming.host.ros2node.node), with the same
devices as ``rfhoming run``; a ros2: base that gives no domain= is on ROS_DOMAIN_ID, as the node."""

from __future__ import annotations

import argparse
import os
from dataclasses import replace

from rfhoming.cli.plans import plan_devices, tag_option
from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import CHOOSE_TAG_S, METHODS, Device, Homing
from rfhoming.host.homing.config import load
from rfhoming.host.portspec import PortSpecError
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.protocol.errors import Error

INSTALL = ("source ROS 2's setup (source /opt/ros/jazzy/setup.bash) or pip install 'rfhoming[ros2node]' "
           "(ROS 2 Jazzy's wheels: Linux x86_64, Python 3.11-3.14)")


class NoRclpy(Error):
    """rclpy, or a message package the node uses, cannot be imported."""


def run(args: argparse.Namespace) -> int:
    config = load(args.config)
    role = METHODS[args.controller].role
    devices, site = plan_devices(args, config, role)
    devices = [_on_ros_domain(d) for d in devices]
    given = tag_option(args.tag)

    def plan_for(tags: tuple[str, ...]) -> Homing:
        return Homing(args.controller, list(devices), config, site=site, tags=tags or given,
                      choose_tag_s=CHOOSE_TAG_S, probe_baud=args.probe_baud, baud=args.baud, flow=args.flow)

    assembly.check(plan_for(()))  # before the node is up: a plan that cannot run is said now
    try:
        from rfhoming.host.ros2node import node
    except ImportError as exc:
        raise NoRclpy(f"needs ROS 2's rclpy ({exc.name or exc} cannot be imported): {INSTALL}") from None
    node.serve(plan_for, args.ros_args)
    return 0


def _on_ros_domain(device: Device) -> Device:
    """A ros2: base with no domain= goes on ROS_DOMAIN_ID's domain (ROS 2's default, 0, if unset)."""
    if device.spec is None:
        return device
    spec = parse_spec(device.spec)
    if spec.kind != "ros2" or "domain" in spec.settings:
        return device
    text = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    if not text.isdigit() or int(text) > 232:
        raise PortSpecError(f"ROS_DOMAIN_ID={text!r} is not a ROS 2 domain (0-232): export a number, or give "
                            "--base ros2:domain=N")
    return replace(device, spec=replace(spec, settings={**spec.settings, "domain": int(text)}))
