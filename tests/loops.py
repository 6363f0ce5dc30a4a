"""Homing loops for tests, built by the one run assembly (host/homing/assembly.py) on ports
the test made: a pty's HostPort, the emulator's in-process pipe, a replay."""

from __future__ import annotations

from typing import Any

from rfhoming.host.homing import assembly
from rfhoming.host.homing.assembly import METHODS, Device, Homing
from rfhoming.host.homing.config import Config
from rfhoming.host.homing.loop import HomingLoop, RunLog


def loop_on(controller: Any, base: Any, sensors: Any, config: Config = Config(), runlog: RunLog | None = None, *,
            role: str | None = None, kind: str | None = None, base_kind: str | None = None,
            **plan: Any) -> HomingLoop:
    """The loop of ``controller`` (a METHODS name or a controller object) with the robot base
    (of ``base_kind``, default rfhoming's) on port ``base`` and its sensor(s) on ``sensors``
    (one port or a list), each of ``kind`` (default: the role's)."""
    role = role or METHODS[controller].role
    ports = sensors if isinstance(sensors, list) else [sensors]
    devices = [Device("base", port=base, kind=base_kind), *(Device(role, port=p, kind=kind) for p in ports)]
    return assembly.build(Homing(controller, devices, config, runlog=runlog, **plan)).loop
