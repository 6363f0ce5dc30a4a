"""The emulator's scalar draws give numpy's own values from the same stream (byte-identical runs)."""

from __future__ import annotations

import numpy as np
import pytest

from rfhoming.emulator import draws


@pytest.mark.parametrize(("loc", "scale"), [(0, 1.5), (0.0, 0.0), (-3.25, 7.0), (12.5, 1e-3)])
def test_normal_is_numpys_normal(loc: float, scale: float) -> None:
    ours, theirs = np.random.default_rng(7), np.random.default_rng(7)
    got = [draws.normal(ours, loc, scale) for _ in range(5000)]
    want = [float(theirs.normal(loc, scale)) for _ in range(5000)]
    assert got == want
    assert ours.random() == theirs.random()  # the streams are in step afterwards


@pytest.mark.parametrize(("low", "high"), [(0, 0.3), (-2.0, 2.0), (0.0, 0.0), (5.5, 9.75)])
def test_uniform_is_numpys_uniform(low: float, high: float) -> None:
    ours, theirs = np.random.default_rng(8), np.random.default_rng(8)
    got = [draws.uniform(ours, low, high) for _ in range(5000)]
    want = [float(theirs.uniform(low, high)) for _ in range(5000)]
    assert got == want
    assert ours.random() == theirs.random()
