"""Find candidate serial ports and say what each probably is, from its USB ids -- and, for an
FTDI bridge, from what it answers.

The XPLR-AOA sits behind an FTDI bridge (vendor 0x0403; its product id is not published), but
so does many another device (a USB-UART cable wired to an ESP32's AT UART, for one): an FTDI
port is an XPLR-AOA only when it answers ``AT+GMM`` (or streams ``+UUDF``) as u-connectLocate
does. ESP32 boards use a CP210x (0x10C4), a CH340/CH9102 (0x1A86) or Espressif's native USB
(0x303A); STM32 nodes enumerate as ST's virtual COM port (0x0483:0x5740). The ids are the device
table's: each kind's ``usb`` bridge (rfhoming.protocol.devices).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import serial
from serial.tools import list_ports

from rfhoming.host.ports import PortError
from rfhoming.protocol import devices
from rfhoming.protocol.devices import FTDI, USB_XPLR_AOA
from rfhoming.protocol.uconnect import UConnectDecoder

ASK_TIMEOUT_S = 1.5


def known_vendors() -> dict[int, tuple[str, str]]:
    """USB vendor id -> (the bridge's name, what the chip is), from the device table's ``usb``."""
    return {vid: (k.usb.name, what) for k in devices.KINDS.values() if k.usb for vid, what in k.usb.vendors}


@dataclass(frozen=True)
class Candidate:
    device: str
    kind: str | None
    reason: str
    description: str


def answers_as_xplr_aoa(device: str, timeout: float = ASK_TIMEOUT_S) -> bool | str:
    """Whether ``device`` speaks u-connectLocate: a ``+UUDF``/``+STARTUP`` line, or an answer to
    ``AT+GMM`` (information line, then ``OK``; an echo alone is not one -- ESP-AT echoes too,
    and takes no command without LF). The reason, when the port cannot be asked."""
    try:
        with serial.Serial(device, 115200, rtscts=True, timeout=0.1, write_timeout=0.5, exclusive=True) as port:
            decoder, got_info = UConnectDecoder(), False
            port.write(b"AT+GMM\r")
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                for item in decoder.feed(port.read(256)):
                    if item.kind in ("angle", "startup") or (item.kind == "final" and got_info and item.ok):
                        return True
                    got_info = got_info or item.kind == "info"
    except (serial.SerialException, OSError) as exc:
        return f"not asked: {exc}"
    return False


def candidates(ask: Callable[[str], bool | str] = answers_as_xplr_aoa) -> list[Candidate]:
    """Every serial port with USB ids, recognised or not (recognised first); an FTDI port is
    asked (``ask``) whether it is an XPLR-AOA."""
    out = []
    vendors = known_vendors()
    for info in list_ports.comports():
        ftdi = info.vid == FTDI or (info.vid not in vendors and (info.manufacturer or "").upper().startswith("FTDI"))
        known: tuple[str | None, str] | None = vendors.get(info.vid) if info.vid is not None else None
        ids = f"{info.vid:04X}:{info.pid:04X}" if info.vid is not None else "no USB ids"
        if ftdi:
            known = _ftdi(ask(info.device))
        kind, reason = known if known else (None, f"unrecognised ({ids})")
        out.append(Candidate(info.device, kind, f"{reason} [{ids}]" if known else reason,
                             info.description or ""))
    return sorted(out, key=lambda c: (c.kind is None, c.device))


def _ftdi(answer: bool | str) -> tuple[str | None, str]:
    if answer is True:
        return USB_XPLR_AOA.name, "FTDI USB-UART answering as u-connectLocate (an XPLR-AOA)"
    if answer is False:
        return None, ("FTDI USB-UART that does not answer as an XPLR-AOA (AT+GMM at 115200 Bd): another device, "
                      "e.g. an ESP32's AT UART -- name its kind, e.g. esp-at:PORT")
    return USB_XPLR_AOA.name, f"FTDI USB-UART (the XPLR-AOA's bridge, {answer})"


def resolve_auto(kind: str) -> str:
    """The one port recognised as ``kind``; PortError that lists the choices otherwise."""
    seen = candidates()
    found = [c for c in seen if c.kind == kind]
    if len(found) == 1:
        return found[0].device
    listing = "; ".join(f"{c.device} ({c.reason})" for c in seen) or "no serial ports at all"
    if not found:
        raise PortError(f"auto: no {kind} device recognised. Ports seen: {listing}. Name the port explicitly.")
    raise PortError(f"auto: several {kind} devices ({', '.join(c.device for c in found)}); name the one to use")
