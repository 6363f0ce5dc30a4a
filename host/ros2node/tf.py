"""Each tag a TF frame on /tf (tf2_msgs/TFMessage), for ``rfhoming node``. Where ROS 2 is installed
tf2_msgs is there and the node's own publisher sends it; ROS 2's Python wheels have no tf2_msgs,
so there the node's process publishes it through Cyclone DDS on the node's domain, with the type
--ros2 uses (host/export/ros2live.py), and the graph shows /tf written by a bare DDS participant."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

from rfhoming.host.export import frames, rosmsgs

Send = Callable[[str, str, tuple[float, float]], None]


class TagFrames:
    """parent -> child at (x, y), stamped now, on /tf."""

    def __init__(self, node: Any) -> None:
        try:
            from tf2_msgs.msg import TFMessage  # noqa: F401 - there: the node's own publisher
        except ImportError:
            self.send = _cyclone(node.context.get_domain_id())
            self.by = "cyclonedds"
        else:
            self.send = _rclpy(node)
            self.by = "rclpy"

    def publish(self, parent: str, child: str, xy: tuple[float, float]) -> None:
        self.send(parent, child, xy)


def _rclpy(node: Any) -> Send:
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    publisher = node.create_publisher(TFMessage, "/tf", 100)

    def send(parent: str, child: str, xy: tuple[float, float]) -> None:
        tf = TransformStamped()
        tf.header.stamp, tf.header.frame_id, tf.child_frame_id = node.get_clock().now().to_msg(), parent, child
        tf.transform.translation.x, tf.transform.translation.y = xy
        tf.transform.rotation.w = 1.0
        publisher.publish(TFMessage(transforms=[tf]))

    return send


def _cyclone(domain: int) -> Send:
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from rfhoming.host.dds import participant
    from rfhoming.host.export.ros2live import idl_type, sample
    from rfhoming.protocol import ros2
    from rfhoming.protocol.ros2dds import DEFAULT_QOS

    # ROS 2's discovery range, as rmw reads it: SUBNET reaches the network, anything else this machine
    discovery = "subnet" if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() == "SUBNET" else "localhost"
    dp = participant(domain, discovery)
    writer = DataWriter(dp, Topic(dp, ros2.dds_topic("/tf"), idl_type(rosmsgs.TF)), qos=DEFAULT_QOS)

    def send(parent: str, child: str, xy: tuple[float, float]) -> None:
        _, typename, message = rosmsgs.transforms("/tf", time.time(), [
            frames.Transform(parent, child, (xy[0], xy[1], 0.0), 0.0)])
        writer.write(sample(typename, message))

    return send
