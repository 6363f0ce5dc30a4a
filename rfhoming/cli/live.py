"""What the commands offer someone watching live: ``--foxglove[=PORT]``, the Foxglove view
(run, demo, listen, serve), ``--ros2``, the MCAP recording's topics published on ROS 2
(run, listen, locate, serve), and ``--mcap``, the same topics recorded (run, demo). The options
themselves are rfhoming.cli.parsers.common's."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from rfhoming.host.drivers.robot import RobotBase
from rfhoming.host.portspec import PortSpecError
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.host.sink import Sink
from rfhoming.protocol.errors import Error

if TYPE_CHECKING:  # imported when --ros2 is given: it needs cyclonedds
    from rfhoming.host.export.ros2live import Ros2Publisher

SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]  # what the view takes (host/foxglove_front.py)


def wait_for_viewer(view: Any, seconds: float, out: TextIO = sys.stderr) -> None:
    """Hold the run until a viewer subscribes (or ``seconds`` pass), saying so on ``out``."""
    if view is None or seconds <= 0:
        return
    print(json.dumps({"kind": "waiting", "for": "a viewer to subscribe", "timeout_s": seconds}), file=out, flush=True)
    if not view.wait_for_viewer(seconds):
        print(json.dumps({"kind": "no viewer", "after_s": seconds, "note": "running anyway"}), file=out, flush=True)


def linger(view: Any, seconds: float, out: TextIO = sys.stderr) -> None:
    """Keep the finished run's view up ``seconds`` (inf: until Ctrl-C)."""
    if view is None or seconds <= 0:
        return
    print(json.dumps({"kind": "lingering", "address": view.address, "seconds": None if math.isinf(seconds) else seconds,
                      "note": "Ctrl-C to stop"}), file=out, flush=True)
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(min(0.5, max(0.0, end - time.monotonic())))
    except KeyboardInterrupt:
        pass


def start_foxglove(args: argparse.Namespace, command: str, out: TextIO = sys.stderr, host: str = "127.0.0.1") -> Any:
    """The view if --foxglove was given (its address printed as a JSON line on ``out``), else
    None; SystemExit(2) with a one-line reason when it cannot start."""
    if getattr(args, "foxglove", None) is None:
        return None
    try:
        from rfhoming.host.foxglove_view import FoxgloveView
    except ImportError as exc:
        print(f"rfhoming {command}: --foxglove needs the foxglove extra ({exc.name} is missing): "
              "pip install 'rfhoming[foxglove]'", file=sys.stderr)
        raise SystemExit(2) from None
    try:
        view = FoxgloveView(port=args.foxglove, host=host)
    except Exception as exc:  # foxglove-sdk raises its own error types for a busy port
        print(f"rfhoming {command}: cannot start the Foxglove server on port {args.foxglove}: {exc}; "
              "choose another with --foxglove=PORT", file=sys.stderr)
        raise SystemExit(2) from None
    print(json.dumps({"kind": "listening", "address": view.address, "protocols": SUBPROTOCOLS}), file=out, flush=True)
    return view


class ExtraMissing(Error):
    """An option needs a pip extra that is not installed; the message names it."""


BASE_TOPICS = frozenset({"/odom", "/scan", "/tf"})
"""What a ROS 2 base publishes itself: not published again by --ros2 on its domain."""


def ros2_publisher(text: str, ros2_bases: Iterable[int] = (), *, source: str | None = None, site: Any = None,
                   robot: bool = True) -> Ros2Publisher:
    """``--ros2 [domain=N][,discovery=subnet]``: a sink publishing on that domain. ``ros2_bases``:
    the domains of the command's ROS 2 bases, whose own topics it leaves to them; the rest go to
    host/export/ros2live.py ``Ros2Publisher``."""
    try:
        from rfhoming.host.export.ros2live import Ros2Publisher
    except ImportError as exc:
        raise ExtraMissing(f"--ros2 needs the ros2 and ros extras ({exc.name} is missing): "
                           "pip install 'rfhoming[ros,ros2]'") from None
    spec = parse_spec("ros2:" + text)
    if set(spec.settings) - {"domain", "discovery"}:
        raise PortSpecError(f"--ros2 {text}: takes domain=N and discovery=localhost|subnet")
    domain = spec.settings.get("domain", 0)
    return Ros2Publisher(domain, spec.settings.get("discovery", "localhost"), source=source, site=site, robot=robot,
                         skip=BASE_TOPICS if domain in set(ros2_bases) else frozenset())


def start_ros2(args: argparse.Namespace, drivers: list[Any]) -> Ros2Publisher | None:
    """``--ros2`` for commands that show devices (listen, capture, serve): None without it, else a
    sink for the drivers' items (stamped on the host's clock). An Error (one line, exit 2) when it
    cannot start."""
    if getattr(args, "ros2", None) is None:
        return None
    bases = [d for d in drivers if isinstance(d, RobotBase)]
    sink = ros2_publisher(args.ros2, [d.topics.domain for d in bases if hasattr(d, "topics")])
    for d in drivers:
        d.listeners.append(sink.on_item)
    return sink


def mcap_recorder(path: Path) -> Sink:
    """The MCAP recorder sink; an Error naming the extra when its packages are missing."""
    try:
        from rfhoming.host.export.recorder import McapRecorder
    except ImportError as exc:
        raise ExtraMissing(f"--mcap needs the ros extra ({exc.name} is missing): pip install 'rfhoming[ros]'") from None
    return McapRecorder(path)
