"""Radio profiles: the file and its loader, the emulator's measured XPLR-AOA errors, the fitter on
walks the project makes (tests/aoa_walks.py), rfhoming radio-fit, and --radio on the commands.
Never reads the real recordings: they are for the benches."""

from __future__ import annotations

import csv
import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomlkit
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aoa_walks import LOOP, SITE, TAG, reports, walk, wire
from rfhoming.emulator import scenario as scenarios
from rfhoming.emulator.aoa_error import MeasuredAoa
from rfhoming.host.angle_residuals import residuals
from rfhoming.host.aoa_fit import Walk, fit_aoa
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.radio_fit import Recording, RadioFitError, fit, write
from rfhoming.host.site import parse as parse_site
from rfhoming.protocol.radio_profile import (
    AngleError,
    AoaProfile,
    Missing,
    ProfileError,
    load,
    resolve,
    to_toml,
)
from rfhoming.protocol.uconnect import Dialect, encode_angle_event

ROOT = Path(__file__).resolve().parents[1]
RFHOMING = [sys.executable, "-m", "rfhoming"]

SITE4 = parse_site({
    "site": {"name": "test-room-4"},
    "anchors": {"west": {"id": "CCF9578E0A01", "position": [0.0, 3.0, 2.3], "yaw_deg": 0.0},
                "south": {"id": "CCF9578E0A02", "position": [6.0, 0.0, 2.3], "yaw_deg": 90.0},
                "east": {"id": "CCF9578E0A03", "position": [12.0, 3.0, 2.3], "yaw_deg": 180.0},
                "north": {"id": "CCF9578E0A04", "position": [6.0, 6.0, 2.3], "yaw_deg": -90.0}},
    "tags": {TAG: {"height": 1.1}},
})
"""A wall anchor in the middle of each wall, as the real recordings' room."""


# -- the file --------------------------------------------------------------------------

GOOD = """\
[profile]
name = "room"

[recordings.walk1]
capture = "capture:walk1.pcapng"
truth = "walk1.csv"

[aoa.azimuth]
white_sigma_deg = 2.0
curve_at_deg = [0.0, 45.0]
compression_deg = [0.0, -8.0]

[aoa.sources."azimuth.white_sigma_deg"]
recordings = ["walk1"]
how = "by hand"

[aoa.sources."azimuth.compression_deg"]
recordings = ["walk1"]
how = "by hand"

[rssi.ble.exponent]
mean = 1.9
sd = 0.2
low = 1.1
high = 3.1
pivot_m = 5.9
near_m = 1.0
far_m = 12.0
source = "by hand"

[rssi.ble.offset]
sd_db = 2.3
source = "by hand"

[rssi.ble.shadowing]
sd_db = 3.3
distance_m = 1.4
source = "by hand"

[rssi.ble.residual]
sd_db = 2.9
time_s = 1.6
white_sd_db = 3.3
source = "by hand"
"""


def write_profile(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "p.toml"
    path.write_text(text)
    return path


def test_a_profile_file_loads_with_its_rssi_tables(tmp_path: Path) -> None:
    profile = load(write_profile(tmp_path, GOOD))
    assert profile.name == "room" and list(profile.recordings) == ["walk1"]
    assert profile.aoa is not None and profile.aoa.azimuth.white_sigma_deg == 2.0
    assert profile.aoa.azimuth.compression(22.5) == pytest.approx(-4.0)
    assert list(profile.rssi) == ["ble"] and profile.rssi["ble"].shadowing.sd_db == 3.3  # read by rssi_profile.py


def test_a_profile_is_parsed_once_while_its_file_is_unchanged(tmp_path: Path) -> None:
    """campaign --radio: every job names the profile; a worker parses it once, and again once it is edited."""
    path = write_profile(tmp_path, GOOD)
    first = load(path)
    assert load(path) is first and load(str(path)) is first
    path.write_text(GOOD.replace("white_sigma_deg = 2.0", "white_sigma_deg = 3.0"))
    assert load(path).aoa is not None and load(path).aoa.azimuth.white_sigma_deg == 3.0  # type: ignore[union-attr]


@pytest.mark.parametrize("change, named", [
    (("white_sigma_deg = 2.0", "white_sigma_deg = -1.0"), "white_sigma_deg = -1.0"),
    (("white_sigma_deg = 2.0", "white_sigma = 2.0"), "white_sigma"),
    (("white_sigma_deg = 2.0", 'white_sigma_deg = "lots"'), "white_sigma_deg"),
    (("[rssi.ble.exponent]", "[weather]"), "[weather]"),
    (("sd_db = 2.3", "sd_db = -2.3"), "rssi.ble.offset"),
    (('name = "room"', 'name = "room"\nformat = 2'), "format"),
    (("[profile]\nname = \"room\"\n", ""), "[profile]"),
    (("compression_deg = [0.0, -8.0]", "compression_deg = [0.0, -8.0]\nbias_deg = 1.0"), "azimuth.bias_deg"),
    (('recordings = ["walk1"]\nhow = "by hand"\n\n[aoa.sources."azimuth.compression_deg"]',
      'recordings = ["walk9"]\nhow = "by hand"\n\n[aoa.sources."azimuth.compression_deg"]'), "walk9"),
    (("compression_deg = [0.0, -8.0]", "compression_deg = [0.0, -4.0, -8.0]"), "compression_deg"),
    (("curve_at_deg = [0.0, 45.0]", "curve_at_deg = [45.0, 0.0]"), "curve_at_deg"),
    (("[aoa.sources.", "[aoa.missing]\nrate_low = 0.2\nrate_high = 0.1\n\n[aoa.sources."), "rate_high"),
    (("[profile]", "[profile"), "not valid TOML"),
])
def test_a_bad_profile_fails_with_one_line_naming_the_key(tmp_path: Path, change: tuple[str, str], named: str) -> None:
    old, new = change
    assert old in GOOD
    with pytest.raises(ProfileError) as caught:
        load(write_profile(tmp_path, GOOD.replace(old, new, 1)))
    message = str(caught.value)
    assert "\n" not in message and named in message, message


def test_rssi_must_be_tables(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match=r"\[rssi\] must hold tables"):
        load(write_profile(tmp_path, "rssi = 3\n" + GOOD[:GOOD.index("[rssi.ble.exponent]")]))


def test_no_such_profile_says_what_radio_takes(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match="ideal, measured"):
        load(tmp_path / "absent.toml")
    assert resolve("ideal") is None


def test_the_shipped_profile_has_a_recording_or_a_reason_for_every_figure() -> None:
    profile = load("measured")
    assert profile.aoa is not None and len(profile.recordings) >= 2
    raw = to_toml(profile)["aoa"]
    for table in ("azimuth", "elevation", "missing"):
        for key in raw[table]:
            figure = f"{table}.{key}"
            assert key == "curve_at_deg" or figure in profile.aoa.sources or figure in profile.aoa.assumed, figure
    assert "carried_board" in profile.aoa.assumed  # the robot's board: no recording, said so


def test_a_written_profile_reads_back_the_same(tmp_path: Path) -> None:
    profile = load("measured")
    write(profile, tmp_path / "copy.toml")
    again = load(tmp_path / "copy.toml")
    assert again.aoa == profile.aoa and again.recordings == profile.recordings and again.header == profile.header


# -- the emulator's measured errors ------------------------------------------------------

BOARD = (0.0, 3.0, 2.3, 0.0)


def only(**figures: float) -> AoaProfile:
    return AoaProfile(azimuth=AngleError(**figures), elevation=AngleError())


def test_the_error_stays_put_while_the_tag_stands_and_comes_back_with_place_and_heading() -> None:
    board = MeasuredAoa(only(field_sigma_deg=5.0, field_length_m=1.0, field_heading_m=1.0),
                        "west", np.random.default_rng(1), room_seed=7)
    here, there = (4.0, 3.0, 1.1, 0.0), (7.0, 4.5, 1.1, 0.0)

    def error(t: float, pose: tuple[float, float, float, float]) -> float:
        got = board.report(TAG, t, 10.0, -20.0, BOARD, pose)
        assert got is not None
        return got[0] - 10.0

    standing = [error(t, here) for t in np.arange(0.0, 60.0, 0.5)]
    assert max(standing) - min(standing) < 1e-9  # tens of seconds standing: one error
    away = error(61.0, there)
    back = error(90.0, here)
    turned = error(91.0, (*here[:3], math.pi))
    assert back == pytest.approx(standing[0]) and away != pytest.approx(back)
    assert turned != pytest.approx(back)  # the carrier's body faces the other way


def test_a_new_room_seed_is_another_room() -> None:
    profile = only(field_sigma_deg=5.0, field_length_m=1.0)
    errors = [MeasuredAoa(profile, "west", np.random.default_rng(1), room).report(TAG, 0.0, 0.0, 0.0, BOARD,
                                                                                   (4.0, 3.0, 1.1, 0.0))
              for room in (1, 1, 2)]
    assert errors[0] == errors[1] != errors[2]


@pytest.mark.parametrize("true_deg", [60.0, -60.0])
def test_compression_pulls_wide_angles_toward_boresight(true_deg: float) -> None:
    board = MeasuredAoa(only(curve_at_deg=(0.0, 60.0), compression_deg=(0.0, -10.0)), "w", np.random.default_rng(0), 0)
    got = board.report(TAG, 0.0, true_deg, 0.0, BOARD, (1.0, 1.0, 1.0, 0.0))
    assert got is not None and got[0] == pytest.approx(math.copysign(50.0, true_deg))


def test_events_are_lost_at_the_drawn_rate_in_runs() -> None:
    profile = AoaProfile(missing=Missing(rate_low=0.2, rate_high=0.2, burst_events=3.0))
    board = MeasuredAoa(profile, "w", np.random.default_rng(3), 0)
    lost = np.array([board.report(TAG, t * 0.025, 0.0, 0.0, BOARD, (1.0, 1.0, 1.0, 0.0)) is None
                     for t in range(40_000)])
    runs = np.diff(np.flatnonzero(np.diff(np.r_[False, lost, False].astype(int))))[::2]
    assert lost.mean() == pytest.approx(0.2, abs=0.02)
    assert runs.mean() == pytest.approx(3.0, rel=0.15)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_skew_stretches_the_outward_side_and_keeps_the_median(side: float) -> None:
    board = MeasuredAoa(only(white_sigma_deg=4.0, curve_at_deg=(0.0, 60.0), skew=(0.5, 0.5)), "w",
                        np.random.default_rng(5), 0)
    errors = side * np.array([board.report(TAG, t * 0.02, side * 30.0, 0.0, BOARD, (1.0, 1.0, 1.0, 0.0))[0]  # type: ignore[index]
                              for t in range(20_000)]) - 30.0
    low, mid, high = np.percentile(errors, [15.87, 50, 84.13])
    assert mid == pytest.approx(0.0, abs=0.15)
    assert high - mid == pytest.approx(6.0, rel=0.1) and mid - low == pytest.approx(2.0, rel=0.15)


def test_anchors_under_the_measured_profile_report_its_errors_and_lose_events() -> None:
    from rfhoming.campaigns import kit

    ideal, measured = (kit.record(seed=2, duration=6.0, radio=radio) for radio in ("ideal", "measured"))
    assert all(t["error_model"] == "radio profile" for t in measured.anchors_truth)
    assert all("az_scale" in t for t in ideal.anchors_truth)
    counts = {name: len(rec.events) for name, rec in (("ideal", ideal), ("measured", measured))}
    assert 0 < counts["measured"] < counts["ideal"]  # the profile loses events; the ideal boards do not


# -- the fitter ----------------------------------------------------------------------------

def simulated(profile: AoaProfile, walks: int, seed: int, site: object = SITE4) -> list[Walk]:
    """``walks`` walks of one loop through one room (the same field), each its own seed."""
    out = []
    for k in range(walks):
        path = walk(100.0 * k)
        events = reports(profile, path, seed=seed * 100 + k, room_seed=seed, site=site)  # type: ignore[arg-type]
        out.append(Walk(f"w{k}", path, residuals(site, events, path)))  # type: ignore[arg-type]
    return out


KNOWN = AngleError(bias_deg=2.0, field_sigma_deg=4.0, field_length_m=1.0, field_heading_m=1.0,
                   slow_sigma_deg=3.0, slow_time_s=0.8, white_sigma_deg=2.0)


def assert_recovered(fitted: AngleError, known: AngleError) -> None:
    assert fitted.bias_deg == pytest.approx(known.bias_deg, abs=1.5)
    for key in ("field_sigma_deg", "slow_sigma_deg", "white_sigma_deg"):
        assert getattr(fitted, key) == pytest.approx(getattr(known, key), rel=0.35, abs=0.8), key
    assert known.field_length_m / 2.5 <= fitted.field_length_m <= known.field_length_m * 2.5
    assert known.slow_time_s / 2.5 <= fitted.slow_time_s <= known.slow_time_s * 2.5


def test_a_profile_fitted_to_walks_with_known_errors_recovers_them() -> None:
    fitted, _ = fit_aoa(simulated(AoaProfile(azimuth=KNOWN, missing=Missing(0.0, 0.1, 1.5)), walks=5, seed=3))
    assert_recovered(fitted.azimuth, KNOWN)
    assert fitted.missing.rate_high == pytest.approx(0.1, abs=0.04) and fitted.missing.burst_events > 1.2
    assert "azimuth.slow_sigma_deg" in fitted.sources  # two walks of one place: the field is told from the wander


SITE8 = parse_site({
    "site": {"name": "test-room-8"},
    "anchors": {f"a{k}": {"id": f"CCF9578E0B{k:02d}", "position": [x, y, 2.3], "yaw_deg": yaw}
                for k, (x, y, yaw) in enumerate(((0.0, 1.5, 0.0), (0.0, 4.5, 0.0), (12.0, 1.5, 180.0),
                                                 (12.0, 4.5, 180.0), (3.0, 0.0, 90.0), (9.0, 0.0, 90.0),
                                                 (3.0, 6.0, -90.0), (9.0, 6.0, -90.0)))},
    "tags": {TAG: {"height": 1.1}},
})
"""Two anchors on each wall: each board's field is one draw, and a fit needs several."""


@pytest.mark.slow
@settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(bias=st.floats(-4, 4), field=st.floats(2.0, 6.0), slow=st.floats(1.5, 4.0), white=st.floats(0.5, 3.0),
       compression=st.floats(-15.0, 0.0), seed=st.integers(1, 1000))
def test_fitting_recovers_any_known_parameters(bias: float, field: float, slow: float, white: float,
                                               compression: float, seed: int) -> None:
    """The sizes of the parts, whatever they are, each to a third of the whole variance: the
    walks cross one room, whose field is one draw per board, so the split between field and
    wander is only as good as that draw (tests/test_radio_profile.py's fast sibling checks the
    field's length and the wander's time on one seed, with a margin)."""
    known = AngleError(bias_deg=bias, field_sigma_deg=field, field_length_m=0.6, field_heading_m=1.0,
                       slow_sigma_deg=slow, slow_time_s=0.6, white_sigma_deg=white,
                       curve_at_deg=(0.0, 30.0, 60.0), compression_deg=(0.0, compression / 4, compression))
    fitted, _ = fit_aoa(simulated(AoaProfile(azimuth=known), walks=5, seed=seed, site=SITE8))
    a = fitted.azimuth
    total = field**2 + slow**2 + white**2
    assert a.bias_deg == pytest.approx(bias, abs=1.5)
    assert a.field_sigma_deg**2 + a.slow_sigma_deg**2 + a.white_sigma_deg**2 == pytest.approx(total, rel=0.25)
    for part, size in (("field_sigma_deg", field), ("slow_sigma_deg", slow), ("white_sigma_deg", white)):
        assert getattr(a, part) ** 2 == pytest.approx(size**2, abs=0.35 * total), part  # its share of the whole
    assert a.compression(60.0) == pytest.approx(compression, abs=3.0 + field / 2)  # a bin holds a little field


def test_compression_and_bursts_are_found() -> None:
    known = dataclasses.replace(KNOWN, curve_at_deg=(0.0, 30.0, 60.0), compression_deg=(0.0, -2.0, -14.0),
                                burst_rate_hz=0.1, burst_duration_s=0.5, burst_offset_min_deg=25.0, burst_outward=0.0)
    fitted, _ = fit_aoa(simulated(AoaProfile(azimuth=known), walks=5, seed=4))
    a = fitted.azimuth
    assert a.compression(60.0) == pytest.approx(-14.0, abs=4.0) and a.compression(30.0) == pytest.approx(-2.0, abs=2.5)
    assert a.burst_rate_hz == pytest.approx(0.1, rel=0.5) and a.burst_outward < 0.25


def test_one_walk_cannot_tell_the_field_from_the_wander_and_says_so() -> None:
    path = walk(0.0, loop=LOOP[:3])  # two sides of the room, never back
    fitted, _ = fit_aoa([Walk("w", path, residuals(SITE4, reports(AoaProfile(azimuth=KNOWN), path, seed=5, site=SITE4),
                                                   path))])
    assert "azimuth.slow_sigma_deg" in fitted.assumed and fitted.azimuth.slow_sigma_deg == 0.0
    total = math.hypot(fitted.azimuth.field_sigma_deg, fitted.azimuth.white_sigma_deg)
    assert total == pytest.approx(math.hypot(KNOWN.field_sigma_deg, KNOWN.slow_sigma_deg, KNOWN.white_sigma_deg),
                                  rel=0.35)


def test_recordings_of_another_site_are_refused() -> None:
    path = walk(0.0)
    stranger = [e._replace(anchor="000000000BAD") for e in reports(AoaProfile(), path, seed=1)]
    with pytest.raises(RadioFitError, match="none of its angle events"):
        fit(SITE, [Recording("w", "capture:w.pcapng", stranger, path, "w.csv")], "p")


# -- rfhoming radio-fit ----------------------------------------------------------------------

def recorded(tmp_path: Path, name: str, start_s: float, seed: int) -> tuple[Path, Path]:
    """A capture of the two anchors (one interface each, +UUDF lines as a 1.0 board prints them)
    and its waypoint file (ms and cm, as the data set's)."""
    path = walk(start_s)
    capture = CaptureWriter(tmp_path / f"{name}.pcapng")
    names = {a.id: a.name for a in SITE.anchors}
    for anchor in SITE.anchors:
        capture.describe(anchor.name, kind="xplr-aoa")
    profile = AoaProfile(azimuth=KNOWN, elevation=AngleError(bias_deg=-4.0, white_sigma_deg=3.0))
    for reading in reports(profile, path, seed=seed):
        capture.tap(names[reading.anchor], "in", reading.t, encode_angle_event(wire(reading), Dialect.V1_0))
    capture.close()
    truth = tmp_path / f"{name}.csv"
    with truth.open("w", newline="") as f:
        rows = csv.writer(f)
        for w in path.waypoints:
            rows.writerow([round(w.arrive_s * 1000), "NaN" if w.leave_s == w.arrive_s else round(w.leave_s * 1000),
                           round(w.x * 100), round(w.y * 100)])
    return capture.path, truth


@pytest.fixture
def site_file(tmp_path: Path) -> Path:
    path = tmp_path / "site.toml"
    path.write_text(tomlkit.dumps({
        "site": {"name": "test-room"},
        "anchors": {a.name: {"id": a.id, "position": list(a.position), "yaw_deg": a.yaw_deg} for a in SITE.anchors},
        "tags": {TAG: {"height": 1.1}}}))
    return path


def radio_fit(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*RFHOMING, "radio-fit", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=600, check=False)


def test_radio_fit_writes_a_profile_every_scenario_can_take(tmp_path: Path, site_file: Path) -> None:
    (a, ta), (b, tb) = recorded(tmp_path, "walk1", 0.0, 1), recorded(tmp_path, "walk2", 200.0, 2)
    done = radio_fit(site_file, "--from", f"capture:{a}", "--truth", ta, "--from", f"capture:{b}", "--truth", tb,
                     "-o", "room.toml", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    profile = load(tmp_path / "room.toml")
    assert list(profile.recordings) == ["walk1", "walk2"] and profile.recordings["walk2"].truth == str(tb)
    assert profile.aoa is not None and profile.aoa.elevation.bias_deg == pytest.approx(-4.0, abs=1.0)
    assert scenarios.load("kit-room", radio=str(tmp_path / "room.toml")).radio_name == "room"
    assert "calibrated (host/aoa_calibrate.py)" in profile.aoa.sources["azimuth.slow_time_s"].how  # the CLI's board
    assert not profile.rssi


@pytest.mark.slow  # a second radio-fit process; the one above stays quick
def test_radio_fit_copies_the_rssi_tables_it_is_told(tmp_path: Path, site_file: Path) -> None:
    a, ta = recorded(tmp_path, "walk1", 0.0, 1)
    done = radio_fit(site_file, "--from", f"capture:{a}", "--truth", ta, "--rssi-from", "measured", "-o", "room.toml",
                     cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    mine, measured = load(tmp_path / "room.toml"), load("measured")
    assert mine.rssi and {k: v.to_table() for k, v in mine.rssi.items()} == {k: v.to_table() for k, v in measured.rssi.items()}


@pytest.mark.parametrize("extra, says", [
    (["--truth", "walk1.csv", "--truth", "walk1.csv"], "2 --truth for 1 --from"),
    (["--truth", "absent.csv"], "absent.csv"),
    (["--rssi-from", "absent.toml"], "--rssi-from"),
])
def test_radio_fit_fails_fast_with_one_line(tmp_path: Path, site_file: Path, extra: list[str], says: str) -> None:
    capture, _ = recorded(tmp_path, "walk1", 0.0, 1)
    done = radio_fit(site_file, "--from", f"capture:{capture}", *extra, "-o", "room.toml", cwd=tmp_path)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and says in lines[-1] and not (tmp_path / "room.toml").exists(), done.stderr


# -- --radio --------------------------------------------------------------------------------

def test_a_scenario_carries_its_radio() -> None:
    assert scenarios.load("s0-open").radio is None
    measured = scenarios.load("s0-open", radio="measured", seed=4)
    assert measured.radio is not None and measured.radio_name == "measured" and measured.room_seed == 4
    with pytest.raises(scenarios.ScenarioError, match="--radio ideal"):
        scenarios.load("s0-open", aoa_preset=2, radio="measured")
    with pytest.raises(scenarios.ScenarioError, match="no radio profile"):
        scenarios.load("s0-open", radio="absent.toml")


@pytest.mark.parametrize("argv, radio", [
    (["emulate", "s0-open"], "measured"),  # demo and emulate show real radios unless told otherwise
    (["emulate", "s0-open", "--aoa-preset", "2"], "ideal"),  # a preset is S0's idealised noise
    (["emulate", "s0-open", "--radio", "ideal"], "ideal"),
])
def test_emulate_takes_measured_radios_by_default(monkeypatch: pytest.MonkeyPatch, argv: list[str], radio: str) -> None:
    from rfhoming.cli.commands import emulate
    from rfhoming.cli.main import main

    got = []

    def load(*_: object, **kwargs: object) -> None:
        got.append(kwargs["radio"])
        raise scenarios.ScenarioError("stop here")

    monkeypatch.setattr(emulate, "load", load)
    assert main(argv) == 2 and got == [radio]


def test_demo_takes_measured_radios_by_default_and_campaigns_their_papers() -> None:
    from rfhoming.cli.main import build_parser

    parser = build_parser()
    assert parser.parse_args(["demo"]).radio == "measured"
    assert parser.parse_args(["campaign", "s1-dock"]).radio == "ideal"


def test_campaigns_take_the_radio_and_leave_it_out_when_ideal() -> None:
    from rfhoming.campaigns import s1

    jobs = s1.CAMPAIGN.make_jobs(2, 0, "measured")
    assert jobs and all(job.kwargs["radio"] == "measured" for job in jobs)
    assert all("radio" not in job.kwargs for job in s1.CAMPAIGN.make_jobs(2, 0))


def test_emulate_refuses_a_radio_that_is_not_there(tmp_path: Path) -> None:
    done = subprocess.run([*RFHOMING, "emulate", "s0-open", "--radio", "absent.toml"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 2 and "give ideal or measured" in done.stderr.strip().splitlines()[-1]


def test_a_demo_runs_under_the_measured_radios_and_says_so(tmp_path: Path) -> None:
    from rfhoming.demo import run_demo
    from rfhoming.host.homing.config import Config

    summary = run_demo("s0-open", 1, tmp_path / "out", Config(), "4,3", in_process=True, radio="measured")
    assert summary["radio"] == "measured" and summary["success"]
