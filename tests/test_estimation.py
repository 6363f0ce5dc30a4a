"""Ranging, bearings, lateration, the S4 beacon filters and the S2 particle filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from rfhoming.host.estimation import ranging
from rfhoming.host.estimation.beacon import BeaconEkf, BeaconUkf, CircleInitializer, S4Model, initial_state, jacobian, measure
from rfhoming.host.estimation.bearings import Degenerate, intersect, kohonen_update, triangulate
from rfhoming.host.estimation.lateration import multilaterate, strongest_three, trilaterate
from rfhoming.host.estimation.particle import ParticleFilter, PfParams, direction
from rfhoming.host.estimation.ray_fusion import FusionPrior, RayRangeFusion

coord = st.floats(-20, 20)


# -- ranging --------------------------------------------------------------------------------
def test_log_distance_both_ways() -> None:
    m = ranging.LogDistance(-59.0, 2.0)
    assert m.rssi(1.0) == -59.0 and m.rssi(10.0) == pytest.approx(-79.0)
    assert m.distance(-79.0) == pytest.approx(10.0)


def test_fits_recover_their_parameters() -> None:
    rng = np.random.default_rng(1)
    d = rng.uniform(0.5, 10, 4000)
    rssi = -60.0 - 10 * 2.4 * np.log10(d) + rng.normal(0, 3.0, d.size)
    fit = ranging.fit_log_distance(d, rssi)
    assert fit.model.p0_dbm == pytest.approx(-60.0, abs=0.3) and fit.model.n == pytest.approx(2.4, abs=0.05)
    assert fit.rssi_residual_db == pytest.approx(3.0, rel=0.05)
    p0_only = ranging.fit_p0(d, rssi, n=2.4)
    assert p0_only.model.p0_dbm == pytest.approx(-60.0, abs=0.2)
    exp = ranging.fit_exponential(np.exp(-0.07 * np.linspace(-90, -40, 50)) * 0.02, np.linspace(-90, -40, 50))
    assert exp.model.a == pytest.approx(0.02) and exp.model.b == pytest.approx(-0.07)


def test_s3_table_means_path_loss_vs_exponential() -> None:
    d, mean, _ = np.array(ranging.S3_TABLE).T
    paper_log = ranging.LogDistance(-64.30, 2.7)
    paper_exp = ranging.Exponential(0.0165, -0.0662)
    rmse = lambda m: float(np.sqrt(np.mean((m.distance(mean) - d) ** 2)))  # noqa: E731
    # S3's published exponential model beats its published log-distance model on the means too
    assert rmse(paper_exp) < 0.7 * rmse(paper_log)
    # our log-distance least-squares fit beats S3's fixed n = 2.7 on the same means
    assert ranging.fit_log_distance(d, mean).distance_rmse_m < rmse(paper_log)


def test_binned_fit_ignores_a_pile_at_the_floor() -> None:
    """S0 configuration 5 as a calibration drive sees it: 5 m -> 0.5 m, a dwell at 0.5 m, the
    range d(1 ± 0.2) ± 1 m floored at 0.05 m and turned into RSSI by the true curve."""
    rng = np.random.default_rng(3)
    d = np.concatenate([np.linspace(5.0, 0.5, 1100), np.full(150, 0.5)])
    noisy = np.maximum(d * (1 + rng.uniform(-0.2, 0.2, d.size)) + rng.uniform(-1, 1, d.size), 0.05)
    rssi = -59.0 - 22.0 * np.log10(noisy)
    plain, binned = ranging.fit_log_distance(d, rssi), ranging.fit_log_distance_binned(d, rssi)
    assert abs(plain.model.n - 2.2) > 0.3  # the floor pile skews a plain fit
    assert binned.model.n == pytest.approx(2.2, abs=0.15) and binned.model.p0_dbm == pytest.approx(-59.0, abs=1.0)
    gaussian = -60.0 - 24.0 * np.log10(d) + rng.normal(0, 3.0, d.size)  # symmetric noise: as the plain fit
    assert ranging.fit_log_distance_binned(d, gaussian).model.n == pytest.approx(
        ranging.fit_log_distance(d, gaussian).model.n, abs=0.1)
    with pytest.raises(ValueError, match="two 0.25 m distance bins"):
        ranging.fit_log_distance_binned(np.full(20, 1.0), np.full(20, -60.0))


@pytest.mark.parametrize(("d", "rssi", "words"), [([1, 1], [-50, -51], "one distance"), ([1], [-50], "two"), ([0, 1], [-1, -2], "positive")])
def test_fits_refuse_what_cannot_be_fitted(d, rssi, words) -> None:
    with pytest.raises(ValueError, match=words):
        ranging.fit_log_distance(np.array(d, float), np.array(rssi, float))


# -- ray fusion -----------------------------------------------------------------------------
def approach(seed: int) -> tuple[list[tuple[float, float, float, float]], tuple[float, float]]:
    """Readings (x, y, bearing, range) at 10 Hz on a straight 3 m -> 0.3 m approach to (5, 2),
    S0 configuration 5's noise: ±20°, range d(1 ± 0.2) ± 1 m floored at 0.05 m."""
    rng = np.random.default_rng(seed)
    target, heading = (5.0, 2.0), 0.3
    out = []
    for d in np.linspace(3.0, 0.3, 60):
        x, y = target[0] - d * math.cos(heading), target[1] - d * math.sin(heading)
        noisy = max(d * (1 + rng.uniform(-0.2, 0.2)) + rng.uniform(-1, 1), 0.05)
        out.append((x, y, heading + math.radians(rng.uniform(-20, 20)), noisy))
    return out, target


def test_ray_fusion_averages_the_whole_approach() -> None:
    """On a straight approach only ranges tell how far: keeping every reading beats S0's mean of
    the last 20 raw vector goals."""
    fused_err, last20_err = [], []
    for seed in range(30):
        readings, target = approach(seed)
        fusion = RayRangeFusion()
        for k, (x, y, a, d) in enumerate(readings):
            fusion.add(0.1 * k, x, y, a, d, fusion.estimate())
        fused_err.append(math.dist(fusion.estimate(), target))
        raw = [(x + d * math.cos(a), y + d * math.sin(a)) for x, y, a, d in readings[-20:]]
        last20_err.append(math.dist(np.mean(raw, axis=0), target))
    assert np.mean(fused_err) < 0.85 * np.mean(last20_err)


def test_ray_fusion_keeps_out_far_readings_and_forgets() -> None:
    fusion = RayRangeFusion(FusionPrior(max_range_m=3.0, half_life_s=1.0))
    assert fusion.estimate() is None
    fusion.add(0.0, 0.0, 0.0, 0.0, 8.0, None)  # 8 m away: left out
    assert fusion.estimate() is None and fusion.readings == 0
    fusion.add(0.0, 0.0, 0.0, 0.0, 2.0, None)
    fusion.add(10.0, 0.0, 0.0, 0.0, 1.0, (2.0, 0.0))  # ten half-lives later: the first is gone
    assert fusion.estimate()[0] == pytest.approx(1.0, abs=0.01)


# -- bearings -------------------------------------------------------------------------------
@given(coord, coord, coord, coord, coord, coord)
def test_intersect_finds_the_target_or_refuses(x1, y1, x2, y2, tx, ty) -> None:
    assume(math.hypot(tx - x1, ty - y1) > 0.1 and math.hypot(tx - x2, ty - y2) > 0.1)
    a1, a2 = math.atan2(ty - y1, tx - x1), math.atan2(ty - y2, tx - x2)
    try:
        x, y = intersect((x1, y1), a1, (x2, y2), a2)
    except Degenerate:
        assert abs(math.sin(a2 - a1)) < math.sin(math.radians(3)) + 1e-9
        return
    assert math.hypot(x - tx, y - ty) < 1e-6 * (1 + math.hypot(tx, ty))


def test_intersect_refuses_crossing_behind() -> None:
    with pytest.raises(Degenerate, match="behind"):
        intersect((0, 0), 0.0, (5, 1), math.pi / 2)


def test_triangulate_weights_and_parallel() -> None:
    anchors = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    target = np.array([3.0, 7.0])
    bearings = np.arctan2(target[1] - anchors[:, 1], target[0] - anchors[:, 0]) + [0.02, -0.01, 0.0, 0.01]
    point, cov = triangulate(anchors, bearings)
    assert np.linalg.norm(point - target) < 0.2 and np.all(np.linalg.eigvalsh(cov) > 0)
    with pytest.raises(Degenerate):
        triangulate(np.array([[0, 0], [0, 1]]), np.array([0.0, 0.0]))


def test_kohonen_moves_the_goal_onto_the_new_ray() -> None:
    goal = (5.0, 1.0)
    robot = (0.0, 0.0)
    bearing = 0.0  # the target is straight along +x
    new = kohonen_update(goal, robot, bearing, k=1.0)
    assert new == pytest.approx((5.0, 0.0))
    half = kohonen_update(goal, robot, bearing, k=0.8)
    assert half == pytest.approx((5.0, 0.2))


# -- lateration -----------------------------------------------------------------------------
@given(st.floats(0.2, 4.8), st.floats(0.2, 4.8))
def test_trilateration_and_multilateration_exact(tx: float, ty: float) -> None:
    anchors = np.array([[0, 0], [5, 0], [5, 5], [0, 5]], float)
    d = np.hypot(*(anchors - [tx, ty]).T)
    assert trilaterate(anchors[:3], d[:3]) == pytest.approx([tx, ty], abs=1e-9)
    assert multilaterate(anchors, d) == pytest.approx([tx, ty], abs=1e-9)


def test_lateration_detects_collinear_anchors() -> None:
    line = np.array([[0, 0], [1, 1], [2, 2], [3, 3]], float)
    with pytest.raises(Degenerate, match="collinear"):
        trilaterate(line, np.ones(4))
    with pytest.raises(Degenerate, match="collinear"):
        multilaterate(line, np.ones(4))


def test_strongest_three() -> None:
    assert sorted(strongest_three(np.array([-70, -50, -90, -60]))) == [0, 1, 3]


# -- S4 beacon filters ----------------------------------------------------------------------
def test_jacobian_matches_finite_differences() -> None:
    m = S4Model()
    x = np.random.default_rng(2).uniform(0, 5, (3, m.size))
    h = jacobian(m, x)
    eps = 1e-6
    for j in range(m.size):
        dx = np.zeros_like(x)
        dx[:, j] = eps
        numeric = (measure(m, x + dx) - measure(m, x - dx)) / (2 * eps)
        assert np.allclose(h[:, :, j], numeric, atol=1e-4)


def lawnmower(t: float, v: float = 0.2) -> np.ndarray:
    pts = []
    for i, x in enumerate(np.arange(0.0, 4.01, 1.0)):
        ys = (0.0, 8.0) if i % 2 == 0 else (8.0, 0.0)
        pts += [(x, ys[0]), (x, ys[1])]
    pts = np.array(pts)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = (v * t) % seg.sum()
    k = int(np.searchsorted(np.cumsum(seg), s))
    s0 = np.concatenate([[0], np.cumsum(seg)])[k]
    return pts[k] + (s - s0) / seg[k] * (pts[k + 1] - pts[k])


def simulate(filter_cls, k: int = 40, seed: int = 0, dim: int = 2, missing_every: int = 0):
    rng = np.random.default_rng(seed)
    m = S4Model(dim=dim)
    beacons = np.concatenate([rng.uniform([0.2, 0.2], [3.8, 7.8], (k, 2)), np.zeros((k, dim - 2))], axis=1)
    offsets = np.zeros((3, dim))
    offsets[1, 0], offsets[2, 1] = 0.6, 0.6
    init = CircleInitializer(m, k)
    filt, prev = None, None
    for step in range(3200):
        centre = np.zeros(dim)
        centre[:2] = lawnmower(step / 10)
        rec = centre + offsets + 0.1 * rng.standard_normal((k, 3, dim))
        dist = np.linalg.norm(rec - beacons[:, None], axis=2)
        rssi = m.p0_dbm - 20 * np.log10(dist) + rng.choice([-2.0, 2.0], (k, 3)) + rng.normal(0, math.sqrt(5), (k, 3))
        rssi[dist > 4.0] = np.nan
        if missing_every and step % missing_every == 0:
            rssi[:, 1] = np.nan
        zpos = rec + rng.normal(0, 0.1, rec.shape)
        if filt is None:
            init.update(zpos, rssi)
            if init.ready:
                b, c = init.estimate()
                x0, p0 = initial_state(m, zpos, np.nan_to_num(b, nan=2.0), c)
                filt = filter_cls(m, x0, p0)
        else:
            filt.predict((zpos - prev).reshape(k, -1), dt=0.1)
            filt.update(zpos.reshape(k, -1), rssi)
        prev = zpos
    return np.linalg.norm(filt.beacon - beacons, axis=1)


@pytest.mark.slow
@pytest.mark.parametrize("cls", [BeaconEkf, BeaconUkf])
def test_s4_filters_localise_beacons(cls) -> None:
    err = simulate(cls)
    assert np.median(err) < 0.4 and np.mean(err) < 0.6


@pytest.mark.slow
def test_s4_ekf_3d_and_missing_receivers() -> None:
    err = simulate(BeaconEkf, k=20, dim=3, missing_every=3)
    assert np.median(err) < 0.6


def test_missing_rssi_equals_the_update_without_that_row() -> None:
    m = S4Model()
    rng = np.random.default_rng(3)
    x0 = rng.uniform(0, 4, (1, m.size))
    p0 = np.eye(m.size) * 0.5
    z_pos = x0[:, :6] + 0.05
    rssi = np.array([[-50.0, np.nan, -55.0]])
    ekf = BeaconEkf(m, x0, p0)
    ekf.update(z_pos, rssi)
    keep = [0, 1, 2, 3, 4, 5, 6, 8]  # positions, RSSI 0 and 2: row 7 (receiver 1's RSSI) removed
    h = jacobian(m, x0)[0][keep]
    r = np.diag([m.r_pos] * 6 + [m.r_rssi] * 2)
    y = (np.concatenate([z_pos[0], [-50.0, -55.0]]) - measure(m, x0)[0][keep])
    k = p0 @ h.T @ np.linalg.inv(h @ p0 @ h.T + r)
    assert np.allclose(ekf.x[0], x0[0] + k @ y)
    assert np.allclose(ekf.p[0], (np.eye(m.size) - k @ h) @ p0)


def _seeded_s4_run(steps: int = 300) -> tuple[S4Model, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One beacon, three receivers wandering around it: (model, x0, u, z_pos, rssi), all heard."""
    m = S4Model()
    rng = np.random.default_rng(11)
    x0 = np.concatenate([rng.uniform(0, 4, 6), [2.0, 2.0]])
    u = rng.normal(0, 0.05, (steps, 6))
    truth = x0[:6] + np.cumsum(u, axis=0)
    z_pos = truth + rng.normal(0, 0.2, truth.shape)
    beacon = np.array([1.5, 2.5])
    d = np.linalg.norm(truth.reshape(steps, 3, 2) - beacon, axis=2)
    rssi = m.p0_dbm - 20 * np.log10(d) + rng.normal(0, 3, d.shape)
    return m, x0, u, z_pos, rssi


def test_s4_ekf_matches_a_textbook_joseph_form_ekf_over_a_seeded_run() -> None:
    m, x0, u, z_pos, rssi = _seeded_s4_run()
    rssi[::7, 1] = np.nan  # and a receiver that sometimes hears nothing
    ekf = BeaconEkf(m, x0[None], np.eye(8))
    x, p = x0.copy(), np.eye(8)
    q = np.diag([m.q] * 6 + [0.0, 0.0])
    for s in range(len(u)):
        ekf.predict(u[s][None])
        ekf.update(z_pos[s][None], rssi[s][None])
        x[:6] += u[s]
        p = p + q
        keep = np.concatenate([np.ones(6, bool), ~np.isnan(rssi[s])])
        h = jacobian(m, x[None])[0][keep]
        r = np.diag(np.array([m.r_pos] * 6 + [m.r_rssi] * 3)[keep])
        k = p @ h.T @ np.linalg.inv(h @ p @ h.T + r)
        x = x + k @ (np.concatenate([z_pos[s], rssi[s]])[keep] - measure(m, x[None])[0][keep])
        i_kh = np.eye(8) - k @ h
        p = i_kh @ p @ i_kh.T + k @ r @ k.T
        assert np.abs(ekf.x[0] - x).max() < 1e-9 and np.abs(ekf.p[0] - p).max() < 1e-9, s


def test_s4_ekf_matches_filterpy_over_a_seeded_run() -> None:
    kalman = pytest.importorskip("filterpy.kalman")
    m, x0, u, z_pos, rssi = _seeded_s4_run()
    ekf = BeaconEkf(m, x0[None], np.eye(8))
    ref = kalman.ExtendedKalmanFilter(dim_x=8, dim_z=9, dim_u=6)
    ref.x = x0.reshape(8, 1).copy()
    ref.P = np.eye(8)
    ref.B = np.vstack([np.eye(6), np.zeros((2, 6))])
    ref.Q = np.diag([m.q] * 6 + [0.0, 0.0])
    ref.R = np.diag([m.r_pos] * 6 + [m.r_rssi] * 3)
    for s in range(len(u)):
        ekf.predict(u[s][None])
        ekf.update(z_pos[s][None], rssi[s][None])
        ref.predict(u[s].reshape(6, 1))
        ref.update(np.concatenate([z_pos[s], rssi[s]]).reshape(9, 1), lambda x: jacobian(m, x.reshape(1, 8))[0],
                   lambda x: measure(m, x.reshape(1, 8))[0].reshape(9, 1))
        assert np.abs(ekf.x[0] - ref.x[:, 0]).max() < 1e-9 and np.abs(ekf.p[0] - ref.P).max() < 1e-9, s


def test_circle_initializer_finds_the_beacon_from_exact_ranges() -> None:
    m = S4Model()
    init = CircleInitializer(m, 1, n_init=5)
    receivers = np.array([[[0.0, 0.0], [3.0, 0.0], [0.0, 3.0]]])
    beacon = np.array([1.0, 2.0])
    rssi = m.p0_dbm - 20 * np.log10(np.linalg.norm(receivers[0] - beacon, axis=1))[None]
    for _ in range(5):
        init.update(receivers, rssi)
    est, cov = init.estimate()
    assert init.ready and est[0] == pytest.approx(beacon, abs=1e-6)
    assert cov[0] == pytest.approx(np.eye(2) * 500 / 5)


# -- S2 direction and particle filter -------------------------------------------------------
@pytest.mark.parametrize(("powers", "deg"), [((-50, -70, -60, -60), 0), ((-60, -60, -50, -70), 90),
                                              ((-70, -50, -60, -60), 180), ((-60, -60, -70, -50), -90)])
def test_direction_axis_convention(powers, deg) -> None:
    theta, r = direction(*powers)
    assert math.degrees(theta) == pytest.approx(deg) and r == pytest.approx(20.0)


def test_particle_filter_halves_the_instantaneous_error() -> None:
    rng = np.random.default_rng(5)
    pf = ParticleFilter(PfParams(), np.random.default_rng(6))
    target = np.array([6.0, 2.0])
    raw_err, pf_err = [], []
    for k in range(200):
        robot = (0.02 * k, 0.0, 0.1)
        dx, dy = target - robot[:2]
        s_r = math.hypot(dx, dy) + rng.normal(0, 1.0)
        s_t = math.atan2(dy, dx) - robot[2] + rng.normal(0, math.radians(20))
        pf.predict(0.1)
        pf.update(robot, s_r, s_t)
        fix = np.array(robot[:2]) + s_r * np.array([math.cos(robot[2] + s_t), math.sin(robot[2] + s_t)])
        if k >= 50:
            raw_err.append(np.linalg.norm(fix - target))
            pf_err.append(np.linalg.norm(pf.estimate() - target))
    assert np.mean(pf_err) < 0.5 * np.mean(raw_err)
    assert pf.resamples > 0
    r, b = pf.relative((0.0, 0.0, 0.0))
    assert r == pytest.approx(math.hypot(*target), abs=1.0)


def test_bounded_weights_find_an_emitter_behind_a_wall_that_s2_weights_lose() -> None:
    """Behind a wall every range reads 2.5x long (8 dB at n = 2); bearings stay true. The bounded
    weights take ranges as upper bounds and triangulate from the robot's motion."""
    target = np.array([3.0, 3.0])
    errors = {}
    for likelihood in ("s2", "bounded"):
        rng = np.random.default_rng(5)
        pf = ParticleFilter(PfParams(likelihood=likelihood), np.random.default_rng(6))
        for k in range(300):
            robot = (0.02 * k, -1.0, 0.0)  # driving past the wall, 6 m along x
            dx, dy = target - robot[:2]
            s_r = 2.5 * math.hypot(dx, dy) * math.exp(rng.normal(0, 0.2))
            s_t = math.atan2(dy, dx) - robot[2] + rng.normal(0, math.radians(15))
            pf.predict(0.1)
            pf.update(robot, s_r, s_t)
        errors[likelihood] = float(np.linalg.norm(pf.estimate() - target))
    assert errors["bounded"] < 1.0 < errors["s2"]


def test_bounded_weights_reseed_a_lost_cloud_from_the_fix() -> None:
    pf = ParticleFilter(PfParams(likelihood="bounded"), np.random.default_rng(1))
    pf.update((0.0, 0.0, 0.0), 5.0, 0.0)  # first fix: ahead
    for _ in range(5):
        pf.predict(0.1)
        pf.update((0.0, 0.0, 0.0), 5.0, math.pi / 2)  # then every fix says: to the left
    assert pf.injections > 0
    r, b = pf.relative((0.0, 0.0, 0.0))
    assert b == pytest.approx(math.pi / 2, abs=0.3) and r < 6.5
