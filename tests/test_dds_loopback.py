"""DDS on this machine only under ``discovery=localhost`` (the default): every socket of
rfhoming's DDS participant is on 127.0.0.1, or -- Cyclone's receive sockets, which Cyclone
binds to 0.0.0.0 whatever its configuration (host/dds_guard.py) -- carries the filter that
drops every datagram from outside 127.0.0.0/8; that filter keeps a datagram from another address
out and lets loopback ones in; and ROS 2's own Fast DDS with docs/ros2/fastdds-loopback.xml
listens on 127.0.0.1 only. Before, the participant's ports took datagrams from the network."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

psutil = pytest.importorskip("psutil")
pytest.importorskip("cyclonedds")

from test_ros2 import random_domain  # noqa: E402

from rfhoming.host import dds_guard  # noqa: E402

PROFILE = Path(__file__).resolve().parents[1] / "docs" / "ros2" / "fastdds-loopback.xml"
PROBE = """
import json, os, psutil, socket
{join}
out = []
for c in psutil.Process(os.getpid()).net_connections(kind="inet"):
    with socket.socket(fileno=os.dup(c.fd)) as s:
        first = s.getsockopt(socket.SOL_SOCKET, 26, 64)[:2] if c.type == socket.SOCK_DGRAM else b""
    out.append([c.laddr.ip, c.laddr.port, first.hex()])
print(json.dumps(out))
"""


def sockets_of(join: str, env: dict[str, str] | None = None) -> list[tuple[str, int, str]]:
    """The inet sockets of a fresh process that ran ``join``: (address, port, the first
    instruction of its socket filter, hex; '' for none)."""
    code = textwrap.dedent(PROBE).format(join=join)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})
    assert done.returncode == 0, done.stderr
    import json

    return [tuple(s) for s in json.loads(done.stdout.splitlines()[-1])]


def test_the_dds_participant_takes_loopback_traffic_only() -> None:
    domain = random_domain()
    found = sockets_of(f"from rfhoming.host.dds import participant\nparticipant({domain})")
    ours = [s for s in found if s[1] in dds_guard.ports(domain) or s[0] == "127.0.0.1"]
    assert ours and {ip for ip, _, _ in found} <= {"127.0.0.1", "0.0.0.0"}, found
    assert all(first == "3000" for ip, _, first in found if ip == "0.0.0.0"), found  # ldb: the loopback filter


@pytest.mark.xfail(strict=True, reason="Cyclone DDS 11 binds its receive sockets to INADDR_ANY whatever its "
                                       "configuration (ddsi_udp.c; "
                                       "github.com/eclipse-cyclonedds/cyclonedds/issues/2090): filtered instead")
def test_the_dds_participant_binds_loopback_only() -> None:
    domain = random_domain()
    found = sockets_of(f"from rfhoming.host.dds import participant\nparticipant({domain})")
    assert {ip for ip, _, _ in found} == {"127.0.0.1"}, found


async def test_the_emulators_participant_is_filtered_too() -> None:
    """``emulate --pose-from`` (and ``--robot ros2``) join a domain too: the command filters
    their sockets as the host's participant does."""
    from rfhoming.cli.commands.emulate import start
    from rfhoming.emulator.runtime import Emulator
    from rfhoming.emulator.scenario import load

    domain = random_domain()
    emulator = Emulator(load("s0-open"), transport="pipe", pose_from={"topic": "/gt", "domain": domain})
    await start(emulator)
    try:
        found = [c for c in psutil.Process().net_connections(kind="udp") if c.laddr.port in dds_guard.ports(domain)]
        assert found and all(c.laddr.ip == "127.0.0.1" or first_instruction(c.fd) == "3000" for c in found), found
    finally:
        await emulator.close()


def first_instruction(fd: int) -> str:
    with socket.socket(fileno=os.dup(fd)) as sock:
        return sock.getsockopt(socket.SOL_SOCKET, dds_guard.SO_ATTACH_FILTER, 64)[:2].hex()


def test_the_filter_lets_loopback_in_and_keeps_other_sources_out() -> None:
    """On a socket bound as Cyclone binds its own: a datagram from this machine's non-loopback
    address (delivered on the machine, it never leaves it) is dropped, one from 127.0.0.1 is
    read -- sent after it, it is the first to come."""
    other = next((a.address for addrs in psutil.net_if_addrs().values() for a in addrs
                  if a.family == socket.AF_INET and not a.address.startswith("127.")), None)
    if other is None:
        pytest.skip("no IPv4 address but loopback on this machine")
    domain = random_domain()
    before = dds_guard.sockets()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:
        listener.bind(("0.0.0.0", dds_guard.ports(domain)[-1]))
        assert dds_guard.guard(domain, before) == 1
        for source, text in ((other, b"from the network side"), ("127.0.0.1", b"from loopback")):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
                sender.bind((source, 0))
                sender.sendto(text, (source, dds_guard.ports(domain)[-1]))
        listener.settimeout(30)  # a hang guard: the loopback datagram is there already
        data, (host, _) = listener.recvfrom(100)
    assert (data, host) == (b"from loopback", "127.0.0.1")


def test_the_fast_dds_profile_listens_on_loopback_only() -> None:
    pytest.importorskip("rclpy")
    join = ("import rclpy\nrclpy.init()\nnode = rclpy.create_node('probe')\n"
            "from std_msgs.msg import String\nnode.create_publisher(String, 'chatter', 10)")
    found = sockets_of(join, {"FASTRTPS_DEFAULT_PROFILES_FILE": str(PROFILE), "FASTDDS_DEFAULT_PROFILES_FILE": str(PROFILE),
                              "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp", "ROS_DOMAIN_ID": str(random_domain()),
                              "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT"})
    assert found and {ip for ip, _, _ in found} == {"127.0.0.1"}, found
