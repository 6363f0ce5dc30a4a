"""XPLR-AOA anchor running u-connectLocate: the AT interpreter and the +UUDF event output.

Sans-IO, like the real board seen from its UART: :meth:`receive` takes host bytes, the board
echoes them and answers each CR-terminated line; :meth:`on_advertisement` is one CTE
advertisement heard by the antenna array (the emulator computes its angles);
:meth:`tick` advances time; :meth:`read` drains the bounded TX buffer.

Every behaviour below is in docs/protocol.md's tables with its source, or marked *assumed*
there; a hardship no source shows is a fault option, off by default:

- commands are parsed as AT syntax: integers are plain decimals (no sign other than ``-``, no
  blanks, no ``_``, no leading zeros), strings are double-quoted printable ASCII without a
  quote inside, ids are hex; anything else answers ``ERROR`` and changes nothing, so every
  stored value can be printed back and put in a ``+UUDF`` line;
- a line longer than 512 bytes is discarded whole (answered ``ERROR``), its tail never runs;
- ``AT+UDFCFG`` follows the family's table (:data:`~rfhoming.protocol.uconnect.commands.UDFCFG`):
  1.x edits the *pending* settings, which take effect after ``AT&W`` + ``AT+CPWROFF``;
  2.x and u-locateEmbed apply them at once (``AT&W`` still makes them survive a restart).
  ``AT+UDFFILT`` and ``AT+UMRS`` wait for the restart on every family; ``AT+UDFENABLE`` acts
  at once and is never stored;
- u-locateEmbed ships with the namespace filter ``NINA-B4TAG`` (the C209's namespace), so a
  tag with another Eddystone namespace is never reported until the filter is cleared;
- with ``paced=True`` output leaves at the UART's rate (10 bits a byte): a 115200 Bd link
  carries about 175 ``+UUDF`` lines a second, the rest queue in the bounded TX buffer and
  arrive late -- a command's echo and answer queue behind them like any output;
- field 5 carries the second polarisation's RSSI on 1.0 and "reserved" values (-43, 6, 8) later;
  field 10 is the tag's periodic-advertising event counter, with gaps where packets were missed.

Fault options (off by default): ``torn_answers`` lets echo and answers jump the TX queue into
a half-sent ``+UUDF`` line; ``deaf_after_boot_ms`` ignores the host for that long after
``+STARTUP``.
"""

from __future__ import annotations

import copy
import re
import struct
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

from rfhoming.protocol.uconnect import AngleEvent, Dialect, encode_angle_event, encode_answer, encode_startup
from rfhoming.protocol.uconnect.commands import (
    BAUD_RATES,
    FLOW_OFF,
    FLOW_ON,
    LIVE_FAMILIES,
    UDFCFG,
    accepts,
    config_answer,
    family,
    is_at_string,
)

TX_BUFFER = 8192
"""UART TX buffer, bytes; a URC that does not fit is dropped whole and counted."""
RX_LINE = 512
TAG_TIMEOUT_MS = 5000
RESTART_MS = 300
"""Time from AT+CPWROFF's OK to +STARTUP."""
RESERVED = (-43, 6, 8)
"""Values of the reserved 5th +UUDF field in real lines from 1.2 on (docs/protocol.md, field 5)."""
BINARY_ANGLE = 0x01
"""Frame type of an angle in u-locateEmbed binary output (AT+UDFCFG=7,2), as the public parser reads it."""
C209_NAMESPACE = b"NINA-B4TAG".hex().upper()
"""The Eddystone namespace of u-blox's C209 tag firmware (c209-aoa-tag src/main.c), 20 hex digits."""
DEFAULT_NAMESPACE_FILTER = {Dialect.EMBED: [C209_NAMESPACE]}
"""Namespace filter a family ships with: u-locateEmbed ignores tags of any other namespace."""

_IDENTITY = {
    Dialect.V1_0: ('"NINA-B4-DF"', '"1.0.2-001"', '"u-connectLocate","1.0.2-001","NINA-B4"'),
    Dialect.V1_2: ('"NINA-B411-40B"', '"1.2.0-005"', '"u-connectLocate","1.2.0-005","NINA-B411"'),
    Dialect.V2: ('"NINA-B411-40B"', '"2.1.0-010"', '"u-connectLocate","2.1.0-010","NINA-B411"'),
    Dialect.EMBED: ('"NINA-B411-40B"', '"1.0.0-026"', '"u-locateEmbed","1.0.0-026","NINA-B411"'),
}
"""AT+GMM, AT+GMR, ATI9 per dialect, quoted as u-blox's C209 tag answers AT+GMM (c209-aoa-tag
src/at_host.c). *Assumed*: no public capture shows an anchor's strings; "NINA-B4-DF" is the
module name in UG-R02's tables, and the ordering code is documented. Hosts tell u-locateEmbed by ATI9."""

TAG_LIMIT = {Dialect.V1_0: 5, Dialect.V1_2: 20, Dialect.V2: 20, Dialect.EMBED: 20}

_INTEGER = re.compile(r"0|-?[1-9][0-9]{0,9}")


class AtSyntaxError(ValueError):
    """A command line the board refuses (answered ERROR)."""


def parse_params(text: str) -> list[int | str]:
    """``1,"abc",-5`` -> ``[1, "abc", -5]`` as an AT interpreter reads parameters.

    Strings are double-quoted, printable ASCII, without a quote inside (commas are allowed);
    integers are plain decimals. Empty parameters and anything else raise AtSyntaxError."""
    params: list[int | str] = []
    i, n = 0, len(text)
    while True:
        if i < n and text[i] == '"':
            end = text.find('"', i + 1)
            if end < 0:
                raise AtSyntaxError("unterminated string")
            params.append(text[i + 1:end])
            i = end + 1
        else:
            end = text.find(",", i)
            end = n if end < 0 else end
            token = text[i:end]
            if not _INTEGER.fullmatch(token):
                raise AtSyntaxError(f"not an integer: {token!r}")
            params.append(int(token))
            i = end
        if i == n:
            return params
        if text[i] != ",":
            raise AtSyntaxError(f"',' expected at {i}")
        i += 1
        if i == n:
            raise AtSyntaxError("empty last parameter")


@dataclass
class Settings:
    """What AT&W stores."""

    udfcfg: dict[int, int | str]
    filters: dict[int, list[str]] = field(default_factory=lambda: {1: [], 2: []})
    baud: int = 115200
    flow_control: bool = True


def factory_settings(mac: str, dialect: Dialect = Dialect.V1_2) -> Settings:
    """The family's AT+UDFCFG defaults (tag 4, the anchor id, defaults to the MAC) and filters."""
    fam = family(dialect)
    return Settings(udfcfg={tag: mac if entry.default is None else entry.default
                            for tag, entry in UDFCFG.items() if fam in entry.ranges},
                    filters={1: list(DEFAULT_NAMESPACE_FILTER.get(dialect, [])), 2: []})


@dataclass(frozen=True)
class Advertisement:
    """One CTE advertisement as the array measured it (angles in the board's frame, degrees)."""

    instance_id: str
    namespace: str
    azimuth_deg: float
    elevation_deg: float
    rssi1_dbm: float
    rssi2_dbm: float
    event_counter: int | None = None
    """The tag's periodic-advertising event counter (2.x tags): it counts every event the tag
    sent, so missed packets leave gaps. None: the board counts what it heard."""


MEDIAN_EVENTS = 3
"""``AT+UDFCFG=8,1`` (the default): each output angle is the median of a tag's last this many raw ones."""


@dataclass
class _Tag:
    last_heard_ms: int
    last_event_ms: int | None = None
    seq: int = 0
    raw_azimuths: deque[int] = field(default_factory=lambda: deque(maxlen=MEDIAN_EVENTS))
    raw_elevations: deque[int] = field(default_factory=lambda: deque(maxlen=MEDIAN_EVENTS))


class XplrAoaFirmware:
    """The anchor board. Times are integer milliseconds since the emulator started."""

    def __init__(self, mac: str = "CCF9578E0D89", dialect: Dialect = Dialect.V1_2, baud: int = 115200,
                 *, paced: bool = False, torn_answers: bool = False, deaf_after_boot_ms: int = 0) -> None:
        """``baud``: the stored UART rate, as if set by AT+UMRS and AT&W before this boot.
        ``paced``: output leaves at the UART's rate (the emulator's links); otherwise
        :meth:`read` returns everything at once (sans-IO tests). ``torn_answers`` and
        ``deaf_after_boot_ms`` are fault options no source shows (docs/protocol.md); the
        power-up boot is never deaf (the board was on before the host opened its port)."""
        if len(mac) != 12:
            raise ValueError("mac must be 12 hex digits")
        self.mac = mac
        self.dialect = dialect
        self.family = family(dialect)
        self.paced = paced
        self.torn_answers = torn_answers
        self.deaf_after_boot_ms = deaf_after_boot_ms
        self.saved = factory_settings(mac, dialect)
        self.saved.baud = baud
        self.counters: dict[str, int] = {"events": 0, "tx_overflow": 0, "rx_overflow": 0, "rx_ignored": 0}
        self._out = bytearray()
        self._urgent = 0  # echo and answers go before this index of the unsent output
        self._credit = 0.0  # bytes the UART may send now (paced)
        self._uart_ms = 0
        self._line = bytearray()
        self._overflowed = False
        self._now_ms = 0
        self._restart_at: int | None = None
        self.powered = True
        self.boot(0)
        self._deaf_until = 0

    # -- life cycle -------------------------------------------------------------------
    def boot(self, now_ms: int) -> None:
        """Power-up or reset: load stored settings, forget tags, print +STARTUP."""
        self._now_ms = now_ms
        self.booted_ms = now_ms
        self._deaf_until = now_ms + self.deaf_after_boot_ms
        self.active = copy.deepcopy(self.saved)
        self.pending = copy.deepcopy(self.saved)
        self.enabled = bool(self.active.udfcfg[3])
        self.tags: dict[str, _Tag] = {}
        self._line.clear()
        self._overflowed = False
        self._restart_at = None
        self._emit(encode_startup())

    @property
    def baud(self) -> int:
        """The UART rate in effect (a host at another rate sees garbage)."""
        return self.active.baud

    def tick(self, now_ms: int) -> None:
        if self.paced and self._out:  # the UART's clock only runs forwards
            elapsed = max(0, now_ms - self._uart_ms)
            self._credit = min(self._credit + elapsed * self.baud / 10_000, len(self._out))
        self._uart_ms = max(self._uart_ms, now_ms)
        self._now_ms = now_ms
        if self._restart_at is not None and now_ms >= self._restart_at:
            self.boot(now_ms)
        for tag_id in [t for t, s in self.tags.items() if now_ms - s.last_heard_ms > TAG_TIMEOUT_MS]:
            del self.tags[tag_id]

    def read(self) -> bytes:
        """What the UART has sent since the last read."""
        n = min(len(self._out), int(self._credit)) if self.paced else len(self._out)
        data = bytes(self._out[:n])
        del self._out[:n]
        self._credit -= n
        self._urgent = max(0, self._urgent - n)
        return data

    def _emit(self, data: bytes, urgent: bool = False) -> None:
        """Queue output; ``urgent`` (echo, answers) jumps the queue only with ``torn_answers``."""
        if len(self._out) + len(data) > TX_BUFFER:
            self.counters["tx_overflow"] += 1
            return
        if urgent and self.torn_answers:
            self._out[self._urgent:self._urgent] = data
            self._urgent += len(data)
        else:
            self._out += data

    # -- host -> board ----------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Bytes from the host: echoed as received; each CR ends a command."""
        if self._restart_at is not None:
            return  # restarting: the UART is down
        if self._now_ms < self._deaf_until:
            self.counters["rx_ignored"] += len(data)
            return
        for byte in data:
            self._emit(bytes((byte,)), urgent=True)
            if byte == 0x0D:
                line, overflowed = bytes(self._line), self._overflowed
                self._line.clear()
                self._overflowed = False
                if overflowed:
                    self._answer(ok=False)  # the whole line is lost, its tail never runs
                elif line.strip():
                    self._execute_bytes(line.strip())
            elif byte != 0x0A:
                if len(self._line) >= RX_LINE:
                    if not self._overflowed:
                        self.counters["rx_overflow"] += 1
                    self._overflowed = True
                    continue
                self._line.append(byte)

    def _answer(self, info: list[str] | None = None, ok: bool = True) -> None:
        self._emit(encode_answer(info or [], ok), urgent=True)

    def _execute_bytes(self, line: bytes) -> None:
        if any(b < 0x20 or b > 0x7E for b in line):  # control or non-ASCII byte: not a command
            return self._answer(ok=False)
        self._execute(line.decode("ascii"))

    def _execute(self, line: str) -> None:
        upper = line.upper()
        gmm, gmr, ati9 = _IDENTITY[self.dialect]
        flow = FLOW_ON if self.pending.flow_control else FLOW_OFF
        simple = {
            "AT": [],
            "AT+GMI": ['"u-blox"'],
            "AT+GMM": [gmm],
            "AT+GMR": [gmr],
            "ATI9": [ati9],
            "AT+UMLA=1": [f"+UMLA:{self.mac}"],
            "AT+UMRS?": [f"+UMRS:{self.pending.baud},{flow},8,1,1,1"],
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
            self.saved = factory_settings(self.mac, self.dialect)
            self.pending = copy.deepcopy(self.saved)
            return self._answer()
        if upper == "AT+UDFCFG?":
            return self._answer([config_answer(t, v) for t, v in sorted(self.pending.udfcfg.items())])
        for prefix, handler in (
            ("AT+UDFENABLE=", self._udfenable),
            ("AT+UDFCFG=", self._udfcfg),
            ("AT+UDFFILT=", self._udffilt),
            ("AT+UMRS=", self._umrs),
        ):
            if upper.startswith(prefix):
                try:
                    info = handler(parse_params(line[len(prefix):]))
                except (ValueError, KeyError):
                    return self._answer(ok=False)
                return self._answer(info)
        return self._answer(ok=False)

    def _udfenable(self, params: list[int | str]) -> list[str]:
        if params not in ([0], [1]):
            raise AtSyntaxError("AT+UDFENABLE takes 0 or 1")
        self.enabled = params == [1]
        return []

    def _udfcfg(self, params: list[int | str]) -> list[str]:
        tag = params[0]
        if not isinstance(tag, int) or tag not in self.pending.udfcfg:
            raise AtSyntaxError(f"no tag {tag}")
        if len(params) == 1:
            return [config_answer(tag, self.pending.udfcfg[tag])]
        if len(params) != 2 or not accepts(self.family, tag, params[1]):
            raise AtSyntaxError(f"bad value for tag {tag}")
        self.pending.udfcfg[tag] = params[1]
        if self.family in LIVE_FAMILIES:
            self.active.udfcfg[tag] = params[1]
        return []

    def _udffilt(self, params: list[int | str]) -> list[str]:
        kind = params[0]
        if not isinstance(kind, int):
            raise KeyError(kind)  # ERROR, as for an unknown kind
        digits = {1: 20, 2: 12}[kind]  # KeyError: ERROR
        if len(params) == 1:
            listed = "".join(f',"{i}"' for i in self.pending.filters[kind])
            return [f"+UDFFILT:{kind}{listed}"]
        action, ids = params[1], params[2:]
        if not all(isinstance(i, str) and len(i) == digits and is_at_string(i)
                   and all(c in "0123456789abcdefABCDEF" for c in i) for i in ids):
            raise AtSyntaxError("ids must be quoted hex")
        upper = [str(i).upper() for i in ids]
        if action == 1 and not ids:
            self.pending.filters[kind] = []
        elif action == 2 and ids and len(self.pending.filters[kind]) + len(ids) <= 100:
            self.pending.filters[kind].extend(upper)
        else:
            raise AtSyntaxError(f"bad action {action}")
        return []

    def _umrs(self, params: list[int | str]) -> list[str]:
        """``<baud>,<flow>[,8,1,1,<change_after_confirm>]``: only baud and flow control are
        supported (UBX-21004616 A.5); flow 1 on, 2 off."""
        if len(params) not in (2, 5, 6) or params[0] not in BAUD_RATES or params[1] not in (FLOW_ON, FLOW_OFF):
            raise AtSyntaxError("bad AT+UMRS")
        if len(params) >= 5 and (params[2:5] != [8, 1, 1] or params[5:] not in ([], [0], [1])):
            raise AtSyntaxError("only 8N1 is supported")
        self.pending.baud, self.pending.flow_control = int(params[0]), params[1] == FLOW_ON
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
            if len(self.tags) >= TAG_LIMIT[self.dialect] and not cfg[6]:  # tag 6: track unlimited tags
                return
            tag = self.tags[adv.instance_id] = _Tag(self._now_ms)
        tag.last_heard_ms = self._now_ms
        smooth = bool(cfg[8])
        azimuth = _printed(tag.raw_azimuths, adv.azimuth_deg, smooth)
        elevation = _printed(tag.raw_elevations, adv.elevation_deg if cfg[5] else 0.0, smooth)
        min_interval = int(cfg[1])
        if tag.last_event_ms is not None and self._now_ms - tag.last_event_ms < min_interval:
            return
        tag.last_event_ms = self._now_ms
        tag.seq = (tag.seq + 1) & 0xFFFF
        if adv.event_counter is not None and self.dialect in (Dialect.V2, Dialect.EMBED):
            tag.seq = adv.event_counter & 0xFFFF  # the tag's own counter: gaps where packets were missed
        timestamp = _int32(self._now_ms - self.booted_ms)
        rssi1 = _clamp(round(adv.rssi1_dbm), -127, 20)
        if self.dialect is Dialect.V1_0:
            reserved = _clamp(round(adv.rssi2_dbm), -127, 20)  # 1.0: the 2nd polarisation
        else:
            reserved = RESERVED[tag.seq % len(RESERVED)]  # "reserved" from 1.2 on; real lines: -43, 6, 8
        channel = 37 + tag.seq % 3  # every dialect: UG-R10 §6 shows 10-field lines on 37-39 too
        if cfg[7] == 1:  # undocumented $MEAS text format, emulated so hosts can detect it
            self._emit(f"\r\n$MEAS,{azimuth},{elevation},{rssi1},{reserved},{channel},{timestamp},0,0\r\n".encode())
            return
        if cfg[7] == 2:  # u-locateEmbed binary output: FE type len16 payload (docs/protocol.md)
            payload = bytes.fromhex(adv.instance_id) + struct.pack(
                "<bbbBiH", azimuth, elevation, rssi1, channel, timestamp, tag.seq)
            self._emit(b"\xfe" + bytes((BINARY_ANGLE,)) + struct.pack("<H", len(payload)) + payload)
            return
        raw = bool(cfg.get(121, 0))
        event = AngleEvent(
            adv.instance_id, rssi1, azimuth, elevation, reserved, channel,
            str(cfg[4]), str(cfg[2]), timestamp, tag.seq,
            tag.raw_azimuths[-1] if raw else None, tag.raw_elevations[-1] if raw else None,
        )
        dialect = self.dialect
        if dialect is Dialect.EMBED and not raw:
            dialect = Dialect.V2
        self._emit(encode_angle_event(event, dialect))
        self.counters["events"] += 1


def output_angles(raw_deg: Sequence[float], smooth: bool = True) -> list[int]:
    """The angles a board prints for one tag's successive measured angles (degrees): rounded,
    clamped to +-90 and, with median buffering (``smooth``, tag 8's default), the median of the
    last :data:`MEDIAN_EVENTS`, as :meth:`XplrAoaFirmware.on_advertisement` does one by one."""
    buffer: deque[int] = deque(maxlen=MEDIAN_EVENTS)
    return [_printed(buffer, value, smooth) for value in raw_deg]


def _printed(buffer: deque[int], value_deg: float, smooth: bool) -> int:
    """One measured angle into a tag's buffer: what the board prints for it (rounded, clamped,
    and with ``smooth`` the median of the buffer)."""
    raw = _clamp(round(value_deg), -90, 90)
    buffer.append(raw)
    return _median(buffer) if smooth else raw


def _clamp(value: int, low: int, high: int) -> int:
    return low if value < low else high if value > high else value


def _median(values: deque[int]) -> int:
    ordered = sorted(values)
    return ordered[len(ordered) // 2]


def _int32(value: int) -> int:
    """printf %d of a 32-bit millisecond counter."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value
