"""Campaigns: the same numbers inline, on processes and on Dask; each campaign's report
reduces real runs (small --runs; the full campaigns live in docs/RESULTS.md)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.campaigns import kinematic, s0, s1, s3, s4
from rfhoming.cli.commands.campaign import REGISTRY, load
from rfhoming.host.outputs import Manifest, whole
from rfhoming.campaigns.runner import Job, run_jobs
from rfhoming.cli.main import main
from rfhoming.emulator.scenario import load as scenario
from rfhoming.host.homing.s0_aoa import S0Params
from rfhoming.host.homing.types import Pose


@pytest.mark.slow
@pytest.mark.timeout(900)  # a hang guard: pure CPU work (the jobs thrice), no waits; slow only on a loaded machine
def test_inline_process_and_dask_give_identical_results() -> None:
    """Every campaign's jobs (a few of each: every S0 mode, both S0 house methods, S1, S2 B
    behind its wall with the hall's walls reflecting, S3, S4) give the same results inline, on
    two worker processes and on Dask (the reflection caches are per session)."""
    distributed = pytest.importorskip("distributed")
    assert scenario("s2-b").path_loss.reflections and scenario("s2-b").path_loss.reflect_bounds
    picks = {"s0-table3": len(s0.MODES), "s0-house": 2, "s1-dock": 2, "s3-arena": 2, "s4-montecarlo": 1}
    jobs = [job for name, n in picks.items() for job in load(name).jobs(1, 7)[:n]]
    jobs += [j for j in load("s2-scenarios").jobs(1, 0) if j.kwargs["scenario"] == "b" and j.kwargs["system"] != "preliminary"]
    jobs = [Job(i, job.fn, job.kwargs) for i, job in enumerate(jobs)]

    def results(rows):  # everything but the time it took (wall_s; S4's filter timings)
        timing = ("wall_s", "_seconds", "_us_per_beacon_step")
        return [{k: v for k, v in r.items() if not k.endswith(timing)} for r in rows]

    inline = results(run_jobs(jobs, workers=1))
    pooled = results(run_jobs(jobs, workers=2))
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        on_dask = results(run_jobs(jobs, dask_address=cluster.scheduler_address))
    assert {r["mode"] for r in inline[:len(s0.MODES)]} == set(s0.MODES)
    assert [r["arrived"] for r in inline if "system" in r] == [True, True]
    assert inline == pooled == on_dask
    assert [r["index"] for r in inline] == list(range(len(jobs)))


@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3, 3), st.floats(-1, 1), st.floats(-1, 1), st.floats(-0.5, 0.5))
def test_goal_seen_from_the_robot_cancels_odometry_drift(gx, gy, rx, ry, dx, dtheta) -> None:
    """A perfect estimate in a drifted odometry frame is the true goal seen from the robot; a
    wrong one keeps its error."""
    true_pose = (rx, ry, 0.7)
    c, s_ = math.cos(dtheta), math.sin(dtheta)

    def drifted(x: float, y: float) -> tuple[float, float]:  # the odometry frame: turned and shifted
        return c * x - s_ * y + dx, s_ * x + c * y + dx / 2

    odometry = Pose(*drifted(rx, ry), true_pose[2] + dtheta)
    seen = s0.goal_seen_from_robot(drifted(gx, gy), odometry, true_pose)
    assert math.dist(seen, (gx, gy)) < 1e-9
    off = s0.goal_seen_from_robot(drifted(gx + 0.3, gy), odometry, true_pose)
    assert math.dist(off, (gx, gy)) == pytest.approx(0.3, abs=1e-9)


def test_s0_method_rows_run_the_papers_estimator() -> None:
    """S0's rows are the paper's method -- k = 0.8 per reading and the hybrid report, without our
    fusions -- so that the tables set it beside ours, not a tuned copy."""
    for mode in ("idealised-10hz-paper", "idealised-50hz-paper"):
        params, _ = s0.PARAMS[mode]
        assert (params.k, params.close_fusion_m, params.ray_fusion, params.robust_fit) == (0.8, 0.0, False, False)
    assert s0.PARAMS["idealised-10hz-paper"][1] == 0.1
    assert s0.PAPER_S0.folded  # the house runs the board: S0's estimator behind the fold handling



def test_a_job_failure_is_raised_not_swallowed() -> None:
    with pytest.raises(KeyError):
        run_jobs([Job(0, "rfhoming.campaigns.s0:table3_run", {"config": 9, "mode": "idealised", "target": (1, 1), "seed": 0})],
                 workers=1)


@pytest.mark.slow
def test_unreachable_dask_scheduler_is_a_clear_error(tmp_path, capsys) -> None:
    pytest.importorskip("distributed")
    code = main(["campaign", "s3-arena", "--runs", "1", "--dask", "tcp://127.0.0.1:9", "--out", str(tmp_path), "--quiet"])
    assert code == 2
    assert "no Dask scheduler" in capsys.readouterr().err


def test_every_campaign_is_registered_and_loads() -> None:
    for name in REGISTRY:
        campaign = load(name)
        assert campaign.name == name and campaign.default_runs > 0
        assert campaign.jobs(1, 0)


def test_idealised_s0_homes_and_reports_table3_metrics() -> None:
    row = kinematic.home((6.0, -4.0), 10.0, 0.2, 0.0, seed=3)
    assert row["success"] and row["final_error_m"] < 0.5
    assert row["net_velocity_mps"] == pytest.approx(math.hypot(6, 4) / row["time_s"], rel=0.1)
    assert 0.9 < row["path_efficiency"] <= 1.0


@pytest.mark.slow  # 4 s of closed loop
def test_a_single_noisy_reading_does_not_end_a_run() -> None:
    """Configuration 5's ±1 m can put the first vector goal under the robot: no arrival on it."""
    for seed in range(20):
        row = kinematic.home((0.06, -1.14), 20.0, 0.2, 1.0, seed=seed)
        assert row["time_s"] > 0.5


def test_paper_gain_is_reproducible_with_the_unfolded_sensor() -> None:
    row = kinematic.home((-5.0, 5.0), 5.0, 0.05, 0.0, seed=1, params=S0Params(folded=False, k=0.8, tau=5.0,
                                                                              ray_fusion=False))
    assert row["success"]


@pytest.mark.slow
def test_s1_trial_docks_and_alignment_fixes_the_heading() -> None:
    start = (0.9, 0.6, math.pi / 2 + 0.25)
    plain = s1.trial("paper", start, seed=5)
    aligned = s1.trial("aligned", start, seed=5)
    assert plain["docked"] and aligned["docked"]
    assert aligned["final_error_m"] < 0.25 and aligned["heading_error_deg"] < 5.0


def test_s3_filters_reduce_the_spread_and_kalman_most() -> None:
    row = s3.filters_run(seed=1)
    raw, kal, med = np.array(row["raw"]), np.array(row["kalman"]), np.array(row["median"])
    assert np.all(kal[1:] < raw[1:] / 2) and np.all(kal[1:] < med[1:])
    assert np.allclose(raw[1:], s3.TABLE1_STD[1:], rtol=0.25)  # the simulation follows Table I


@pytest.mark.slow
def test_s4_our_filter_matches_filterpy_on_the_same_data() -> None:
    pytest.importorskip("filterpy")
    z, u, rssi, beacons = s4.flights(1, seed=2)
    ours, _, _ = s4.run_filter("ekf", z, u, rssi)
    theirs, _, _ = s4.filterpy_ekf(z, u, rssi, 3)
    assert np.allclose(ours[:3], theirs, atol=1e-9)
    assert np.median(np.linalg.norm(ours - beacons, axis=1)) < 1.0


def test_cli_writes_json_markdown_and_plot(tmp_path, capsys) -> None:
    code = main(["campaign", "s3-arena", "--runs", "3", "--workers", "1", "--out", str(tmp_path), "--json", "--quiet"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["command"] == "rfhoming campaign s3-arena --runs 3 --seed 0"
    saved = json.loads((tmp_path / "s3-arena.json").read_text())
    assert len(saved["rows"]) == 1 + len(s3.ARENAS) * 9 * 3
    assert "| paper (one measurement per point) |" in (tmp_path / "s3-arena.md").read_text()
    assert saved["wall_s"] > 0
    assert (tmp_path / "s3-arena.png").stat().st_size > 1000
    manifest = tmp_path / "s3-arena.manifest.json"  # written last: the three files are one run's set
    assert set(json.loads(manifest.read_text())["files"]) == {"s3-arena.json", "s3-arena.md", "s3-arena.png"}
    assert whole(manifest)
    (tmp_path / "s3-arena.md").write_text("another run's table\n")  # what a kill between two renames would leave
    assert not whole(manifest)
    Manifest(manifest, []).start()  # the next run's first step: no manifest until its set is whole
    assert not manifest.exists() and not whole(manifest)


def test_missing_optional_package_fails_before_any_job() -> None:
    from dataclasses import replace as dc_replace

    from rfhoming.campaigns.runner import CampaignError

    campaign = dc_replace(load("s3-arena"), requires=("no_such_package_rfhoming",))
    with pytest.raises(CampaignError, match="needs no_such_package_rfhoming: pip install"):
        campaign.check_requirements()
    assert load("s4-montecarlo").requires == ("filterpy",)


def test_checkpoint_keeps_finished_jobs_across_a_crash(tmp_path) -> None:
    jobs = load("s3-arena").jobs(1, 3)[:4]
    broken = jobs[:3] + [Job(3, "rfhoming.campaigns.s3:point_run", {"point": 99, "seed": 1})]  # IndexError
    checkpoint = tmp_path / "s3.partial.jsonl"
    with pytest.raises(IndexError):
        run_jobs(broken, workers=1, checkpoint=checkpoint)
    assert len(checkpoint.read_text().splitlines()) == 3
    ran = []
    rows = run_jobs(jobs, workers=1, checkpoint=checkpoint, progress=ran.append)
    assert ran == [3, 1]  # three from the checkpoint, one run now
    assert json.loads(json.dumps(rows)) == json.loads(json.dumps(run_jobs(jobs, workers=1)))


def test_a_directory_named_like_a_scenario_does_not_shadow_it(tmp_path, monkeypatch) -> None:
    from rfhoming.emulator.scenario import load as load_scenario

    (tmp_path / "s1-dock").mkdir()  # e.g. left by `rfhoming campaign s1-dock --out s1-dock`
    monkeypatch.chdir(tmp_path)
    assert load_scenario("s1-dock").name == "s1-dock"


@pytest.mark.slow
def test_s4_smoother_removes_the_per_link_offsets_the_ekf_keeps() -> None:
    from rfhoming.host.estimation.beacon import refine_batch

    z, u, rssi, beacons = s4.flights(2, seed=5)
    ekf, _, _ = s4.run_filter("ekf", z, u, rssi, "area")
    smoothed, offsets = refine_batch(s4.MODEL, np.repeat(z[1:], s4.BEACONS_PER_FLIGHT, axis=1), rssi, ekf)
    before, after = (np.linalg.norm(e - beacons, axis=1) for e in (ekf, smoothed))
    assert after.mean() < 0.15 and after.mean() < before.mean() / 2
    assert np.median(np.abs(offsets)) > 0.5  # it did find offsets (S4's are ±2 dB per link)


# -- s3-arena and s4-montecarlo under a radio profile's measured RSSI ------------------------

def test_s3_and_s4_jobs_take_the_radio() -> None:
    for name in ("s3-arena", "s4-montecarlo"):
        campaign = load(name)
        measured = campaign.make_jobs(1, 0, "measured")
        assert measured and all(job.kwargs["radio"] == "measured" for job in measured)
        assert all("radio" not in job.kwargs for job in campaign.make_jobs(1, 0))


def test_s3_measured_draws_repeat_by_seed_and_are_not_the_papers() -> None:
    fix = s3.point_run(4, 11, "6 m", "measured")
    assert fix == s3.point_run(4, 11, "6 m", "measured")
    assert fix["radios"] == {"radio": "measured", "rssi_table": "ble", "paper_radio": "ble", "assumed": ""}
    assert fix != s3.point_run(4, 12, "6 m", "measured")
    ideal = s3.point_run(4, 11, "6 m")
    assert "radios" not in ideal and ideal["trilateration_m"] != fix["trilateration_m"]
    filt = s3.filters_run(3, "measured")
    assert filt == s3.filters_run(3, "measured")
    # Table I's 0.21 dB at 0 m is not what a measured link does: its residual and white noise stay
    assert s3.filters_run(3)["raw"][0] < 0.5 < 2.0 < filt["raw"][0]
    assert all(k <= r for k, r in zip(filt["kalman"], filt["raw"]))


def test_s4_measured_rssi_repeats_by_seed_on_the_same_flights() -> None:
    z, u, ideal, beacons = s4.flights(1, seed=4)
    z2, u2, measured, beacons2 = s4.flights(1, seed=4, radio="measured")
    assert np.array_equal(z, z2) and np.array_equal(beacons, beacons2)  # the same flights: a paired comparison
    assert np.array_equal(measured, s4.flights(1, seed=4, radio="measured")[2], equal_nan=True)
    assert not np.array_equal(measured, ideal, equal_nan=True)
    assert np.isnan(measured).mean() > np.isnan(ideal).mean()  # out of range as before, and some readings lost
    assert np.isnan(measured)[np.isnan(ideal)].all()  # nothing heard beyond the thesis's 4 m


def _s4_rows(radios: dict[str, str] | None) -> list[dict[str, object]]:
    row: dict[str, object] = {"beacons": 2, **({"radios": radios} if radios else {})}
    for name in s4.VARIANTS:
        row[f"{name}_error_m"] = [0.1, 0.3]
        row[f"{name}_us_per_beacon_step"] = 1.0
    return [row]


def test_the_s3_and_s4_reports_name_the_radios() -> None:
    rows = run_jobs(load("s3-arena").make_jobs(1, 0, "measured"), workers=1)
    md = s3.report(rows).markdown
    assert md.startswith("Radios: measured: S3's BLE receivers take the profile's [rssi.ble]") and "assumed" not in md
    assert s3.report(run_jobs(load("s3-arena").make_jobs(1, 0), workers=1)).markdown.startswith("Radios: ideal")
    radios = {"radio": "room.toml", "rssi_table": "xplr", "paper_radio": "ble", "assumed": "no [rssi.ble]"}
    report = s4.report(_s4_rows(radios))
    assert report.summary["radios"] == radios
    assert report.markdown.startswith("Radios: room.toml: S4's BLE receivers take the profile's [rssi.xplr]")
    assert "*assumed*: no [rssi.ble]" in report.markdown
    assert s4.report(_s4_rows(None)).markdown.startswith("Radios: ideal: the thesis's χ")


def test_a_profile_without_the_papers_radio_takes_the_nearest_marked_assumed(tmp_path) -> None:
    import tomllib

    import tomlkit

    from rfhoming.campaigns import rssi_draws
    from rfhoming.campaigns.runner import CampaignError
    from rfhoming.protocol.radio_profile import load as load_profile, to_toml

    raw = to_toml(load_profile("measured"))
    raw["rssi"] = {"xplr": raw["rssi"]["xplr"]}
    (tmp_path / "xplr.toml").write_text(tomlkit.dumps(raw))
    radio = rssi_draws.rssi_radio(str(tmp_path / "xplr.toml"), "ble")
    assert radio is not None and radio.table == "xplr" and "no [rssi.ble]" in radio.assumed
    fix = s3.point_run(0, 1, "6 m", str(tmp_path / "xplr.toml"))
    assert fix["radios"]["rssi_table"] == "xplr" and "nearest measured" in fix["radios"]["assumed"]
    del raw["rssi"]
    (tmp_path / "none.toml").write_text(tomlkit.dumps(raw))
    assert "rssi" not in tomllib.loads((tmp_path / "none.toml").read_text())
    with pytest.raises(CampaignError, match=r"no \[rssi.ble\] table"):
        rssi_draws.rssi_radio(str(tmp_path / "none.toml"), "ble")


def test_the_measured_channels_vectorised_draws_are_its_scalar_ones() -> None:
    from rfhoming.campaigns import rssi_draws

    radio = rssi_draws.rssi_radio("measured", "ble")
    assert radio is not None
    ch = rssi_draws.channel(radio, 2.0, np.random.default_rng(5))
    link = ("beacon3", "receiver1")
    ends = np.array([[1.0, 2.0, 0.5, 0.25], [1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 2.0, 6.0]])
    expected = [ch.shadowing_db(link, ((e[0], e[1]), (e[2], e[3]))) for e in ends]
    assert np.allclose(ch.shadowing_at(link, ends), expected) and np.ptp(expected) > 0
    state = ch.link(link)
    e = radio.rssi.exponent
    d = np.array([0.5, e.pivot_m, 3.0])
    turn = ch.turned_db(link, d)
    assert turn[1] == pytest.approx(state.offset_db)  # at the pivot only the offset
    assert turn[0] == pytest.approx(state.offset_db - 10 * (state.exponent - 2.0) * math.log10(e.near_m / e.pivot_m))


def test_s4s_time_processes_hold_the_tables_variance_correlation_and_losses() -> None:
    from rfhoming.campaigns import rssi_draws

    radio = rssi_draws.rssi_radio("measured", "ble")
    assert radio is not None
    r = radio.rssi.residual
    ch = rssi_draws.channel(radio, 2.0, np.random.default_rng(1))
    time = rssi_draws.TimeProcesses(ch, np.full(300, 0.15), 0.1, np.random.default_rng(2))
    noise = np.array([time.noise() for _ in range(1500)])
    missed = np.array([time.missed() for _ in range(1500)])
    assert noise.std() == pytest.approx(math.hypot(r.sd_db, r.white_sd_db), rel=0.03)
    lag1 = np.mean(noise[1:] * noise[:-1]) / noise.var()
    assert lag1 == pytest.approx(r.sd_db**2 * math.exp(-0.1 / r.time_s) / (r.sd_db**2 + r.white_sd_db**2), abs=0.03)
    assert missed.mean() == pytest.approx(0.15, abs=0.01)
    assert np.mean(missed[1:] & missed[:-1]) > 0.15**2 * 2  # in bursts: a loss follows a loss more than by chance
