"""Cyclone DDS's receive sockets kept to this machine's traffic, under ``discovery=localhost``.

Cyclone binds its unicast receive sockets to INADDR_ANY whatever its configuration
(eclipse-cyclonedds ``src/core/ddsi/src/ddsi_udp.c``, ``ddsi_udp_create_conn``: ``bind_to_any``
for ``DDSI_TRAN_QOS_RECV_UC``; open reports: github.com/eclipse-cyclonedds/cyclonedds/issues/1923,
github.com/eclipse-cyclonedds/cyclonedds/issues/2090): with the loopback interface, no
multicast and 127.0.0.1 peers it sends from and advertises 127.0.0.1 only, yet its discovery and
data ports (7400 + 250·domain + 10 + 2·index, and + 1) take datagrams from the network. No
option of the installed version (11.0.1: ``General/Interfaces``, ``DontRoute``,
``ExternalNetworkAddress``) changes the bind. So each of those sockets of this process gets a
classic BPF socket filter (``SO_ATTACH_FILTER``, no privilege needed) that drops, in the kernel,
every datagram whose IPv4 source is not in 127.0.0.0/8 before Cyclone can read it. ``ss`` still
shows them on 0.0.0.0; what reaches them is this machine's loopback traffic only. A datagram in
the instant between the socket's bind and the filter is not dropped (Cyclone opens them while the
participant is made). Linux only; elsewhere :func:`guard` raises OSError.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import socket
import stat

SO_ATTACH_FILTER = 26  # asm-generic/socket.h (SO_GET_FILTER is the same number)
SKF_NET_OFF = -0x100000  # linux/filter.h: offsets from the network (IP) header
LOOPBACK_ONLY = (
    (0x30, 0, 0, (SKF_NET_OFF + 12) & 0xFFFFFFFF),  # ldb [ip source's first byte]
    (0x15, 0, 1, 127),  # jeq #127: keep, else drop
    (0x06, 0, 0, 0xFFFFFFFF),  # ret: the whole datagram
    (0x06, 0, 0, 0),  # ret 0: dropped
)
PARTICIPANTS = 31  # participant indices Cyclone may take: 0 to MaxAutoParticipantIndex (30, protocol/ros2dds.py)


class _Instruction(ctypes.Structure):
    _fields_ = [("code", ctypes.c_uint16), ("jt", ctypes.c_uint8), ("jf", ctypes.c_uint8), ("k", ctypes.c_uint32)]


class _Program(ctypes.Structure):
    _fields_ = [("len", ctypes.c_uint16), ("filter", ctypes.POINTER(_Instruction))]


def sockets() -> set[int]:
    """This process's socket descriptors now (to tell the ones a participant opens)."""
    found = set()
    for name in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            if stat.S_ISSOCK(os.fstat(int(name)).st_mode):
                found.add(int(name))
    return found


def ports(domain: int) -> range:
    """The unicast ports of Cyclone's participants on ``domain`` ([RTPS] §9.6.1.1: PB 7400, DG 250, d1 10, PG 2)."""
    first = 7400 + 250 * domain + 10
    return range(first, first + 2 * PARTICIPANTS)


def guard(domain: int, before: set[int]) -> int:
    """Attach the loopback-only filter to every IPv4 UDP socket bound to 0.0.0.0 on one of
    ``domain``'s ports that this process opened since ``before``; how many. OSError when the
    system cannot (not Linux, no /proc)."""
    code = (_Instruction * len(LOOPBACK_ONLY))(*(_Instruction(*i) for i in LOOPBACK_ONLY))
    program = bytes(_Program(len(LOOPBACK_ONLY), code))  # points at ``code``, alive until the last setsockopt
    guarded = 0
    for fd in sockets() - before:
        with socket.socket(fileno=os.dup(fd)) as sock:
            if sock.family != socket.AF_INET or sock.type != socket.SOCK_DGRAM:
                continue
            host, port = sock.getsockname()
            if host == "0.0.0.0" and port in ports(domain):
                sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, program)
                guarded += 1
    return guarded
