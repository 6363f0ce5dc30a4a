"""The fixed-anchor localiser holds up where real recordings broke it -- the EKF recovers from a jump, calibration
writes only what its points determine and what the site file accepts, one tag carried from
point to point calibrates, the cone angle model, robust fits, self-calibration."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rfhoming.host import site as sites
from rfhoming.host.estimation.anchors3d import board_angles
from rfhoming.host.locate import Locator
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.protocol.uconnect import AngleEvent
from test_locate import SITE

TAG = "CCF9578E0D8A"  # the kit site's "cart", height 1.0 m


def synthetic(site: sites.Site, path, duration: float, *, rate_hz: float = 25.0, noise_deg: float = 1.0,
              seed: int = 0, model: str | None = None, tag: str = TAG, true=None):
    """Angle events of one tag at ``path(t)`` (x, y, z) from every anchor of ``site`` (their
    nominal poses, or ``true``: anchor id -> (rotation, az_scale, az_bias)), integer degrees
    like the board's."""
    rng = np.random.default_rng(seed)
    events = []
    for k in range(int(duration * rate_hz)):
        for j, a in enumerate(site.anchors):
            t = k / rate_hz + j * 0.004
            rot, scale, bias = true[a.id] if true else (a.rotation(), 1.0, 0.0)
            d = rot.T @ (np.asarray(path(t)) - np.array(a.position))
            if d[0] <= 0:
                continue
            m = model or getattr(a, "angle_model", "spherical")
            az, el = board_angles(d) if m == "spherical" else board_angles(d, m)
            az = scale * az + bias + rng.normal(0, noise_deg)
            el = el + rng.normal(0, 2 * noise_deg)
            events.append(bearing_of(round(t, 6), AngleEvent(tag, -50, round(max(-90, min(90, az))),
                                                             round(max(-90, min(90, el))), -50, 37, a.id, "",
                                                             int(t * 1000))))
    return events


def run(locator: Locator, events):
    out = []
    for e in events:
        out += locator.feed(e)
    return out + locator.flush()


def test_ekf_recovers_when_the_tag_jumps():
    """Old code: one fix, every pair refused without a count, the track kept alive (its time
    advanced) and coasting until its covariance grew wide enough: metres off for seconds."""
    site = sites.load(SITE)
    a, b = np.array([3.0, 2.0, 1.0]), np.array([9.0, 4.5, 1.0])
    events = synthetic(site, lambda t: a if t < 4.0 else b, 10.0)
    loc = Locator(site, tracker="ekf", reorder_s=0.0)
    out = run(loc, events)
    settled = [p for p in out if p.t > 4.6]  # 25 refusals (0.25 s) and a fresh 0.3 s window
    assert settled and all(np.linalg.norm(p.point[:2] - b[:2]) < 0.5 for p in settled)
    assert loc.counters["restarts"] >= 1
    before = [p for p in out if 2.0 < p.t < 4.0]
    assert all(np.linalg.norm(p.point[:2] - a[:2]) < 0.3 for p in before)


def test_a_replayed_angle_stream_without_set_up_is_no_false_alarm(tmp_path):
    """Old code: each driver sent AT into the replay, waited, and reported a wiring problem
    (and after the wake timeout "set-up failed ... is this an XPLR-AOA") though every event was used."""
    import json
    import subprocess

    from rfhoming.host.capture import CaptureWriter
    from test_locate import RFHOMING

    path = tmp_path / "angles.pcapng"
    writer = CaptureWriter(path)
    anchors = (("west", "CCF9578E0A01", -20), ("east", "CCF9578E0A02", 25), ("south", "CCF9578E0A03", 10))
    for port, _, _ in anchors:
        writer.describe(port, kind="xplr-aoa")
    for k in range(300):
        for port, anchor, az in anchors:
            line = f'+UUDF:{TAG},-42,{az},-10,-43,37,"{anchor}","",{k * 20}\r\n'
            writer.tap(port, "in", 1000.0 + k * 0.02, line.encode())
    writer.close()
    cli = subprocess.run([*RFHOMING, "-v", "locate", str(SITE), "--from", f"capture:{path}"],
                         capture_output=True, text=True, timeout=60)
    assert cli.returncode == 0, cli.stderr
    counters = [json.loads(line) for line in cli.stderr.splitlines() if line.startswith('{"kind": "counters"')]
    assert len(counters) == 3 and all(c["problem"] is None for c in counters), counters
    assert "set-up failed" not in cli.stderr and "AT" not in cli.stderr.replace("ATTR", "")
    notes = [line for line in cli.stderr.splitlines() if "no set-up exchange" in line]
    assert len(notes) == 1 and "west, east, south" in notes[0]
    summary = json.loads(cli.stdout.splitlines()[-1])
    assert summary["events"] == 900


ONE_HEIGHT = {"CCF9578E0C01": (2.0, 1.5, 1.0), "CCF9578E0C02": (6.0, 3.0, 1.0), "CCF9578E0C03": (10.0, 4.5, 1.0),
              "CCF9578E0C04": (3.5, 4.8, 1.0), "CCF9578E0C05": (9.0, 1.2, 1.0)}


def _static_events(site, points, elevation=lambda el, rng: el + rng.normal(0, 3), az_scale=1.0, seed=1):
    rng = np.random.default_rng(seed)
    events = []
    for tag, p in points.items():
        for k in range(60):
            for a in site.anchors:
                az, el = board_angles(a.rotation().T @ (np.array(p) - np.array(a.position)))
                az = round(max(-90, min(90, az_scale * az + rng.normal(0, 2))))
                events.append(bearing_of(k * 0.02, AngleEvent(tag, -50, az, round(elevation(el, rng)), -50, 37, a.id, "", 0)))
    return events


def test_calibration_on_points_at_one_height_writes_a_site_file_locate_accepts(tmp_path):
    """Old code: elevation fitted from points at one height; a board whose elevation reads
    mostly a reflection gave el_scale 0.23, which the site file refuses (0.5..2)."""
    from rfhoming.host.calibration import calibrate

    site = sites.load(SITE)
    events = _static_events(site, ONE_HEIGHT, elevation=lambda el, rng: 0.2 * el - 15 + rng.normal(0, 6))
    fits = calibrate(site, events, ONE_HEIGHT)
    path = tmp_path / "site.toml"
    path.write_text(SITE.read_text())
    sites.write_calibration(path, {f.anchor: f.calibration for f in fits})
    loaded = sites.load(path)  # SiteError on the old code
    assert all(a.calibration.el_scale == 1.0 and a.calibration.el_bias_deg == 0.0 for a in loaded.anchors)
    assert all("one height" in (getattr(f, "held", None) or {}).get("el_scale", "") for f in fits)


def test_calibration_refuses_a_fit_beyond_the_site_file_limits():
    from rfhoming.host.calibration import CalibrationError, calibrate

    site = sites.load(SITE)
    points = {**ONE_HEIGHT, "CCF9578E0C06": (6.0, 5.0, 1.5)}
    with pytest.raises(CalibrationError, match="limit"):
        calibrate(site, _static_events(site, points, az_scale=2.6), points)


def test_azimuth_only_calibration_holds_elevation():
    from rfhoming.host.calibration import calibrate

    site = sites.load(SITE)
    points = {**ONE_HEIGHT, "CCF9578E0C06": (6.0, 5.0, 1.5), "CCF9578E0C07": (8.0, 2.0, 0.3)}
    events = _static_events(site, points, elevation=lambda el, rng: 1.2 * el + 4 + rng.normal(0, 2), az_scale=1.1)
    full = calibrate(site, events, points)
    assert all(abs(f.calibration.el_bias_deg - 4) < 2.5 for f in full)
    only = calibrate(site, events, points, azimuth_only=True)
    assert all(f.calibration.el_scale == 1.0 and f.calibration.el_bias_deg == 0.0 for f in only)
    assert all(abs(f.calibration.az_scale - 1.1) < 0.05 for f in only)


def _carried(points, dwell_s=8.0, walk_s=3.0):
    """One tag carried from point to point: dwell, walk, dwell... (x, y, z) at t."""
    legs = []
    t = 1.0
    for k, p in enumerate(points):
        legs.append((t, t + dwell_s, np.array(p), np.array(points[min(k + 1, len(points) - 1)])))
        t += dwell_s + walk_s

    def at(t):
        if t < legs[0][0]:
            return legs[0][2]
        for _start, end, p, q in legs:
            if t <= end:
                return p
            if t <= end + walk_s:
                return p + (q - p) * (t - end) / walk_s
        return legs[-1][2]
    return at, t


def test_one_tag_carried_from_point_to_point_calibrates_from_found_dwells():
    """Old code: the points file maps a tag to one point, so this session cannot be described."""
    from rfhoming.host.calibration import Point, assign_dwells, calibrate

    site = sites.load(SITE)
    where = [(2.0, 1.5, 0.8), (6.0, 3.0, 0.3), (10.0, 4.5, 1.2), (3.5, 4.8, 0.5), (9.0, 1.2, 1.0)]
    path, duration = _carried(where)
    truth = {a.id: (a.rotation(), 1.08, 2.0) for a in site.anchors}
    events = synthetic(site, path, duration, noise_deg=1.5, true=truth, tag=TAG)
    points, report = assign_dwells(events, [Point(TAG, p) for p in where])
    assert len(report) == 1 and "5 dwells found" in report[0]
    for p, (start, _, _, _) in zip(points, [(1.0 + k * 11.0, 0, 0, 0) for k in range(5)]):
        assert start <= p.start_s <= start + 2.0 and p.end_s - p.start_s >= 5.0
    fits = calibrate(site, events, points, azimuth_only=True)
    assert all(abs(f.calibration.az_scale - 1.08) < 0.04 and abs(f.calibration.az_bias_deg - 2.0) < 1.0 for f in fits)
    with pytest.raises(Exception, match="dwells"):
        assign_dwells(events, [Point(TAG, p) for p in where[:4]])


NOMINAL_YAW = {"west": 0.0, "east": 180.0, "south": 90.0, "north": -90.0}


@pytest.mark.slow  # 8 s: the self-calibration's own quick tests stay in the inner loop
def test_self_calibration_recovers_the_emulated_boards_hidden_errors():
    """The emulator draws each board's azimuth scale, bias and mounting yaw, and elevation
    errors, from the seed and tells the host nothing; the walk of three tags (of known heights)
    over the room gives them back with elevation fitted, up to the gauge (the scales' geometric
    mean). By default elevation is held (reported once for every anchor) and the tracker's
    check is not run: the boards' hidden elevation scales then leak into the azimuth fit (north's
    scale 1.04 for 0.95), yet it still cuts the held-out azimuth rms by half and is written."""
    from rfhoming.campaigns.kit import record
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    rec = record(seed=4, duration=30.0)
    truth = {t["device"]: t for t in rec.anchors_truth}
    gauge = math.exp(np.mean([math.log(t["az_scale"]) for t in truth.values()]))
    held = self_calibrate(site, [rec.events])
    assert held.write and held.held_out.miss_after_m < held.held_out.miss_before_m
    assert held.held["el_scale"].startswith("held by default") and "el_bias_deg" in held.held
    assert not held.elevation_fitted and math.isnan(held.foresight[0])
    assert all(f.calibration.el_scale == 1.0 and f.calibration.el_bias_deg == 0.0 for f in held.fits)
    assert held.held_out.az_rms_after_deg < 0.5 * held.held_out.az_rms_before_deg
    result = self_calibrate(site, [rec.events], elevation=True)
    assert result.write and result.held_out.miss_after_m < result.held_out.miss_before_m
    assert result.elevation_fitted and result.foresight[1] > result.foresight[0]
    assert result.rms_after_deg < 0.5 * result.rms_before_deg
    written = 0
    for f in result.fits:  # what is written is the board's; what is held was within a few sd of its default
        t = truth[f.anchor]
        yaw_error = (t["true_yaw_deg"] - NOMINAL_YAW[f.anchor] + 180) % 360 - 180
        bias = t["az_bias_deg"] + t["az_scale"] * yaw_error
        if "az_scale" in f.sigma:
            assert abs(f.calibration.az_scale - t["az_scale"] / gauge) < 0.05 and f.sigma["az_scale"] < 0.03
        else:
            assert f.calibration.az_scale == 1.0 and abs(t["az_scale"] / gauge - 1) < 0.06
        if "az_bias_deg" in f.sigma:
            assert abs(f.calibration.az_bias_deg - bias) < 1.5 and f.sigma["az_bias_deg"] < 1.0
        else:
            assert f.calibration.az_bias_deg == 0.0 and abs(bias) < 1.0
            assert f.held["az_bias_deg"].startswith("not determined")
        written += ("az_scale" in f.sigma) + ("az_bias_deg" in f.sigma)
    assert written >= 6


@pytest.mark.slow
def test_self_calibration_refuses_tags_that_did_not_cover_the_room():
    from rfhoming.campaigns.kit import record
    from rfhoming.host.calibration import CalibrationError
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    still = [e for e in record(seed=4, duration=30.0, calibration=True).events
             if e.tag == "CCF9578E0C02"]  # one tag standing in the middle
    with pytest.raises(CalibrationError, match="did not cover the room"):
        self_calibrate(site, [still])


@pytest.mark.slow
def test_self_calibration_holds_elevation_that_the_data_cannot_determine():
    """High wall anchors over tags all carried at one height nobody gave: the height and the
    elevation bias trade off, so elevation asked for (--fit-elevation) is still held, with the
    reason; the same walk with the height given (--height) fits it, and then the tracker's
    check is run too; without --fit-elevation it is held by default, the check not run."""
    from rfhoming.campaigns.kit import WALL_ROOM, record
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    site = replace(site, anchors=tuple(replace(a, position=(*a.position[:2], 2.3)) for a in site.anchors),
                   tags=tuple(replace(t, height=None) for t in site.tags))
    rec = record(seed=5, duration=40.0, room=WALL_ROOM)
    unknown = self_calibrate(site, [rec.events], elevation=True)
    for f in unknown.fits:
        assert "not observable" in f.held["el_scale"] and "el_scale" not in f.sigma
        assert f.calibration.el_scale == 1.0 and f.calibration.el_bias_deg == 0.0
    given_height = self_calibrate(site, [rec.events], height=WALL_ROOM["tag_height_m"], elevation=True)
    assert any("el_bias_deg" in f.sigma for f in given_height.fits) and given_height.elevation_fitted
    assert given_height.write == (given_height.held_out.improves
                                  and given_height.foresight[1] > given_height.foresight[0])
    if given_height.held_out.improves:
        assert not math.isnan(given_height.foresight[1])
    held = self_calibrate(site, [rec.events], height=WALL_ROOM["tag_height_m"])
    assert not held.elevation_fitted and "el_scale" in held.held and math.isnan(held.foresight[1])
    assert held.write == held.held_out.improves


def test_self_calibration_holds_what_the_caller_names():
    """bench/selfcal_parts.py's variants: a named parameter stays at its default on every anchor,
    with the reason; an unknown name is refused before any fit."""
    from rfhoming.campaigns.kit import record
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    with pytest.raises(ValueError, match="az_scal"):
        self_calibrate(site, [], hold=("az_scal",))
    result = self_calibrate(site, [record(seed=4, duration=30.0).events], hold=("az_scale", "az_compression"))
    for f in result.fits:
        assert f.calibration.az_scale == 1.0 and f.calibration.az_compression == 0.0 and "az_scale" not in f.sigma
        assert f.held["az_scale"] == f.held["az_compression"] == "held by the caller"
    assert result.held["az_scale"] == "held by the caller"


def test_self_calibration_asks_the_tracker_only_when_elevation_is_fitted():
    """The write rule: beating the site on held-out epochs is enough while elevation is held;
    with an elevation fitted, locate's tracker must also foresee the reports better."""
    from rfhoming.host.calibration import AnchorFit
    from rfhoming.host.self_calibration import HeldOut, SelfCalibration

    better = HeldOut(5.0, 4.5, 0.6, 0.5)
    azimuth = [AnchorFit("west", sites.Calibration(), 100, 5.0, 4.5, sigma={"az_bias_deg": 0.5})]
    with_el = [AnchorFit("west", sites.Calibration(), 100, 5.0, 4.5, sigma={"az_bias_deg": 0.5, "el_bias_deg": 1.0})]
    worse_foresight = (-5.2, -5.3)
    assert SelfCalibration(azimuth, 100, 5.0, 4.5, better, "", foresight=worse_foresight).write
    assert SelfCalibration(azimuth, 100, 5.0, 4.5, better, "").write  # not asked: nan
    assert not SelfCalibration(with_el, 100, 5.0, 4.5, better, "", foresight=worse_foresight).write
    assert not SelfCalibration(with_el, 100, 5.0, 4.5, better, "").write
    assert SelfCalibration(with_el, 100, 5.0, 4.5, better, "", foresight=(-5.3, -5.2)).write
    assert not SelfCalibration(azimuth, 100, 5.0, 4.9, HeldOut(5.0, 4.95, 0.6, 0.5), "").write  # under the 2 % cut


@pytest.mark.slow
def test_self_calibration_holds_a_parameter_at_its_bound_and_writes_nothing_worse():
    """One board 50 deg off (beyond the site file's 45 deg bias limit, angles clipped at 90): its
    bias runs to the bound, so it is held with the reason instead of written at the bound, and
    the calibration that is left does not beat the site on held-out epochs: nothing written."""
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    true = {a.id: (a.rotation(), 1.0, 50.0 if a.name == "west" else 0.0) for a in site.anchors}
    events = synthetic(site, lambda t: np.array([6 + 5 * np.sin(0.21 * t), 3 + 2.5 * np.sin(0.37 * t), 1.0]),
                       90.0, rate_hz=10, true=true)
    result = self_calibrate(site, [events])
    west = next(f for f in result.fits if f.anchor == "west")
    assert west.held["az_bias_deg"].startswith("ran to its bound") and west.calibration.az_bias_deg == 0.0
    assert "az_bias_deg" not in west.sigma
    assert not result.write and result.verdict.startswith("not written")


@pytest.mark.slow
def test_self_calibration_that_cannot_help_writes_nothing(tmp_path):
    """Boards with no hidden error: the site file is already right, so no parameter is
    determined away from its default, or no fit beats it on held-out epochs by the margin, and
    nothing is written (one line says why)."""
    from rfhoming.campaigns.kit import record
    from rfhoming.host.self_calibration import self_calibrate

    site = sites.load(SITE)
    perfect = {"mount_error_deg": 0.0, "scale_error": 0.0, "bias_deg": 0.0, "reflection": 0.0}
    rec = record(seed=6, duration=30.0, boards=perfect)
    result = self_calibrate(site, [rec.events])
    assert not result.write and result.verdict.startswith("not written")
    assert not result.changes or result.held_out.az_rms_after_deg > (1 - 0.02) * result.held_out.az_rms_before_deg


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=50, deadline=None)
@given(st.floats(-80, 80), st.floats(-60, 60))
def test_cone_angles_round_trip_and_differ_from_spherical_off_axis(az, el):
    from rfhoming.host.estimation.anchors3d import board_direction

    if math.sin(math.radians(az)) ** 2 + math.sin(math.radians(el)) ** 2 >= 0.99:
        return  # no direction has these cosines
    d = board_direction(az, el, "cone")
    assert abs(np.linalg.norm(d) - 1) < 1e-9
    assert abs(d[1] + math.sin(math.radians(az))) < 1e-9 and abs(d[2] - math.sin(math.radians(el))) < 1e-9
    back = board_angles(d, "cone")
    assert abs(back[0] - az) < 1e-6 and abs(back[1] - el) < 1e-6
    if abs(az) > 20 and abs(el) > 20:  # off both axes the two readings are different directions
        assert np.linalg.norm(d - board_direction(az, el)) > 0.01


@settings(max_examples=15, deadline=None)
@given(st.floats(1.0, 11.0), st.floats(1.0, 5.0), st.floats(0.0, 1.5))
def test_ekf_converges_on_exact_cone_angles(x, y, z):
    from rfhoming.host.estimation.anchors3d import rotation
    from rfhoming.host.estimation.tracking import BearingEkf

    anchors = [((0.0, 3.0, 2.4), 0.0), ((12.0, 3.0, 2.4), 180.0), ((6.0, 0.0, 2.4), 90.0), ((6.0, 6.0, 2.4), -90.0)]
    ekf = BearingEkf(0.1)
    ekf.start(0.0, np.array([x + 0.8, y - 0.6, z + 0.3]), np.eye(3) * 1.0)
    for k in range(200):
        pos, yaw = anchors[k % 4]
        rot = rotation(yaw, -20)
        az, el = board_angles(rot.T @ (np.array([x, y, z]) - np.array(pos)), "cone")
        ekf.update_angles(0.02 * (k + 1), np.array(pos), rot, az, el, 2.0, model="cone")
    assert np.linalg.norm(ekf.x[:3] - np.array([x, y, z])) < 0.05


def test_calibration_chooses_the_boards_angle_model_by_residual():
    from rfhoming.host.calibration import calibrate

    site = sites.load(SITE)
    points = {**ONE_HEIGHT, "CCF9578E0C06": (6.0, 5.0, 1.5), "CCF9578E0C07": (8.0, 2.0, 0.3)}
    rng = np.random.default_rng(3)
    for truth in ("cone", "spherical"):
        events = []
        for tag, p in points.items():
            for k in range(40):
                for a in site.anchors:
                    az, el = board_angles(a.rotation().T @ (np.array(p) - np.array(a.position)), truth)
                    events.append(bearing_of(k * 0.02, AngleEvent(tag, -50, round(az + rng.normal(0, 1)),
                                                                  round(el + rng.normal(0, 1)), -50, 37, a.id, "", 0)))
        fits = calibrate(site, events, points)
        assert {f.angle_model for f in fits} == {truth}
        assert fits[0].rms_by_model[truth] < fits[0].rms_by_model[{"cone": "spherical", "spherical": "cone"}[truth]]


def test_cauchy_loss_keeps_a_reflected_ray_from_pulling_the_fix():
    from rfhoming.host.estimation.anchors3d import locate, make_ray

    site = sites.load(SITE)
    tag = np.array([4.0, 2.0, 1.0])
    rays = []
    for k, a in enumerate(site.anchors):
        az, el = board_angles(a.rotation().T @ (tag - np.array(a.position)))
        if k == 0:
            az += 25.0  # a reflection
        rays.append(make_ray(a.name, a.position, a.rotation(), az, el, 2.0))
    fix = locate(rays, height=1.0, loss="cauchy")
    assert np.linalg.norm(fix.point[:2] - tag[:2]) < 0.15
    assert fix.rms > 2  # the quality says one ray disagreed


@pytest.mark.slow
def test_rts_smoother_beats_the_causal_filter_on_a_recording():
    from rfhoming.campaigns.kit import record
    from rfhoming.host.locate import smooth

    site = sites.load(SITE)
    rec = record(seed=1, duration=20.0)
    raw, cv = (run(Locator(site, reorder_s=0.0, track=False), rec.events),
               run(Locator(site, reorder_s=0.0, tracker="cv"), rec.events))  # the smoother's own model, causal
    smoothed = smooth(raw)

    def error(out):
        return np.mean([np.linalg.norm(p.point[:2] - rec.truth(p.tag, p.t)[:2]) for p in out if p.t > 2])

    assert all(p.smoothed for p in smoothed) and not any(p.smoothed for p in cv)
    assert len(smoothed) == len(raw)
    assert error(smoothed) < 0.9 * error(cv)


def test_rts_smoother_matches_filterpy():
    """Checked against an independent implementation: filterpy's Kalman filter and RTS smoother
    with the same constant-velocity model, start and noise."""
    from filterpy.kalman import KalmanFilter

    from rfhoming.host.estimation.tracking import ConstantVelocity, rts_smooth

    rng = np.random.default_rng(5)
    times = np.cumsum(rng.uniform(0.05, 0.15, 60))
    truth = np.stack([np.sin(times), 0.5 * times, 0.2 * np.cos(times)], axis=1)
    r = np.diag([0.04, 0.09, 0.01])
    z = truth + rng.multivariate_normal(np.zeros(3), r, len(times))
    mine, mine_cov = rts_smooth(times, z, np.repeat(r[None], len(times), 0), accel_psd=0.5, gate=1e9)
    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.x = np.concatenate([z[0], np.zeros(3)])
    kf.P = np.zeros((6, 6))
    kf.P[:3, :3] = r
    kf.P[3:, 3:] = np.eye(3)
    kf.H = np.hstack([np.eye(3), np.zeros((3, 3))])
    kf.R = r
    cv = ConstantVelocity(0.5)
    fs, qs = [np.eye(6)], [np.zeros((6, 6))]
    for dt in np.diff(times):
        f, q = cv._transition(float(dt))
        fs.append(f)
        qs.append(q)
    xs, ps = [kf.x.copy()], [kf.P.copy()]
    for k in range(1, len(times)):
        kf.predict(F=fs[k], Q=qs[k])
        kf.update(z[k])
        xs.append(kf.x.copy())
        ps.append(kf.P.copy())
    smoothed, cov, _, _ = kf.rts_smoother(np.array(xs), np.array(ps), Fs=np.array(fs), Qs=np.array(qs))
    assert np.allclose(mine, smoothed, atol=1e-6)
    assert np.allclose(mine_cov, cov[:, :3, :3], atol=1e-6)


def _capture_of(events, path, site):
    from rfhoming.host.capture import CaptureWriter

    names = {a.id: a.name for a in site.anchors}
    writer = CaptureWriter(path)
    for name in names.values():
        writer.describe(name, kind="xplr-aoa")
    for e in events:
        line = f'+UUDF:{e.tag},-42,{int(e.clockwise_deg)},{int(e.elevation_deg)},-43,37,"{e.anchor}","",{int(e.t * 1000)}\r\n'
        writer.tap(names[e.anchor], "in", 1000.0 + e.t, line.encode())
    writer.close()


@pytest.mark.slow
def test_calibrate_cli_takes_dwells_of_one_carried_tag(tmp_path):
    import json
    import subprocess

    from test_locate import RFHOMING

    site = sites.load(SITE)
    where = [(2.0, 1.5, 0.8), (6.0, 3.0, 0.3), (10.0, 4.5, 1.2), (3.5, 4.8, 0.5), (9.0, 1.2, 1.0)]
    path, duration = _carried(where)
    truth = {a.id: (a.rotation(), 0.93, -3.0) for a in site.anchors}
    _capture_of(synthetic(site, path, duration, noise_deg=1.5, true=truth), tmp_path / "cal.pcapng", site)
    points = tmp_path / "points.toml"
    points.write_text("".join(f'[[dwell]]\ntag = "{TAG}"\nposition = [{x}, {y}, {z}]\n\n' for x, y, z in where))
    cli = subprocess.run([*RFHOMING, "calibrate", str(SITE), "--points", str(points), "--azimuth-only",
                          "--from", f"capture:{tmp_path / 'cal.pcapng'}", "--dry-run"],
                         capture_output=True, text=True, timeout=90)
    assert cli.returncode == 0, cli.stderr
    assert "5 dwells found" in cli.stderr
    report = [json.loads(line) for line in cli.stdout.splitlines()]
    assert len(report) == 4 and all(abs(r["az_scale"] - 0.93) < 0.04 for r in report)
    assert all(r["held"]["el_scale"] == "azimuth-only calibration" for r in report)
    points.write_text(f'[[dwell]]\ntag = "{TAG}"\nposition = [1, 2, 3]\nfrom_s = 5\n')
    bad = subprocess.run([*RFHOMING, "calibrate", str(SITE), "--points", str(points), "--dry-run",
                          "--from", f"capture:{tmp_path / 'cal.pcapng'}"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "from_s and to_s must both be given" in bad.stderr


@pytest.mark.slow
def test_calibrate_self_cli_reports_each_parameter_and_refuses_a_dwell(tmp_path):
    import json
    import subprocess

    from rfhoming.campaigns.kit import record
    from test_locate import RFHOMING

    site = sites.load(SITE)
    _capture_of(record(seed=4, duration=30.0).events, tmp_path / "walk.pcapng", site)
    cli = subprocess.run([*RFHOMING, "calibrate", str(SITE), "--self", "--dry-run",
                          "--from", f"capture:{tmp_path / 'walk.pcapng'}"], capture_output=True, text=True, timeout=300)
    assert cli.returncode == 0, cli.stderr
    assert len(cli.stderr.splitlines()) == 2 and cli.stderr.startswith("rfhoming calibrate: reading 1 recording")
    summary = json.loads(cli.stdout)  # one line: the verdict, each anchor's fit and what was held
    assert "geometric mean 1" in summary["gauge"] and "held-out azimuth rms" in summary["verdict"]
    assert set(summary["anchors"]) == {"west", "east", "south", "north"} and not summary["written"]
    assert summary["held"]["el_scale"].startswith("held by default") and "el_bias_deg" in summary["held"]
    assert all({"el_scale", "el_bias_deg"} <= set(a["held"]) for a in summary["anchors"].values())
    fitted = subprocess.run([*RFHOMING, "calibrate", str(SITE), "--self", "--dry-run", "--fit-elevation",
                             "--from", f"capture:{tmp_path / 'walk.pcapng'}"], capture_output=True, text=True,
                            timeout=300)
    assert fitted.returncode == 0, fitted.stderr
    assert "el_scale" not in json.loads(fitted.stdout)["held"]  # asked for: fitted (or held per anchor, with why)
    verbose = subprocess.run([*RFHOMING, "calibrate", str(SITE), "--self", "--dry-run", "--verbose",
                              "--from", f"capture:{tmp_path / 'walk.pcapng'}"], capture_output=True, text=True,
                             timeout=300)
    report = [json.loads(line) for line in verbose.stdout.splitlines()][:-1]
    assert len(report) == 4 and all(r["self"] for r in report)
    for r in report:  # each parameter written with its uncertainty, or held saying why (with its value and uncertainty)
        assert all(name in r["sigma"] or name in r["held"] for name in ("az_scale", "az_bias_deg", "az_compression"))
    assert sum(len(r["sigma"]) for r in report) >= 4
    assert '"kind": "counters"' in verbose.stderr
    # boards with no hidden error: nothing to gain on held-out epochs, so the site file is left as it was
    perfect = {"mount_error_deg": 0.0, "scale_error": 0.0, "bias_deg": 0.0, "reflection": 0.0}
    _capture_of(record(seed=6, duration=30.0, boards=perfect).events, tmp_path / "plain.pcapng", site)
    own_site = tmp_path / "site.toml"
    own_site.write_text(SITE.read_text())
    kept = subprocess.run([*RFHOMING, "calibrate", str(own_site), "--self", "--from",
                           f"capture:{tmp_path / 'plain.pcapng'}"], capture_output=True, text=True, timeout=300)
    assert kept.returncode == 0, kept.stderr
    assert json.loads(kept.stdout)["verdict"].startswith("not written")
    assert own_site.read_text() == SITE.read_text()
    located = subprocess.run([*RFHOMING, "locate", str(own_site), "--from", f"capture:{tmp_path / 'plain.pcapng'}"],
                             capture_output=True, text=True, timeout=300)
    assert located.returncode == 0 and "no calibration in" in located.stderr
    still = list(synthetic(site, lambda t: np.array([6.0, 3.0, 1.0]), 30.0))
    _capture_of(still, tmp_path / "still.pcapng", site)
    refused = subprocess.run([*RFHOMING, "calibrate", str(SITE), "--self", "--dry-run",
                              "--from", f"capture:{tmp_path / 'still.pcapng'}"], capture_output=True, text=True,
                             timeout=120)
    assert refused.returncode == 2 and "did not cover the room" in refused.stderr
