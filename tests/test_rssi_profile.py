"""The ``[rssi.NAME]`` tables of a radio profile: what they accept, and how they refuse."""

from __future__ import annotations

import copy
from typing import Any

import pytest

import rfhoming
from rfhoming.protocol import devices
from rfhoming.protocol.rssi_profile import RADIOS, RssiProfile, RssiProfileError, sections


def table() -> dict[str, Any]:
    """A complete table, as bench/fit_rssi.py writes one."""
    return {
        "title": "BLE scanners",
        "exponent": {"mean": 1.9, "sd": 0.2, "low": 1.1, "high": 3.1, "pivot_m": 5.9, "near_m": 1.0,
                     "far_m": 12.0, "source": "links' own fits"},
        "offset": {"sd_db": 2.3, "source": "links' levels"},
        "shadowing": {"sd_db": 3.3, "distance_m": 1.4, "source": "pairs at one place"},
        "residual": {"sd_db": 2.9, "time_s": 1.6, "white_sd_db": 3.3, "source": "pairs in time"},
        "loss": {"fraction_low": 0.07, "fraction_high": 0.19, "burst_s": 0.2, "source": "gaps", "assumed": "why"},
        "polarisation": {"mean_db": 1.6, "sd_db": 6.4, "source": "field 5"},
    }


def test_a_table_reads_back_as_it_was_written() -> None:
    p = RssiProfile.from_table(table(), "rssi.ble")
    assert p.exponent.mean == 1.9 and p.shadowing.distance_m == 1.4 and p.loss is not None and p.loss.burst_s == 0.2
    assert RssiProfile.from_table(p.to_table(), "rssi.ble") == p
    assert p.assumed() == {"loss": "why"}


def test_loss_and_polarisation_may_be_left_out() -> None:
    t = table()
    del t["loss"], t["polarisation"]
    p = RssiProfile.from_table(t)
    assert p.loss is None and p.polarisation is None and "loss" not in p.to_table()


def _set(path: str, value: Any) -> dict[str, Any]:
    t = copy.deepcopy(table())
    *groups, key = path.split(".")
    here = t
    for g in groups:
        here = here[g]
    if value is DELETE:
        del here[key]
    else:
        here[key] = value
    return t


DELETE = object()


@pytest.mark.parametrize(("path", "value", "names"), [
    ("offset", DELETE, "[rssi.ble.offset]"),
    ("shadow", {"sd_db": 1.0}, "'shadow'"),
    ("exponent.sd", -1, "[rssi.ble.exponent] sd = -1"),
    ("shadowing.distance_m", 0, "[rssi.ble.shadowing] distance_m = 0"),
    ("residual.time_s", "fast", "[rssi.ble.residual] time_s = \"fast\""),
    ("residual.white_sd_db", DELETE, "[rssi.ble.residual] lacks white_sd_db"),
    ("residual.colour", 1.0, "colour"),
    ("loss.fraction_high", 0.01, "[rssi.ble.loss] fraction_high = 0.01"),
    ("exponent.mean", 4.0, "[rssi.ble.exponent] mean = 4"),
    ("exponent.near_m", 7.0, "[rssi.ble.exponent] pivot_m = 5.9 must lie between near_m = 7"),
    ("offset.source", "  ", "[rssi.ble.offset] has no source"),
    ("polarisation", 3.0, "[rssi.ble.polarisation]"),
    ("title", 7, "title"),
])
def test_a_bad_table_fails_in_one_line_naming_the_key(path: str, value: Any, names: str) -> None:
    with pytest.raises(RssiProfileError) as caught:
        RssiProfile.from_table(_set(path, value), "rssi.ble")
    message = str(caught.value)
    assert isinstance(caught.value, rfhoming.Error)
    assert names in message and "\n" not in message, message


def test_a_profile_names_only_known_radios() -> None:
    assert set(sections({"ble": table(), "xplr": table()})) == {"ble", "xplr"}
    with pytest.raises(RssiProfileError, match=r"unknown radio \[rssi.wifi\]; the radios are ble, xplr, subghz"):
        sections({"wifi": table()})


def test_every_board_that_measures_rssi_names_its_radio() -> None:
    radios = {name: board.radio for name, (_kind, board) in devices.BOARDS.items()}
    assert radios == {"xplr-aoa": "xplr", "esp32": "ble", "at86rf212": "subghz", "esp-at": "ble", "hci": "ble",
                      "base": None}
    assert {r for r in radios.values() if r} == set(RADIOS)
