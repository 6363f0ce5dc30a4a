"""The robust bearing fit: heavy-tailed and slow bearing errors do not drag the tag's position."""

from __future__ import annotations

import math

import numpy as np

from rfhoming.host.estimation.bearing_fit import BearingFit
from rfhoming.host.estimation.bearings import triangulate

TAG = (4.0, 3.0)


def _path(n: int) -> list[tuple[float, float]]:
    """An arc toward the tag, as a robot that corrects its heading drives it."""
    return [(0.1 * k, 1.5 * math.sin(k / n * math.pi)) for k in range(n)]


def _bearings(rng: np.random.Generator, path: list[tuple[float, float]], burst: slice, burst_deg: float,
              outliers: float) -> list[float]:
    """True bearings + 2° white noise, a slow 35° burst over ``burst``, and a fraction of wild rays."""
    out = []
    for k, (x, y) in enumerate(path):
        a = math.atan2(TAG[1] - y, TAG[0] - x) + math.radians(rng.normal(0, 2))
        if burst.start <= k < burst.stop:
            a += math.radians(burst_deg)
        if rng.random() < outliers:
            a += math.radians(rng.uniform(-80, 80))
        out.append(a)
    return out


def test_a_burst_and_wild_rays_do_not_drag_the_fit() -> None:
    rng = np.random.default_rng(3)
    path = _path(30)
    bearings = _bearings(rng, path, slice(15, 25), 35.0, 0.15)
    fit = BearingFit(spacing_m=0.0, min_rays=10, refit_every=1)
    for k, ((x, y), a) in enumerate(zip(path, bearings)):  # RSSI ranges: ±35 % (lognormal)
        fit.add(0.02 * k, x, y, a, math.dist((x, y), TAG) * float(rng.lognormal(0.0, 0.3)))
    got = fit.estimate()
    assert got is not None
    assert math.dist(got, TAG) < 0.3
    plain, _ = triangulate(np.array(path), np.array(bearings))  # least squares: the burst drags it
    assert math.dist(tuple(plain), TAG) > 3 * math.dist(got, TAG)


def test_no_parallax_no_estimate() -> None:
    """Rays from one place (a robot turning on the spot) cannot place the tag: no estimate."""
    fit = BearingFit(min_rays=5, refit_every=1, spacing_s=0.0)
    for k in range(40):
        fit.add(0.3 * k, 0.0, 0.0, math.atan2(TAG[1], TAG[0]) + math.radians(k % 3 - 1), 4.0)
    assert fit.rays == 40
    assert fit.estimate() is None


def test_rays_are_kept_sparsely_along_the_path() -> None:
    """Readings at 50 Hz standing still share one slow error: one ray per spacing is kept."""
    fit = BearingFit()
    for k in range(50):
        fit.add(0.02 * k, 0.0, 0.0, 0.5, 3.0)
    assert fit.rays == 4  # one per 0.25 s over 1 s, the first included


def test_older_rays_that_disagree_are_forgotten() -> None:
    """Rays from where a reflection pointed elsewhere, then many rays toward the real tag: the
    fit follows the recent rays rather than averaging the two."""
    fit = BearingFit(spacing_m=0.0, min_rays=10, refit_every=1, max_rays=400)
    wrong = (-3.0, 4.0)
    t = 0.0
    for k in range(40):  # along y = 0, toward the wrong place
        x, y = 0.1 * k, 0.0
        fit.add(t, x, y, math.atan2(wrong[1] - y, wrong[0] - x), math.dist((x, y), wrong))
        t += 0.3
    for k in range(40):  # then up x = 4, toward the tag
        x, y = 6.0, 0.08 * k - 2
        fit.add(t, x, y, math.atan2(TAG[1] - y, TAG[0] - x), math.dist((x, y), TAG))
        t += 0.3
    got = fit.estimate()
    assert got is not None and math.dist(got, TAG) < 0.3


def test_s0_reports_the_fit_and_a_slow_error_does_not_drag_it() -> None:
    """S0 on a straight-ish approach whose last 0.6 s of bearings read 25° off (a burst of the
    real board, docs/emulator.md): S0's own estimates follow the last readings, the fit of the path's
    bearings stays near the tag."""
    from rfhoming.host.homing.s0_aoa import S0Homing, S0Params
    from rfhoming.host.homing.types import Pose

    reports = {}
    for robust in (False, True):
        rng = np.random.default_rng(5)
        ctrl = S0Homing(S0Params(folded=False, robust_fit=robust))
        for k in range(300):  # 6 s at 50 Hz along an arc
            t = 0.02 * k
            pose = Pose(0.5 * t, 1.2 * math.sin(t / 6 * math.pi), 0.0)
            bearing = math.atan2(TAG[1] - pose.y, TAG[0] - pose.x) + math.radians(rng.normal(0, 2))
            if t > 5.4:
                bearing += math.radians(25)
            d = math.dist((pose.x, pose.y), TAG) * float(rng.lognormal(0.0, 0.3))
            ctrl.on_reading(t, pose, bearing - pose.theta, d)
        assert ctrl.reported is not None
        reports[robust] = math.dist(ctrl.reported, TAG)
        assert (ctrl.fitted is not None) is robust
    assert reports[True] < 0.3 < reports[False] and 3 * reports[True] < reports[False]


def test_rays_from_beside_the_fit_do_not_vouch_for_it() -> None:
    """A robot that turns and creeps 0.4 m, 1.1 m from the tag, with ±20° bearing noise (S0's
    configuration 5) and RSSI ranges that read short: a point beside the robot is "seen" from
    every side by its own rays, but nothing taken from afar places it: no estimate."""
    rng = np.random.default_rng(1)
    fit = BearingFit(min_rays=10, refit_every=1)
    tag = (1.1, 0.2)
    for k in range(60):
        x, y = 0.0, 0.4 * k / 60
        a = math.atan2(tag[1] - y, tag[0] - x) + math.radians(rng.uniform(-20, 20))
        fit.add(0.3 * k, x, y, a, 0.3 * float(rng.lognormal(0.0, 0.3)))
    assert fit.last_fit is not None
    assert fit.estimate() is None


def test_the_cauchy_solver_lands_where_scipy_least_squares_does() -> None:
    from scipy.optimize import least_squares

    from rfhoming.host.estimation.bearing_fit import _cauchy_least_squares

    rng = np.random.default_rng(5)
    path = _path(120)
    a = np.array(_bearings(rng, path, slice(40, 60), 35.0, 0.1))
    x, y = np.array(path).T

    def fun(p: np.ndarray) -> np.ndarray:
        return np.remainder(np.arctan2(p[1] - y, p[0] - x) - a + math.pi, 2 * math.pi) - math.pi

    def jac(p: np.ndarray) -> np.ndarray:
        dx, dy = p[0] - x, p[1] - y
        r2 = dx * dx + dy * dy
        return np.stack([-dy / r2, dx / r2], axis=1)

    for start in [(1.0, 1.0), (8.0, -2.0), (4.5, 3.5)]:
        ref = least_squares(fun, start, jac=jac, loss="cauchy", f_scale=1.0, max_nfev=60)
        ours = _cauchy_least_squares(lambda p: (fun(p), jac(p)), start)
        assert ours is not None
        assert math.dist(ours.x, ref.x) < 1e-3 and ours.cost <= ref.cost * (1 + 1e-8)
        assert np.allclose(ours.jac, ref.jac, rtol=1e-2, atol=1e-4)  # scipy's robust-loss scaling
    assert _cauchy_least_squares(lambda p: (fun(p) * np.nan, jac(p)), (1.0, 1.0)) is None
