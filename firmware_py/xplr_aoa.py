"""XPLR-AOA anchor running u-connectLocate: the AT interpreter and the +UUDF event output.

Sans-IO, like the real board seen from its UART: :meth:`receive` takes host bytes, the board
echoes them and answers each CR-terminated line; :meth:`on_advertisement` is one CTE
advertisement heard by the antenna array (the emulator computes its angles);
:meth:`tick` advances time; :meth:`read` drains the bounded TX buffer.

Configuration semantics (protocols.md §1): ``AT+UDFCFG``, ``AT+UDFFILT`` and ``AT+UMRS``
edit the *pending* settings, which read back at once but take effect only after ``AT&W``
(store) and ``AT+CPWROFF`` (restart -> ``+STARTUP``); unsaved settings are lost at restart.
``AT+UDFENABLE`` acts at once and is never stored.
"""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass, field

from rfhoming.protocol.uconnect import AngleEvent, Dialect, encode_angle_event, encode_answer, encode_startup
from rfhoming.protocol.uconnect.commands import BAUD_RATES, STRING_TAGS, UDFCFG_RANGES

TX_BUFFER = 8192
"""UART TX buffer, bytes; a URC that does not fit is dropped whole and counted."""
RX_LINE = 512
TAG_TIMEOUT_MS = 5000
RESTART_MS = 300
"""Time from AT+CPWROFF's OK to +STARTUP."""

_IDENTITY = {
    Dialect.V1_0: ('"NINA-B4-DF"', '"1.0.2-001"', '"u-connectLocate","1.0.2-001","NINA-B4"'),
    Dialect.V1_2: ("NINA-B411-40B", '"1.2.0-005"', '"u-connectLocate","1.2.0-005","NINA-B411"'),
    Dialect.V2: ("NINA-B411-40B", '"2.1.0-010"', '"u-connectLocate","2.1.0-010","NINA-B411"'),
    Dialect.EMBED: ("NINA-B411-40B", '"1.0.0-026"', '"u-locateEmbed","1.0.0-026","NINA-B411"'),
}
"""AT+GMM, AT+GMR, ATI9 per dialect. The u-locateEmbed strings are this emulator's convention
(not captured from a board): hosts tell it apart by 'u-locateEmbed' in ATI9."""

TAG_LIMIT = {Dialect.V1_0: 5, Dialect.V1_2: 20, Dialect.V2: 20, Dialect.EMBED: 20}
LATER_TAGS = {9, 11}
EMBED_TAGS = {121}


@dataclass
class Settings:
    """What AT&W stores."""

    udfcfg: dict[int, int | str]
    filters: dict[int, list[str]] = field(default_factory=lambda: {1: [], 2: []})
    baud: int = 115200
    flow_control: bool = True


def factory_settings(mac: str) -> Settings:
    return Settings(udfcfg={1: 1, 2: "", 3: 1, 4: mac, 5: 1, 6: 0, 7: 0, 8: 1, 9: 20, 11: 0, 121: 0})


@dataclass(frozen=True)
class Advertisement:
    """One CTE advertisement as the array measured it (angles in the board's frame, degrees)."""

    instance_id: str
    namespace: str
    azimuth_deg: float
    elevation_deg: float
    rssi1_dbm: float
    rssi2_dbm: float


@dataclass
class _Tag:
    last_heard_ms: int
    last_event_ms: int | None = None
    seq: int = 0
    raw_azimuths: deque = field(default_factory=lambda: deque(maxlen=3))
    raw_elevations: deque = field(default_factory=lambda: deque(maxlen=3))


class XplrAoaFirmware:
    """The anchor board. Times are integer milliseconds since the emulator started."""

    def __init__(self, mac: str = "CCF9578E0D89", dialect: Dialect = Dialect.V1_2, baud: int = 115200) -> None:
        """``baud``: the stored UART rate, as if set by AT+UMRS and AT&W before this boot."""
        if len(mac) != 12:
            raise ValueError("mac must be 12 hex digits")
        self.mac = mac
        self.dialect = dialect
        self.saved = factory_settings(mac)
        self.saved.baud = baud
        self.counters: dict[str, int] = {"events": 0, "tx_overflow": 0, "rx_overflow": 0}
        self._out = bytearray()
        self._line = bytearray()
        self._now_ms = 0
        self._restart_at: int | None = None
        self.powered = True
        self.boot(0)

    # -- life cycle -------------------------------------------------------------------
    def boot(self, now_ms: int) -> None:
        """Power-up or reset: load stored settings, forget tags, print +STARTUP."""
        self._now_ms = now_ms
        self.booted_ms = now_ms
        self.active = copy.deepcopy(self.saved)
        self.pending = copy.deepcopy(self.saved)
        self.enabled = bool(self.active.udfcfg[3])
        self.tags: dict[str, _Tag] = {}
        self._line.clear()
        self._restart_at = None
        self._emit(encode_startup())

    @property
    def baud(self) -> int:
        """The UART rate in effect (a host at another rate sees garbage)."""
        return self.active.baud

    def tick(self, now_ms: int) -> None:
        self._now_ms = now_ms
        if self._restart_at is not None and now_ms >= self._restart_at:
            self.boot(now_ms)
        for tag_id in [t for t, s in self.tags.items() if now_ms - s.last_heard_ms > TAG_TIMEOUT_MS]:
            del self.tags[tag_id]

    def read(self) -> bytes:
        data = bytes(self._out)
        self._out.clear()
        return data

    def _emit(self, data: bytes) -> None:
        if len(self._out) + len(data) > TX_BUFFER:
            self.counters["tx_overflow"] += 1
            return
        self._out += data

    # -- host -> board ----------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Bytes from the host: echoed as received; each CR ends a command."""
        if self._restart_at is not None:
            return  # restarting: the UART is down
        for byte in data:
            self._emit(bytes((byte,)))
            if byte == 0x0D:
                line, self._line = self._line.decode("ascii", "replace"), bytearray()
                if line.strip():
                    self._execute(line.strip())
            elif byte != 0x0A:
                if len(self._line) >= RX_LINE:
                    self.counters["rx_overflow"] += 1
                    self._line.clear()
                self._line.append(byte)

    def _answer(self, info: list[str] | None = None, ok: bool = True) -> None:
        self._emit(encode_answer(info or [], ok))

    def _execute(self, line: str) -> None:
        upper = line.upper()
        gmm, gmr, ati9 = _IDENTITY[self.dialect]
        simple = {
            "AT": [],
            "AT+GMI": ['"u-blox"'],
            "AT+GMM": [gmm],
            "AT+GMR": [gmr],
            "ATI9": [ati9],
            "AT+UMLA=1": [f"+UMLA:{self.mac}"],
            "AT+UMRS?": [f"+UMRS:{self.pending.baud},{int(self.pending.flow_control)}"],
        }
        if upper in simple:
            return self._answer(simple[upper])
        if upper == "AT&W":
            self.saved = copy.deepcopy(self.pending)
            return self._answer()
        if upper == "AT+CPWROFF":
            self._answer()
            self._restart_at = self._now_ms + RESTART_MS
            return None
        if upper == "AT+UFACTORY":
            self.saved = factory_settings(self.mac)
            self.pending = copy.deepcopy(self.saved)
            return self._answer()
        for prefix, handler in (
            ("AT+UDFENABLE=", self._udfenable),
            ("AT+UDFCFG", self._udfcfg),
            ("AT+UDFFILT=", self._udffilt),
            ("AT+UMRS=", self._umrs),
        ):
            if upper.startswith(prefix):
                try:
                    info = handler(line[len(prefix):])
                except (ValueError, IndexError, KeyError):
                    return self._answer(ok=False)
                return self._answer(info)
        return self._answer(ok=False)

    def _udfenable(self, arg: str) -> list[str]:
        if arg not in ("0", "1"):
            raise ValueError(arg)
        self.enabled = arg == "1"
        return []

    def _known_tag(self, tag: int) -> bool:
        if tag in EMBED_TAGS:
            return self.dialect is Dialect.EMBED
        if tag in LATER_TAGS:
            return self.dialect in (Dialect.V2, Dialect.EMBED)
        return tag in UDFCFG_RANGES

    def _format_cfg(self, tag: int) -> str:
        value = self.pending.udfcfg[tag]
        return f'+UDFCFG:{tag},"{value}"' if tag in STRING_TAGS else f"+UDFCFG:{tag},{value}"

    def _udfcfg(self, arg: str) -> list[str]:
        if arg == "?":
            return [self._format_cfg(t) for t in sorted(self.pending.udfcfg) if self._known_tag(t)]
        if not arg.startswith("="):
            raise ValueError(arg)
        tag_text, _, value = arg[1:].partition(",")
        tag = int(tag_text)
        if not self._known_tag(tag):
            raise ValueError(tag)
        if not value:
            return [self._format_cfg(tag)]
        if tag in STRING_TAGS:
            if len(value) < 2 or value[0] != '"' or value[-1] != '"' or len(value) - 2 > 30:
                raise ValueError(value)
            self.pending.udfcfg[tag] = value[1:-1]
        else:
            number = int(value)
            if number not in UDFCFG_RANGES[tag]:
                raise ValueError(value)
            self.pending.udfcfg[tag] = number
        return []

    def _udffilt(self, arg: str) -> list[str]:
        parts = arg.split(",")
        kind = int(parts[0])
        digits = {1: 20, 2: 12}[kind]
        if len(parts) == 1:
            ids = "".join(f',"{i}"' for i in self.pending.filters[kind])
            return [f"+UDFFILT:{kind}{ids}"]
        action = int(parts[1])
        ids = [p.strip('"').upper() for p in parts[2:]]
        if any(len(i) != digits for i in ids):
            raise ValueError(ids)
        if action == 1 and not ids:
            self.pending.filters[kind] = []
        elif action == 2 and ids and len(self.pending.filters[kind]) + len(ids) <= 100:
            self.pending.filters[kind].extend(ids)
        else:
            raise ValueError(action)
        return []

    def _umrs(self, arg: str) -> list[str]:
        baud_text, flow_text = arg.split(",")
        baud = int(baud_text)
        if baud not in BAUD_RATES or flow_text not in ("0", "1"):
            raise ValueError(arg)
        self.pending.baud, self.pending.flow_control = baud, flow_text == "1"
        return []

    # -- radio -> board ---------------------------------------------------------------
    def on_advertisement(self, adv: Advertisement) -> None:
        """One advertisement heard now: maybe one +UUDF (filters, tag limit, rate limit)."""
        if self._restart_at is not None or not self.enabled:
            return
        cfg = self.active.udfcfg
        filters = self.active.filters
        if filters[2] and adv.instance_id not in filters[2]:
            return
        if filters[1] and adv.namespace not in filters[1]:
            return
        tag = self.tags.get(adv.instance_id)
        if tag is None:
            if len(self.tags) >= TAG_LIMIT[self.dialect]:
                return
            tag = self.tags[adv.instance_id] = _Tag(self._now_ms)
        tag.last_heard_ms = self._now_ms
        raw_az = _clamp(round(adv.azimuth_deg), -90, 90)
        raw_el = _clamp(round(adv.elevation_deg), -90, 90) if cfg[5] else 0
        tag.raw_azimuths.append(raw_az)
        tag.raw_elevations.append(raw_el)
        min_interval = int(cfg[1])
        if tag.last_event_ms is not None and self._now_ms - tag.last_event_ms < min_interval:
            return
        tag.last_event_ms = self._now_ms
        smooth = bool(cfg[8])
        azimuth = _median(tag.raw_azimuths) if smooth else raw_az
        elevation = _median(tag.raw_elevations) if smooth else raw_el
        tag.seq = (tag.seq + 1) & 0xFFFF
        timestamp = _int32(self._now_ms - self.booted_ms)
        rssi1 = _clamp(round(adv.rssi1_dbm), -127, 20)
        rssi2 = _clamp(round(adv.rssi2_dbm), -127, 20)
        if self.dialect in (Dialect.V1_0, Dialect.V1_2):
            channel = 37 + tag.seq % 3  # legacy advertising channels
        else:
            channel = (tag.seq * 11) % 37  # periodic advertising hops the data channels
        if int(cfg[7]) == 1:  # undocumented $MEAS text format, emulated so hosts can detect it
            self._emit(f"\r\n$MEAS,{azimuth},{elevation},{rssi1},{rssi2},{channel},{timestamp},0,0\r\n".encode())
            return
        event = AngleEvent(
            adv.instance_id, rssi1, azimuth, elevation, rssi2, channel,
            str(cfg[4]), str(cfg[2]), timestamp, tag.seq,
            raw_az if cfg[121] else None, raw_el if cfg[121] else None,
        )
        dialect = self.dialect
        if dialect is Dialect.EMBED and not cfg[121]:
            dialect = Dialect.V2
        self._emit(encode_angle_event(event, dialect))
        self.counters["events"] += 1


def _clamp(value: int, low: int, high: int) -> int:
    return low if value < low else high if value > high else value


def _median(values: deque) -> int:
    ordered = sorted(values)
    return ordered[len(ordered) // 2]


def _int32(value: int) -> int:
    """printf %d of a 32-bit millisecond counter."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value
