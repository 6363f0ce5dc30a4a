"""Fixed-point filters for RSSI and angles, each with a float reference and a numpy batch form.

Scalar classes keep integer state exactly as firmware would (formats in
:mod:`rfhoming.host.estimation.fixed`): ``update(sample) -> output``. The ``*_float`` classes are the
references the tests bound the error against. The ``*_batch`` functions run many independent
series at once (columns of a (T, M) array) for campaigns and give bit-identical results to the
scalar classes.

RSSI filters take and return Q7.8; angle filters take and return BAM16 and handle the ±180°
wrap (their float references work in degrees). :class:`AngleFilter` is the angle filters at the
public API's units: degrees in and out, memory in seconds.
"""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from rfhoming.host.estimation.fixed import INT32, bam16_to_deg, deg_to_bam16, div_round, sat, wrap16, wrap32, wrap_deg

INT32_MIN, INT32_MAX = INT32

# -- moving average (S1: N = 10) --------------------------------------------------------------


class MovingAverage:
    """Mean of the last ``n`` Q7.8 samples (fewer at start-up); int32 running sum."""

    def __init__(self, n: int = 10) -> None:
        self.n = n
        self._window: deque[int] = deque(maxlen=n)
        self._sum = 0

    def update(self, q8: int) -> int:
        if len(self._window) == self.n:
            self._sum -= self._window[0]
        self._window.append(q8)
        self._sum += q8
        return div_round(self._sum, len(self._window))


class MovingAverageFloat:
    def __init__(self, n: int = 10) -> None:
        self._window: deque[float] = deque(maxlen=n)

    def update(self, x: float) -> float:
        self._window.append(x)
        return sum(self._window) / len(self._window)


def _div_round_np(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    return np.asarray(np.where(num >= 0, (num + den // 2) // den, -((-num + den // 2) // den)))


def moving_average_batch(q8: np.ndarray, n: int = 10) -> np.ndarray:
    """(T, M) or (T,) Q7.8 -> the same outputs as MovingAverage per column."""
    x = np.asarray(q8, dtype=np.int64)
    csum = np.cumsum(x, axis=0)
    shifted = np.zeros_like(csum)
    shifted[n:] = csum[:-n]
    counts = np.minimum(np.arange(1, len(x) + 1), n).reshape((-1,) + (1,) * (x.ndim - 1))
    return _div_round_np(csum - shifted, counts)


# -- exponential moving average -----------------------------------------------------------------


class Ema:
    """y += α (x − y); state Q7.16 in int32; α = 2^−shift, or ``alpha_q15`` (Q0.15) if given.

    The first sample initialises the state (no start-up transient from zero).
    """

    def __init__(self, shift: int = 3, alpha_q15: int | None = None) -> None:
        if alpha_q15 is not None and not 0 < alpha_q15 < 1 << 15:
            raise ValueError("alpha_q15 must be in 1..32767 (α in (0, 1))")
        self.shift = shift
        self.alpha_q15 = alpha_q15
        self._y: int | None = None

    @property
    def alpha(self) -> float:
        return self.alpha_q15 / 32768 if self.alpha_q15 is not None else 2.0 ** -self.shift

    def update(self, q8: int) -> int:
        x = q8 << 8  # Q7.8 -> Q7.16
        if self._y is None:
            self._y = x
        elif self.alpha_q15 is None:
            self._y = sat(self._y + ((x - self._y) >> self.shift), 32)
        else:
            self._y = sat(self._y + ((self.alpha_q15 * (x - self._y)) >> 15), 32)
        return sat((self._y + 128) >> 8, 16)


class EmaFloat:
    def __init__(self, alpha: float) -> None:
        self.alpha = alpha
        self._y: float | None = None

    def update(self, x: float) -> float:
        self._y = x if self._y is None else self._y + self.alpha * (x - self._y)
        return self._y


def ema_batch(q8: np.ndarray, shift: int = 3, alpha_q15: int | None = None) -> np.ndarray:
    x = np.asarray(q8, dtype=np.int64) << 8
    out = np.empty_like(x)
    y = x[0].copy()
    out[0] = (y + 128) >> 8
    for t in range(1, len(x)):
        step = (x[t] - y) >> shift if alpha_q15 is None else (alpha_q15 * (x[t] - y)) >> 15
        y = np.clip(y + step, *INT32)
        out[t] = (y + 128) >> 8
    return np.clip(out, -32768, 32767)


# -- running median -----------------------------------------------------------------------------


class RunningMedian:
    """Median of the last ``n`` samples (the lower middle one for an even count at start-up)."""

    def __init__(self, n: int = 5) -> None:
        self._window: deque[int] = deque(maxlen=n)
        self._sorted: list[int] = []

    def update(self, x: int) -> int:
        if len(self._window) == self._window.maxlen:
            self._sorted.pop(bisect.bisect_left(self._sorted, self._window[0]))
        self._window.append(x)
        bisect.insort(self._sorted, x)
        return self._sorted[(len(self._sorted) - 1) // 2]


def running_median_batch(x: np.ndarray, n: int = 5) -> np.ndarray:
    a = np.asarray(x, dtype=np.int64)
    out = np.empty_like(a)
    for t in range(min(n - 1, len(a))):
        out[t] = np.sort(a[: t + 1], axis=0)[t // 2]
    if len(a) >= n:
        windows = np.lib.stride_tricks.sliding_window_view(a, n, axis=0)
        out[n - 1 :] = np.sort(windows, axis=-1)[..., (n - 1) // 2]
    return out


# -- scalar Kalman for RSSI (S3) ----------------------------------------------------------------


class ScalarKalman:
    """Random-walk model x_k = x_{k−1} + w (var Q), z_k = x_k + v (var R).

    Mean Q7.16 (int32), variances Q16.16 (int32, saturated), gain Q0.15. The first sample
    initialises the mean with variance R.
    """

    def __init__(self, q: float = 0.05, r: float = 9.0) -> None:
        self.q = sat(round(q * 65536), 32)
        self.r = sat(round(r * 65536), 32)
        self._x: int | None = None
        self._p = self.r

    def update(self, q8: int) -> int:
        z = q8 << 8
        x = self._x
        if x is None:
            self._x = z
            return q8
        p = self._p + self.q
        if p > INT32_MAX:  # saturate (sat() inlined: this is the per-sample hot path)
            p = INT32_MAX
        k = (p << 15) // (p + self.r)  # Q0.15, 0 … 32767
        x += (k * (z - x)) >> 15
        if x > INT32_MAX:
            x = INT32_MAX
        elif x < INT32_MIN:
            x = INT32_MIN
        self._x = x
        self._p = ((32768 - k) * p) >> 15
        out = (x + 128) >> 8
        return 32767 if out > 32767 else -32768 if out < -32768 else out

    @property
    def variance(self) -> float:
        return self._p / 65536


class ScalarKalmanFloat:
    def __init__(self, q: float = 0.05, r: float = 9.0) -> None:
        self.q, self.r = q, r
        self._x: float | None = None
        self._p = r

    def update(self, z: float) -> float:
        if self._x is None:
            self._x = z
            return z
        p = self._p + self.q
        k = p / (p + self.r)
        self._x += k * (z - self._x)
        self._p = (1 - k) * p
        return self._x


def kalman_batch(q8: np.ndarray, q: float = 0.05, r: float = 9.0) -> np.ndarray:
    z = np.asarray(q8, dtype=np.int64) << 8
    q_, r_ = sat(round(q * 65536), 32), sat(round(r * 65536), 32)
    out = np.empty_like(z)
    x = z[0].copy()
    p = np.full_like(x, r_)
    out[0] = z[0] >> 8
    for t in range(1, len(z)):
        p = np.minimum(p + q_, INT32[1])
        k = (p << 15) // (p + r_)
        x = np.clip(x + ((k * (z[t] - x)) >> 15), *INT32)
        p = ((32768 - k) * p) >> 15
        out[t] = (x + 128) >> 8
    return np.clip(out, -32768, 32767)


# -- circular versions for angles (BAM16 in, BAM16 out) ------------------------------------------


class CircularMovingAverage:
    """Mean of the last ``n`` angles: the newest one plus the mean of wrapped differences to it
    (correct while the window spans less than 180°)."""

    def __init__(self, n: int = 10) -> None:
        self._window: deque[int] = deque(maxlen=n)

    def update(self, bam: int) -> int:
        self._window.append(bam & 0xFFFF)
        total = sum(wrap16(a - bam) for a in self._window)
        return (bam + div_round(total, len(self._window))) & 0xFFFF


class CircularMovingAverageFloat:
    """Reference with the same definition: newest angle + mean wrapped difference, in degrees.
    (Not the unit-vector mean: for 0°, 0°, 90° that gives 26.6°, this 30°.)"""

    def __init__(self, n: int = 10) -> None:
        self._window: deque[float] = deque(maxlen=n)

    def update(self, deg: float) -> float:
        self._window.append(deg)
        diffs = [wrap_deg(a - deg) for a in self._window]
        return wrap_deg(deg + sum(diffs) / len(diffs))


class CircularEma:
    """y += α·wrap(x − y) with the state in BAM32 (16 extra fraction bits)."""

    def __init__(self, shift: int = 3) -> None:
        self.shift = shift
        self._y: int | None = None

    def update(self, bam: int) -> int:
        x = (bam & 0xFFFF) << 16
        if self._y is None:
            self._y = x
        else:
            self._y = (self._y + (wrap32(x - self._y) >> self.shift)) & 0xFFFFFFFF
        return ((self._y + 0x8000) >> 16) & 0xFFFF


class CircularEmaFloat:
    def __init__(self, alpha: float) -> None:
        self.alpha = alpha
        self._y: float | None = None

    def update(self, deg: float) -> float:
        self._y = deg if self._y is None else wrap_deg(self._y + self.alpha * wrap_deg(deg - self._y))
        return self._y


class CircularMedian:
    """Median of the last ``n`` angles, as wrapped differences to the newest."""

    def __init__(self, n: int = 5) -> None:
        self._window: deque[int] = deque(maxlen=n)

    def update(self, bam: int) -> int:
        self._window.append(bam & 0xFFFF)
        diffs = sorted(wrap16(a - bam) for a in self._window)
        return (bam + diffs[(len(diffs) - 1) // 2]) & 0xFFFF


class CircularKalman:
    """ScalarKalman on an angle: BAM32 mean, innovation wrapped; variances in deg² (Q16.16)."""

    def __init__(self, q: float = 1.0, r: float = 25.0) -> None:
        self.q = sat(round(q * 65536), 32)
        self.r = sat(round(r * 65536), 32)
        self._x: int | None = None
        self._p = self.r

    def update(self, bam: int) -> int:
        z = (bam & 0xFFFF) << 16
        if self._x is None:
            self._x = z
            return bam & 0xFFFF
        p = sat(self._p + self.q, 32)
        k = (p << 15) // (p + self.r)
        self._x = (self._x + ((k * wrap32(z - self._x)) >> 15)) & 0xFFFFFFFF
        self._p = ((32768 - k) * p) >> 15
        return ((self._x + 0x8000) >> 16) & 0xFFFF


class CircularKalmanFloat:
    def __init__(self, q: float = 1.0, r: float = 25.0) -> None:
        self.q, self.r = q, r
        self._x: float | None = None
        self._p = r

    def update(self, deg: float) -> float:
        if self._x is None:
            self._x = deg
            return deg
        p = self._p + self.q
        k = p / (p + self.r)
        self._x = wrap_deg(self._x + k * wrap_deg(deg - self._x))
        self._p = (1 - k) * p
        return self._x


# -- the public API's units: degrees in and out, memory in seconds --------------------------------

ANGLE_FILTERS = ("mean", "median", "ema", "kalman")


class AngleFilter:
    """One of the circular filters above at the public API's units: degrees in and out, its
    memory in seconds at a stated sample rate (the BAM16 fixed-point filter runs inside, as
    firmware would). ``window_s`` sizes the mean and the median, ``tau_s`` the EMA (alpha the
    nearest power of two to 1 / (tau_s rate_hz)); the Kalman filter's process noise is a
    random walk of ``q_deg2_per_s`` (deg^2 per second, so it means the same at any rate) and its
    measurement noise ``r_deg2``. Output in [-180, 180)."""

    def __init__(self, kind: str, rate_hz: float, *, window_s: float = 0.5, tau_s: float = 0.5,
                 q_deg2_per_s: float = 10.0, r_deg2: float = 25.0) -> None:
        if kind not in ANGLE_FILTERS:
            raise ValueError(f"kind must be one of {', '.join(ANGLE_FILTERS)}")
        if not rate_hz > 0 or not window_s > 0 or not tau_s > 0:
            raise ValueError("rate_hz, window_s and tau_s must be positive")
        n = max(1, round(window_s * rate_hz))
        self.kind = kind
        if kind == "mean":
            self._f: CircularMovingAverage | CircularMedian | CircularEma | CircularKalman = CircularMovingAverage(n)
        elif kind == "median":
            self._f = CircularMedian(n)
        elif kind == "ema":
            self._f = CircularEma(max(0, round(math.log2(max(1.0, tau_s * rate_hz)))))
        else:
            self._f = CircularKalman(q_deg2_per_s / rate_hz, r_deg2)

    def update(self, degrees: float) -> float:
        return bam16_to_deg(self._f.update(deg_to_bam16(degrees)))
