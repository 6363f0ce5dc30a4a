"""Estimation speed against filterpy, in one run.

- fixed-point scalar Kalman, µs/sample, vs filterpy KalmanFilter on the same 1-D model;
- the batch filter (kalman_batch) in samples/s;
- one S4 EKF step (3 receivers + beacon, 2-D), µs, vs a filterpy ExtendedKalmanFilter of the
  same model (same h and Jacobian functions), for one beacon and per beacon in a batch;
- one particle-filter step at N = 1000 (predict, weights, systematic resampling), µs, vs the
  same step with filterpy's systematic_resample.

    python bench/estimation_bench.py [--json]

Times are CPU time (``time.process_time``), the best of a few repeats: on a shared machine the
wall clock measures the other users too.

Needs the bench extra: pip install -e '.[bench]'
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from collections.abc import Callable

import numpy as np

from rfhoming.host.estimation.beacon import BeaconEkf, S4Model, jacobian, measure
from rfhoming.host.estimation.filters import ScalarKalman, kalman_batch
from rfhoming.host.estimation.fixed import to_q8
from rfhoming.host.estimation.particle import ParticleFilter, PfParams


def best(fn: Callable[[], None], repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def bench_kalman(samples: int = 20000) -> dict:
    from filterpy.kalman import KalmanFilter

    rng = np.random.default_rng(0)
    z = (-70 + rng.normal(0, 4, samples)).tolist()
    zq = [to_q8(v) for v in z]

    def ours() -> None:
        k = ScalarKalman(0.05, 9.0)
        update = k.update
        for v in zq:
            update(v)

    def theirs() -> None:
        kf = KalmanFilter(dim_x=1, dim_z=1)
        kf.x = np.array([[z[0]]])
        kf.F = np.array([[1.0]])
        kf.H = np.array([[1.0]])
        kf.P *= 9.0
        kf.Q = np.array([[0.05]])
        kf.R = np.array([[9.0]])
        for v in z[: samples // 10]:
            kf.predict()
            kf.update(v)

    t_ours = best(ours) / samples * 1e6
    t_theirs = best(theirs, 3) / (samples // 10) * 1e6
    batch = np.array([zq] * 200).T.copy()  # (T, 200 series)
    t_batch = best(lambda: kalman_batch(batch), 3)
    return {"fixed_us_per_sample": t_ours, "filterpy_us_per_sample": t_theirs, "speedup": t_theirs / t_ours,
            "batch_samples_per_s": batch.size / t_batch}


def _s4_inputs(steps: int, k: int, rng: np.random.Generator):
    m = S4Model()
    x0 = np.concatenate([rng.uniform(0, 4, (k, 6)), rng.uniform(0, 4, (k, 2))], axis=1)
    u = rng.normal(0, 0.02, (steps, k, 6))
    z = x0[None, :, :6] + np.cumsum(u, axis=0)
    rssi = measure(m, np.concatenate([z, np.broadcast_to(x0[None, :, 6:], (steps, k, 2))], axis=2).reshape(-1, 8))
    rssi = rssi.reshape(steps, k, -1)[:, :, 6:] + rng.normal(0, 3, (steps, k, 3))
    return m, x0, u, z, rssi


def bench_ekf(steps: int = 400, batch: int = 1000) -> dict:
    from filterpy.kalman import ExtendedKalmanFilter

    rng = np.random.default_rng(1)
    m, x0, u, z, rssi = _s4_inputs(steps, 1, rng)
    p0 = np.eye(8)

    def ours() -> None:
        f = BeaconEkf(m, x0, p0)
        for s in range(steps):
            f.predict(u[s])
            f.update(z[s], rssi[s])

    def theirs() -> None:
        f = ExtendedKalmanFilter(dim_x=8, dim_z=9, dim_u=6)
        f.x = x0[0].reshape(8, 1).copy()
        f.P = p0.copy()
        f.F = np.eye(8)
        f.B = np.vstack([np.eye(6), np.zeros((2, 6))])
        f.Q = np.diag([m.q] * 6 + [0, 0])
        f.R = np.diag([m.r_pos] * 6 + [m.r_rssi] * 3)

        def hj(x: np.ndarray) -> np.ndarray:
            return jacobian(m, x.reshape(1, -1))[0]

        def hx(x: np.ndarray) -> np.ndarray:
            return measure(m, x.reshape(1, -1))[0].reshape(-1, 1)

        for s in range(steps):
            f.predict(u[s][0].reshape(6, 1))
            f.update(np.concatenate([z[s][0], rssi[s][0]]).reshape(-1, 1), hj, hx)

    t_ours = best(ours, 3) / steps * 1e6
    t_theirs = best(theirs, 3) / steps * 1e6
    m, xb, ub, zb, rb = _s4_inputs(50, batch, np.random.default_rng(2))

    def batched() -> None:
        f = BeaconEkf(m, xb, p0)
        for s in range(50):
            f.predict(ub[s])
            f.update(zb[s], rb[s])

    t_batch = best(batched, 3) / 50 / batch * 1e6
    return {"ours_us_per_step": t_ours, "filterpy_us_per_step": t_theirs, "speedup_single": t_theirs / t_ours,
            "ours_batched_us_per_beacon_step": t_batch, "speedup_batched": t_theirs / t_batch, "batch": batch}


class _FilterpyResampled(ParticleFilter):
    def resample(self) -> None:
        from filterpy.monte_carlo import systematic_resample

        idx = systematic_resample(self.w)
        self.x = self.x.take(idx, axis=1)
        self.w.fill(1.0 / self.params.n)
        self.resamples += 1


def bench_pf(steps: int = 300) -> dict:
    rng = np.random.default_rng(3)
    fixes = [(rng.uniform(2, 8), rng.uniform(-math.pi, math.pi)) for _ in range(steps)]

    def run(cls: type) -> Callable[[], None]:
        def go() -> None:
            pf = cls(PfParams(), np.random.default_rng(4))
            pf.update((0.0, 0.0, 0.0), 5.0, 0.3)
            for s_r, s_t in fixes:
                pf.predict(0.1)
                pf.update((0.0, 0.0, 0.0), s_r, s_t)
                pf.resample()

        return go

    t_ours = best(run(ParticleFilter), 3) / steps * 1e6
    t_theirs = best(run(_FilterpyResampled), 3) / steps * 1e6
    return {"n": 1000, "ours_us_per_step": t_ours, "filterpy_resampler_us_per_step": t_theirs,
            "speedup": t_theirs / t_ours}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    try:
        import filterpy  # noqa: F401
    except ImportError:
        print("estimation_bench needs filterpy: pip install -e '.[bench]'", file=sys.stderr)
        return 2
    result = {"python": platform.python_version(), "kalman": bench_kalman(), "ekf": bench_ekf(), "pf": bench_pf()}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    k, e, p = result["kalman"], result["ekf"], result["pf"]
    print(f"scalar Kalman   fixed {k['fixed_us_per_sample']:.2f} us/sample   filterpy {k['filterpy_us_per_sample']:.1f}   {k['speedup']:.0f}x   batch {k['batch_samples_per_s']:,.0f} samples/s")
    print(f"S4 EKF step     ours {e['ours_us_per_step']:.1f} us   filterpy {e['filterpy_us_per_step']:.1f} us   {e['speedup_single']:.1f}x   "
          f"batched {e['ours_batched_us_per_beacon_step']:.2f} us/beacon ({e['speedup_batched']:.0f}x)")
    print(f"PF step N=1000  ours {p['ours_us_per_step']:.1f} us   with filterpy resampler {p['filterpy_resampler_us_per_step']:.1f} us   {p['speedup']:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
