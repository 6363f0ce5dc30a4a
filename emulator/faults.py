"""Faults on device links, at given times or rates, seeded.

Spec syntax (``rfhoming emulate --fault``): ``KIND[@DEVICE][:key=value,...]``; without
``@DEVICE`` the fault hits every device.

| kind | keys | effect |
|---|---|---|
| ber | rate | flips each bit the device sends or receives with probability ``rate`` |
| drop | rate | drops each byte with probability ``rate`` |
| garbage | every, len | a burst of ``len`` random bytes every ``every`` seconds |
| unplug | at or after_bytes, for | the endpoint disappears at ``at`` s for ``for`` s (a pty comes back at its path) |
| reboot | at or after_bytes | the device restarts at ``at`` s (the AoA board prints +STARTUP again) |
| baud | at or after_bytes, rate | the device's UART moves to ``rate`` at ``at`` s (the host sees garbage) |

``after_bytes=N`` instead of ``at=S`` fires on what the host did, not on the clock: once the host
has written to the device and the device has then sent N bytes without another write from the
host (set up, then streaming). A device's ``after_bytes`` faults fire in the order given, each
waiting for a write from the host after the one before (after an unplug: its reconnection).
A device the host keeps writing to (a base under a loop's commands) never reaches N.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rfhoming.protocol.errors import Error

KINDS = {"ber": {"rate"}, "drop": {"rate"}, "garbage": {"every", "len"}, "unplug": {"at", "after_bytes", "for"},
         "reboot": {"at", "after_bytes"}, "baud": {"at", "after_bytes", "rate"}}
WHEN = {"at", "after_bytes"}
"""A one-off fault's trigger: a simulated time, or a count of bytes sent after the host's last write."""

MAX_TIME_S = 1e7
"""A fault time beyond this (about four months) is a typo, and would overflow when added to."""

RANGES: dict[tuple[str, str], tuple[float, float, bool, str]] = {
    # (kind, key) -> (low, high, whole number, what it is); ``every`` at least 1 ms: bursts any
    # closer would be all the emulator does (every=0 never ended)
    ("ber", "rate"): (0.0, 1.0, False, "a probability per bit"),
    ("drop", "rate"): (0.0, 1.0, False, "a probability per byte"),
    ("garbage", "every"): (1e-3, MAX_TIME_S, False, "seconds between bursts"),
    ("garbage", "len"): (1, 65536, True, "bytes per burst"),
    ("baud", "rate"): (50, 12_000_000, True, "a baud rate"),
    ("unplug", "for"): (1e-3, MAX_TIME_S, False, "seconds unplugged; without for= it stays out"),
    **{(kind, "after_bytes"): (1, 1e12, True, "bytes sent after the host's last write")
       for kind in ("unplug", "reboot", "baud")},
}
"""Each key's range; ``at`` (seconds of simulated time) is 0 to MAX_TIME_S."""


class FaultError(Error, ValueError):
    pass


@dataclass(frozen=True)
class Fault:
    kind: str
    device: str | None
    params: dict[str, float] = field(default_factory=dict)

    @classmethod
    def parse(cls, spec: str) -> Fault:
        head, _, tail = spec.partition(":")
        kind, _, device = head.partition("@")
        if kind not in KINDS:
            raise FaultError(f"unknown fault {kind!r} in {spec!r}; kinds: {', '.join(KINDS)}")
        params: dict[str, float] = {}
        for item in filter(None, tail.split(",")):
            key, eq, value = item.partition("=")
            if not eq or key not in KINDS[kind]:
                raise FaultError(f"fault {kind} takes {sorted(KINDS[kind])}, got {item!r} in {spec!r}")
            params[key] = _value(kind, key, value, spec)
        if KINDS[kind] >= WHEN and len(WHEN & set(params)) != 1:
            raise FaultError(f"fault {kind} needs one of at=S or after_bytes=N in {spec!r}")
        missing = KINDS[kind] - set(params) - WHEN - {"for"}
        if missing:
            raise FaultError(f"fault {kind} needs {sorted(missing)} in {spec!r}")
        return cls(kind, device or None, params)

    def hits(self, device: str) -> bool:
        return self.device is None or self.device == device


def _value(kind: str, key: str, text: str, spec: str) -> float:
    """``text`` as a number within the key's range; FaultError saying the range otherwise."""
    low, high, whole, what = RANGES.get((kind, key), (0.0, MAX_TIME_S, False, "seconds of simulated time"))
    number = "a whole number" if whole else "a number"
    try:
        value = float(text)
    except ValueError:
        raise FaultError(f"{key}={text!r} in {spec!r} is not a number: expected {number} from {low:g} to {high:g} "
                         f"({what})") from None
    if not low <= value <= high or (whole and not value.is_integer()):  # NaN fails the range too
        raise FaultError(f"{key}={text!r} in {spec!r}: expected {number} from {low:g} to {high:g} ({what})")
    return value


class ByteFaults:
    """The rate faults of one link, applied to every chunk in both directions."""

    def __init__(self, faults: list[Fault], rng: np.random.Generator) -> None:
        self.rng = rng
        self.ber = sum(f.params["rate"] for f in faults if f.kind == "ber")
        self.drop = sum(f.params["rate"] for f in faults if f.kind == "drop")
        self.garbage = [f for f in faults if f.kind == "garbage"]
        self._next_garbage = [f.params["every"] for f in self.garbage]
        self.counters = {"flipped_bits": 0, "dropped_bytes": 0, "garbage_bytes": 0}

    def apply(self, data: bytes) -> bytes:
        if not data or (self.ber == 0 and self.drop == 0):
            return data
        buf = np.frombuffer(data, dtype=np.uint8).copy()
        if self.ber:
            flips = self.rng.random((len(buf), 8)) < self.ber
            if flips.any():
                self.counters["flipped_bits"] += int(flips.sum())
                buf ^= np.packbits(flips, axis=1, bitorder="little")[:, 0]
        if self.drop:
            keep = self.rng.random(len(buf)) >= self.drop
            self.counters["dropped_bytes"] += int((~keep).sum())
            buf = buf[keep]
        return buf.tobytes()

    def bursts(self, t: float) -> bytes:
        """Garbage due at simulated time ``t`` seconds."""
        out = b""
        for i, f in enumerate(self.garbage):
            while t >= self._next_garbage[i]:
                self._next_garbage[i] += f.params["every"]
                n = int(f.params["len"])
                out += self.rng.integers(0, 256, n, dtype=np.uint8).tobytes()
                self.counters["garbage_bytes"] += n
        return out


def scramble(data: bytes, rng: np.random.Generator) -> bytes:
    """What a UART at the wrong baud makes of ``data``: framing errors, random bytes."""
    if not data:
        return data
    n = max(1, len(data) // 2)
    return rng.integers(0, 256, n, dtype=np.uint8).tobytes()
