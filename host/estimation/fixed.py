"""Fixed-point formats, kept exactly as MCU firmware would keep them.

| quantity | format | storage | LSB | range |
|---|---|---|---|---|
| RSSI / power sample | Q7.8 | int16 | 1/256 dB | −128 … +127.996 dB |
| filter state (EMA, Kalman mean) | Q7.16 | int32 | 1/65536 dB | ±32768 dB |
| variance (Kalman P, Q, R) | Q16.16 | int32 | 1/65536 dB² | 0 … 32768 dB² |
| gain | Q0.15 | int16 | 1/32768 | 0 … 0.99997 |
| angle | BAM16 | uint16 | 360/65536 ° | one turn, wraps by itself |
| angle state | BAM32 | uint32 | 360/2³² ° | one turn |

Every conversion and arithmetic result saturates to its storage instead of wrapping (angles
excepted: their wrap is the point). Python ints model the C integers; the masks and
:func:`sat` calls are where C would need care.
"""

from __future__ import annotations

import math

INT32 = (-(1 << 31), (1 << 31) - 1)


def sat(value: int, bits: int = 16) -> int:
    """Saturate to a signed ``bits``-bit integer."""
    high = (1 << (bits - 1)) - 1
    return high if value > high else -high - 1 if value < -high - 1 else value


def to_q8(dbm: float) -> int:
    """dBm -> Q7.8, rounded, saturated."""
    return sat(round(dbm * 256), 16)


def from_q8(q: int) -> float:
    return q / 256


def div_round(num: int, den: int) -> int:
    """num / den rounded half away from zero (den > 0), as C firmware writes it."""
    return (num + den // 2) // den if num >= 0 else -((-num + den // 2) // den)


def deg_to_bam16(deg: float) -> int:
    return round(deg / 360 * 65536) & 0xFFFF


def bam16_to_deg(bam: int) -> float:
    """BAM16 -> degrees in [−180, 180)."""
    return wrap16(bam) * 360 / 65536


def wrap16(bam: int) -> int:
    """A 16-bit angle difference as signed (−32768 … 32767): the shortest way round."""
    bam &= 0xFFFF
    return bam - 65536 if bam >= 32768 else bam


def wrap32(value: int) -> int:
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value


def wrap_deg(deg: float) -> float:
    """Degrees -> [−180, 180)."""
    return (deg + 180.0) % 360.0 - 180.0


def wrap_rad(rad: float) -> float:
    return math.remainder(rad, 2 * math.pi)
