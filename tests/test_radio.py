"""Radio and AoA models: fold, noise statistics through firmware and codec, path loss."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfhoming.emulator.radio import AoaModel, PathLossModel, RadioChannel, fold_front, idealised_rssi, measure_azimuth
from rfhoming.firmware.xplr_aoa import Advertisement, XplrAoaFirmware
from rfhoming.protocol.uconnect import UConnectDecoder
from rfhoming.protocol.uconnect import commands as c


@pytest.mark.parametrize(("true", "folded"), [(0, 0), (45, 45), (90, 90), (120, 60), (-150, -30), (180, 0), (270, -90)])
def test_front_back_fold(true: float, folded: float) -> None:
    assert fold_front(true) == pytest.approx(folded)


def test_board_sign_left_is_negative() -> None:
    model = AoaModel(angle_deg=0.0)
    assert measure_azimuth(model, 30.0, np.random.default_rng(0)) == -30.0
    assert measure_azimuth(model, 150.0, np.random.default_rng(0)) == -30.0


def events_through_codec(model: AoaModel, true_ccw: float, n: int) -> np.ndarray:
    """Angles as a host reads them: model -> firmware -> +UUDF bytes -> decoder."""
    rng = np.random.default_rng(7)
    fw = XplrAoaFirmware()
    fw.tick(1000)  # the board ignores the host for a second after +STARTUP
    fw.receive(c.set_config(8, 0).wire + c.store().wire)  # no median smoothing
    fw.receive(c.restart().wire)
    fw.tick(1000)
    decoder = UConnectDecoder()
    decoder.feed(fw.read())
    out = []
    for k in range(n):
        fw.tick(2000 + k * 20)
        fw.on_advertisement(Advertisement("CCF9578E0D8A", "", measure_azimuth(model, true_ccw, rng), 0, -60, -60))
        out += [i.azimuth for i in decoder.feed(fw.read()) if i.kind == "angle"]
    assert len(out) == n
    return -np.array(out, dtype=float)  # back to CCW


@pytest.mark.parametrize("true", [0.0, 40.0, -70.0])
def test_gaussian_angle_error_matches_the_model(true: float) -> None:
    model = AoaModel("gaussian", angle_deg=3.0, edge_growth=3.0)
    errors = events_through_codec(model, true, 2500) - true
    sigma = math.hypot(model.sigma_deg(true), 1 / math.sqrt(12))  # plus integer rounding
    assert abs(errors.mean()) < 4 * sigma / math.sqrt(len(errors))
    assert errors.std() == pytest.approx(sigma, rel=0.08)


def test_accuracy_degrades_toward_90_degrees() -> None:
    model = AoaModel("gaussian", angle_deg=2.0, edge_growth=3.0)
    assert model.sigma_deg(80) > 2.5 * model.sigma_deg(0)


@pytest.mark.parametrize("config", [1, 3, 5])
def test_s0_uniform_presets(config: int) -> None:
    model = AoaModel.s0_preset(config)
    errors = events_through_codec(model, 10.0, 2000) - 10.0
    half = model.angle_deg
    assert errors.min() >= -half - 1 and errors.max() <= half + 1
    assert errors.std() == pytest.approx(math.sqrt(half**2 / 3 + 1 / 12), rel=0.08)


def test_idealised_distance_noise_inverts_to_the_preset_range() -> None:
    model, path = AoaModel.s0_preset(4), PathLossModel()
    rng = np.random.default_rng(1)
    d = np.array([path.distance_for(idealised_rssi(model, path, 5.0, 0.0, rng)) for _ in range(2000)])
    assert d.min() >= 5 * 0.8 - 1e-9 and d.max() <= 5 * 1.2 + 1e-9
    assert abs(d.mean() - 5) < 0.05


def test_path_loss_statistics_and_per_link_bias() -> None:
    model = PathLossModel(fast_sigma_db=3.0, link_sigma_db=4.0, wall_loss_db=6.0)
    rng = np.random.default_rng(3)
    channel = RadioChannel(model, rng)
    samples = np.array([channel.received_dbm(("tag", "rx"), 4.0, 0.0, 1) for _ in range(3000)])
    mean = model.mean_dbm(4.0, 0.0, 1)
    bias = channel._bias[("tag", "rx")]
    assert samples.mean() == pytest.approx(mean + bias, abs=0.25)
    assert samples.std() == pytest.approx(3.0, rel=0.06)
    biases = [RadioChannel(model, np.random.default_rng(s)).received_dbm(("a", "b"), 1.0, 0, 0) for s in range(400)]
    assert np.std(biases) == pytest.approx(5.0, rel=0.1)  # hypot(3, 4): the total scatter
    assert channel.received_dbm(("tag", "rx"), 100.0, 0.0, 0) is None


def test_rician_fading_adds_spread() -> None:
    calm = PathLossModel(fast_sigma_db=0.0, link_sigma_db=0.0)
    faded = PathLossModel(fast_sigma_db=0.0, link_sigma_db=0.0, rician_k=3.0)
    a = [RadioChannel(calm, np.random.default_rng(0)).received_dbm(("a", "b"), 3, 0, 0) for _ in range(10)]
    ch = RadioChannel(faded, np.random.default_rng(0))
    b = [ch.received_dbm(("a", "b"), 3, 0, 0) for _ in range(2000)]
    assert np.std(a) < 1e-9 and 1.0 < np.std(b) < 5.0
