"""XPLR-AOA driver: set-up, angle events stamped with host time, recovery.

State machine::

    opening --open--> setting_up --AT ok, config applied, UDFENABLE=1--> streaming
    streaming --"+STARTUP" (board rebooted)--> setting_up
    any --device gone--> disconnected --re-open with back-off--> setting_up
    any --only garbage for garbage_timeout s--> baud_mismatch, or binary_output when the
        garbage is u-locateEmbed binary frames (AT+UDFCFG=7,2), or unknown_output when it is
        well-formed text lines that are not +UUDF ($MEAS, raw-IQ JSON debug lines)

Set-up (docs/hardware.md explains each command): ``AT`` until the board answers;
``AT+UDFENABLE=0``, so a board that still streams from an earlier run stops crowding the link
(u-blox's own clients do the same); identify the firmware with ``AT+GMM``, ``AT+GMR`` and
``ATI9`` -- an identification that fails only costs the guess (1.2, the common dialect, until
the ``+UUDF`` field count says otherwise); read each wanted ``AT+UDFCFG`` and the stored tag
filter (``AT+UDFFILT=2``, read at every set-up: a filter an earlier ``tags=`` or another program
stored outlives them, and a board that reports one tag only must say so) and write those that
differ and that the family accepts (``tags=none`` clears the filter); if something was written, ``AT&W``, read
back, and ``AT+CPWROFF`` when the family applies settings at restart (1.x), the tag filter
changed (no source says it applies at once, so it is treated as applying at restart on every
family), or the board still reports the old value; then ``AT+UDFENABLE=1``. With an on-board tag
filter the driver then checks its effect: other tags still arriving is reported once (the host
filter stays as a backstop).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.common import (
    BoundedStream,
    CommandFailed,
    Driver,
    Wiring,
    serial_port,
)
from rfhoming.host.ports import Port, Tap
from rfhoming.host.portspec import PortSpec
from rfhoming.protocol.uconnect import (
    AngleEvent,
    CommandMatcher,
    Dialect,
    Response,
    UConnectDecoder,
)
from rfhoming.protocol import pcapng
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.uconnect import commands as c
from rfhoming.protocol.uconnect.items import Echo, FinalCode, InfoLine, Startup, TagData, UnknownLine
from rfhoming.protocol.uconnect.binary import BinaryDecoder

log = logging.getLogger(__name__)


def replayed_without_set_up(port: Any) -> bool:
    """A replay (host/replay.py ReplayPort) of a capture in which the host wrote nothing: the
    board was streaming already, so there is no answer to wait for."""
    packets = getattr(port, "packets", None)
    return packets is not None and not any(p.direction == pcapng.OUTBOUND for p in packets)

FLOW_HINT = "check the RTS/CTS wiring, or try flow=none in the port spec (e.g. /dev/ttyUSB0,flow=none)"
SILENT_HINT = ("the tag is not advertising (battery, or asleep), or the tag and anchor firmware "
               "generations do not match; see docs/hardware.md, troubleshooting")
STORED_FILTER_HINT = ("the board's stored tag filter lets only {ids} through (tags=none in the port spec "
                      "clears it; tags=ID sets another)")
NAMESPACE_HINT = ("; u-locateEmbed reports only tags whose Eddystone namespace is NINA-B4TAG "
                  "(4E494E412D4234544147, the C209's): advertise that namespace, or clear the board's "
                  "filter with AT+UDFFILT=1,1, AT&W, AT+CPWROFF")
LEAK_EVENTS = 3
"""Events of other tags after an on-board filter was set before the driver says it had no effect."""



@dataclass(frozen=True)
class AoaSetup:
    """What the user asked of the board, and how patient to be with it."""

    config: dict[int, int | str] = field(default_factory=dict)
    instance_filter: tuple[str, ...] = ()
    host_filter: frozenset[str] = frozenset()
    command_timeout: float = 1.0
    retries: int = 3
    wake_timeout: float = 5.0
    """How long to say AT before giving up on a board (it ignores the host after booting)."""
    restart_timeout: float = 3.0
    garbage_timeout: float = 3.0
    silence_timeout: float = 5.0
    """Streaming without one +UUDF this long: say why that may be."""
    choose_tag_s: float | None = None
    """With no ``host_filter``: hold every event back for this long of the board's time, listening; then home on
    the only tag heard, or report the tags heard (:attr:`AoaDriver.ambiguous_tags`) and keep
    holding. None: pass every tag on (listen, capture)."""
    probe_baud: bool = False
    clear_filter: bool = False
    """Clear the tag filter stored on the board (``tags=none``)."""

    def with_tags(self, tags: tuple[str, ...] | frozenset[str]) -> AoaSetup:
        """Home on ``tags``: the board's own instance filter (so other tags stop crowding the
        link) and the host filter as a backstop; no tags: clear the board's filter."""
        wanted = tuple(sorted({t.upper() for t in tags}))
        return replace(self, instance_filter=wanted, host_filter=frozenset(wanted), clear_filter=not wanted)


def bearing_of(t_host: float, event: AngleEvent) -> Bearing:
    """A ``+UUDF`` event as the neutral reading, stamped with the host time its bytes arrived:
    the board's azimuth is negative to its left (docs/protocol.md "The angle event"), REP 103's
    counter-clockwise, so its sign turns; elevation (up positive) and RSSI stay."""
    return Bearing(t_host, event.anchor_id, event.instance_id, math.radians(-event.azimuth),
                   math.radians(event.elevation), float(event.rssi1))


def filter_ids(info: list[str]) -> tuple[str, ...]:
    """The ids of a ``+UDFFILT:<type>[,"<id>"...]`` read-back (none: no filter)."""
    line = next((i for i in info if i.startswith("+UDFFILT:")), "")
    return tuple(i.strip('"').upper() for i in line.partition(":")[2].split(",")[1:] if i.strip('"'))


def identify_dialect(model: str, version: str, software: str) -> Dialect:
    """AT+GMM / AT+GMR / ATI9 answers -> the +UUDF dialect (docs/protocol.md); the common
    dialect (1.2) when the answers say nothing. Answers are taken quoted or not (u-blox's tag
    quotes AT+GMM; no anchor capture is public), the model as a whole word: a C209 tag's
    "NINA-B4-TAG" or a "NINA-B4-DF-TAG" build is no 1.0 anchor."""
    if "locateembed" in software.lower():
        return Dialect.EMBED
    if model.strip().strip('"') == "NINA-B4-DF":
        return Dialect.V1_0
    digits = version.strip('"').split(".")[0]
    if digits.isdigit() and int(digits) >= 2:
        return Dialect.V2
    return Dialect.V1_2


def dialect_of_event(event: AngleEvent, guess: Dialect) -> Dialect:
    """What a +UUDF line's field count says of the dialect (it wins over a guess)."""
    if event.azimuth_raw is not None:
        return Dialect.EMBED
    if event.seq is not None:
        return guess if guess in (Dialect.V2, Dialect.EMBED) else Dialect.V2
    return guess if guess in (Dialect.V1_0, Dialect.V1_2) else Dialect.V1_2


def looks_binary(data: bytes, chain: int = 3) -> bool:
    """Whether ``data`` holds ``chain`` back-to-back u-locateEmbed binary frames
    (``FE type len16-LE payload``): random garbage at a wrong baud rate almost never does."""
    start = data.find(b"\xfe")
    while start >= 0:
        i, n = start, 0
        while i + 4 <= len(data) and data[i] == 0xFE:
            length = int.from_bytes(data[i + 2:i + 4], "little")
            if length > 64 or i + 4 + length > len(data):
                break
            i += 4 + length
            n += 1
            if n >= chain:
                return True
        start = data.find(b"\xfe", start + 1)
    return False


class AoaDriver(Driver):
    kind = "xplr-aoa"
    sets_up = True
    items = (AngleEvent, TagData, Startup, Echo, InfoLine, FinalCode, UnknownLine, Drop)
    poke = b"AT\r"  # a board that streams nothing still answers AT

    @classmethod
    def speaks(cls, data: bytes) -> bool:
        """A u-connectLocate line is in ``data``: an event, or an answer to AT (not an unknown line)."""
        return any(i.kind in ("angle", "startup", "final", "echo", "info", "tag_data")
                   for i in UConnectDecoder().feed(data))

    @classmethod
    def options(cls, wiring: Wiring) -> dict[str, Any]:
        """Tag choice and baud probing; an anchor (a site's fixed board) keeps the defaults."""
        if wiring.role not in (None, "aoa"):
            return {}
        return {"setup": AoaSetup(choose_tag_s=wiring.choose_tag_s, probe_baud=wiring.probe_baud)}

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> AoaDriver:
        """``tags=`` sets the board's tag filter and the host's, ``timeout=`` bounds each set-up command."""
        setup = options.pop("setup", AoaSetup())
        if "tags" in spec.settings:  # tags=none: () -- clear the board's filter
            setup = setup.with_tags(spec.tags)
        if spec.timeout:
            setup = replace(setup, command_timeout=spec.timeout)
        return cls(port or serial_port(spec, taps), setup, **options)

    def __init__(self, port: Port, setup: AoaSetup = AoaSetup(), *, queue_size: int = 1000,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.setup = setup
        self.decoder = UConnectDecoder()
        self.matcher = CommandMatcher()
        self.dialect: Dialect | None = None
        self.identity: dict[str, str] = {}
        self.board_filter: tuple[str, ...] | None = None
        """The tag ids the board's stored filter lets through (() none; None: not read yet, or
        the firmware has no AT+UDFFILT)."""
        self.counters.update(setups=0, reboots=0, retries=0, filtered=0, held=0, baud_mismatch=0, binary_output=0,
                             unknown_output=0, config_skipped=0, restarts=0, silent=0, board_filter_leaks=0,
                             binary_events=0)
        self.tags_heard: dict[str, int] = {}
        """Every tag id seen in a +UUDF line (before any filter) and how often; at most 256 ids
        (a board tracks at most 20 at a time)."""
        self.last_event: float | None = None
        self.chosen: frozenset[str] = setup.host_filter
        self.ambiguous_tags: list[str] = []
        self._choosing_since: int | None = None  # the board's clock (ms) at the first event heard
        self._answer: asyncio.Future[Response] | None = None
        self._startup = asyncio.Event()
        self._last_valid = time.monotonic()
        self._bytes_at_valid = 0
        self._streaming_at = 0.0
        self._recent = bytearray()
        self._unknown_lines: deque[str] = deque(maxlen=5)
        self._binary: BinaryDecoder | None = None  # decodes u-locateEmbed binary output once it is recognised

    # -- reading ----------------------------------------------------------------------
    def on_chunk(self, data: bytes, t_host: float) -> None:
        self._recent += data
        del self._recent[:-512]  # bounded: enough to recognise binary output
        if self._binary is not None:
            self._feed_binary(data, t_host)
        for item in self.decoder.feed(data):
            kind = item.kind
            if kind == "drop" and self._binary is None and looks_binary(bytes(self._recent)):
                self._binary_output(t_host)  # explained once, at the first frames
            if kind == "drop" and self._binary is not None:
                continue  # binary output is decoded; the text decoder's drops are only counted
            if not (item.kind == "angle" and self.chosen and item.instance_id not in self.chosen):
                self.emit(t_host, item)  # another tag's angles are counted (filtered), not shown
            if kind == "drop":
                continue
            if item.kind == "unknown":
                self._unknown_lines.append(item.text[:60])  # text, yet not +UUDF: say what it is
            else:
                self._last_valid = time.monotonic()
                self._bytes_at_valid = self.port.counters["bytes_in"]
                self._unknown_lines.clear()
            if item.kind == "angle":
                self._on_angle(item, t_host)
                continue
            if kind == "startup":
                self._startup.set()
                if self.state == "streaming":
                    self.counters["reboots"] += 1
                    log.warning("%s: the board restarted (+STARTUP); setting it up again", self.port.name)
                    self.state = "setting_up"  # from now: its settings and UDFENABLE are gone
                    self._needs_setup.set()
            # an unknown line while a command waits is its answer whose echo was torn
            response = self.matcher.on_item(item)
            if response is not None and self._answer is not None and not self._answer.done():
                self._answer.set_result(response)

    def _feed_binary(self, data: bytes, t_host: float) -> None:
        """u-locateEmbed binary frames -> angle events (only the azimuth is vouched for)."""
        assert self._binary is not None
        for item in self._binary.feed(data):
            self.emit(t_host, item)
            if isinstance(item, AngleEvent):
                self.counters["binary_events"] += 1
                self._last_valid = time.monotonic()
                self._bytes_at_valid = self.port.counters["bytes_in"]
                self._on_angle(item, t_host)

    def _on_angle(self, event: AngleEvent, t_host: float) -> None:
        self.last_event = time.monotonic()
        if len(self.tags_heard) < 256 or event.instance_id in self.tags_heard:
            self.tags_heard[event.instance_id] = self.tags_heard.get(event.instance_id, 0) + 1
        if self.dialect is not None:
            found = dialect_of_event(event, self.dialect)
            if found is not self.dialect:
                log.info("%s: +UUDF has %s fields: dialect %s, not %s", self.port.name,
                         found.field_count, found.value, self.dialect.value)
                self.dialect = found
        if not self.chosen and self.setup.choose_tag_s is not None and not self._choose(event.timestamp_ms):
            self.counters["held"] += 1
        elif self.chosen and event.instance_id not in self.chosen:
            self.counters["filtered"] += 1
            self._check_board_filter(event)
        else:
            self.out.put(bearing_of(t_host, event))

    def _check_board_filter(self, event: AngleEvent) -> None:
        """An on-board filter is set, yet another tag streams: say so once; the host filters."""
        if self.state != "streaming" or event.instance_id in self.setup.instance_filter \
                or not self.setup.instance_filter:
            return
        self.counters["board_filter_leaks"] += 1
        if self.counters["board_filter_leaks"] == LEAK_EVENTS:
            log.warning("%s: the board still reports tag %s although its filter is %s: the filter has no "
                        "effect on this firmware; filtering on the host instead", self.port.name,
                        event.instance_id, ",".join(self.setup.instance_filter))

    def _choose(self, board_ms: int) -> bool:
        """Listening for the tags in view: True once the only one heard is chosen. Measured on
        the board's clock, so a slow host (or a lockstep world) hears the same span of air."""
        assert self.setup.choose_tag_s is not None
        if self._choosing_since is None:
            self._choosing_since = board_ms
        if board_ms - self._choosing_since < self.setup.choose_tag_s * 1000 or self.ambiguous_tags:
            return False
        if len(self.tags_heard) > 1:
            self.ambiguous_tags = sorted(self.tags_heard)
            heard = ", ".join(f"{t} ({self.tags_heard[t]} events)" for t in self.ambiguous_tags)
            self.problem = (f"{len(self.ambiguous_tags)} tags in view: {heard}; choose the one to home on "
                            f"with --tag ID (or tags=ID in the port spec, tags = [\"ID\"] in [devices.aoa])")
            log.error("%s: %s", self.port.name, self.problem)
            return False
        self.chosen = frozenset(self.tags_heard)
        log.info("%s: homing on tag %s, the only one in view", self.port.name, next(iter(self.chosen)))
        return True

    # -- commands ---------------------------------------------------------------------
    async def command(self, command: c.Command, *, timeout: float | None = None, tries: int | None = None,
                      through_restart: bool = False) -> Response:
        """Send one command and wait for its answer, retrying on timeout; CommandFailed on ERROR
        or on a +STARTUP before the answer (``through_restart``: try again then, as waking a board
        that was just powered must: it may print +STARTUP after the host's first AT)."""
        timeout = self.setup.command_timeout if timeout is None else timeout
        tries = self.setup.retries + 1 if tries is None else tries
        for _ in range(tries):
            self._answer = asyncio.get_running_loop().create_future()
            self.matcher.cancel()
            self.port.write(self.matcher.send(command))
            try:
                async with asyncio.timeout(timeout):
                    response = await self._answer
            except TimeoutError:
                self.matcher.cancel()
                self.counters["retries"] += 1
                continue
            if response.restarted and through_restart:
                self.counters["retries"] += 1
                continue
            if response.restarted:
                raise CommandFailed(f"{command.text}: the board restarted (+STARTUP) before it answered")
            if not response.ok:
                raise CommandFailed(f"{command.text} answered ERROR")
            return response
        raise CommandFailed(f"{command.text}: no answer after {tries} tries ({timeout:g} s each)")

    async def _wake(self, probe: bool = True) -> None:
        """AT until the board answers: it ignores the host for a second after +STARTUP. A quiet
        board at another rate answers nothing: with ``probe_baud``, AT at each documented rate."""
        tries = max(1, round(self.setup.wake_timeout / 0.25))
        self.problem = f"waiting for an answer to AT; if none comes, {FLOW_HINT}"
        try:
            await self.command(c.at(), timeout=0.25, tries=tries, through_restart=True)
        except CommandFailed:
            if probe and self.setup.probe_baud and await self._probe():
                return await self._wake(probe=False)
            hint = FLOW_HINT if self.port.counters["bytes_in"] == 0 else (
                "bytes arrive but no answer: is this an XPLR-AOA, at this baud rate?")
            if self.setup.probe_baud:
                hint += f"; it answered at none of {', '.join(map(str, c.BAUD_RATES))} baud"
            else:
                hint += "; a board at another rate stays quiet: " + self._other_rates()
            raise CommandFailed(f"no answer to AT within {self.setup.wake_timeout:g} s: {hint}") from None

    def _other_rates(self) -> str:
        """How to give the board's rate, never suggesting the one the host already uses."""
        others = [b for b in c.BAUD_RATES if b != self.port.baud]
        return (f"give its rate with baud= in the port spec (it documents {', '.join(map(str, others))} besides "
                f"{self.port.baud}), or use --probe-baud to try each")

    # -- set-up -----------------------------------------------------------------------
    async def session(self) -> None:
        """Set the board up after every open and every reboot; watch for garbage meanwhile."""
        watchdogs = [asyncio.create_task(self._watch_garbage()), asyncio.create_task(self._watch_silence())]
        try:
            if replayed_without_set_up(self.port):
                self.state = "streaming"
                log.debug("%s: a replayed angle stream with no set-up exchange recorded: angles taken as "
                          "recorded, no board to set up", self.port.name)
                await asyncio.Event().wait()  # until the reader ends the session
            await self.keep_set_up()
        finally:
            for task in watchdogs:
                task.cancel()

    async def _identify(self, command: c.Command) -> str:
        """One identification answer, or '' when the board refuses it (never blocks set-up)."""
        try:
            return " ".join((await self.command(command)).info)
        except CommandFailed as exc:
            log.warning("%s: %s; guessing the dialect", self.port.name, exc)
            return ""

    async def _set_up(self) -> None:
        self.state = "setting_up"
        await self._wake()
        # a board still streaming from an earlier run would crowd the link and delay every answer
        await self.command(c.enable_angles(False))
        self.identity = {"model": await self._identify(c.identify_model()),
                         "version": await self._identify(c.identify_version()),
                         "software": await self._identify(c.identify_software())}
        self.dialect = identify_dialect(self.identity["model"], self.identity["version"], self.identity["software"])
        written = await self._apply_config()
        if written:
            await self.command(c.store())
            stale = [tag for tag, value in written.items() if not await self._reads_back(tag, value)]
            if c.family(self.dialect) not in c.LIVE_FAMILIES or "filter" in written or stale:
                await self._restart()
        await self.command(c.enable_angles(True))
        self.counters["setups"] += 1
        self.problem = None
        self.state = "streaming"
        self._streaming_at = time.monotonic()
        log.info("%s: streaming (%s, %s)", self.port.name, self.identity["model"] or "model unknown",
                 self.dialect.value)

    async def _restart(self) -> None:
        self._startup.clear()
        await self.command(c.restart())
        self.counters["restarts"] += 1
        try:
            async with asyncio.timeout(self.setup.restart_timeout):
                await self._startup.wait()
        except TimeoutError:
            raise CommandFailed("no +STARTUP after AT+CPWROFF") from None
        await self._wake()

    async def _reads_back(self, tag: int | str, value: Any) -> bool:
        if isinstance(tag, str):  # "filter", the one setting that is not a UDFCFG tag
            return (await self.command(c.read_filter(c.FILTER_INSTANCE))).info == [value]
        return (await self.command(c.read_config(tag))).info == [c.config_answer(tag, value)]

    async def _apply_config(self) -> dict[int | str, Any]:
        """Write the settings that differ and that this family has; returns what was written."""
        assert self.dialect is not None
        fam = c.family(self.dialect)
        written: dict[int | str, Any] = {}
        for tag, value in sorted(self.setup.config.items()):
            if not c.accepts(fam, tag, value):
                self.counters["config_skipped"] += 1
                log.warning("%s: AT+UDFCFG=%d,%r is not a %s setting; skipped", self.port.name, tag, value, fam)
                continue
            if (await self.command(c.read_config(tag))).info != [c.config_answer(tag, value)]:
                await self.command(c.set_config(tag, value, fam))
                written[tag] = value
        stored = await self._read_board_filter()
        wanted: tuple[str, ...] | None = tuple(i.upper() for i in self.setup.instance_filter) \
            if self.setup.instance_filter else () if self.setup.clear_filter else None
        if wanted is not None and stored is not None and stored != wanted:
            await self.command(c.set_filter(c.FILTER_INSTANCE, c.FILTER_CLEAR))
            if wanted:
                await self.command(c.set_filter(c.FILTER_INSTANCE, c.FILTER_APPEND, wanted))
            written["filter"] = "+UDFFILT:2" + "".join(f',"{i}"' for i in wanted)
            self.board_filter = wanted
        elif stored:
            log.warning("%s: %s", self.port.name, STORED_FILTER_HINT.format(ids=", ".join(stored)))
        return written

    async def _read_board_filter(self) -> tuple[str, ...] | None:
        """The stored instance-id filter; None when the firmware refuses to tell."""
        try:
            self.board_filter = filter_ids((await self.command(c.read_filter(c.FILTER_INSTANCE))).info)
        except CommandFailed as exc:
            log.warning("%s: %s; the board's tag filter is unknown", self.port.name, exc)
            self.board_filter = None
        return self.board_filter

    async def _watch_silence(self) -> None:
        """Streaming, AT works, yet no +UUDF: say the likely reasons once per silence."""
        warned = False
        while True:
            await asyncio.sleep(0.5)
            if self.state != "streaming":
                continue
            since = max(self.last_event or 0.0, self._streaming_at)
            if time.monotonic() - since < self.setup.silence_timeout:
                if warned and self.problem and self.problem.startswith("no +UUDF"):
                    self.problem = None  # events again
                warned = False
            elif not warned:
                warned = True
                self.counters["silent"] += 1
                hint = SILENT_HINT + (NAMESPACE_HINT if self.dialect is Dialect.EMBED else "")
                if self.board_filter:
                    hint = STORED_FILTER_HINT.format(ids=", ".join(self.board_filter)) + "; or " + hint
                self.problem = f"no +UUDF for {self.setup.silence_timeout:g} s although the board answers: {hint}"
                log.warning("%s: %s", self.port.name, self.problem)

    # -- garbage / baud ---------------------------------------------------------------
    async def _watch_garbage(self) -> None:
        while True:
            await asyncio.sleep(0.25)
            garbage = self.port.counters["bytes_in"] - self._bytes_at_valid
            if garbage > 64 and time.monotonic() - self._last_valid > self.setup.garbage_timeout:
                if self._binary is None and looks_binary(bytes(self._recent)):
                    self._binary_output(time.monotonic())
                    continue
                if len(self._unknown_lines) >= 3:  # well-formed lines: the baud rate is right
                    self.counters["unknown_output"] += 1
                    self.state = "unknown_output"
                    self.problem = (f"the board writes text lines that are not +UUDF, e.g. "
                                    f"{self._unknown_lines[-1]!r}: $MEAS lines come from AT+UDFCFG=7,1 (set 7,0); "
                                    "JSON lines are a debug output (raw IQ samples) of some firmware builds; "
                                    "flash a release build (docs/hardware.md)")
                    log.error("%s: %s", self.port.name, self.problem)
                    self._last_valid = time.monotonic()
                    self._bytes_at_valid = self.port.counters["bytes_in"]
                    continue
                self.counters["baud_mismatch"] += 1
                self.state = "baud_mismatch"
                self.problem = (f"only garbage for {self.setup.garbage_timeout:g} s at {self.port.baud} baud: "
                                f"the board probably runs at another rate (AT+UMRS); {self._other_rates()}")
                log.error("%s: %s", self.port.name, self.problem)
                if self.setup.probe_baud and await self._probe():
                    self._needs_setup.set()
                self._last_valid = time.monotonic()
                self._bytes_at_valid = self.port.counters["bytes_in"]

    def _binary_output(self, t_host: float) -> None:
        """u-locateEmbed binary frames recognised: say so once, decode them from now on."""
        self.counters["binary_output"] += 1
        self.state = "binary_output"
        self.problem = ("the board writes u-locateEmbed binary output (AT+UDFCFG=7,2), not +UUDF "
                        "lines: decoding only its azimuth is vouched for (docs/protocol.md); set "
                        "AT+UDFCFG=7,0 for +UUDF lines (add 7: 0 to the AoA set-up, or send it, "
                        "AT&W, AT+CPWROFF); the text decoder's drops are counted from now on, not shown")
        log.error("%s: %s", self.port.name, self.problem)
        self._binary = BinaryDecoder()
        self._feed_binary(bytes(self._recent), t_host)
        self._last_valid = time.monotonic()
        self._bytes_at_valid = self.port.counters["bytes_in"]

    async def _probe(self) -> bool:
        """Try every documented rate until the board answers AT.

        An ERROR counts: our AT at the wrong rates reached the board as garbage and may prefix
        its line buffer; any final code proves the link works at this rate.
        """
        tried = self.port.baud
        for baud in sorted(c.BAUD_RATES, key=lambda b: b == tried):  # the rate in use was tried already
            log.info("%s: probing: AT at %d baud", self.port.name, baud)
            self.port.set_baud(baud)
            self.matcher.cancel()
            try:
                self._answer = asyncio.get_running_loop().create_future()
                self.port.write(self.matcher.send(c.at()))
                async with asyncio.timeout(0.5):
                    response = await self._answer
            except TimeoutError:
                self.matcher.cancel()
                continue
            if not response.restarted:  # OK or ERROR: either way the board understood us
                log.warning("%s: the board answers at %d baud", self.port.name, baud)
                return True
        self.port.set_baud(tried)
        return False

    def bearing(self, t: float, item: Any) -> Bearing | None:
        return bearing_of(t, item) if item.kind == "angle" else None

    def cannot_go_on(self) -> str | None:
        return self.problem if self.ambiguous_tags else None

    def health(self) -> dict[str, Any]:
        return {**super().health(), "dialect": self.dialect.value if self.dialect else None,
                "board_filter": None if self.board_filter is None else ",".join(self.board_filter),
                "problem": self.problem, "queued": len(self.out), "queue_dropped": self.out.dropped,
                **{f"decoder.{k}": v for k, v in self.decoder.counters.items()}}
