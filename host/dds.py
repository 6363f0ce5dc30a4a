"""Joining a ROS 2 domain over DDS, and its readers and writers: the host's network I/O for ROS 2
(the types, QoS profiles and domain configuration are rfhoming.protocol.ros2dds's, which does no
I/O). Imported only where DDS is used (the ros2 extra)."""

# no `from __future__ import annotations`: as in protocol/ros2dds.py

import logging
import threading
from collections.abc import Callable
from typing import Any

from cyclonedds.core import DDSException, Listener, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.internal import InvalidSample
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from rfhoming.host import dds_guard
from rfhoming.protocol import ros2
from rfhoming.protocol.ros2dds import DEFAULT_QOS, SENSOR_QOS, TYPES, DdsError, config

log = logging.getLogger(__name__)
_participants: dict[int, tuple[Domain | None, DomainParticipant, str]] = {}
_lock = threading.Lock()


def participant(domain: int, discovery: str = "localhost") -> DomainParticipant:
    """One participant per domain per process (two ports on a domain share it, as rclpy's
    nodes share a context). A domain is opened with one discovery range for the process."""
    with _lock:
        held = _participants.get(domain)
        if held is not None:
            if held[2] != discovery:
                raise DdsError(f"ROS 2 domain {domain} is already open with discovery={held[2]} in this process")
            return held[1]
        xml = config(domain, discovery)
        before = dds_guard.sockets()
        try:
            dom = _domain(domain, xml)
            dp = DomainParticipant(domain)
        except Exception as exc:  # cyclonedds raises DDSException with a return code
            raise DdsError(f"cannot join ROS 2 domain {domain} ({exc})") from None
        if xml is not None:
            _guard(domain, before)
        _participants[domain] = (dom, dp, discovery)
        return dp


def _guard(domain: int, before: set[int]) -> None:
    """Cyclone's receive sockets take loopback datagrams only (host/dds_guard.py); where the
    system cannot filter them, said once."""
    try:
        dds_guard.guard(domain, before)
    except OSError as exc:
        log.warning("ROS 2 domain %d: Cyclone DDS listens on every interface and its sockets could not be kept to "
                    "loopback traffic (%s); a firewall must keep the network off ports %d-%d", domain,
                    exc.strerror or exc, dds_guard.ports(domain)[0], dds_guard.ports(domain)[-1])


def _domain(domain: int, xml: str | None) -> Domain | None:
    """The domain with its configuration, or None where it needs none or exists already in this
    process (the emulated ROS 2 robot, run in-process by a test or a campaign, made it first)."""
    if xml is None:
        return None
    try:
        return Domain(domain, xml)
    except DDSException as exc:
        if exc.code == DDSException.DDS_RETCODE_PRECONDITION_NOT_MET:
            return None
        raise


def reader(dp: DomainParticipant, topic: str, ros_type: str, on_sample: Callable[[Any], None],
           qos: Qos = SENSOR_QOS) -> DataReader[Any]:
    """A reader of a ROS topic; ``on_sample`` is called on Cyclone's listener thread."""
    def on_data(r: DataReader[Any]) -> None:
        for sample in r.take(64):
            if not isinstance(sample, InvalidSample):  # a writer gone (disposed, unregistered): no data
                on_sample(sample)

    return DataReader(dp, Topic(dp, ros2.dds_topic(topic), TYPES[ros_type]), qos=qos,
                      listener=Listener(on_data_available=on_data))


def writer(dp: DomainParticipant, topic: str, ros_type: str, qos: Qos = DEFAULT_QOS) -> DataWriter[Any]:
    return DataWriter(dp, Topic(dp, ros2.dds_topic(topic), TYPES[ros_type]), qos=qos)


