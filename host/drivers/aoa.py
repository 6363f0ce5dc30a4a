"""XPLR-AOA driver: set-up, angle events stamped with host time, recovery.

State machine::

    opening --open--> setting_up --AT ok, dialect known, config applied, UDFENABLE=1--> streaming
    streaming --"+STARTUP" (board rebooted)--> setting_up
    any --device gone--> disconnected --re-open with back-off--> setting_up
    any --only garbage for garbage_timeout s--> baud_mismatch (--probe: try each documented rate)

Set-up: ``AT`` (retried while the board boots), identify the dialect from ``AT+GMM``,
``AT+GMR`` and ``ATI9``, read each wanted ``AT+UDFCFG``/``AT+UDFFILT`` and, only if one
differs, write them, ``AT&W`` and ``AT+CPWROFF`` (they take effect at restart), then
``AT+UDFENABLE=1``.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from rfhoming.host.drivers.common import BoundedStream, Driver
from rfhoming.host.ports import HostPort
from rfhoming.protocol.uconnect import AngleEvent, CommandMatcher, Dialect, Response, UConnectDecoder
from rfhoming.protocol.uconnect import commands as c

log = logging.getLogger(__name__)


class CommandFailed(Exception):
    pass


@dataclass(frozen=True)
class AoaSetup:
    """What the user asked of the board, and how patient to be with it."""

    config: dict[int, int | str] = field(default_factory=dict)
    instance_filter: tuple[str, ...] = ()
    host_filter: frozenset[str] = frozenset()
    command_timeout: float = 1.0
    retries: int = 3
    restart_timeout: float = 3.0
    garbage_timeout: float = 3.0
    probe_baud: bool = False


class TimedAngle(NamedTuple):
    """An angle event with the host time its bytes arrived."""

    t_host: float
    event: AngleEvent


def identify_dialect(model: str, version: str, software: str) -> Dialect:
    """AT+GMM / AT+GMR / ATI9 answers -> the +UUDF dialect (docs/protocol.md)."""
    if "locateembed" in software.lower():
        return Dialect.EMBED
    if "NINA-B4-DF" in model:
        return Dialect.V1_0
    digits = version.strip('"').split(".")[0]
    if digits.isdigit() and int(digits) >= 2:
        return Dialect.V2
    return Dialect.V1_2


class AoaDriver(Driver):
    kind = "xplr-aoa"

    def __init__(self, port: HostPort, setup: AoaSetup = AoaSetup(), *, queue_size: int = 1000,
                 reconnect: bool = True) -> None:
        super().__init__(port, reconnect=reconnect)
        self.setup = setup
        self.decoder = UConnectDecoder()
        self.matcher = CommandMatcher()
        self.events = BoundedStream[TimedAngle](queue_size)
        self.dialect: Dialect | None = None
        self.identity: dict[str, str] = {}
        self.counters.update(setups=0, reboots=0, retries=0, filtered=0, baud_mismatch=0)
        self._answer: asyncio.Future[Response] | None = None
        self._startup = asyncio.Event()
        self._last_valid = time.monotonic()
        self._bytes_at_valid = 0
        self._needs_setup = asyncio.Event()
        self.problem: str | None = None

    # -- reading ----------------------------------------------------------------------
    def on_chunk(self, data: bytes, t_host: float) -> None:
        for item in self.decoder.feed(data):
            kind = item.kind
            if kind == "angle" and self.setup.host_filter and item.instance_id not in self.setup.host_filter:
                self.counters["filtered"] += 1  # another tag: counted, neither shown nor used
                self._last_valid = time.monotonic()
                self._bytes_at_valid = self.port.counters["bytes_in"]
                continue
            self.emit(t_host, item)
            if kind in ("drop", "unknown"):
                continue
            self._last_valid = time.monotonic()
            self._bytes_at_valid = self.port.counters["bytes_in"]
            if kind == "angle":
                self.events.put(TimedAngle(t_host, item))
                continue
            if kind == "startup":
                self._startup.set()
                if self.state == "streaming":
                    self.counters["reboots"] += 1
                    log.warning("%s: the board restarted (+STARTUP); setting it up again", self.port.name)
                    self._needs_setup.set()
            response = self.matcher.on_item(item)
            if response is not None and self._answer is not None and not self._answer.done():
                self._answer.set_result(response)

    # -- commands ---------------------------------------------------------------------
    async def command(self, command: c.Command) -> Response:
        """Send one command and wait for its answer, retrying on timeout; CommandFailed on ERROR."""
        for _ in range(self.setup.retries + 1):
            self._answer = asyncio.get_running_loop().create_future()
            self.port.write(self.matcher.send(command))
            try:
                response = await asyncio.wait_for(self._answer, self.setup.command_timeout)
            except asyncio.TimeoutError:
                self.matcher.cancel()
                self.counters["retries"] += 1
                continue
            if not response.ok:
                raise CommandFailed(f"{command.text} answered ERROR")
            return response
        raise CommandFailed(f"{command.text}: no answer after {self.setup.retries + 1} tries "
                            f"({self.setup.command_timeout} s each)")

    # -- set-up -----------------------------------------------------------------------
    async def session(self) -> None:
        """Set the board up after every open and every reboot; watch for garbage meanwhile."""
        watchdog = asyncio.create_task(self._watch_garbage())
        try:
            while True:
                self._needs_setup.clear()
                try:
                    await self._set_up()
                except CommandFailed as exc:
                    self.state = "setup_failed"
                    self.problem = str(exc)
                    log.error("%s: set-up failed: %s", self.port.name, exc)
                    await asyncio.sleep(1.0)
                    continue
                await self._needs_setup.wait()
        finally:
            watchdog.cancel()

    async def _set_up(self) -> None:
        self.state = "setting_up"
        await self.command(c.at())
        model = (await self.command(c.identify_model())).info
        version = (await self.command(c.identify_version())).info
        software = (await self.command(c.identify_software())).info
        self.identity = {"model": " ".join(model), "version": " ".join(version), "software": " ".join(software)}
        self.dialect = identify_dialect(self.identity["model"], self.identity["version"], self.identity["software"])
        if await self._apply_config():
            await self.command(c.store())
            self._startup.clear()
            await self.command(c.restart())
            try:
                await asyncio.wait_for(self._startup.wait(), self.setup.restart_timeout)
            except asyncio.TimeoutError:
                raise CommandFailed("no +STARTUP after AT+CPWROFF") from None
            await self.command(c.at())
        await self.command(c.enable_angles(True))
        self.counters["setups"] += 1
        self.problem = None
        self.state = "streaming"
        log.info("%s: streaming (%s, %s)", self.port.name, self.identity["model"], self.dialect.value)

    async def _apply_config(self) -> bool:
        """Write the settings that differ; True when something changed (restart needed)."""
        changed = False
        for tag, value in sorted(self.setup.config.items()):
            wanted = c.set_config(tag, value)
            current = (await self.command(c.read_config(tag))).info
            if current != [wanted.text.replace("AT+UDFCFG=", "+UDFCFG:")]:
                await self.command(wanted)
                changed = True
        if self.setup.instance_filter:
            wanted_ids = [i.upper() for i in self.setup.instance_filter]
            current = (await self.command(c.read_filter(c.FILTER_INSTANCE))).info
            if current != ["+UDFFILT:2" + "".join(f',"{i}"' for i in wanted_ids)]:
                await self.command(c.set_filter(c.FILTER_INSTANCE, c.FILTER_CLEAR))
                await self.command(c.set_filter(c.FILTER_INSTANCE, c.FILTER_APPEND, tuple(wanted_ids)))
                changed = True
        return changed

    # -- garbage / baud ---------------------------------------------------------------
    async def _watch_garbage(self) -> None:
        while True:
            await asyncio.sleep(0.25)
            garbage = self.port.counters["bytes_in"] - self._bytes_at_valid
            if garbage > 64 and time.monotonic() - self._last_valid > self.setup.garbage_timeout:
                self.counters["baud_mismatch"] += 1
                self.state = "baud_mismatch"
                self.problem = (f"only garbage for {self.setup.garbage_timeout:g} s at {self.port.baud} baud: "
                                "the board probably runs at another rate (AT+UMRS); use --probe-baud or "
                                "--baud with the board's rate")
                log.error("%s: %s", self.port.name, self.problem)
                if self.setup.probe_baud and await self._probe():
                    self._needs_setup.set()
                self._last_valid = time.monotonic()
                self._bytes_at_valid = self.port.counters["bytes_in"]

    async def _probe(self) -> bool:
        """Try every documented rate until the board answers AT.

        An ERROR counts: our AT at the wrong rates reached the board as garbage and may prefix
        its line buffer; any final code proves the link works at this rate.
        """
        for baud in c.BAUD_RATES:
            self.port.set_baud(baud)
            self.matcher.cancel()
            try:
                self._answer = asyncio.get_running_loop().create_future()
                self.port.write(self.matcher.send(c.at()))
                response = await asyncio.wait_for(self._answer, 0.5)
            except asyncio.TimeoutError:
                self.matcher.cancel()
                continue
            if not response.restarted:  # OK or ERROR: either way the board understood us
                log.warning("%s: the board answers at %d baud", self.port.name, baud)
                return True
        return False

    def health(self) -> dict[str, Any]:
        return {**super().health(), "dialect": self.dialect.value if self.dialect else None,
                "problem": self.problem, "queued": len(self.events), "queue_dropped": self.events.dropped,
                **{f"decoder.{k}": v for k, v in self.decoder.counters.items()}}
