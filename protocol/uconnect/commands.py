"""Builders for every u-connectLocate command in protocols.md, and a command/answer matcher.

A builder validates its arguments and returns a :class:`Command`; ``Command.wire`` is what
goes to the board (commands end in CR only). :class:`CommandMatcher` pairs one outstanding
command with its echo, information lines and final code while URCs keep arriving in between.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple

from rfhoming.protocol.uconnect.items import Item

BAUD_RATES = (19200, 38400, 57600, 115200, 230400, 460800, 921600, 1000000)
"""Rates AT+UMRS accepts (protocols.md §1); also the list a host probes on garbage."""

UDFCFG_RANGES: dict[int, range | None] = {
    1: range(0, 10001),  # min interval between events per tag, ms
    2: None,  # user string
    3: range(0, 2),  # angle calculation on at start-up
    4: None,  # anchor id string
    5: range(0, 2),  # azimuth only (0) or azimuth + elevation (1)
    6: range(0, 3),  # antenna board: 0 C211, 1 CoreHW patch, 2 ANT-B10
    7: range(0, 3),  # output format: 0 +UUDF (1 $MEAS text, 2 binary: unsupported)
    8: range(0, 2),  # angle post-processing
    9: range(0, 10001),  # later firmware: event interval, ms
    11: range(0, 101),  # later firmware: smoothing factor
    121: range(0, 2),  # u-locateEmbed: raw angles appended
}
"""AT+UDFCFG tags and valid values; ``None`` marks a quoted string tag (≤ 30 chars)."""

STRING_TAGS = frozenset(tag for tag, valid in UDFCFG_RANGES.items() if valid is None)


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


def set_config(tag: int, value: int | str) -> Command:
    """``AT+UDFCFG=<tag>,<value>``; strings are quoted, numbers range-checked."""
    if tag not in UDFCFG_RANGES:
        raise ValueError(f"unknown AT+UDFCFG tag {tag}; known: {sorted(UDFCFG_RANGES)}")
    valid = UDFCFG_RANGES[tag]
    if valid is None:
        text = str(value)
        if len(text) > 30 or '"' in text or not text.isascii():
            raise ValueError(f"AT+UDFCFG tag {tag} takes an ASCII string of at most 30 chars")
        return Command(f'AT+UDFCFG={tag},"{text}"')
    if not isinstance(value, int) or value not in valid:
        raise ValueError(f"AT+UDFCFG tag {tag} takes {valid.start}..{valid.stop - 1}")
    return Command(f"AT+UDFCFG={tag},{value}")


def read_config(tag: int | None = None) -> Command:
    """``AT+UDFCFG=<tag>`` for one tag, ``AT+UDFCFG?`` for all."""
    if tag is None:
        return Command("AT+UDFCFG?")
    if tag not in UDFCFG_RANGES:
        raise ValueError(f"unknown AT+UDFCFG tag {tag}")
    return Command(f"AT+UDFCFG={tag}")


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
    """``AT+UMRS``: takes effect after ``AT&W`` and ``AT+CPWROFF``."""
    if baud not in BAUD_RATES:
        raise ValueError(f"baud {baud} not supported; choose one of {BAUD_RATES}")
    return Command(f"AT+UMRS={baud},{int(bool(flow_control))}")


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
        if kind == "echo":
            if item.text == self.pending.text:
                self._echoed = True
            else:
                self.counters["echo_mismatch"] += 1
        elif kind in ("info", "unknown"):
            self._info.append(item.text)
        elif kind == "final":
            return self._complete(item.ok, restarted=False)
        elif kind == "startup":
            return self._complete(False, restarted=True)
        return None

    def _complete(self, ok: bool, restarted: bool) -> Response:
        assert self.pending is not None
        response = Response(self.pending, ok, self._info, self._echoed, restarted)
        self.pending = None
        self.counters["ok" if ok else "error"] += 1
        return response
