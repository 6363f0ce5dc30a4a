"""``kinds=`` of the Python API: every item kind, and nothing else (a typo yielded nothing)."""

from __future__ import annotations

import io
import typing

import pytest

import rfhoming
from rfhoming.api import KINDS, Item, UnknownKind


def item_types() -> list[type]:
    from rfhoming.host.drivers.hci import Advertisement, HciPacket

    named = {"Advertisement": Advertisement, "HciPacket": HciPacket}
    return [named[t.__forward_arg__] if isinstance(t, typing.ForwardRef) else t for t in typing.get_args(Item)]


def test_the_items_are_those_the_device_tables_drivers_yield() -> None:
    """Item is written out for type checkers; it must be every item some kind's driver shows
    (its ``items``), and a Reader's H4 packets, and nothing else."""
    from rfhoming.host.session import driver_class
    from rfhoming.protocol import devices
    from rfhoming.reader import H4Packet

    yielded = {t for record in devices.KINDS.values() for t in driver_class(record).items}
    assert set(item_types()) == yielded | {H4Packet}


def test_the_kinds_are_those_of_the_items() -> None:
    assert set(KINDS) == {t.kind for t in item_types()} and len(KINDS) == len(set(KINDS))


@pytest.mark.parametrize("opener", [rfhoming.open, rfhoming.read, lambda spec, kinds: rfhoming.Reader(io.BytesIO(), kinds=kinds)])
def test_an_unknown_kind_is_refused_with_the_list_of_kinds(opener) -> None:
    with pytest.raises(UnknownKind) as caught:
        opener("capture:run.pcapng", kinds={"angel", "angle"})
    message = str(caught.value)
    assert "'angel'" in message and "'angle'" not in message.split(";")[0] and all(k in message for k in KINDS)
    assert isinstance(caught.value, rfhoming.Error)


def test_a_bare_string_is_not_taken_for_its_letters() -> None:
    with pytest.raises(UnknownKind, match=r"kinds=\{'angle'\}"):
        rfhoming.open("capture:run.pcapng", kinds="angle")  # type: ignore[call-overload]
