"""A radio profile fitted to a site's recordings: what ``rfhoming radio-fit`` writes (docs/usage.md).

Each recording is the site's anchors' angle events (read through the usual sources by the
command) with its truth: the walk of a waypoint file (host/groundtruth.py) or, where none was
kept, a stand-in made from the recordings themselves: the anchors self-calibrated on every
recording without truth (host/self_calibration.py), then each such recording located and
RTS-smoothed (host/locate.py). The stand-in's own error counts as the radios', so a profile
fitted to it comes out harder than the radios are, never kinder. Residuals are taken against
the anchors' poses as the site gives them, without its calibration: the emulator places a
profile's boards at their nominal poses, so what a calibration would correct is part of what
the profile must reproduce.
"""

from __future__ import annotations

import datetime
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import tomlkit

import numpy as np

from rfhoming.host import outputs
from rfhoming.host.angle_residuals import residuals
from rfhoming.host.bearing import Bearing
from rfhoming.host.aoa_calibrate import calibrate, walk_to_calibrate
from rfhoming.host.aoa_fit import Walk, fit_aoa
from rfhoming.host.groundtruth import WalkedPath, Waypoint
from rfhoming.host.locate import Locator, smooth
from rfhoming.host.site import Calibration, Site
from rfhoming.protocol.errors import Error
from rfhoming.protocol.radio_profile import Board, Header, RadioProfile, parse, to_toml
from rfhoming.protocol.radio_profile import Recording as RecordingEntry

PROXY = "self-calibrated track (rfhoming locate after calibrate --self, RTS-smoothed): no ground truth"
"""What a profile's [recordings.ID] truth says when the stand-in was used."""


class RadioFitError(Error, ValueError):
    """Recordings a profile cannot be fitted to; the message says what to give instead."""


@dataclass(frozen=True)
class Recording:
    """One recording to fit: its id, the spec it was read from, its events and its walk."""

    id: str
    source: str
    events: Sequence[Bearing]
    truth: WalkedPath
    truth_name: str  # the waypoint file, or PROXY


def fit(site: Site, recordings: Sequence[Recording], name: str, *, tag: str | None = None,
        height: float | None = None, description: str = "", board: Board | None = None,
        progress: Callable[[str], None] = lambda _: None) -> tuple[RadioProfile, dict[str, object]]:
    """The profile of these recordings (its ``[aoa]``), and what the fit saw; ``tag``: the walked
    tag (the site's first by default), ``height``: its height (the site's by default). With
    ``board`` (the emulator's, emulator/aoa_error.py's ``simulated_errors``: the CLI passes it),
    the direct fit is then calibrated through it on the same walks (host/aoa_calibrate.py), so
    the emulator reproduces the recordings' statistics rather than the fit's parameters."""
    plain = replace(site, anchors=tuple(replace(a, calibration=Calibration()) for a in site.anchors))
    if tag is None and not plain.tags:
        raise RadioFitError("the site names no tag: add [tags.ID] with the walked tag's height to the site file, "
                            "or give --tag ID and --height M")
    walks = []
    for r in recordings:
        try:
            walks.append(Walk(r.id, r.truth, residuals(plain, r.events, r.truth, tag=tag, height=height)))
        except ValueError as exc:
            raise RadioFitError(f"{r.source}: {exc}") from None
        if not walks[-1].residuals:
            raise RadioFitError(f"{r.source}: none of its angle events is of the site's anchors and first tag "
                                "within the truth's span: check the site file and the --truth that goes with it")
    aoa, report = fit_aoa(walks)
    if board is not None:
        info = plain.tag(tag or plain.tags[0].id) if (tag or plain.tags) else None
        z = height if height is not None else info.height if info is not None and info.height is not None else 1.0
        rng = np.random.default_rng(0)  # the schedules: fixed, so a fit is repeatable
        for w in walks:  # the board is driven at each walk's event rate: it needs a span of reports
            spans = [float(r.t[-1] - r.t[0]) for r in w.residuals.values() if len(r.t) >= 2]
            if not spans or max(spans) <= 0:
                raise RadioFitError(f"{w.id}: no anchor reported twice at different times, so its event "
                                    "rate is unknown: give a longer recording")
        to_match = [walk_to_calibrate(plain, w.id, w.path, w.residuals, z, rng) for w in walks]
        aoa, report["calibration"] = calibrate(aoa, to_match, board, progress=progress)
    header = Header(name=name, description=description or f"fitted to {len(recordings)} recording(s) of {site.name}",
                    fitted_by=f"rfhoming radio-fit, {datetime.date.today().isoformat()}")
    entries = {r.id: RecordingEntry(r.source, r.truth_name) for r in recordings}
    return RadioProfile(header, entries, aoa), report


def track_truth(site: Site, recordings: Sequence[Sequence[Bearing]], *, tag: str | None = None,
                height: float | None = None, progress: Callable[[str], None] = lambda _: None) -> list[WalkedPath]:
    """A stand-in truth for each recording: the anchors self-calibrated on all of them (kept
    uncalibrated where that is refused), each recording located and smoothed, the walked
    ``tag``'s track (the site's first tag by default)."""
    walked = tag or (site.tags[0].id if site.tags else None)
    from rfhoming.host.calibration import CalibrationError
    from rfhoming.host.self_calibration import self_calibrate

    calibrated = site
    try:
        result = self_calibrate(site, recordings, height=height, progress=progress)
        if result.write:
            fits = {f.anchor: f for f in result.fits}
            calibrated = replace(site, anchors=tuple(
                replace(a, calibration=fits[a.name].calibration, angle_model=fits[a.name].angle_model)
                if a.name in fits else a for a in site.anchors))
    except CalibrationError as exc:
        progress(f"self-calibration refused ({exc}); the track comes from the uncalibrated site\n")
    paths = []
    for events in recordings:
        locator = Locator(calibrated, track=False)
        fixes = [p for r in events for p in locator.feed(r)] + locator.flush()
        track = sorted({round(p.t, 6): p for p in smooth(fixes) if walked is None or p.tag == walked}.items())
        if len(track) < 2:
            raise RadioFitError("a recording without --truth gave fewer than two positions: it cannot stand in "
                                "for its own truth; give --truth FILE for it")
        paths.append(WalkedPath(tuple(Waypoint(t, t, float(p.point[0]), float(p.point[1])) for t, p in track)))
    return paths


def write(profile: RadioProfile, path: Path | str) -> None:
    """The profile as TOML, replacing ``path`` whole (a temporary file renamed over it); read
    back first, so no file is written that the loader would refuse."""
    doc = tomlkit.document()
    doc.add(tomlkit.comment(f"rfhoming radio profile {profile.name!r} (docs/emulator.md, \"Radio profiles\"): "
                            "rfhoming emulate/demo/campaign --radio THIS_FILE"))
    for key, value in to_toml(profile).items():
        doc[key] = value
    text = tomlkit.dumps(doc)
    parse(tomlkit.parse(text).unwrap(), str(path))
    outputs.replace_text(path, text)
