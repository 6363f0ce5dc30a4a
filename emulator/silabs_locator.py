"""An emulated Silicon Labs AoA locator: the MQTT messages its host application would publish.

Sans-IO, as the protocol beside it: :meth:`SilabsLocator.messages` turns where a tag truly is
into the (topic, payload) pairs of ``bt_aoa_host_locator`` (protocol/silabs_aoa.py), the angles
read in the board's frame as docs/protocol.md ("Silicon Labs AoA locator (MQTT)") describes it
-- azimuth counter-clockwise from the board's x axis over the whole circle, written 0..360,
elevation out of its plane -- plus an error: white Gaussian noise and a bias per tag, a stand-in
(*assumed*: no Silicon Labs board has been measured here, so no radio profile of one exists).
Whoever owns a broker connection (the test, a runner) publishes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rfhoming.emulator.anchors import rotation
from rfhoming.protocol import silabs_aoa


@dataclass
class SilabsLocator:
    """One locator board: its id (``ble-pd-`` and its address), where it is and how it is turned
    (the rotation the site file's yaw/pitch/roll give; its x axis is the anchor's boresight)."""

    locator_id: str
    position: tuple[float, float, float]
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    sigma_deg: float = 2.0
    """White noise on each angle (degrees)."""
    bias_sigma_deg: float = 1.0
    """Spread of the constant error each tag gets on each angle (degrees)."""
    prefix: str = silabs_aoa.PREFIX
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(1))
    _bias: dict[str, tuple[float, float]] = field(default_factory=dict)
    _sequence: int = 0

    def true_angles(self, tag_xyz: tuple[float, float, float]) -> tuple[float, float]:
        """(azimuth, elevation) degrees of a tag in the board's frame, azimuth in (-180, 180]."""
        d = rotation(self.yaw_deg, self.pitch_deg, self.roll_deg).T @ (np.asarray(tag_xyz) - np.asarray(self.position))
        x, y, z = (float(v) for v in d)
        return math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, math.hypot(x, y)))

    def angle(self, tag: str, tag_xyz: tuple[float, float, float]) -> silabs_aoa.Angle:
        """The locator's report of ``tag``: true angles plus its errors, azimuth written 0..360."""
        bias = self._bias.get(tag)
        if bias is None:
            bias = self._bias[tag] = (float(self.rng.normal(0.0, self.bias_sigma_deg)),
                                      float(self.rng.normal(0.0, self.bias_sigma_deg)))
        az, el = self.true_angles(tag_xyz)
        az += bias[0] + float(self.rng.normal(0.0, self.sigma_deg))
        el += bias[1] + float(self.rng.normal(0.0, self.sigma_deg))
        self._sequence = (self._sequence + 1) % 65536  # the CTE event counter it copies is 16 bits
        distance = math.dist(tag_xyz, self.position)
        return silabs_aoa.Angle(self.locator_id, tag, az % 360.0, max(-90.0, min(90.0, el)), distance,
                                self._sequence, self.sigma_deg, self.sigma_deg)

    def messages(self, tags: dict[str, tuple[float, float, float]]) -> list[tuple[str, bytes]]:
        """One angle message per tag (tag id -> where it is now)."""
        out = []
        for tag, xyz in tags.items():
            a = self.angle(tag, xyz)
            out.append((silabs_aoa.angle_topic(a.locator, a.tag, self.prefix), silabs_aoa.encode(a)))
        return out
