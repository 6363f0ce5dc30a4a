"""Driver for an ESP32 running Espressif's ESP-AT firmware, as a BLE RSSI receiver.

After every open and every reboot (``ready``) it sets the board up -- ``AT``, ``AT+BLEINIT?``,
``AT+BLEINIT=1`` if needed (a client or dual role is kept), ``AT+BLESCAN=0`` (a board still
scanning from an earlier run), ``AT+BLESCANPARAM=...``, ``AT+BLESCAN=1,...`` -- and turns every
``+BLESCAN:`` report into the same :class:`~rfhoming.host.drivers.rss.BleRssi` reading the
rfhoming ESP32 scanner gives, so the S3 trilateration, S1 and S4 consumers take either. ESP-AT
reports carry no timestamp: the reading's time is the host's arrival time of its line.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass
from typing import Any

from rfhoming.host.drivers.common import BoundedStream, CommandFailed, Driver, scan_settings, serial_port
from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.ports import Port, Tap
from rfhoming.host.portspec import PortSpec
from rfhoming.protocol.drop import Drop
from rfhoming.protocol.espat import EspAtDecoder, Event, Final, Info, ScanReport

log = logging.getLogger(__name__)
UNIT_MS = 0.625
NO_BLE_HINT = ("this ESP-AT build has no Bluetooth LE commands (the default ESP32-C2 firmware has none: "
               "build the ESP32C2-2MB-BLE variant, ESP-AT docs 'Bluetooth LE AT Commands')")
BUSY_RETRY_S = 0.1
RESTART_TIMEOUT_S = 5.0



@dataclass(frozen=True)
class EspAtSetup:
    """How to scan; times in milliseconds/seconds, converted to the firmware's units here."""

    active: bool = False
    interval_ms: float = 100.0
    window_ms: float = 100.0  # = interval: listen all the time
    duration_s: int = 0  # 0 = until stopped
    filter_mac: str | None = None  # "24:0A:C4:96:E6:88": only this advertiser
    filter_name: str | None = None  # only advertisers with this local name
    node_id: int = 0  # the readings' node_id (ESP-AT has none of its own)
    command_timeout: float = 2.0
    retries: int = 2
    silence_timeout: float = 10.0
    """Scanning without one report this long: say why that may be."""

    def __post_init__(self) -> None:
        if not 2.5 <= self.window_ms <= self.interval_ms <= 10_240:
            raise ValueError("need 2.5 ms <= window_ms <= interval_ms <= 10240 ms (ESP-AT's range)")
        if self.filter_mac and self.filter_name:
            raise ValueError("ESP-AT filters by MAC or by name, not both")

    def commands(self) -> list[str]:
        interval, window = round(self.interval_ms / UNIT_MS), round(self.window_ms / UNIT_MS)
        scan = f"AT+BLESCAN=1,{self.duration_s}"
        if self.filter_mac:
            scan += f',1,"{self.filter_mac.lower()}"'
        elif self.filter_name:
            scan += f',2,"{self.filter_name}"'
        return [f"AT+BLESCANPARAM={int(self.active)},0,0,{interval},{window}", scan]


def setup_from_spec(spec: PortSpec, setup: EspAtSetup) -> EspAtSetup:
    """The spec's scan settings (active, interval, window, mac, adname) over ``setup``."""
    s = spec.settings
    scanning: EspAtSetup = scan_settings(spec, setup, filter_mac=s.get("mac", setup.filter_mac),
                                         filter_name=s.get("adname", setup.filter_name))
    return scanning


class EspAtDriver(Driver):
    kind = "esp-at"
    sets_up = True
    items = (ScanReport, Info, Final, Event, Drop)

    @classmethod
    def from_spec(cls, spec: PortSpec, taps: list[Tap], *, port: Any = None, **options: Any) -> EspAtDriver:
        return cls(port or serial_port(spec, taps), setup_from_spec(spec, options.pop("setup", EspAtSetup())), **options)

    def __init__(self, port: Port, setup: EspAtSetup = EspAtSetup(), *, queue_size: int = 4000,
                 reconnect: bool = True, out: BoundedStream[Any] | None = None) -> None:
        super().__init__(port, reconnect=reconnect, out=out, queue_size=queue_size)
        self.setup = setup
        self.decoder = EspAtDecoder()
        self.counters.update(setups=0, reboots=0, retries=0, scans_done=0, silent=0)
        self._answer: asyncio.Future[list[Any]] | None = None
        self._lines: list[Any] = []
        self.counters.update(busy=0)
        self._booted = asyncio.Event()

    def on_chunk(self, data: bytes, t_host: float) -> None:
        for item in self.decoder.feed(data):
            self.emit(t_host, item)
            if item.kind == "scan_report":
                self.last_item = time.monotonic()
                self.out.put(BleRssi(t_host, self.setup.node_id, item.address, item.rssi_dbm))
            elif item.kind == "info":
                self._lines.append(item)
            elif isinstance(item, Final):
                if self._answer is not None and not self._answer.done():
                    self._answer.set_result([*self._lines, item])
                self._lines = []
            elif item.kind == "event" and item.what == "ready" and self.state != "streaming":
                self._booted.set()
            elif item.kind == "event" and item.what == "ready":
                self.counters["reboots"] += 1
                log.warning("%s: the board restarted (ready); setting it up again", self.port.name)
                self._needs_setup.set()
            elif item.kind == "event" and item.what == "blescandone":
                self.counters["scans_done"] += 1
            elif item.kind == "event" and item.what == "busy p...":
                self.counters["busy"] += 1  # still running an earlier command: ours was not taken
                if self._answer is not None and not self._answer.done():
                    self._answer.set_result([])

    async def command(self, text: str) -> list[Any]:
        """Send one command; its information lines and final answer (CommandFailed on ERROR)."""
        for _ in range(self.setup.retries + 1):
            self._answer, self._lines = asyncio.get_running_loop().create_future(), []
            self.port.write(text.encode() + b"\r\n")
            try:
                async with asyncio.timeout(self.setup.command_timeout):
                    answer = await self._answer
            except TimeoutError:
                self.counters["retries"] += 1
                continue
            if not answer:  # busy p...: try again once the board is done
                await asyncio.sleep(BUSY_RETRY_S)
                continue
            if not answer[-1].ok:
                raise CommandFailed(f"{text} answered ERROR")
            return answer
        raise CommandFailed(f"{text}: no answer after {self.setup.retries + 1} tries "
                            f"({self.setup.command_timeout:g} s each); {self.silent_hint()}")

    def silent_hint(self) -> str:
        return ("is it an ESP32 with ESP-AT at this baud rate, and is this its AT UART? ESP-AT takes commands on a "
                "separate UART, not on the USB port used for flashing (docs/hardware.md, ESP32 with ESP-AT)")

    async def session(self) -> None:
        """Set the board up after every open and every reboot; say so when nothing arrives."""
        quiet = asyncio.create_task(self.watch_quiet(self.setup.silence_timeout, "+BLESCAN report", self._quiet_hint))
        try:
            await self.keep_set_up()
        finally:
            quiet.cancel()

    def _quiet_hint(self) -> str:
        s = self.setup
        hint = "no Bluetooth LE advertiser in range"
        if s.filter_mac or s.filter_name:
            hint += f", or none matches the scan's filter ({'mac=' + s.filter_mac if s.filter_mac else 'adname=' + str(s.filter_name)})"
        if self.counters["scans_done"]:
            hint += "; the board's scan ended (+BLESCANDONE): a scan with a duration stops"
        return hint

    async def _set_up(self) -> None:
        self.state = "setting_up"
        await self.command("AT")
        try:
            answer = await self.command("AT+BLEINIT?")
        except CommandFailed:
            raise CommandFailed(f"AT+BLEINIT? answered ERROR: {NO_BLE_HINT}") from None
        role = next((i.value for i in answer if i.name == "BLEINIT"), "0")
        if role not in ("0", "1", "3"):  # a server cannot become a client without a restart (3.2; master
            await self._restart()       # also allows AT+BLEINIT=0 first)
            role = "0"
        if role == "0":
            await self.command("AT+BLEINIT=1")
        else:
            try:  # it may still scan from an earlier run; not scanning may answer ERROR
                await self.command("AT+BLESCAN=0")
            except CommandFailed:
                pass
        for text in self.setup.commands():
            await self.command(text)
        self.counters["setups"] += 1
        self.problem = None
        self.state, self.streaming_at = "streaming", time.monotonic()

    async def _restart(self) -> None:
        """``AT+RST``, then wait for ``ready``: every version documents it as the way to a new role."""
        self._booted.clear()
        await self.command("AT+RST")
        try:
            async with asyncio.timeout(RESTART_TIMEOUT_S):
                await self._booted.wait()
        except TimeoutError:
            raise CommandFailed(f"no ready within {RESTART_TIMEOUT_S:g} s of AT+RST") from None

    def health(self) -> dict[str, Any]:
        return {**super().health(), "queued": len(self.out), "queue_dropped": self.out.dropped,
                "problem": self.problem, **{f"decoder.{k}": v for k, v in self.decoder.counters.items()}}
