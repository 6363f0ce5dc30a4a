"""Builders for every u-connectLocate command in docs/protocol.md §1, and a command/answer matcher.

A builder validates its arguments and returns a :class:`Command`; ``Command.wire`` is what
goes to the board (commands end in CR only). :class:`CommandMatcher` pairs one outstanding
command with its echo, information lines and final code while URCs keep arriving in between.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple

from rfhoming.protocol.uconnect.decoder import MAX_STRING
from rfhoming.protocol.uconnect.encoder import Dialect
from rfhoming.protocol.uconnect.items import Item

BAUD_RATES = (19200, 38400, 57600, 115200, 230400, 460800, 921600, 1000000)
"""Rates AT+UMRS accepts (docs/protocol.md §1, `AT+UMRS`); also the list a host probes on garbage."""

FLOW_ON = 1
FLOW_OFF = 2
"""AT+UMRS flow control values of u-connect firmware: 1 = CTS/RTS on, 2 = off (UBX-14044127)."""

FAMILIES = ("1.x", "2.x", "embed")
"""Firmware families whose AT+UDFCFG tables differ: u-connectLocate 1.x, 2.x, u-locateEmbed."""

_ALL = dict.fromkeys(FAMILIES)


@dataclass(frozen=True)
class ConfigTag:
    """One ``AT+UDFCFG`` tag: what each family accepts and its factory default.

    ``ranges`` maps a family to its valid values (``None``: a quoted ASCII string of at most
    30 characters); a family missing from it answers ERROR for the tag. ``default`` None means
    the anchor's MAC address (tag 4)."""

    tag: int
    meaning: str
    ranges: dict[str, range | None]
    default: int | str | None
    source: str


def _same(valid: range | None, families: tuple[str, ...] = FAMILIES) -> dict[str, range | None]:
    return {f: valid for f in families}


_GUIDE = "UBX-21004616 R02 appendix A.3.3"
_LATER = "docs/protocol.md, `AT+UDFCFG` per firmware family: assumed from public 2.x / u-locateEmbed clients ([ANTB10], [BIN])"

UDFCFG: dict[int, ConfigTag] = {t.tag: t for t in (
    ConfigTag(1, "minimum interval between +UUDF events per tag, ms", _same(range(0, 10001)), 1, _GUIDE),
    ConfigTag(2, "user string, in every +UUDF", _same(None), "", _GUIDE),
    ConfigTag(3, "angle calculation on at start-up", _same(range(0, 2)), 1, _GUIDE),
    ConfigTag(4, "anchor id, in every +UUDF", _same(None), None, _GUIDE),
    ConfigTag(5, "0 azimuth only, 1 azimuth and elevation", _same(range(0, 2)), 1, _GUIDE),
    ConfigTag(6, "track unlimited tags, worse angles (needs tag 8 = 0)", _same(range(0, 2)), 0, _GUIDE),
    ConfigTag(7, "output format: 0 +UUDF, 1 CoreHW text ($MEAS), 2 u-locateEmbed binary",
              {"1.x": range(0, 2), "2.x": range(0, 2), "embed": range(0, 3)}, 0, f"{_GUIDE}; {_LATER}"),
    ConfigTag(8, "median buffering of the output angle", _same(range(0, 2)), 1, _GUIDE),
    ConfigTag(9, "report interval, ms", _same(range(0, 10001), ("2.x", "embed")), 20, _LATER),
    ConfigTag(10, "angle smoothing", _same(range(0, 100), ("2.x", "embed")), 0, _LATER),
    ConfigTag(11, "fixed smoothing factor", _same(range(0, 101), ("2.x", "embed")), 0, _LATER),
    ConfigTag(13, "field 3 is 0 the azimuth or 1 the direct angle", _same(range(0, 2), ("2.x", "embed")), 0, _LATER),
    ConfigTag(121, "unsmoothed angles appended to +UUDF", _same(range(0, 2), ("embed",)), 0, _LATER),
)}
"""The ``AT+UDFCFG`` table per firmware family, with ranges and defaults (docs/protocol.md)."""

LIVE_FAMILIES = frozenset({"2.x", "embed"})
"""Families that apply ``AT+UDFCFG`` at once (1.x only after ``AT&W`` + ``AT+CPWROFF``); a
host must not rely on either: it reads back and restarts only when the old value stays."""

def family(dialect: Dialect) -> str:
    """The AT+UDFCFG family of a +UUDF dialect."""
    return {Dialect.V1_0: "1.x", Dialect.V1_2: "1.x", Dialect.V2: "2.x", Dialect.EMBED: "embed"}[dialect]


def accepts(fam: str, tag: int, value: int | str) -> bool:
    """Whether a ``fam`` board takes ``AT+UDFCFG=<tag>,<value>``."""
    entry = UDFCFG.get(tag)
    if entry is None or fam not in entry.ranges:
        return False
    valid = entry.ranges[fam]
    if valid is None:
        return isinstance(value, str) and is_at_string(value)
    return isinstance(value, int) and not isinstance(value, bool) and value in valid


def is_at_string(text: str) -> bool:
    """A value a string setting can hold: printable ASCII, no quote, at most 30 characters."""
    return len(text) <= MAX_STRING and all(" " <= ch <= "~" and ch != '"' for ch in text)


class Command(NamedTuple):
    """One AT command line, without its CR."""

    text: str

    @property
    def wire(self) -> bytes:
        return self.text.encode("ascii") + b"\r"


def _hex_id(value: str, digits: int) -> str:
    if len(value) != digits or any(c not in "0123456789abcdefABCDEF" for c in value):
        raise ValueError(f"expected {digits} hex digits, got {value!r}")
    return value.upper()


def at() -> Command:
    return Command("AT")


def identify_manufacturer() -> Command:
    return Command("AT+GMI")


def identify_model() -> Command:
    return Command("AT+GMM")


def identify_version() -> Command:
    return Command("AT+GMR")


def identify_software() -> Command:
    return Command("ATI9")


def local_address() -> Command:
    return Command("AT+UMLA=1")


def enable_angles(on: bool) -> Command:
    return Command(f"AT+UDFENABLE={int(bool(on))}")


def _known(tag: int) -> ConfigTag:
    entry = UDFCFG.get(tag)
    if entry is None:
        raise ValueError(f"unknown AT+UDFCFG tag {tag}; known: {sorted(UDFCFG)}")
    return entry


def set_config(tag: int, value: int | str, fam: str | None = None) -> Command:
    """``AT+UDFCFG=<tag>,<value>``; strings are quoted, numbers range-checked (for ``fam``, or
    against the widest range any family accepts)."""
    entry = _known(tag)
    families = [fam] if fam is not None else [f for f in FAMILIES if f in entry.ranges]
    if fam is not None and fam not in entry.ranges:
        raise ValueError(f"AT+UDFCFG tag {tag} does not exist on {fam} firmware "
                         f"(only {', '.join(entry.ranges)})")
    if entry.ranges[families[0]] is None:
        text = str(value)
        if not is_at_string(text):
            raise ValueError(f"AT+UDFCFG tag {tag} takes a printable ASCII string of at most "
                             f"{MAX_STRING} chars, without quotes")
        return Command(f'AT+UDFCFG={tag},"{text}"')
    if not any(accepts(f, tag, value) for f in families):
        valid = max((r for f in families if (r := entry.ranges[f]) is not None), key=len)
        raise ValueError(f"AT+UDFCFG tag {tag} takes {valid.start}..{valid.stop - 1}")
    return Command(f"AT+UDFCFG={tag},{value}")


def read_config(tag: int | None = None) -> Command:
    """``AT+UDFCFG=<tag>`` for one tag, ``AT+UDFCFG?`` for all."""
    if tag is None:
        return Command("AT+UDFCFG?")
    _known(tag)
    return Command(f"AT+UDFCFG={tag}")


def config_answer(tag: int, value: int | str) -> str:
    """The information line that reads back ``AT+UDFCFG=<tag>``."""
    return f'+UDFCFG:{tag},"{value}"' if isinstance(value, str) else f"+UDFCFG:{tag},{value}"


FILTER_NAMESPACE = 1
FILTER_INSTANCE = 2
FILTER_CLEAR = 1
FILTER_APPEND = 2


def set_filter(kind: int, action: int, ids: tuple[str, ...] = ()) -> Command:
    """``AT+UDFFILT``: type 1 namespace (20 hex), 2 instance ids (12 hex, ≤ 100); clear/append."""
    digits = {FILTER_NAMESPACE: 20, FILTER_INSTANCE: 12}.get(kind)
    if digits is None:
        raise ValueError("filter type must be 1 (namespace) or 2 (instance id)")
    if action not in (FILTER_CLEAR, FILTER_APPEND):
        raise ValueError("filter action must be 1 (clear) or 2 (append)")
    if action == FILTER_CLEAR and ids:
        raise ValueError("clearing a filter takes no ids")
    if len(ids) > 100:
        raise ValueError("at most 100 ids in a filter")
    quoted = "".join(f',"{_hex_id(i, digits)}"' for i in ids)
    return Command(f"AT+UDFFILT={kind},{action}{quoted}")


def read_filter(kind: int) -> Command:
    if kind not in (FILTER_NAMESPACE, FILTER_INSTANCE):
        raise ValueError("filter type must be 1 (namespace) or 2 (instance id)")
    return Command(f"AT+UDFFILT={kind}")


def set_serial(baud: int, flow_control: bool) -> Command:
    """``AT+UMRS=<baud>,<flow>``, flow 1 on / 2 off: takes effect after ``AT&W`` and
    ``AT+CPWROFF``."""
    if baud not in BAUD_RATES:
        raise ValueError(f"baud {baud} not supported; choose one of {BAUD_RATES}")
    return Command(f"AT+UMRS={baud},{FLOW_ON if flow_control else FLOW_OFF}")


def read_serial() -> Command:
    return Command("AT+UMRS?")


def store() -> Command:
    return Command("AT&W")


def restart() -> Command:
    return Command("AT+CPWROFF")


def factory_defaults() -> Command:
    return Command("AT+UFACTORY")


@dataclass
class Response:
    """A completed command: its information lines and whether it ended in ``OK``."""

    command: Command
    ok: bool
    info: list[str] = field(default_factory=list)
    echoed: bool = False
    restarted: bool = False
    """The board printed ``+STARTUP`` before answering: the command died with the board."""


class CommandMatcher:
    """Pairs the one outstanding command with its answer; URCs are left to the caller.

    AT is strictly one command at a time, so at most one is pending. Lines that arrive with
    no command pending (a stray ``OK``, an info line) are counted, not guessed at.
    """

    def __init__(self) -> None:
        self.pending: Command | None = None
        self._info: list[str] = []
        self._echoed = False
        self.counters: Counter[str] = Counter()

    def send(self, command: Command) -> bytes:
        """Register ``command`` as outstanding and return the bytes to write."""
        if self.pending is not None:
            raise RuntimeError(f"{self.pending.text!r} is still waiting for its answer")
        self.pending, self._info, self._echoed = command, [], False
        return command.wire

    def cancel(self) -> None:
        """Forget the outstanding command (its timeout expired)."""
        if self.pending is not None:
            self.counters["timeout"] += 1
        self.pending = None

    def on_item(self, item: Item) -> Response | None:
        """Feed one decoded item; returns the :class:`Response` when one completes."""
        kind = item.kind
        if kind in ("angle", "tag_data", "drop"):
            return None
        if self.pending is None:
            if kind in ("echo", "info", "final"):
                self.counters["unexpected_" + kind] += 1
            return None
        if item.kind == "echo":
            if item.text == self.pending.text:
                self._echoed = True
            else:
                self.counters["echo_mismatch"] += 1
        elif item.kind == "info" or item.kind == "unknown":
            self._info.append(item.text)
        elif item.kind == "final":
            return self._complete(item.ok, restarted=False)
        elif item.kind == "startup":
            return self._complete(False, restarted=True)
        return None

    def _complete(self, ok: bool, restarted: bool) -> Response:
        assert self.pending is not None
        response = Response(self.pending, ok, self._info, self._echoed, restarted)
        self.pending = None
        self.counters["ok" if ok else "error"] += 1
        return response
