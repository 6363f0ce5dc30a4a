"""radio-fit and calibrate --self on another board's kind of data set: no elevation (the board
reports 0), a static survey (each capture one dwell, its truth one waypoint) and slow reports
(1 a second per anchor). The data set is made here: no recording is read."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import tomlkit

from rfhoming.host.angle_residuals import true_angles
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.site import parse as parse_site
from rfhoming.protocol.radio_profile import load
from rfhoming.protocol.uconnect import AngleEvent, Dialect, encode_angle_event

RFHOMING = [sys.executable, "-m", "rfhoming"]
TAG = "CCF9578E0D8A"
SQUARE = {"site": {"name": "survey-square"},
          "anchors": {"sw": {"id": "CCF9578E0B01", "position": [0.0, 0.0, 1.0], "yaw_deg": 45.0},
                      "se": {"id": "CCF9578E0B02", "position": [12.0, 0.0, 1.0], "yaw_deg": 135.0},
                      "ne": {"id": "CCF9578E0B03", "position": [12.0, 12.0, 1.0], "yaw_deg": -135.0},
                      "nw": {"id": "CCF9578E0B04", "position": [0.0, 12.0, 1.0], "yaw_deg": -45.0}},
          "tags": {TAG: {"height": 1.0}}}
"""Four beacons-as-anchors at the corners of a 12 x 12 m square, facing its middle, level with the tag."""

POINTS = ((2.0, 2.0), (6.0, 2.0), (10.0, 2.0), (2.0, 6.0), (6.0, 6.0), (10.0, 6.0), (2.0, 10.0), (6.0, 10.0),
          (10.0, 10.0), (4.0, 8.0))
DWELL_S = 120.0
RATE_HZ = 1.0


def survey(folder: Path, *, rate_hz: float = RATE_HZ, points: tuple[tuple[float, float], ...] = POINTS,
           seed: int = 0) -> tuple[Path, list[tuple[Path, Path]]]:
    """The site file and, per surveyed point, a capture of the four anchors (azimuth off by a
    white 6 deg and an error that stays put at the point, elevation always 0) and its truth: one
    waypoint, standing from arrival to leave."""
    site = parse_site(SQUARE)
    site_file = folder / "site.toml"
    site_file.write_text(tomlkit.dumps(SQUARE))
    rng = np.random.default_rng(seed)
    out = []
    for k, (x, y) in enumerate(points):
        t0 = 1000.0 + k * (DWELL_S + 30.0)
        capture = CaptureWriter(folder / f"point{k}.pcapng")
        for a in site.anchors:
            capture.describe(a.name, kind="xplr-aoa")
        for a in site.anchors:
            (az, _), = true_angles(a, np.array([[x, y, 1.0]]))
            stays = rng.normal(0, 4.0)
            for t in np.arange(t0, t0 + DWELL_S, 1 / rate_hz) + rng.uniform(0, 1 / rate_hz):
                reported = int(np.clip(round(az + stays + rng.normal(0, 6.0)), -90, 90))
                event = AngleEvent(TAG, -60, reported, 0, -62, 37, a.id, "", int(t * 1000) & 0x7FFFFFFF)
                capture.tap(a.name, "in", float(t), encode_angle_event(event, Dialect.V1_0))
        capture.close()
        truth = folder / f"point{k}.csv"
        truth.write_text(f"arrival_ms,leave_ms,x_cm,y_cm\n{round(t0 * 1000)},{round((t0 + DWELL_S) * 1000)},"
                         f"{round(x * 100)},{round(y * 100)}\n")
        out.append((capture.path, truth))
    return site_file, out


def test_radio_fit_writes_a_profile_of_a_static_survey_without_elevation(tmp_path: Path) -> None:
    site_file, points = survey(tmp_path)
    args = [a for capture, truth in points for a in ("--from", f"capture:{capture}", "--truth", str(truth))]
    done = subprocess.run([*RFHOMING, "radio-fit", str(site_file), *args, "-o", "square.toml"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    profile = load(tmp_path / "square.toml")
    assert profile.aoa is not None


def test_a_capture_that_cannot_be_read_is_named(tmp_path: Path) -> None:
    site_file, points = survey(tmp_path, points=POINTS[:1])
    (tmp_path / "bad.pcapng").write_bytes(b"garbage\n")
    done = subprocess.run([*RFHOMING, "radio-fit", str(site_file), "--from", "capture:bad.pcapng", "--truth",
                           str(points[0][1]), "-o", "square.toml"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1].startswith(
        "rfhoming radio-fit: capture:bad.pcapng: "), done.stderr


def test_figures_at_the_end_of_the_fits_grid_are_warned_of() -> None:
    from rfhoming.host.aoa_fit import warnings
    from rfhoming.protocol.radio_profile import AngleError, AoaProfile

    said = warnings(AoaProfile(azimuth=AngleError(field_heading_m=10.0, compression_spread=1.0),
                               elevation=AngleError(field_length_m=0.05)))
    assert any(line.startswith("azimuth.field_heading_m = 10") for line in said)
    assert any(line.startswith("azimuth.compression_spread = 1") for line in said)
    assert any(line.startswith("elevation.field_length_m = 0.05") for line in said)
    assert not warnings(AoaProfile(azimuth=AngleError(field_length_m=1.0, field_heading_m=1.0, slow_time_s=0.5),
                                   elevation=AngleError(field_length_m=1.0, slow_time_s=0.5)))


def calibrate_self(site_file: Path, points: list[tuple[Path, Path]], cwd: Path) -> subprocess.CompletedProcess[str]:
    sources = [a for capture, _ in points for a in ("--from", f"capture:{capture}")]
    return subprocess.run([*RFHOMING, "calibrate", str(site_file), "--self", "--dry-run", *sources], cwd=cwd,
                          capture_output=True, text=True, timeout=600, check=False)


def test_calibrate_self_takes_a_slow_static_survey_and_says_why_it_writes_nothing(tmp_path: Path) -> None:
    """One report a second, no elevation, each point its own capture: calibrate --self reads
    it (each anchor's epoch window grows to hold three reports) and, the boards being true,
    finds no parameter the ten points determine -- each held with its value and uncertainty."""
    site_file, points = survey(tmp_path)
    done = calibrate_self(site_file, points, tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.splitlines()[-1])
    assert not summary["written"] and summary["verdict"].startswith("not written"), summary["verdict"]


def test_calibrate_self_names_anchors_that_report_too_slowly(tmp_path: Path) -> None:
    """A report every 5 s: no window up to 10 s holds three, and the refusal says that -- not
    "record longer"."""
    site_file, points = survey(tmp_path, rate_hz=0.2, points=POINTS[:4])
    done = calibrate_self(site_file, points, tmp_path)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and "report too slowly" in last and "every 5.0 s" in last, done.stderr
    assert "record longer" not in last
