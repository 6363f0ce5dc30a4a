"""Radio channel and angle-of-arrival models, seeded and reproducible.

Received power (dBm) = tx + P0 − 10 n log10(d / d0) − L_wall · (obstacles crossed)
                       + b_link + N(0, σ_fast²) [+ Rician fading],
with ``b_link ~ N(0, σ_link²)`` drawn once per link. The defaults give about 5.3 dB of scatter
around the log-distance fit, like public indoor BLE recordings (5.6 dB on Daniş et al.'s; docs/RESULTS.md,
"Estimation on real recordings").

With ``reflections`` on, each first-order reflection off a wall (emulator/multipath.py) is a
path of its own: the same law over the image's distance, its own walls, and
``reflection_loss_db`` more. Paths add as powers (incoherently): the fast noise already stands
for the fading that their phases would make, and is drawn once per reception, after the sum.

AoA: the true bearing of the tag relative to the board's boresight (CCW, degrees) is folded
into the front half-plane (a planar array cannot tell front from back: 120° reads as 60°), noise
is added (Gaussian growing toward ±90°, or S0's uniform presets), the result is clipped to
±90° and written with the board's sign: azimuth is negative when the tag is to the LEFT.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfhoming.emulator import draws


@dataclass(frozen=True)
class PathLossModel:
    p0_dbm: float = -59.0  # at d0 for 0 dBm transmit power (BLE, 2.4 GHz)
    n: float = 2.2
    d0_m: float = 1.0
    fast_sigma_db: float = 3.5
    link_sigma_db: float = 4.0
    wall_loss_db: float = 6.0
    rician_k: float | None = None
    max_range_m: float = 60.0
    reflections: bool | None = None  # None: on when the scenario has obstacles (scenario.load)
    reflection_loss_db: float = 8.0  # concrete at normal incidence, ITU-R P.2040 (docs/emulator.md)
    reflect_bounds: bool = False  # the world's bounds are walls that reflect (a hall's)

    def mean_dbm(self, distance_m: float, tx_power_dbm: float = 0.0, walls: int = 0) -> float:
        d = max(distance_m, 0.05)
        return tx_power_dbm + self.p0_dbm - 10 * self.n * math.log10(d / self.d0_m) - self.wall_loss_db * walls

    def path_dbm(self, distance_m: float, tx_power_dbm: float, walls: int, reflections: int) -> float:
        """Mean power along one path of a multipath set."""
        return self.mean_dbm(distance_m, tx_power_dbm, walls) - self.reflection_loss_db * reflections

    def distance_for(self, rssi_dbm: float, tx_power_dbm: float = 0.0) -> float:
        """Inverse of :meth:`mean_dbm` without walls."""
        return self.d0_m * 10 ** ((tx_power_dbm + self.p0_dbm - rssi_dbm) / (10 * self.n))


Ends = tuple[tuple[float, float], tuple[float, float]]
"""Where a link's transmitter and receiver are (world x, y, metres): what shadowing depends on."""


class RadioChannel:
    """Samples received power per link; the per-link bias is drawn on first use. The scenario's
    own (``ideal``) channel: the keywords that a measured channel uses (emulator/measured_rssi.py:
    the reading's time, its ends, its distance) change nothing here."""

    def __init__(self, model: PathLossModel, rng: np.random.Generator) -> None:
        self.model = model
        self.rng = rng
        self._bias: dict[tuple[str, str], float] = {}

    def received_dbm(self, link: tuple[str, str], distance_m: float, tx_power_dbm: float,
                     walls: int, *, t: float = 0.0, ends: Ends | None = None) -> float | None:
        """One sample, or None beyond the model's range."""
        if distance_m > self.model.max_range_m:
            return None
        return self.sample(link, self.model.mean_dbm(distance_m, tx_power_dbm, walls), t=t, ends=ends,
                           distance_m=distance_m)

    def sample(self, link: tuple[str, str], mean_dbm: float, *, t: float = 0.0, ends: Ends | None = None,
               distance_m: float | None = None) -> float:
        """One reception of a link whose mean power is ``mean_dbm``: its bias, fast noise, fading."""
        m = self.model
        bias = self._bias.get(link)
        if bias is None:
            bias = self._bias[link] = draws.normal(self.rng, 0, m.link_sigma_db)
        power = mean_dbm + bias + draws.normal(self.rng, 0, m.fast_sigma_db)
        if m.rician_k is not None:
            k = m.rician_k
            los = math.sqrt(k / (k + 1))
            scatter = self.rng.normal(0, math.sqrt(1 / (2 * (k + 1))), 2)
            power += 20 * math.log10(max(math.hypot(los + scatter[0], scatter[1]), 1e-6))
        return power

    def lost(self, link: tuple[str, str], t: float) -> bool:
        """Whether the receiver misses the link's transmission at ``t``: never, here (the
        firmware models' own collisions and sensitivity aside)."""
        return False

    def second_dbm(self, link: tuple[str, str], rssi_dbm: float) -> float:
        """The XPLR-AOA's second polarisation for a reading of ``rssi_dbm`` on the first."""
        return rssi_dbm + draws.normal(self.rng, 0, 1.5)


def power_sum_dbm(powers_dbm: list[float]) -> float:
    """Incoherent sum of path powers (dBm)."""
    if len(powers_dbm) == 1:
        return powers_dbm[0]
    return 10 * math.log10(sum(10 ** (p / 10) for p in powers_dbm))


S0_PRESETS: dict[int, tuple[float, float, float]] = {
    1: (5.0, 0.05, 0.0),
    2: (5.0, 0.10, 0.0),
    3: (10.0, 0.10, 0.0),
    4: (10.0, 0.20, 0.0),
    5: (20.0, 0.20, 1.0),
}
"""S0 Table 2: uniform angle noise ±deg, distance noise ±fraction, ±metres."""


@dataclass(frozen=True)
class AoaModel:
    kind: str = "gaussian"  # or "uniform"
    angle_deg: float = 3.0  # σ at boresight (gaussian) or half-width (uniform)
    edge_growth: float = 3.0  # gaussian σ grows to σ·(1 + edge_growth) at ±90°
    distance_rel: float = 0.0  # uniform presets: RSSI made from d·(1 ± rel) ± abs
    distance_abs_m: float = 0.0
    fold: bool = True

    @classmethod
    def s0_preset(cls, config: int) -> AoaModel:
        angle, rel, absolute = S0_PRESETS[config]
        return cls("uniform", angle, 0.0, rel, absolute)

    @property
    def idealised_rssi(self) -> bool:
        return self.kind == "uniform"

    def sigma_deg(self, true_deg: float) -> float:
        return self.angle_deg * (1 + self.edge_growth * (abs(true_deg) / 90.0) ** 4)


def fold_front(relative_deg: float) -> float:
    """Mirror a bearing behind the array's plane into the front half-plane (−90…90)."""
    a = math.remainder(relative_deg, 360.0)
    if a > 90:
        return 180.0 - a
    if a < -90:
        return -180.0 - a
    return a


def seen_azimuth(relative_ccw_deg: float, fold: bool) -> float:
    """The true azimuth a board's array sees (CCW, degrees): folded into its front half-plane, or
    over the whole circle for an array that tells front from back."""
    return fold_front(relative_ccw_deg) if fold else math.remainder(relative_ccw_deg, 360.0)


def true_angles(d: np.ndarray, cone: bool) -> tuple[float, float]:
    """The true (azimuth CCW, elevation) in degrees of a direction ``d`` in a planar array's frame
    (x its boresight, z up); a direction behind its plane is seen as its front image. ``cone``:
    the angles of a planar array's phase differences, sin(az) = d.y / |d| and sin(el) = d.z / |d|;
    else the spherical angles atan2."""
    if d[0] < 0:
        d = d * np.array([-1.0, 1.0, 1.0])
    if cone:
        r = float(np.linalg.norm(d))
        return math.degrees(math.asin(d[1] / r)), math.degrees(math.asin(d[2] / r))
    return fold_front(math.degrees(math.atan2(d[1], d[0]))), math.degrees(math.atan2(d[2], math.hypot(d[0], d[1])))


def measure_azimuth(model: AoaModel, relative_ccw_deg: float, rng: np.random.Generator) -> float:
    """The azimuth the board reports (board sign: negative = left), before integer rounding."""
    a = seen_azimuth(relative_ccw_deg, model.fold)
    if model.kind == "uniform":
        a += draws.uniform(rng, -model.angle_deg, model.angle_deg)
    else:
        a += draws.normal(rng, 0, model.sigma_deg(a))
    return -max(-90.0, min(90.0, a))


def idealised_rssi(model: AoaModel, path: PathLossModel, distance_m: float, tx_power_dbm: float,
                   rng: np.random.Generator) -> float:
    """S0's idealised distance noise expressed as the RSSI the calibration inverts."""
    noisy = distance_m * (1 + draws.uniform(rng, -model.distance_rel, model.distance_rel))
    noisy += draws.uniform(rng, -model.distance_abs_m, model.distance_abs_m)
    return path.mean_dbm(max(noisy, 0.05), tx_power_dbm)
