"""RSSI as real receivers measure it: a radio profile's ``[rssi.NAME]`` made concrete, seeded.

A reading of a link (transmitter, receiver) at time t with the ends at (s, r) is

    the scenario's mean power (path loss, walls, reflections)
    - 10 (n_link - n) log10(d' / pivot)     the link's own exponent, turned about the pivot
                                            (d' = d held within the recordings' span)
    + b_link                                its offset
    + S_link(s, r)                          shadowing: a Gaussian field over both ends
    + X_link(t)                             Ornstein-Uhlenbeck: what changes in time
    + N(0, white^2)

and the receiver misses some readings, in bursts (a two-state Markov chain in time). What is
drawn once per link (exponent, offset, field, loss fraction) comes from the channel's seed and
the link's name alone, so a link's radio map does not depend on what the robot did or heard
first: the same place gives the same shadowing, this run or the next with the same seed. What
changes in time (the residual, the white noise, the losses) comes from the runner's stream.

:func:`channel` is the one entry point: the scenario's own channel (``ideal``) where a board's
radio has no profile, else a :class:`MeasuredChannel`. docs/emulator.md, "Measured RSSI".
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from rfhoming.emulator import draws
from rfhoming.emulator.fields import FourierField
from rfhoming.emulator.radio import Ends, PathLossModel, RadioChannel
from rfhoming.protocol import devices
from rfhoming.protocol.rssi_profile import RssiProfile

FIELD_FEATURES = 128
"""Random Fourier features per shadowing field: enough that its values look Gaussian."""


class ShadowField(FourierField):
    """A link's shadowing: a Gaussian-kernel field over its two ends (s_x, s_y, r_x, r_y) with
    covariance sd^2 exp(-|Δ|^2 / distance^2) (emulator/fields.py)."""

    def __init__(self, sd_db: float, distance_m: float, rng: np.random.Generator) -> None:
        super().__init__("gaussian", sd_db, distance_m, 4, rng, FIELD_FEATURES)
        self._last: tuple[Ends, float] | None = None  # ends that stay put (a parked robot, a fixed pair) cost nothing

    def at(self, ends: Ends) -> float:
        if self._last is not None and self._last[0] == ends:
            return self._last[1]
        (sx, sy), (rx, ry) = ends
        value = float(self.values(np.array([sx, sy, rx, ry])))
        self._last = (ends, value)
        return value


def ou_keep(dt_s: float | np.ndarray, time_s: float) -> float | np.ndarray:
    """How much of an Ornstein-Uhlenbeck residual is kept after ``dt_s`` (its time constant ``time_s``)."""
    return np.exp(-np.maximum(0.0, dt_s) / time_s) if isinstance(dt_s, np.ndarray) else math.exp(-max(0.0, dt_s) / time_s)


def p_lost(fraction: float | np.ndarray, was_lost: bool | np.ndarray | None, dt_s: float, burst_s: float
           ) -> float | np.ndarray:
    """P(a reading ``dt_s`` after the last is lost | the last's state ``was_lost``): the two-state chain
    relaxes to the link's loss ``fraction`` with bursts ``burst_s`` long on average (None: no last)."""
    if was_lost is None:
        return fraction
    keep = np.exp(-max(0.0, dt_s) / (burst_s * np.maximum(1 - np.asarray(fraction, float), 1e-9)))
    out = fraction + (np.asarray(was_lost, float) - fraction) * keep
    return float(out) if np.ndim(out) == 0 else np.asarray(out, float)


@dataclass
class _Link:
    """One link's draws (fixed) and its processes' state."""

    exponent: float
    offset_db: float
    field: ShadowField | None
    loss: float
    residual_db: float | None = None  # the OU state, None before the first reading
    residual_t: float = 0.0
    lost: bool | None = None  # the loss chain's state, None before the first transmission
    lost_t: float = 0.0


class MeasuredChannel(RadioChannel):
    """A radio whose RSSI behaves as a profile measured: a drop-in for :class:`RadioChannel`
    (the runners pass each reading's time, ends and distance, which the ideal one ignores)."""

    def __init__(self, model: PathLossModel, profile: RssiProfile, rng: np.random.Generator) -> None:
        super().__init__(model, rng)
        self.profile = profile
        self._seed = int(rng.integers(2**63))
        self._links: dict[tuple[str, str], _Link] = {}

    def link(self, link: tuple[str, str]) -> _Link:
        """The link's draws, from the channel's seed and the link's name only."""
        found = self._links.get(link)
        if found is None:
            p = self.profile
            g = np.random.default_rng([self._seed, zlib.crc32("\0".join(link).encode())])
            e = p.exponent
            exponent = min(e.high, max(e.low, float(g.normal(e.mean, e.sd))))
            offset = float(g.normal(0.0, p.offset.sd_db))
            s = p.shadowing
            field = ShadowField(s.sd_db, s.distance_m, g) if s.sd_db > 0 else None
            loss = float(g.uniform(p.loss.fraction_low, p.loss.fraction_high)) if p.loss is not None else 0.0
            found = self._links[link] = _Link(exponent, offset, field, loss)
        return found

    def shadowing_db(self, link: tuple[str, str], ends: Ends) -> float:
        """The link's shadowing with its ends at ``ends``: a function of place alone."""
        field = self.link(link).field
        return field.at(ends) if field is not None else 0.0

    def shadowing_at(self, link: tuple[str, str], ends: np.ndarray) -> np.ndarray:
        """The same shadowing at each row of ``ends`` (..., 4: transmitter x, y, receiver x, y)."""
        field = self.link(link).field
        return field.values(ends) if field is not None else np.zeros(np.shape(ends)[:-1])

    def turned_db(self, link: tuple[str, str], distance_m: float | np.ndarray) -> np.ndarray:
        """The link's offset and its exponent's turn about the pivot at ``distance_m`` (held within
        the exponent's span, beyond which the scenario's own slope holds)."""
        state = self.link(link)
        e = self.profile.exponent
        held = np.clip(np.asarray(distance_m, float), e.near_m, e.far_m)
        return np.asarray(state.offset_db - 10 * (state.exponent - self.model.n) * np.log10(held / e.pivot_m), float)

    def sample(self, link: tuple[str, str], mean_dbm: float, *, t: float = 0.0, ends: Ends | None = None,
               distance_m: float | None = None) -> float:
        """One reading at ``t`` of a link whose scenario mean is ``mean_dbm``: turned to the
        link's exponent at ``distance_m`` (none: at the pivot, only the link's offset), with
        ``ends`` for the shadowing (none: a link that never moves, no shadowing but its offset)."""
        state = self.link(link)
        p = self.profile
        power = mean_dbm + (state.offset_db if distance_m is None else float(self.turned_db(link, distance_m)))
        if ends is not None and state.field is not None:
            power += state.field.at(ends)
        r = p.residual
        if r.sd_db > 0:
            if state.residual_db is None:
                state.residual_db = draws.normal(self.rng, 0.0, r.sd_db)
            else:
                keep = float(ou_keep(t - state.residual_t, r.time_s))
                state.residual_db = state.residual_db * keep + math.sqrt(1 - keep * keep) * draws.normal(self.rng, 0.0, r.sd_db)
            state.residual_t = t
            power += state.residual_db
        return power + draws.normal(self.rng, 0.0, r.white_sd_db)

    def lost(self, link: tuple[str, str], t: float) -> bool:
        """Whether the reading at ``t`` is missed: a chain in time with the link's loss fraction
        and bursts ``burst_s`` long on average, so it holds whatever the transmission rate."""
        state = self.link(link)
        loss = self.profile.loss
        if loss is None or state.loss <= 0:
            return False
        chance = float(p_lost(state.loss, state.lost, t - state.lost_t, loss.burst_s))
        state.lost = bool(self.rng.random() < chance)
        state.lost_t = t
        return state.lost

    def second_dbm(self, link: tuple[str, str], rssi_dbm: float) -> float:
        pol = self.profile.polarisation
        if pol is None:
            return super().second_dbm(link, rssi_dbm)
        return rssi_dbm + draws.normal(self.rng, pol.mean_db, pol.sd_db)


def channel(board: str, model: PathLossModel, rng: np.random.Generator,
            profiles: Mapping[str, RssiProfile]) -> RadioChannel:
    """The channel of a ``board`` (a scenario's device type): measured where ``profiles`` (the
    radio profile's ``[rssi.NAME]``, by name) has the table of its radio (the device table's
    ``Board.radio``), else the scenario's own."""
    radio = devices.BOARDS[board][1].radio
    profile = profiles.get(radio) if radio is not None else None
    return RadioChannel(model, rng) if profile is None else MeasuredChannel(model, profile, rng)
