"""A tag a person carries and stands with (the 2026-12 field report's withheld kind): the ``carried`` profile's
``[aoa.person]``, its stance offsets and the body's shadow (emulator/aoa_error.py), and the
emulated carried walks of bench/carried_walks.py. No recording is read."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from rfhoming.emulator.aoa_error import MeasuredAoa, Stance
from rfhoming.host.site import parse as parse_site
from rfhoming.host.radio_fit import write
from rfhoming.protocol.radio_profile import AngleError, Person, ProfileError, load, to_toml

BENCH = Path(__file__).resolve().parents[1] / "bench"
BOARD = (0.0, 3.0, 2.3, 0.0)
"""A wall anchor facing +x."""


def stance(person: Person, seed: int, room: int = 7) -> Stance:
    axis = AngleError(field_length_m=2.0, field_heading_m=1.0)
    return Stance(person, axis, axis, np.random.default_rng(seed), np.random.default_rng(room))


def walk_and_stand(s: Stance, start: float, where: tuple[float, float], facing: float = 0.0) -> list[tuple[float, float]]:
    """Walk 2 s towards ``where`` at 0.5 m/s, then stand 5 s there: the offsets of each report (10 Hz)."""
    out = []
    for k in range(70):
        t = start + k / 10
        moved = max(0.0, 2.0 - t + start) * 0.5
        pose = (where[0] - moved * math.cos(facing), where[1] - moved * math.sin(facing), 1.1, facing)
        out.append(s.offsets("tag", t, BOARD, pose))
    return out


def test_the_offset_stays_put_through_a_stop_and_is_drawn_anew_at_the_next() -> None:
    s = stance(Person(stance_az_sigma_deg=5.0, stance_el_sigma_deg=5.0), seed=1)
    first = walk_and_stand(s, 0.0, (4.0, 3.0))
    second = walk_and_stand(s, 10.0, (4.0, 3.0))  # walks off and comes back to the same place
    assert all(o == (0.0, 0.0) for o in first[1:20])  # moving: no stance offset
    assert len(set(first[25:])) == 1 and first[-1] != (0.0, 0.0)  # standing: one offset, held
    assert len(set(second[25:])) == 1 and second[-1] != first[-1]  # the next stop: another draw


def test_the_place_part_is_the_rooms_and_the_drawn_part_the_walks() -> None:
    place = Person(stance_az_field_deg=8.0, stance_el_field_deg=8.0)
    walks = [walk_and_stand(stance(place, seed=k), 0.0, (5.0, 2.0))[-1] for k in (1, 2)]
    assert walks[0] == walks[1] and walks[0] != (0.0, 0.0)  # one room, one place, one facing: the same
    elsewhere = walk_and_stand(stance(place, seed=1), 0.0, (9.0, 5.0))[-1]
    assert elsewhere != walks[0]
    other_room = walk_and_stand(stance(place, seed=1, room=8), 0.0, (5.0, 2.0))[-1]
    assert other_room != walks[0]
    drawn = Person(stance_az_field_deg=8.0, stance_az_sigma_deg=4.0)
    again = [walk_and_stand(stance(drawn, seed=k), 0.0, (5.0, 2.0))[-1] for k in (1, 2)]
    assert again[0] != again[1]  # the same place, another walk: differs by the drawn part


def test_a_stop_wanders_slowly() -> None:
    s = stance(Person(stance_wander_deg=3.0, stance_wander_s=60.0), seed=3)
    standing = [o[0] for o in walk_and_stand(s, 0.0, (4.0, 3.0))[25:]]
    steps = np.abs(np.diff(standing))
    assert len(set(standing)) > 1 and steps.max() < 3.0 * 0.3  # moves, by far less than its spread per 0.1 s


def test_the_body_shadows_a_board_behind_its_carrier() -> None:
    s = stance(Person(shadow_gain=0.5), seed=1)
    assert s.shadow(BOARD, (4.0, 3.0, 1.1, math.pi)) == pytest.approx(1.0)  # facing the board
    assert s.shadow(BOARD, (4.0, 3.0, 1.1, 0.0)) == pytest.approx(1.5)  # its back to the board
    assert s.shadow(BOARD, (4.0, 3.0, 1.1, math.pi / 2)) == pytest.approx(1.0)


def test_the_carried_profile_sources_every_figure_and_the_measured_one_has_no_person() -> None:
    carried, measured = load("carried"), load("measured")
    assert carried.aoa is not None and measured.aoa is not None
    assert measured.aoa.person == Person() and "person" not in to_toml(measured)["aoa"]
    raw = to_toml(carried)["aoa"]
    assert raw["person"]["stance_az_field_deg"] > 0
    for key in raw["person"]:
        figure = f"person.{key}"
        assert "the 2026-12 field report" in carried.aoa.sources[figure].how if figure in carried.aoa.sources \
            else figure in carried.aoa.assumed, figure
    board = MeasuredAoa(measured.aoa, "west", np.random.default_rng(1), 1)
    assert board.stance is None  # the measured profile's draws are as they were


def test_a_person_figure_needs_a_source(tmp_path: Path) -> None:
    profile = load("carried")
    write(profile, tmp_path / "copy.toml")
    assert load(tmp_path / "copy.toml").aoa == profile.aoa
    text = (tmp_path / "copy.toml").read_text()
    (tmp_path / "bad.toml").write_text(text.replace('[aoa.sources."person.stance_az_sigma_deg"]',
                                                    '[aoa.sources."person.unused"]'))
    with pytest.raises(ProfileError, match=r"stance_az_sigma_deg has no source"):
        load(tmp_path / "bad.toml")


def test_a_carried_walk_is_long_and_mostly_four_stops(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(BENCH))  # its own imports: fidelity, real_aoa
    spec = importlib.util.spec_from_file_location("carried_walks", BENCH / "carried_walks.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    site = parse_site({"site": {"name": "room"}, "anchors": {
        "a": {"id": "000000006501", "position": [0.0, 3.0, 2.3], "yaw_deg": 0.0},
        "b": {"id": "000000006503", "position": [12.0, 3.0, 2.3], "yaw_deg": 180.0},
        "c": {"id": "000000006502", "position": [6.0, 0.0, 2.3], "yaw_deg": 90.0},
        "d": {"id": "000000006504", "position": [6.0, 6.0, 2.3], "yaw_deg": -90.0}}})
    for k in range(3):
        path = bench.carried_walk(np.random.default_rng(k), site)
        stops = sorted((w.leave_s - w.arrive_s for w in path.waypoints), reverse=True)
        span = path.end_s - path.start_s
        assert 250 <= span <= 330 and sum(stops[:4]) / span == pytest.approx(0.87, abs=0.02)
        assert stops[4] < 2.0 and all(0 < w.x < 12 and 0 < w.y < 6 for w in path.waypoints)
