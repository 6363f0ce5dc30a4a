"""ESP32 running Espressif's ESP-AT firmware, as a BLE scanner driven by AT commands.

Sans-IO, like the other models: :meth:`receive` takes the host's bytes, :meth:`read` gives the
board's, :meth:`tick` moves its clock, :meth:`on_advertisement` is a packet at the antenna.
What it does follows the ESP-AT documentation of the firmware version it models
(``version``: ``2.4``, ``3.2`` -- the default --, ``5.0`` or ``master``; docs/protocol.md section 5
says which behaviour comes from which): echo on after boot, ``ready`` after a (re)boot,
``AT+BLEINIT`` roles that cannot change without ``AT+RST`` (dual role 3 from 5.0),
``AT+BLESCANPARAM`` ranges (4..0x4000 units of 0.625 ms, window <= interval), ``AT+BLESCAN``
with a duration (then ``+BLESCANDONE``, from 3.2) and a MAC or NAME filter (prefixes, UUID, RSSI
and the duplicate check on master), ``busy p...`` for a command sent before the previous one
was answered, ``ERROR`` for anything else. Scanning has the radio's limits: only inside the scan window, only on the channel of
this interval (37, 38, 39 in turn), not when two packets collide, not below sensitivity.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from rfhoming.firmware.ble_scan_radio import ScanRadio, listening_channel
from rfhoming.protocol.ad import local_name, structures
from rfhoming.protocol.espat import ScanReport, encode_scan

TX_BUFFER = 16384
MAX_COMMAND = 256
SENSITIVITY_DBM = -97.0
UNIT_US = 625


VERSIONS = ("2.4", "3.2", "5.0", "master")
DEFAULT_SCAN = {"master": (0x140, 0x30)}
"""Scan interval/window after boot: the ESP32 defaults master documents; older docs give none,
so the model starts there with the docs' example 100/50 (assumed)."""


def service_uuids(ad: bytes) -> set[str]:
    """The advertised service UUIDs (AD types 0x02-0x07: 16-, 32-, 128-bit lists) as hex, MSB first."""
    found = set()
    for kind, data in structures(ad):
        width = {0x02: 2, 0x03: 2, 0x04: 4, 0x05: 4, 0x06: 16, 0x07: 16}.get(kind)
        if width:
            found |= {data[i:i + width][::-1].hex() for i in range(0, len(data) - width + 1, width)}
    return found


class EspAtFirmware:
    """The AT command interpreter and the BLE scanner behind it."""

    def __init__(self, version: str = "3.2") -> None:
        if version not in VERSIONS:
            raise ValueError(f"ESP-AT version {version!r}: the model knows {', '.join(VERSIONS)}")
        self.version = version
        self.VERSION = f"AT version:{version} (model)"
        self.counters = {"tx_dropped": 0, "reported": 0, "duty_cycle": 0, "wrong_channel": 0,
                         "collision": 0, "below_sensitivity": 0, "filtered": 0, "errors": 0}
        self._out = bytearray()
        self._rx = b""
        self._now_us = 0
        self.echo = True
        self.role = 0
        self._deinitialised, self._last_role = False, 0  # AT+BLEINIT=0 since boot, from which role
        self.scan_type = 0
        self.interval, self.window = DEFAULT_SCAN.get(version, (100, 50))
        self.scanning = False
        self._scan_until: int | None = None
        self._filter: tuple[int, str] | None = None
        self._dedup: set[str] | None = None
        self.radio = ScanRadio()
        self._write(b"\r\nready\r\n")

    # -- bytes ------------------------------------------------------------------------------
    def read(self) -> bytes:
        data = bytes(self._out)
        self._out.clear()
        return data

    def _write(self, data: bytes) -> None:
        if len(self._out) + len(data) > TX_BUFFER:
            self.counters["tx_dropped"] += 1
            return
        self._out += data

    def receive(self, data: bytes) -> None:
        """Host bytes: each CR LF ends a command; an overlong line is answered with ERROR."""
        self._rx += data
        busy = False
        while b"\r\n" in self._rx:
            line, self._rx = self._rx.split(b"\r\n", 1)
            if busy and line.strip():  # sent before the previous command was answered
                self._write(b"busy p...\r\n")
                continue
            self._command(line)
            busy = bool(line.strip())
        if len(self._rx) > MAX_COMMAND:
            self._rx = b""
            self._error()

    def tick(self, now_us: int) -> None:
        self._now_us = now_us
        if self.scanning and self._scan_until is not None and now_us >= self._scan_until:
            self.scanning, self._scan_until = False, None
            if self.version != "2.4":  # v2.4 documents no +BLESCANDONE
                self._write(b"+BLESCANDONE\r\n")

    # -- commands ---------------------------------------------------------------------------
    def _ok(self) -> None:
        self._write(b"\r\nOK\r\n")

    def _error(self) -> None:
        self.counters["errors"] += 1
        self._write(b"\r\nERROR\r\n")

    def _command(self, raw: bytes) -> None:
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            self._error()
            return
        if not line:
            return
        if self.echo:
            self._write(line.encode() + b"\r\n")
        name, eq, args = line.partition("=")
        handler: Callable[[], None] | None = {
            "AT": lambda: self._ok(),
            "ATE0": lambda: self._set_echo(False),
            "ATE1": lambda: self._set_echo(True),
            "AT+RST": self._reset,
            "AT+GMR": self._version,
            "AT+BLEINIT?": lambda: self._query("BLEINIT", str(self.role)),
            "AT+BLESCANPARAM?": lambda: self._query(
                "BLESCANPARAM", f"{self.scan_type},0,0,{self.interval},{self.window}"),
        }.get(line) if not eq else {
            "AT+BLEINIT": lambda: self._init(args),
            "AT+BLESCANPARAM": lambda: self._scan_param(args),
            "AT+BLESCAN": lambda: self._scan(args),
        }.get(name)
        if handler is None:
            self._error()
        else:
            handler()

    def _set_echo(self, on: bool) -> None:
        self.echo = on
        self._ok()

    def _version(self) -> None:
        self._write(f"{self.VERSION}\r\n".encode())
        self._ok()

    def _query(self, name: str, value: str) -> None:
        self._write(f"+{name}:{value}\r\n".encode())
        self._ok()

    def _reset(self) -> None:
        self._ok()
        answered = bytes(self._out)
        type(self).__init__(self, self.version)  # a reboot: every setting back to its default, then "ready"
        self._out[:0] = answered

    @property
    def _client(self) -> bool:
        return self.role in (1, 3)

    def _init(self, args: str) -> None:
        roles = ("0", "1", "2", "3") if self.version in ("5.0", "master") else ("0", "1", "2")
        if args not in roles or (self.role and args != "0" and int(args) != self.role):
            self._error()  # the role cannot change without AT+RST (or, on master, AT+BLEINIT=0 first)
            return
        if args != "0" and self.version != "master" and self._deinitialised and int(args) != self._last_role:
            self._error()  # before master the docs name only AT+RST for a new role
            return
        if args == "0" and self.role:
            self._deinitialised, self._last_role = True, self.role
        self.role = int(args)
        if self.role == 0:
            self.scanning = False
        self._ok()

    def _scan_param(self, args: str) -> None:
        m = re.fullmatch(r"([01]),([0-3]),([0-3]),(\d{1,5}),(\d{1,5})", args)
        if not self._client or m is None:
            self._error()
            return
        interval, window = int(m.group(4)), int(m.group(5))
        if not (4 <= window <= interval <= 0x4000):
            self._error()
            return
        self.scan_type, self.interval, self.window = int(m.group(1)), interval, window
        self._ok()

    def _scan(self, args: str) -> None:
        kinds = "1234" if self.version == "master" else "12"
        m = re.fullmatch(r'([01])(?:,(\d{1,5}))?(?:,([' + kinds + r']),("[^",]{1,32}"|-?\d{1,3})(,1)?)?', args)
        if not self._client or m is None or (m.group(1) == "0" and m.group(2) is not None):
            self._error()
            return
        if m.group(1) == "0":
            self.scanning, self._scan_until = False, None
            self._ok()
            return
        kind, value, dedup = m.group(3), m.group(4), m.group(5)
        if kind is not None and (kind == "4") == value.startswith('"') or (dedup and self.version != "master"):
            self._error()  # RSSI takes an integer, the others a quoted string; dedup on master only
            return
        duration = int(m.group(2) or 0)
        self._filter = (int(kind), value.strip('"').lower()) if kind else None
        self._dedup = set() if dedup else None
        self.scanning = True
        self._scan_until = self._now_us + duration * 1_000_000 if duration else None
        self._ok()

    # -- radio ------------------------------------------------------------------------------
    def listening_channel(self, t_us: int) -> int | None:
        return listening_channel(t_us, self.scanning, self.interval * UNIT_US, self.window * UNIT_US)

    def on_advertisement(self, t_us: int, channel: int, address: str, rssi_dbm: float, ad: bytes,
                         addr_type: int = 0) -> None:
        """One packet on the air at ``t_us``; ``address`` MSB first as 12 hex digits."""
        reason = self.radio.loss(t_us, channel, len(ad), rssi_dbm, self.listening_channel(t_us), SENSITIVITY_DBM)
        if reason is None and not self._passes(address, ad, rssi_dbm):
            reason = "filtered"
        if reason is None and self._dedup is not None:
            if address in self._dedup:
                reason = "filtered"
            self._dedup.add(address)
        if reason is not None:
            self.counters[reason] += 1
            return
        rssi = max(-127, min(20, round(rssi_dbm)))
        self._write(encode_scan(ScanReport(address.upper(), rssi, ad, b"", addr_type)))
        self.counters["reported"] += 1

    def _passes(self, address: str, ad: bytes, rssi_dbm: float) -> bool:
        """MAC and NAME match whole values; master also prefixes ("24:0A:C4"), UUID and RSSI."""
        if self._filter is None:
            return True
        kind, value = self._filter
        prefix = self.version == "master"
        if kind == 1:
            mac = value.replace(":", "")
            return address.lower().startswith(mac) if prefix else address.lower() == mac
        if kind == 2:
            name = (local_name(ad) or "").lower()
            return name.startswith(value) if prefix else name == value
        if kind == 3:
            return value in service_uuids(ad)
        return rssi_dbm >= int(value)
