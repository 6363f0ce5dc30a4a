"""ED -> dBm against the RSSI_BASE_VAL table, and the chip's quantisation."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.protocol.at86rf212 import (
    ED_MAX,
    channel_frequency_mhz,
    dbm_to_ed,
    ed_to_dbm,
    rssi_base_dbm,
)


@pytest.mark.parametrize(
    ("page", "channel", "base"),
    [(0, 0, -100), (0, 1, -99), (0, 10, -99), (2, 0, -98), (2, 5, -98), (5, 3, -97)],
)
def test_base_table(page: int, channel: int, base: int) -> None:
    assert rssi_base_dbm(page, channel) == base


def test_unknown_mode_names_the_known_ones() -> None:
    with pytest.raises(ValueError, match="page 0 ch 1-10"):
        rssi_base_dbm(1, 0)


def test_ed_conversion() -> None:
    assert ed_to_dbm(0, -99) == -99
    assert ed_to_dbm(84, -99) == -15
    assert ed_to_dbm(10, -99, 1.03) == pytest.approx(-88.7)
    assert ed_to_dbm(255, -99) is None
    with pytest.raises(ValueError, match="ED 85"):
        ed_to_dbm(85, -99)


@given(st.floats(-140, 30), st.sampled_from([-100, -99, -98, -97]), st.sampled_from([1.0, 1.03]))
def test_quantisation_saturates_and_is_within_half_a_step(power: float, base: int, scale: float) -> None:
    ed = dbm_to_ed(power, base, scale)
    assert 0 <= ed <= ED_MAX
    back = ed_to_dbm(ed, base, scale)
    if base < power < base + ED_MAX * scale:
        assert abs(back - power) <= scale / 2 + 1e-9
    elif power <= base:
        assert ed == 0
    else:
        assert ed == ED_MAX


def test_channel_frequencies() -> None:
    assert channel_frequency_mhz(0) == 868.3
    assert channel_frequency_mhz(1) == 906.0
    assert channel_frequency_mhz(10) == 924.0
