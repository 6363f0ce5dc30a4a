"""Driver for rfhoming's binary-framed RSS nodes (ESP32 scanner, AT86RF212 node).

- Node time: ``t_us`` is a u32 that wraps every 71.6 min. :class:`NodeClock` unwraps it and
  maps it to host time with the minimum observed (host arrival − node time) over a window:
  the arrival with the least transport delay is the best offset estimate.
- Loss: a per-node gap in the record counter ``seq`` is counted as lost records.
- Power: ED -> dBm with the base the node reports and the calibrated ED step. An ED at its
  maximum (84) is a power at or above what it says: the chip saturates there, a few tens of
  centimetres from an emitter; :class:`AntennaPowers` flags such readings.
- Antennas: the four 0x02 records of one emitter frame are associated by ``emitter_seq``
  within a window; a 0x03 record carries the set already and is used as it is.
"""

from __future__ import annotations

from collections import deque
from typing import Any, NamedTuple

from rfhoming.host.drivers.common import BoundedStream, Driver, Wiring
from rfhoming.host.ports import HostPort
from rfhoming.protocol.at86rf212 import DEFAULT_SCALE_DB, ED_MAX, ed_to_dbm
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.frames import (
    RECORD_TYPES,
    AdvReport,
    AntennaSet,
    FrameDecoder,
    RfFrame,
    Status,
)

WRAP = 1 << 32
FRAME_ITEMS: tuple[type, ...] = (*(rt.cls for rt in RECORD_TYPES.values()), Drop)
"""What a driver of rfhoming's frames shows its listeners: every record, and what it dropped."""


class BleRssi(NamedTuple):
    t_host: float
    node_id: int
    address: str  # as printed: MSB first, upper-case hex
    rssi_dbm: int


def _four(powers: list[float | None]) -> tuple[float | None, float | None, float | None, float | None]:
    return powers[0], powers[1], powers[2], powers[3]


Four = tuple[bool, bool, bool, bool]
NONE_SATURATED: Four = (False, False, False, False)


def _flags(sat: list[bool]) -> tuple[bool, bool, bool, bool]:
    return sat[0], sat[1], sat[2], sat[3]


class AntennaPowers(NamedTuple):
    """One emitter frame on the four antennas (x1, x2, y1, y2); None = not received.
    ``saturated[i]``: antenna i's ED was at its maximum, so its true power is at least ``dbm[i]``."""

    t_host: float
    node_id: int
    emitter_seq: int
    dbm: tuple[float | None, float | None, float | None, float | None]
    saturated: Four = NONE_SATURATED


class NodeClock:
    """Unwraps a node's u32 microsecond clock and maps it to host seconds."""

    def __init__(self, window: int = 200) -> None:
        self._last: int | None = None
        self._wraps = 0
        self._offsets: deque[float] = deque(maxlen=window)

    def unwrap(self, t_us: int) -> int:
        if self._last is not None and t_us < self._last and self._last - t_us > WRAP // 2:
            self._wraps += 1
        self._last = t_us
        return t_us + self._wraps * WRAP

    def to_host(self, t_us: int, t_arrival: float) -> float:
        node_s = self.unwrap(t_us) / 1e6
        self._offsets.append(t_arrival - node_s)
        return node_s + min(self._offsets)


class LossCounter:
    """Records lost per node, from gaps in the 16-bit record counter."""

    def __init__(self) -> None:
        self._last: dict[int, int] = {}
        self.lost = 0
        self.received = 0

    def see(self, node_id: int, seq: int) -> None:
        last = self._last.get(node_id)
        if last is not None:
            gap = (seq - last - 1) & 0xFFFF
            if gap < 0x8000:  # a jump backwards is a node restart, not a loss
                self.lost += gap
        self._last[node_id] = seq
        self.received += 1


class Associator:
    """Groups per-antenna 0x02 records of one emitter frame; emits when all four arrived or the
    window after the first one has passed."""

    def __init__(self, window_s: float = 0.05) -> None:
        self.window_s = window_s
        self._open: dict[tuple[int, int], tuple[float, list[float | None], list[bool]]] = {}

    def add(self, node_id: int, emitter_seq: int, antenna: int, dbm: float | None, t: float,
            saturated: bool = False) -> list[AntennaPowers]:
        key = (node_id, emitter_seq)
        t0, powers, sat = self._open.setdefault(key, (t, [None] * 4, [False] * 4))
        powers[antenna] = dbm
        sat[antenna] = saturated
        done = self.expire(t)
        if key in self._open and all(p is not None for p in powers):
            del self._open[key]
            done.append(AntennaPowers(t0, node_id, emitter_seq, _four(powers), _flags(sat)))
        return done

    def expire(self, now: float) -> list[AntennaPowers]:
        old = [k for k, (t0, _, _) in self._open.items() if now - t0 > self.window_s]
        out = []
        for k in old:
            t0, powers, sat = self._open.pop(k)
            out.append(AntennaPowers(t0, k[0], k[1], _four(powers), _flags(sat)))
        return out


class RssDriver(Driver):
    kind = "rss-node"
    items = FRAME_ITEMS

    @classmethod
    def speaks(cls, data: bytes) -> bool:
        """A valid frame (its CRC right) is in ``data``."""
        return any(r.kind != "drop" for r in FrameDecoder().feed(data))

    @classmethod
    def options(cls, wiring: Wiring) -> dict[str, Any]:
        """A run's calibration of the AT86RF212's energy detection."""
        return {} if wiring.config is None else {"ed_scale_db": wiring.config.calibration.ed_scale_db}

    def __init__(self, port: HostPort, *, ed_scale_db: float = DEFAULT_SCALE_DB, use_antenna_sets: bool = True,
                 queue_size: int = 4000, reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.decoder = FrameDecoder()
        self.ed_scale_db = ed_scale_db
        self.use_antenna_sets = use_antenna_sets
        self.clocks: dict[int, NodeClock] = {}
        self.loss = LossCounter()
        self.associator = Associator()
        self.status: dict[int, Status] = {}
        self.logs: deque[str] = deque(maxlen=100)

    def _host_time(self, record: Any, t_arrival: float) -> float:
        clock = self.clocks.setdefault(record.node_id, NodeClock())
        return clock.to_host(record.t_us, t_arrival)

    def _dbm(self, ed: int, base: int) -> float | None:
        return ed_to_dbm(ed, base, self.ed_scale_db) if ed <= 84 else None

    def on_chunk(self, data: bytes, t_host: float) -> None:
        for record in self.decoder.feed(data):
            self.emit(t_host, record)
            if record.kind == "drop":
                continue
            self.loss.see(record.node_id, record.seq)
            t = self._host_time(record, t_host)
            if isinstance(record, AdvReport):
                if record.rssi_dbm != 127:
                    self.out.put(BleRssi(t, record.node_id, record.addr[::-1].hex().upper(), record.rssi_dbm))
            elif isinstance(record, AntennaSet) and self.use_antenna_sets:
                valid = [record.valid_mask >> i & 1 == 1 for i in range(4)]
                dbm = _four([self._dbm(a.ed, record.rssi_base_dbm) if ok else None
                             for ok, a in zip(valid, record.antennas)])
                sat = _flags([ok and a.ed == ED_MAX for ok, a in zip(valid, record.antennas)])
                self.out.put(AntennaPowers(t, record.node_id, record.emitter_seq, dbm, sat))
            elif isinstance(record, RfFrame) and not self.use_antenna_sets:
                for done in self.associator.add(record.node_id, record.emitter_seq, record.antenna,
                                                self._dbm(record.ed, record.rssi_base_dbm), t,
                                                record.ed == ED_MAX):
                    self.out.put(done)
            elif isinstance(record, Status):
                self.status[record.node_id] = record
            elif record.kind == "log_text":
                self.logs.append(f"node {record.node_id}: {record.text}")

    def health(self) -> dict[str, Any]:
        return {**super().health(), "records": self.loss.received, "lost_records": self.loss.lost,
                "queued": len(self.out), "queue_dropped": self.out.dropped,
                **{f"decoder.{k}": v for k, v in self.decoder.counters.items()}}
