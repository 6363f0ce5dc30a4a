"""Encoder: byte-exact board output per dialect, and encode -> decode round trips."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.protocol.uconnect import (
    AngleEvent,
    Dialect,
    Echo,
    FinalCode,
    InfoLine,
    UConnectDecoder,
    encode_angle_event,
    encode_answer,
    encode_startup,
)
from rfhoming.protocol.uconnect.encoder import encode_tag_data
from strategies import angle_events

EVENT = AngleEvent("CCF9578E0D8A", -42, 20, 0, -43, 37, "CCF9578E0D89", "", 15869, 23, -5, 3)


@pytest.mark.parametrize(
    ("dialect", "wire"),
    [
        (Dialect.V1_0, b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869\r\n'),
        (Dialect.V1_2, b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869\r\n'),
        (Dialect.V2, b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869,23\r\n'),
        (Dialect.EMBED, b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869,23,-5,3\r\n'),
    ],
)
def test_byte_exact_per_dialect(dialect: Dialect, wire: bytes) -> None:
    assert encode_angle_event(EVENT, dialect) == wire
    assert wire.count(b",") + 1 == dialect.field_count


def test_answer_shapes() -> None:
    assert encode_answer() == b"\r\nOK\r\n"
    assert encode_answer(ok=False) == b"\r\nERROR\r\n"
    assert encode_answer(["+UMLA:CCF9578E0D89"]) == b"\r\n+UMLA:CCF9578E0D89\r\nOK\r\n"
    assert encode_startup() == b"\r\n+STARTUP\r\n"


def test_echo_then_answer_decodes_as_a_session() -> None:
    d = UConnectDecoder()
    items = d.feed(b"AT+GMI\r" + encode_answer(['"u-blox"']))
    assert items == [Echo("AT+GMI"), InfoLine('"u-blox"'), FinalCode(True)]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"azimuth": 91}, "azimuth"),
        ({"rssi1": 21}, "rssi1"),
        ({"channel": 40}, "channel"),
        ({"instance_id": "ccf9578e0d8a"}, "instance_id"),
        ({"user_str": 'say "hi"'}, "user_str"),
        ({"anchor_id": "x" * 31}, "anchor_id"),
        ({"seq": None}, "event counter"),
    ],
)
def test_encoder_refuses_what_the_board_never_writes(change: dict, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        encode_angle_event(EVENT._replace(**change), Dialect.V2)


@given(st.sampled_from(list(Dialect)).flatmap(lambda d: st.tuples(st.just(d), angle_events(d))))
def test_round_trip_every_dialect(dialect_event) -> None:
    dialect, event = dialect_event
    assert UConnectDecoder().feed(encode_angle_event(event, dialect)) == [event]


@given(st.binary(max_size=40))
def test_tag_data_round_trip(payload: bytes) -> None:
    (item,) = UConnectDecoder().feed(encode_tag_data("CCF9578E0D8A", payload))
    assert (item.kind, item.instance_id, item.payload) == ("tag_data", "CCF9578E0D8A", payload)
