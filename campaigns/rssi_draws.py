"""Measured RSSI for the campaigns that simulate their paper's radio themselves (s3-arena,
s4-montecarlo): under ``--radio measured|PROFILE`` their RSSI draws come from a radio profile's
``[rssi.NAME]`` table (protocol/rssi_profile.py) instead of the paper's idealised noise. Each
link's draws are the emulator's measured channel's (emulator/measured_rssi.py); S3 reads through
that channel reading by reading, S4's flights (a million readings a job) step the same
processes over all links at once (the channel's own vectorised :meth:`~MeasuredChannel.turned_db` and
:meth:`~MeasuredChannel.shadowing_at`, and :class:`TimeProcesses` on the channel's formulas).

The campaign keeps its paper's mean power (its path-loss law, its table of means); the profile
gives what real receivers add to it: each link's exponent about the pivot and its offset, the
shadowing over where the two ends are, the correlated residual, the white noise and the losses.
What is drawn once per link comes from the job's seed and the link's name, so a job gives the
same draws on any worker. The estimators are told nothing of this: they see the readings.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from rfhoming.campaigns.runner import CampaignError
from rfhoming.emulator.measured_rssi import MeasuredChannel, ou_keep, p_lost
from rfhoming.emulator.radio import PathLossModel
from rfhoming.protocol.radio_profile import IDEAL, RadioProfile, resolve
from rfhoming.protocol.rssi_profile import RssiProfile

NEAREST = {"ble": ("ble", "xplr", "subghz")}
"""The tables to take for a paper's radio, nearest first."""
WHY = {("ble", "xplr"): "the profile has no [rssi.ble]: the XPLR-AOA's RSSI ([rssi.xplr]), BLE advertisements at "
                        "2.4 GHz heard by another receiver, is the nearest measured radio",
       ("ble", "subghz"): "the profile has no [rssi.ble] or [rssi.xplr]: the sub-GHz node's table ([rssi.subghz]) "
                          "is the only one it has"}


@dataclass(frozen=True)
class Radio:
    """The table a campaign's receivers take from a profile, and what of it is assumed."""

    profile_name: str  # the --radio argument
    table: str  # which [rssi.NAME]
    rssi: RssiProfile
    assumed: str  # why the table is not the paper's radio's own ("" when it is)

    def describe(self, paper_radio: str) -> dict[str, str]:
        """For the job's row and the report: which radios, and what is assumed."""
        groups = self.rssi.assumed()
        notes = [self.assumed] if self.assumed else []
        notes += [f"[rssi.{self.table}.{g}]: {why}" for g, why in groups.items()]
        return {"radio": self.profile_name, "rssi_table": self.table, "paper_radio": paper_radio,
                "assumed": "; ".join(notes)}


def radios_line(radios: dict[str, str] | None, ideal_noise: str, receivers: str, about: str, instead: str) -> str:
    """A report's line on which radios its readings came from: the paper's noise, or a profile's
    table (``receivers`` take it ``about`` the paper's law ``instead`` of the paper's noise)."""
    if radios is None:
        return f"Radios: {ideal_noise}."
    line = (f"Radios: {radios['radio']}: {receivers} take the profile's [rssi.{radios['rssi_table']}] about {about} "
            f"(link exponent and offset, shadowing, correlated residual, white noise, losses) in place of {instead}")
    return line + (f"; *assumed*: {radios['assumed']}." if radios["assumed"] else ".")


def rssi_radio(radio: str, paper_radio: str) -> Radio | None:
    """The ``[rssi.NAME]`` the paper's receivers (``paper_radio``) take under ``radio``: their
    own, else the nearest measured one (marked assumed); None for ``ideal``."""
    if radio == IDEAL:
        return None
    profile = _profile(radio)
    for table in NEAREST.get(paper_radio, (paper_radio,)):
        if table in profile.rssi:
            return Radio(radio, table, profile.rssi[table], WHY.get((paper_radio, table), ""))
    raise CampaignError(f"radio profile {radio!r} has no [rssi.{paper_radio}] table (nor a near one): this campaign "
                        "simulates RSSI, so its profile needs one (docs/emulator.md, \"Measured RSSI\")")


@functools.lru_cache(maxsize=4)
def _profile(radio: str) -> RadioProfile:
    """Read once per process (a campaign's jobs all name the same one)."""
    profile = resolve(radio)
    assert profile is not None
    return profile


def channel(radio: Radio, n: float, rng: np.random.Generator) -> MeasuredChannel:
    """A measured channel whose scenario law has exponent ``n`` (the paper's), seeded by ``rng``
    (its first draw seeds every link's own draws)."""
    return MeasuredChannel(PathLossModel(n=n), radio.rssi, rng)


class TimeProcesses:
    """The residual (Ornstein-Uhlenbeck), the white noise and the loss chain of many links at
    once, stepped at a fixed interval ``dt``: :meth:`MeasuredChannel.sample` and ``lost`` for
    readings ``dt`` apart, one array of links per step. ``loss`` is each link's loss fraction."""

    def __init__(self, ch: MeasuredChannel, loss: np.ndarray, dt: float, rng: np.random.Generator) -> None:
        p = ch.profile
        self.rng, self.residual, self.loss = rng, p.residual, np.asarray(loss, float)
        self.burst = p.loss.burst_s if p.loss is not None else None
        self.dt = dt
        self.state: np.ndarray | None = None
        self.lost: np.ndarray | None = None

    def noise(self) -> np.ndarray:
        """The residual plus white noise of every link at the next reading."""
        r = self.residual
        shape = self.loss.shape
        if r.sd_db > 0:
            fresh = self.rng.normal(0.0, r.sd_db, shape)
            keep = float(ou_keep(self.dt, r.time_s))
            self.state = fresh if self.state is None else self.state * keep + math.sqrt(1 - keep**2) * fresh
            return np.asarray(self.state + self.rng.normal(0.0, r.white_sd_db, shape), float)
        return np.asarray(self.rng.normal(0.0, r.white_sd_db, shape), float)

    def missed(self) -> np.ndarray:
        """Which links miss the next reading (a two-state chain holding each link's fraction)."""
        if self.burst is None:
            return np.zeros(self.loss.shape, bool)
        self.lost = self.rng.random(self.loss.shape) < p_lost(self.loss, self.lost, self.dt, self.burst)
        return self.lost
