"""The XPLR-AOA's angle errors as a radio profile measured them (``--radio measured|PROFILE``).

A profile's ``[aoa]`` (protocol/radio_profile.py) made concrete and seeded, for one board: each
report of a tag is the true angle, shifted by the |angle| compression, plus a bias drawn per
board, tag and run, a field over where the board and the tag are (so an error stays put while
both stand and comes back where they come back: what dwells on real recordings show), a slow
Ornstein-Uhlenbeck wander, white noise and, now and then, a burst (a reflection the board locks
on to for a while: the heavy tail); some events are not reported at all, in runs. A tag a
person carries (a profile's ``[aoa.person]``) adds what standing with it does: offsets that
stay put through each stop, and the body's shadow on the boards behind the carrier.

The field is drawn from the *room's* seed, not the run's: runs in one room (one scenario and
room seed) meet the same field, as walks through one real room meet the same multipath.
"""

from __future__ import annotations

import enum
import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rfhoming.emulator.fields import FourierField
from rfhoming.firmware.xplr_aoa import output_angles
from rfhoming.protocol.radio_profile import AngleError, AoaProfile, BoardWalk, Person, Reported

FIELD_FEATURES = 256
"""Random Fourier features per field: enough that its values are Gaussian to the eye."""


def room_field(sigma: float, length_m: float, rng: np.random.Generator) -> FourierField:
    """A board's multipath field over the 10 numbers of :meth:`AngleProcess.where`: exponential
    kernel, drawn from the room's seed."""
    return FourierField("exponential", sigma, length_m, 10, rng, FIELD_FEATURES)


@dataclass
class _AxisState:
    """One tag's error state on one axis of one board."""

    bias: float
    slow: float = 0.0
    t: float = -math.inf  # of the last report
    burst_end: float = -math.inf
    burst_offset: float = 0.0


Pose = tuple[float, float, float, float]
"""(x, y, z, heading): metres, and radians CCW from +x (the way a tag's carrier faces)."""


class AngleProcess:
    """One axis (azimuth or elevation) of one board: every tag's error on it."""

    def __init__(self, p: AngleError, rng: np.random.Generator, room: np.random.Generator) -> None:
        self.p = p
        self.rng = rng
        self.field = room_field(p.field_sigma_deg, p.field_length_m, room) if p.field_sigma_deg > 0 else None
        self.compression = max(0.0, 1.0 + float(room.normal(0.0, p.compression_spread)))  # this board's
        self._tags: dict[str, _AxisState] = {}

    def where(self, board: Pose, tag: Pose) -> np.ndarray:
        """The field's argument: both ends' places and, scaled by ``field_heading_m``, the ways
        they face (so a turn moves the field as far as the chord it sweeps times that scale)."""
        return _where(board, tag, self.p.field_heading_m)

    def error(self, tag: str, t: float, true_deg: float, azimuth_deg: float, board: Pose, tag_pose: Pose,
              stance: float = 0.0, shadow: float = 1.0) -> float:
        """The error (degrees) of a report at ``t`` of a tag at the true angle ``true_deg`` of
        this axis and the true azimuth ``azimuth_deg`` (what the curves are read at); ``stance``
        and ``shadow``: a person's (:class:`Stance`), added to and stretching the random parts."""
        p, rng = self.p, self.rng
        s = self._tags.get(tag)
        if s is None:
            s = self._tags[tag] = _AxisState(p.bias_deg + float(rng.normal(0.0, p.bias_sigma_deg)))
            s.slow = float(rng.normal(0.0, p.slow_sigma_deg))
        else:
            keep = math.exp(-max(0.0, t - s.t) / p.slow_time_s)
            s.slow = s.slow * keep + math.sqrt(1.0 - keep * keep) * float(rng.normal(0.0, p.slow_sigma_deg))
        dt = 0.0 if s.t == -math.inf else max(0.0, t - s.t)
        s.t = t
        if t >= s.burst_end and p.burst_rate_hz > 0 and rng.random() < 1.0 - math.exp(-p.burst_rate_hz * dt):
            s.burst_end = t + float(rng.exponential(p.burst_duration_s))
            size = p.burst_offset_min_deg + (float(rng.exponential(p.burst_offset_excess_deg))
                                             if p.burst_offset_excess_deg > 0 else 0.0)
            outward = 1.0 if true_deg >= 0 else -1.0
            s.burst_offset = size * outward if rng.random() < p.burst_outward else -size * outward
        burst = s.burst_offset if t < s.burst_end else 0.0
        sign = 1.0 if true_deg > 0 else -1.0 if true_deg < 0 else 0.0
        shift = self.compression * p.compression(abs(azimuth_deg)) * sign + p.offset(abs(azimuth_deg))
        field = self.field(self.where(board, tag_pose)) if self.field is not None else 0.0
        core = field + s.slow + float(rng.normal(0.0, p.white_sigma_deg)) + stance
        skew = p.skew_at(abs(azimuth_deg))
        noise = core * (1.0 + skew if core * (sign or 1.0) > 0 else 1.0 - skew) + burst
        return shift + s.bias + p.spread_at(abs(azimuth_deg)) * shadow * noise


class Posture(enum.Enum):
    """What a person carrying a tag is doing, as a board's stance offsets see it."""

    MOVING = "moving"
    STANDING = "standing"


@dataclass
class _Stop:
    """One tag's posture at one board, and its stance offsets (azimuth, elevation) while it stands."""

    posture: Posture
    t: float
    where: tuple[float, float]
    held: tuple[float, float] = (0.0, 0.0)  # drawn when it stopped
    wander: tuple[float, float] = (0.0, 0.0)  # its Ornstein-Uhlenbeck state now

    @property
    def offsets(self) -> tuple[float, float]:
        return (self.held[0] + self.wander[0], self.held[1] + self.wander[1])


class Stance:
    """A tag a person carries, at one board (a profile's ``[aoa.person]``): the offsets that
    stay put while the tag stands -- the room's stance fields at the place and facing where it
    stopped, plus a draw made anew at every stop -- and the body's shadow on a board behind
    the carrier."""

    def __init__(self, person: Person, azimuth: AngleError, elevation: AngleError, rng: np.random.Generator,
                 room: np.random.Generator) -> None:
        self.p, self.rng = person, rng
        self.fields = tuple(room_field(sigma, axis.field_length_m, room) if sigma > 0 else None
                            for sigma, axis in ((person.stance_az_field_deg, azimuth),
                                                (person.stance_el_field_deg, elevation)))
        self.headings = (azimuth.field_heading_m, elevation.field_heading_m)
        self._tags: dict[str, _Stop] = {}

    def offsets(self, tag: str, t: float, board: Pose, tag_pose: Pose) -> tuple[float, float]:
        """The (azimuth, elevation) stance offsets of a report at ``t`` (0 while the tag moves)."""
        p = self.p
        here = (tag_pose[0], tag_pose[1])
        s = self._tags.get(tag)
        if s is None:
            s = self._tags[tag] = _Stop(Posture.MOVING, t, here)
        dt = t - s.t
        if dt <= 0:
            return s.offsets
        still = math.dist(here, s.where) < p.stance_speed_m_s * dt
        s.t, s.where = t, here
        if still and s.posture is Posture.MOVING:
            s.posture = Posture.STANDING
            drawn = []
            for f, heading, sigma in zip(self.fields, self.headings, (p.stance_az_sigma_deg, p.stance_el_sigma_deg)):
                fixed = f(_where(board, tag_pose, heading)) if f is not None else 0.0
                drawn.append(fixed + float(self.rng.normal(0.0, sigma)))
            s.held = (drawn[0], drawn[1])
            s.wander = (float(self.rng.normal(0.0, p.stance_wander_deg)), float(self.rng.normal(0.0, p.stance_wander_deg)))
        elif still and p.stance_wander_deg > 0:
            keep = math.exp(-dt / p.stance_wander_s)
            step = math.sqrt(1.0 - keep * keep) * p.stance_wander_deg
            s.wander = (s.wander[0] * keep + step * float(self.rng.normal()),
                        s.wander[1] * keep + step * float(self.rng.normal()))
        elif not still and s.posture is Posture.STANDING:
            s.posture, s.held, s.wander = Posture.MOVING, (0.0, 0.0), (0.0, 0.0)
        return s.offsets

    def shadow(self, board: Pose, tag_pose: Pose) -> float:
        """The stretch of the random parts of a board's error by the carrier's body."""
        if self.p.shadow_gain <= 0:
            return 1.0
        to_board = math.atan2(board[1] - tag_pose[1], board[0] - tag_pose[0])
        return 1.0 + self.p.shadow_gain * max(0.0, -math.cos(to_board - tag_pose[3]))


def _where(board: Pose, tag: Pose, heading_m: float) -> np.ndarray:
    """A field's argument (as :meth:`AngleProcess.where`)."""
    return np.array([*board[:3], heading_m * math.cos(board[3]), heading_m * math.sin(board[3]),
                     *tag[:3], heading_m * math.cos(tag[3]), heading_m * math.sin(tag[3])])


class MeasuredAoa:
    """A board's reports under a profile: :meth:`report` gives the reported (azimuth,
    elevation) in the board's sign and degrees, or None for an event it does not report."""

    def __init__(self, profile: AoaProfile, board: str, rng: np.random.Generator, room_seed: int) -> None:
        room = np.random.default_rng([room_seed, zlib.crc32(board.encode())])
        self.azimuth = AngleProcess(profile.azimuth, rng, room)
        self.elevation = AngleProcess(profile.elevation, rng, room)
        self.stance = Stance(profile.person, profile.azimuth, profile.elevation, rng, room) \
            if profile.person != Person() else None
        m = profile.missing
        self.rng = rng
        self.loss = float(rng.uniform(m.rate_low, m.rate_high)) if m.rate_high > 0 else 0.0
        self.stay_lost = 1.0 - 1.0 / m.burst_events
        self.start_loss = min(1.0, self.loss * (1.0 - self.stay_lost) / (1.0 - self.loss)) if self.loss else 0.0
        self._lost: dict[str, bool] = {}

    def report(self, tag: str, t: float, azimuth_deg: float, elevation_deg: float, board: Pose,
               tag_pose: Pose) -> tuple[float, float] | None:
        """The board's report of a tag whose true board angles (board sign, degrees) are given,
        the board and the tag where they are, or None: the event is lost."""
        lost = self._lost.get(tag, False)
        lost = self.rng.random() < (self.stay_lost if lost else self.start_loss)
        self._lost[tag] = lost
        if lost:
            return None
        (az_stance, el_stance), shadow = ((0.0, 0.0), 1.0) if self.stance is None else \
            (self.stance.offsets(tag, t, board, tag_pose), self.stance.shadow(board, tag_pose))
        az = azimuth_deg + self.azimuth.error(tag, t, azimuth_deg, azimuth_deg, board, tag_pose, az_stance, shadow)
        el = elevation_deg + self.elevation.error(tag, t, elevation_deg, azimuth_deg, board, tag_pose, el_stance,
                                                  shadow)
        return max(-90.0, min(90.0, az)), max(-90.0, min(90.0, el))


CALIBRATION_TAG = "CCF9578E0D8A"
"""The tag id :func:`simulated_errors` reports (one tag per walk: any id will do)."""


def simulated_errors(profile: AoaProfile, walk: Sequence[BoardWalk], seed: int, room_seed: int) -> list[Reported]:
    """Each board's reports of one walk under ``profile``, as the emulator's board gives them:
    the measured process of :class:`MeasuredAoa` (the room's field and compression factors from
    ``room_seed``, the rest from ``seed``), then the firmware's rounding and median buffering
    (firmware_py/xplr_aoa.py's ``output_angles``). What ``rfhoming radio-fit`` calibrates a
    profile against (host/aoa_calibrate.py): a :data:`~rfhoming.protocol.radio_profile.Board`."""
    rng = np.random.default_rng(seed)
    out: list[Reported] = []
    for b in walk:
        board = MeasuredAoa(profile, b.board, rng, room_seed)
        kept: list[int] = []
        raw_az: list[float] = []
        raw_el: list[float] = []
        for k, (t, az, el, pose) in enumerate(zip(b.t.tolist(), b.azimuth.tolist(), b.elevation.tolist(),
                                                  b.tag.tolist())):
            got = board.report(CALIBRATION_TAG, t, az, el, b.pose, (pose[0], pose[1], pose[2], pose[3]))
            if got is not None:
                kept.append(k)
                raw_az.append(got[0])
                raw_el.append(got[1])
        out.append((np.array(kept, int), np.array(output_angles(raw_az), float),
                    np.array(output_angles(raw_el), float)))
    return out
