"""Find candidate serial ports and say what each probably is, from its USB ids.

The XPLR-AOA sits behind an FTDI bridge (vendor 0x0403; its product id is not published);
ESP32 boards use a CP210x (0x10C4), a CH340/CH9102 (0x1A86) or Espressif's native USB
(0x303A); STM32 nodes enumerate as ST's virtual COM port (0x0483:0x5740).
"""

from __future__ import annotations

from dataclasses import dataclass

from serial.tools import list_ports

from rfhoming.host.ports import PortError

KNOWN_VENDORS: dict[int, tuple[str, str]] = {
    0x0403: ("xplr-aoa", "FTDI USB-UART (the XPLR-AOA's bridge)"),
    0x10C4: ("esp32", "Silicon Labs CP210x (common on ESP32 boards)"),
    0x1A86: ("esp32", "WCH CH340/CH9102 (common on ESP32 boards)"),
    0x303A: ("esp32", "Espressif native USB (ESP32-S3/C3)"),
    0x0483: ("stm32", "STMicroelectronics virtual COM port (STM32 + AT86RF212 node)"),
}


@dataclass(frozen=True)
class Candidate:
    device: str
    kind: str | None
    reason: str
    description: str


def candidates() -> list[Candidate]:
    """Every serial port with USB ids, recognised or not (recognised first)."""
    out = []
    for info in list_ports.comports():
        known = KNOWN_VENDORS.get(info.vid) if info.vid is not None else None
        if known is None and (info.manufacturer or "").upper().startswith("FTDI"):
            known = KNOWN_VENDORS[0x0403]
        ids = f"{info.vid:04X}:{info.pid:04X}" if info.vid is not None else "no USB ids"
        kind, reason = known if known else (None, f"unrecognised ({ids})")
        out.append(Candidate(info.device, kind, f"{reason} [{ids}]" if known else reason,
                             info.description or ""))
    return sorted(out, key=lambda c: (c.kind is None, c.device))


def resolve_auto(kind: str) -> str:
    """The one port recognised as ``kind``; PortError that lists the choices otherwise."""
    found = [c for c in candidates() if c.kind == kind]
    if len(found) == 1:
        return found[0].device
    listing = "; ".join(f"{c.device} ({c.reason})" for c in candidates()) or "no serial ports at all"
    if not found:
        raise PortError(f"auto: no {kind} device recognised. Ports seen: {listing}. Name the port explicitly.")
    raise PortError(f"auto: several {kind} devices ({', '.join(c.device for c in found)}); name the one to use")
