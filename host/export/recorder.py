"""An MCAP log with ROS 2 messages, written while a run goes or afterwards from its files.

:class:`McapRecorder` takes the two streams a run has: the drivers' decoded items (it is a
driver listener, ``(device, t_host, item)``) and the run log's records (a RunLog listener). Its
writer is the mcap library's ROS 2 support (CDR, schema ``ros2msg``); ``rosbags`` or Foxglove
read the file without rfhoming.

Order: messages are written in log-time order, within and across chunks, so a linear reader
(the mcap library's ``NonSeekingReader``, what reads a crashed file) sees them in time order. The
run log's records come after the odometry they were decided on, by up to 0.2 s in the demos: a
message is held up to :data:`REORDER_S` of message time and written once nothing earlier can
come; one later still (a stall) goes out next with its log time raised to the last one
written -- its header stamp and publish time keep its own time -- and is counted (``late``).

Crash safety: messages go into chunks of at most :data:`CHUNK_BYTES`, and every
:data:`FLUSH_S` -- of message time (robot or host clock) or of host time, whichever comes first --
the open chunk is finished and the file flushed to the operating system, so a killed process
(``kill -9``, a crash) loses at most the last FLUSH_S + REORDER_S; the file then has no summary
at its end, which the mcap library's readers and rosbags read past (docs/usage.md). ``close``
writes the held messages and the summary. (A flush is not an fsync: a power cut may lose what the
OS had not written yet.)

Channels carry ``offered_qos_profiles`` as ``ros2 bag record`` writes it (rosmsgs.py), so
``ros2 bag play`` latches /tf_static.

Frames (REP 105): ``/tf_static`` holds base_link -> each sensor frame (aoa_link, laser,
rss_link, ble_link) from the config's ``[mounting]`` and, with a site (``--controller
anchors``), map -> each fixed anchor's frame (anchor_<id>), written with the first message;
``/tf`` holds odom -> base_link from every odometry record, map -> odom when fixed anchors locate
the robot (S3's odometry offset, the anchors controller's alignment) and S1's odom ->
dock_station as its fit of the station goes (host/export/frames.py). A sensor message's
``frame_id`` is its sensor's frame; the device it came from (its port) is in its channel's
metadata ``device``.

Time: with a robot base every message is stamped on the base's own clock, the run log's time
axis (an item gets the robot time of the latest odometry, as the homing loop does; items before
the first odometry have no robot time and are counted, not written). Without a base (a bare
``listen``) the host's arrival time is used.

:func:`export` builds the same log after the fact, from a run log and/or a capture whose
inbound bytes go through the same decoders as live.
"""

from __future__ import annotations

import heapq
import json
import logging
import math
import time
from collections import Counter, deque
from pathlib import Path
from typing import IO, Any

from mcap.writer import Writer
from mcap_ros2._dynamic import serialize_dynamic  # the encoder mcap_ros2's own Writer uses

from rfhoming.host.capture import DISCONNECTED, SNIFFED
from rfhoming.host.drivers.common import Driver
from rfhoming.host.drivers.robot import Pose2D, Scan
from rfhoming.host.drivers.robot_base import scan_of
from rfhoming.host.drivers.rss import NodeClock
from rfhoming.host import outputs
from rfhoming.host.export import frames, rosmsgs
from rfhoming.host.replay import ReplayPort, load_capture
from rfhoming.host.session import driver_class, recorded_kind
from rfhoming.host.sink import Sink
from rfhoming.protocol import devices
from rfhoming.protocol.errors import Error
from rfhoming.protocol.pcapng import OUTBOUND

log = logging.getLogger(__name__)

FLUSH_S = 1.0
"""At most this much of a run (message or host time) sits in memory, unwritten."""

CHUNK_BYTES = 256 * 1024
"""A chunk is also finished at this size (a fast stream within one second)."""

REORDER_S = 0.5
"""A message is held this long (message time) so that later-made, earlier-stamped ones go first."""

MAX_HELD = 50_000
"""At most this many messages held for ordering; beyond, the earliest is written at once."""


class RunLogError(Error, ValueError):
    """A run log line that is not one (JSON with kind and t); the message names the line."""


class McapRecorder(Sink):
    """Writes ROS 2 messages to an MCAP file. ``clock`` is "robot" (a base is present) or "host".

    ``commands_from``: "runlog" when a run log will give the velocity commands (live runs and
    exports with a run log), "capture" to take them from the bytes sent to the base."""

    def __init__(self, output: Path | str | outputs.Output | IO[bytes], *, clock: str = "robot",
                 commands_from: str = "runlog", mounting: Any = None, source: str | None = None,
                 site: Any = None) -> None:
        """``output``: a path is a live recording (NAME.part until :meth:`close`, which renames it
        into place once it holds a message: host/outputs.py); an Output or a stream is the
        caller's to close. ``mounting``: the config's ``[mounting]`` (sensor frames; None: all
        at the robot's centre); ``source``: the controller's measurement source (which AoA board
        is off the robot); ``site``: the fixed anchors' site (their frames). A live run gives
        them through :meth:`watch`."""
        if clock not in ("robot", "host"):
            raise ValueError(f"clock must be robot or host, not {clock!r}")
        self._out: outputs.Output | None = None
        stream: IO[bytes]
        if isinstance(output, (str, Path)):
            self._out = outputs.Output(output, binary=True)
            stream = self._out.file
        else:
            stream = output.file if isinstance(output, outputs.Output) else output
        self.writer = Writer(stream, chunk_size=CHUNK_BYTES)
        self.writer.start(profile="ros2", library="rfhoming (mcap, mcap-ros2-support)")
        self._flushed_at: tuple[float, float] | None = None  # (message time, host monotonic) of the last flush
        self.clock = clock
        self.commands_from = commands_from
        self.mounting = mounting
        self.source = source
        self.site = site
        self._schemas: dict[str, tuple[int, Any]] = {}  # type -> (schema id, CDR encoder)
        self._channels: dict[tuple[str, str], int] = {}  # (topic, device) -> channel id
        self._clocks: dict[str, NodeClock] = {}
        self._static_written = False
        self._last_xy: tuple[float, float] | None = None
        self.path_m = 0.0  # driven, by odometry: the pose covariance grows with it
        self.robot_time: float | None = None  # of the latest odometry
        self.counts: Counter[str] = Counter()  # messages per topic
        self.skipped: Counter[str] = Counter()  # items not written, per reason
        self.late = 0  # messages later than REORDER_S: written with their log time raised
        self._held: list[tuple[int, int, int, int, int, bytes]] = []  # (log ns, n, channel, publish ns, seq, data)
        self._held_n = 0
        self._written_ns = 0  # log time of the last message written
        self._closed = False
        self.path = (output.name if isinstance(output, outputs.Output) else output if isinstance(output, (str, Path))
                     else getattr(output, "name", "the MCAP output"))
        self.write_error: OSError | None = None  # the first failed write of the file

    def watch(self, loop: Any) -> None:
        """The run's loop: its config's sensor mountings and its controller's source."""
        self.mounting = loop.config.mounting
        self.source = getattr(loop, "source", None)
        self.site = getattr(getattr(loop, "controller", None), "site", None)

    def _failed(self, kind: str, exc: Exception) -> None:
        """An item that cannot be written: counted as skipped, logged once per kind; the file
        that cannot be written (a full disk): said once, naming it (``write_error``)."""
        if isinstance(exc, OSError):
            if self.write_error is None:
                self.write_error = exc
                log.error("MCAP %s: cannot write: %s; %s; later messages are counted as skipped",
                          self.path, exc.strerror or exc, KEPT)
                self.skipped["write error"] += len(self._held)  # never written now (_write)
                self._held.clear()
            self.skipped["write error"] += 1
            return
        if not self.skipped[f"unwritable {kind}"]:
            log.warning("MCAP: cannot write a %s (%s); counting such items as skipped", kind, exc)
        self.skipped[f"unwritable {kind}"] += 1

    def _on_item(self, device: str, t_host: float, item: Any) -> None:
        """A driver's item: a robot base's odometry and scans, whether its driver shows records
        (rfhoming's base) or the loop's Pose2D and Scan (a ROS 2 base), and the sensors' readings."""
        kind = getattr(item, "kind", None)
        if kind == "odometry":  # on the base's clock, unwrapped as its driver does
            clock = self._clocks.setdefault(device, NodeClock())
            item = Pose2D(t_host, clock.unwrap(item.t_us) / 1e6, item.x_mm / 1000, item.y_mm / 1000,
                          item.theta_urad / 1e6, item.v_mm_s / 1000, item.w_mrad_s / 1000, item.flags)
        elif kind in ("range_scan", "range_scan_v2"):
            item = scan_of(item, t_host)
        if isinstance(item, Pose2D):
            self.robot_time = item.t_robot
        t = self._time(t_host)
        if t is None:
            if isinstance(item, (Pose2D, Scan)) or kind in ("angle", "adv_report", "antenna_set", "velocity_command"):
                self.skipped["before odometry"] += 1
            return
        if isinstance(item, Pose2D):
            if self._last_xy is not None:
                self.path_m += math.dist(self._last_xy, (item.x, item.y))
            self._last_xy = (item.x, item.y)
            self._write(t, *rosmsgs.odometry(t, item.x, item.y, item.theta, item.v, item.w, self.path_m), device=device)
            self._write(t, *rosmsgs.odom_transform(t, item.x, item.y, item.theta))
        elif isinstance(item, Scan):
            self._write(t, *rosmsgs.laser_scan(t, item), device=device)
        elif kind == "angle":
            self._write(t, *rosmsgs.aoa_angle(t, self._aoa_frame(item), item, *self._aoa_geometry(item)),
                        device=device)
        elif kind == "adv_report":
            self._write(t, *rosmsgs.rssi_reading(t, item), device=device)
        elif kind == "antenna_set":
            self._write(t, *rosmsgs.antenna_set(t, item), device=device)
        elif kind == "velocity_command" and self.commands_from == "capture":
            self._write(t, *rosmsgs.twist(item.v_mm_s / 1000, item.w_mrad_s / 1000), device=device)

    def _aoa_frame(self, event: Any) -> str:
        """The robot's XPLR-AOA is aoa_link; S1's is on the docking station and a fixed
        anchor is anchor_<its id> (placed by the estimates and the site: frames.py)."""
        if self.source == "dock_aoa":
            return frames.STATION
        if self.source == "anchors":
            return frames.anchor_frame(event.anchor_id)
        return frames.AOA

    def _aoa_geometry(self, event: Any) -> tuple[int, str]:
        """The board's azimuth sign and angle model: the robot's board as ``[mounting]`` says,
        a fixed anchor as its site says, S1's station board the XPLR-AOA's own."""
        if self.source == "anchors" and self.site is not None:
            anchor = next((a for a in self.site.anchors if a.id == event.anchor_id), None)
            return -1, anchor.angle_model if anchor is not None else "spherical"
        if self.source not in ("dock_aoa", "anchors") and self.mounting is not None:
            return int(self.mounting.azimuth_sign), "spherical"
        return -1, "spherical"

    def _on_runlog(self, record: dict[str, Any]) -> None:
        t = float(record["t"])
        kind = record.get("kind")
        if kind == "command" and self.commands_from == "runlog":
            self._write(t, *rosmsgs.twist(record["v"], record["w"]))
        elif kind == "estimate":
            located = record.get("offset") is not None  # S3: anchors fix the robot in the map
            if located:
                self._write(t, *rosmsgs.transforms("/tf", t, [frames.map_to_odom(record["offset"])]))
            if record.get("map_odom") is not None:  # the anchors controller's alignment
                self._write(t, *rosmsgs.transforms("/tf", t, [frames.map_to_odom(record["map_odom"])]))
            if record.get("station") is not None:  # S1: the station fitted in the odometry frame
                self._write(t, *rosmsgs.transforms("/tf", t, [frames.dock_station(record["station"])]))
            if record.get("goal") is not None:
                self._write(t, *rosmsgs.point("/rfhoming/target", t, record["goal"]))
            if record.get("fix") is not None:  # S3 (it has an offset, found or not): the robot in the map, from
                # the anchors, also while it still localises; S2: one target fix in odom
                self._write(t, *rosmsgs.point("/rfhoming/fix", t, record["fix"],
                                              frames.MAP if "offset" in record else frames.ODOM))
        elif kind == "measurement" and not record.get("incomplete"):
            self._write(t, *rosmsgs.bearing(t, record))
        elif kind == "event":
            self._write(t, *rosmsgs.text("/rfhoming/events", record["what"]))

    # -- writing -------------------------------------------------------------------------
    def static_transforms(self) -> list[frames.Transform]:
        """/tf_static: base_link -> each sensor, map -> each of the site's anchors."""
        return frames.sensor_mounts(self.mounting) + frames.anchor_mounts(self.site)

    def _time(self, t_host: float) -> float | None:
        return t_host if self.clock == "host" else self.robot_time

    def _write(self, t: float, topic: str, typename: str, message: dict[str, Any], device: str = "") -> None:
        if self._closed:
            return
        if self.write_error is not None:  # the mcap writer keeps what it failed to write: give it nothing more
            self.skipped["write error"] += 1
            return
        if not self._static_written:
            self._static_written = True
            self._write(t, *rosmsgs.transforms("/tf_static", t, self.static_transforms()))
        schema_id, encode = self._schema(typename)
        channel = self._channels.get((topic, device))
        if channel is None:
            metadata = {"offered_qos_profiles": rosmsgs.offered_qos_profiles(topic)}
            if device:
                metadata["device"] = device
            channel = self._channels[(topic, device)] = self.writer.register_channel(topic, "cdr", schema_id, metadata)
        ns = max(0, round(t * 1e9))
        heapq.heappush(self._held, (ns, self._held_n, channel, ns, self.counts[topic], encode(message)))
        if self._out is not None:
            self._out.own()  # a message of the run: the recording replaces the old file at its close
        self._held_n += 1
        self.counts[topic] += 1
        self._release(ns - round(REORDER_S * 1e9))
        now = time.monotonic()
        if self._flushed_at is None:
            self._flushed_at = (t, now)
        elif t - self._flushed_at[0] >= FLUSH_S or now - self._flushed_at[1] >= FLUSH_S:
            self.flush()
            self._flushed_at = (t, now)

    def _release(self, horizon_ns: float) -> None:
        """Write the held messages up to ``horizon_ns`` (and beyond MAX_HELD), in log-time order."""
        while self._held and (self._held[0][0] <= horizon_ns or len(self._held) > MAX_HELD):
            ns, _, channel, publish_ns, sequence, data = heapq.heappop(self._held)
            if ns < self._written_ns:
                self.late += 1
                ns = self._written_ns
            self._written_ns = ns
            self.writer.add_message(channel, log_time=ns, publish_time=publish_ns, sequence=sequence, data=data)

    def _schema(self, typename: str) -> tuple[int, Any]:
        """The schema of a type (written once, ROS 2 message definition) and its CDR encoder."""
        if typename not in self._schemas:
            text = rosmsgs.msgdef(typename)
            schema_id = self.writer.register_schema(typename, "ros2msg", text.encode())
            self._schemas[typename] = (schema_id, serialize_dynamic(typename, text)[typename])
        return self._schemas[typename]

    def flush(self) -> None:
        """Finish the open chunk and hand the file everything so far: a crash after this loses
        nothing before it."""
        if self.write_error is None:  # after one, the writer's chunk holds the failed write: not again
            self.writer.flush()  # ends the chunk (mcap >= 1.6)

    def close(self) -> None:
        """The held messages and the summary written, the file closed (and, a recording this
        recorder opened, renamed into place); after a write error only closed (what is on disk
        stays as it is: KEPT)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.write_error is None:
                self._release(math.inf)
                self.writer.finish()
        finally:
            if self._out is not None:
                if self.write_error is not None:
                    self._out.abandon()  # its buffer cannot be written either
                self._out.close()

    def summary(self) -> dict[str, Any]:
        return {"messages": sum(self.counts.values()), "topics": dict(sorted(self.counts.items())),
                "skipped": dict(self.skipped), "late": self.late}


def export(output: Path | str, *, runlog: Path | str | None = None, capture: Path | str | None = None,
           mounting: Any = None) -> dict[str, Any]:
    """An MCAP file from a run log and/or a capture; returns the recorder's summary.

    The capture's inbound bytes go through each device's driver decoding (its ``on_chunk``, as
    live, in recorded global order); commands come from the run log if given, else from the
    frames sent to the base. Run log records are merged in by robot time. ``mounting``: the
    run's config ``[mounting]``, for the sensor frames (None: every sensor at the robot's centre);
    the fixed anchors' frames come from the site file a run's capture recorded."""
    if runlog is None and capture is None:
        raise ValueError("nothing to export: give a run log, a capture, or both")
    from rfhoming.host.homing.assembly import recorded_site  # the run's plan: above the recorder

    records = _read_runlog(runlog) if runlog is not None else []
    drivers, packets = _capture_drivers(capture) if capture is not None else ({}, [])
    site = recorded_site(capture) if capture is not None else None
    has_base = runlog is not None or any("base" in devices.kind(d.kind).roles for d in drivers.values())
    source = next((r.get("source") for r in records if r.get("kind") == "measurement"), None)
    if source is None and site is not None:  # only --controller anchors records a site
        source = "anchors"
    out = outputs.Output(output, binary=True)  # the inputs are read: NAME.part, NAME once whole
    try:
        recorder = McapRecorder(out, clock="robot" if has_base else "host",
                                commands_from="runlog" if runlog is not None else "capture", mounting=mounting,
                                source=source, site=site)
        _feed(recorder, drivers, packets, deque(records))
        if recorder.write_error is not None:
            raise recorder.write_error
    except OSError as exc:  # a full disk: name the file; the old one stays, no .part is left
        error = outputs.failed(out, exc, KEPT)
        out.discard()
        raise error from None
    except BaseException:
        out.discard()
        raise
    out.commit()
    return recorder.summary()


KEPT = ("readable up to its last complete chunk (it has no summary at its end; "
        "the mcap library's readers and rosbags read past that)")


def _feed(recorder: McapRecorder, drivers: dict[str, Driver], packets: list[tuple[str, Any]],
          pending: deque[dict[str, Any]]) -> None:
    """The capture's packets through their drivers into ``recorder``, the run log's records
    merged in by robot time; the recorder is closed however it ends."""
    for driver in drivers.values():
        driver.listeners.append(recorder.on_item)
    try:
        for name, p in packets:
            if p.direction == OUTBOUND:  # what the host sent: a base's commands
                for record in drivers[name].sent(p.data):
                    recorder.on_item(name, p.t, record)
                continue
            drivers[name].on_chunk(p.data, p.t)
            while pending and recorder.robot_time is not None and pending[0]["t"] <= recorder.robot_time:
                recorder.on_runlog(pending.popleft())
        while pending:
            recorder.on_runlog(pending.popleft())
    finally:
        recorder.close()


def _capture_drivers(path: Path | str) -> tuple[dict[str, Driver], list[tuple[str, Any]]]:
    """A driver per recorded device (fed by hand, never run) and every packet in recorded time
    order, without the bytes exchanged while sniffing or the disconnect markers."""
    interfaces, per_interface, torn = load_capture(path)
    if torn:
        log.warning("%s ends in a torn block (%d bytes); exporting up to the last complete block", path, torn)
    drivers: dict[str, Driver] = {}
    rows = []
    for i, iface in enumerate(interfaces):
        drivers[iface.name] = driver_class(recorded_kind(iface))(ReplayPort(iface.name, per_interface[i]))
        rows += [(p.t, i, n, p) for n, p in enumerate(per_interface[i]) if p.comment not in (SNIFFED, DISCONNECTED)]
    rows.sort(key=lambda row: row[:3])
    return drivers, [(interfaces[i].name, p) for _, i, _, p in rows]


def _read_runlog(path: Path | str) -> list[dict[str, Any]]:
    records: list[dict[str, Any]] = []
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RunLogError(f"{path} is not a run log: byte {exc.start} is not UTF-8 text") from None
    lines = text.splitlines()
    last = max((n for n, line in enumerate(lines, 1) if line.strip()), default=0)
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            float(record["t"])
        except (ValueError, KeyError, TypeError):
            if n == last and not text.endswith("\n"):  # a writer killed mid-line, as a torn pcapng block
                log.warning("%s:%d: a torn last line (%d bytes, a killed writer); exporting the %d lines before it",
                            path, n, len(line.encode()), len(records))
                break
            raise RunLogError(f"{path}:{n}: not a run log line (JSON with kind and t): {line[:60]!r}") from None
        records.append(record)
    return records
