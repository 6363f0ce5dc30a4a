"""Fixed-point filters: bounded error against float references; batch == scalar, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.host.estimation import filters as f
from rfhoming.host.estimation.fixed import bam16_to_deg, deg_to_bam16, div_round, from_q8, sat, to_q8, wrap16, wrap_deg

rssi_q8 = st.lists(st.integers(to_q8(-110), to_q8(-20)), min_size=1, max_size=120)
angles_bam = st.lists(st.integers(0, 65535), min_size=1, max_size=120)
LSB8 = 1 / 256


def test_q_helpers_saturate_and_round() -> None:
    assert to_q8(200.0) == 32767 and to_q8(-200.0) == -32768
    assert sat(1 << 40, 32) == (1 << 31) - 1
    assert div_round(5, 2) == 3 and div_round(-5, 2) == -3 and div_round(4, 3) == 1
    assert wrap16(65535) == -1 and bam16_to_deg(32768) == -180.0


@given(rssi_q8, st.integers(1, 16))
def test_moving_average_error_bound(samples: list[int], n: int) -> None:
    fx, fl = f.MovingAverage(n), f.MovingAverageFloat(n)
    for s in samples:
        assert abs(from_q8(fx.update(s)) - fl.update(from_q8(s))) <= LSB8 / 2 + 1e-12


@given(rssi_q8, st.integers(0, 8))
def test_ema_shift_error_bound(samples: list[int], shift: int) -> None:
    fx = f.Ema(shift=shift)
    fl = f.EmaFloat(fx.alpha)
    bound = (2**shift + 1) / 65536 + LSB8 / 2
    for s in samples:
        assert abs(from_q8(fx.update(s)) - fl.update(from_q8(s))) <= bound


@given(rssi_q8, st.integers(100, 32767))
def test_ema_q15_error_bound(samples: list[int], alpha_q15: int) -> None:
    fx = f.Ema(alpha_q15=alpha_q15)
    fl = f.EmaFloat(fx.alpha)
    bound = (32768 / alpha_q15 + 1) / 65536 + LSB8 / 2
    for s in samples:
        assert abs(from_q8(fx.update(s)) - fl.update(from_q8(s))) <= bound


@given(st.lists(st.integers(-1000, 1000), min_size=1, max_size=80), st.integers(1, 9))
def test_running_median_matches_sorting(samples: list[int], n: int) -> None:
    m = f.RunningMedian(n)
    for t, s in enumerate(samples):
        window = sorted(samples[max(0, t - n + 1) : t + 1])
        assert m.update(s) == window[(len(window) - 1) // 2]


@given(rssi_q8, st.floats(0.001, 5.0), st.floats(0.5, 50.0))
def test_scalar_kalman_error_bound(samples: list[int], q: float, r: float) -> None:
    fx, fl = f.ScalarKalman(q, r), f.ScalarKalmanFloat(q, r)
    for s in samples:
        assert abs(from_q8(fx.update(s)) - fl.update(from_q8(s))) <= 0.02
    assert fx.variance == pytest.approx(fl._p, abs=0.01)


def test_kalman_cuts_rssi_noise_like_s3() -> None:
    rng = np.random.default_rng(0)
    z = -70 + rng.normal(0, 4.0, 2000)
    k = f.ScalarKalman(q=0.001, r=16.0)
    out = np.array([from_q8(k.update(to_q8(v))) for v in z])
    assert out[500:].std() < 0.5 < 4.0 * 0.9 < z.std()


@given(angles_bam, st.integers(1, 12))
def test_circular_moving_average_error_bound(samples: list[int], n: int) -> None:
    fx, fl = f.CircularMovingAverage(n), f.CircularMovingAverageFloat(n)
    for s in samples:
        got, want = bam16_to_deg(fx.update(s)), fl.update(bam16_to_deg(s))
        assert abs(wrap_deg(got - want)) <= 360 / 65536 / 2 + 1e-9


@given(angles_bam, st.integers(0, 8))
def test_circular_ema_error_bound(samples: list[int], shift: int) -> None:
    fx, fl = f.CircularEma(shift), f.CircularEmaFloat(2.0**-shift)
    for s in samples:
        got, want = bam16_to_deg(fx.update(s)), fl.update(bam16_to_deg(s))
        assert abs(wrap_deg(got - want)) <= 360 / 65536 * (0.5 + 2**shift / 65536) + 1e-9


@given(angles_bam, st.floats(0.01, 20.0), st.floats(1.0, 400.0))
def test_circular_kalman_error_bound(samples: list[int], q: float, r: float) -> None:
    fx, fl = f.CircularKalman(q, r), f.CircularKalmanFloat(q, r)
    for s in samples:
        got, want = bam16_to_deg(fx.update(s)), fl.update(bam16_to_deg(s))
        assert abs(wrap_deg(got - want)) <= 0.05


def test_circular_filters_cross_the_wrap() -> None:
    samples = [170, 178, -176, -170, 175, -179]
    cma = f.CircularMovingAverage(6)
    for deg in samples:
        out = bam16_to_deg(cma.update(deg_to_bam16(deg)))
    assert abs(wrap_deg(out - 179.67)) < 0.05  # not ~0°, as a naive mean would say
    med = f.CircularMedian(5)
    for deg in (179, -179, 178, -178, 180):
        out = bam16_to_deg(med.update(deg_to_bam16(deg)))
    assert abs(wrap_deg(out - 180)) < 0.01


@given(st.lists(st.lists(st.integers(-28000, -5000), min_size=3, max_size=3), min_size=1, max_size=60),
       st.integers(1, 12), st.integers(0, 6))
def test_batch_forms_are_bit_identical(rows: list[list[int]], n: int, shift: int) -> None:
    a = np.array(rows, dtype=np.int64)
    for col in range(a.shape[1]):
        series = a[:, col].tolist()
        ma, em, eq, md, kf = f.MovingAverage(n), f.Ema(shift), f.Ema(alpha_q15=9000), f.RunningMedian(n | 1), f.ScalarKalman(0.05, 9.0)
        assert f.moving_average_batch(a, n)[:, col].tolist() == [ma.update(s) for s in series]
        assert f.ema_batch(a, shift)[:, col].tolist() == [em.update(s) for s in series]
        assert f.ema_batch(a, alpha_q15=9000)[:, col].tolist() == [eq.update(s) for s in series]
        assert f.running_median_batch(a, n | 1)[:, col].tolist() == [md.update(s) for s in series]
        assert f.kalman_batch(a, 0.05, 9.0)[:, col].tolist() == [kf.update(s) for s in series]


def test_bad_alpha_is_refused() -> None:
    with pytest.raises(ValueError, match="alpha_q15"):
        f.Ema(alpha_q15=40000)


@given(st.lists(st.floats(-179.9, 179.9), min_size=1, max_size=80), st.sampled_from(f.ANGLE_FILTERS),
       st.floats(5.0, 100.0))
def test_angle_filter_in_degrees_and_seconds_matches_its_fixed_point_filter(samples, kind, rate_hz) -> None:
    """The degrees/seconds API is the BAM16 filter with its memory converted at the given rate."""
    unit = f.AngleFilter(kind, rate_hz, window_s=0.3, tau_s=0.3, q_deg2_per_s=5.0, r_deg2=16.0)
    n = max(1, round(0.3 * rate_hz))
    fixed = {"mean": f.CircularMovingAverage(n), "median": f.CircularMedian(n),
             "ema": f.CircularEma(max(0, round(math.log2(max(1.0, 0.3 * rate_hz))))),
             "kalman": f.CircularKalman(5.0 / rate_hz, 16.0)}[kind]
    for deg in samples:
        got = unit.update(deg)
        assert -180 <= got < 180
        assert got == bam16_to_deg(fixed.update(deg_to_bam16(deg)))


def test_angle_filter_memory_is_in_seconds_not_samples() -> None:
    """The same 0.5 s window at 10 Hz and at 50 Hz forgets a step after the same time."""
    for rate in (10.0, 50.0):
        mean = f.AngleFilter("mean", rate, window_s=0.5)
        out = [mean.update(0.0 if k < rate else 40.0) for k in range(int(2 * rate))]
        settled = next(k for k, v in enumerate(out) if abs(v - 40.0) < 0.01) / rate
        assert abs(settled - (1.5 - 1 / rate)) < 1e-9  # the window's last old sample leaves at 1.5 s
