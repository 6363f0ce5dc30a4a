"""Command builders validate their arguments; the matcher pairs answers amid URCs."""

from __future__ import annotations

from pathlib import Path

import pytest

from rfhoming.protocol.uconnect import CommandMatcher, UConnectDecoder, encode_answer, encode_startup
from rfhoming.protocol.uconnect import commands as c

OFFICIAL = b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869\r\n'


@pytest.mark.parametrize(
    ("command", "wire"),
    [
        (c.at(), b"AT\r"),
        (c.identify_manufacturer(), b"AT+GMI\r"),
        (c.identify_model(), b"AT+GMM\r"),
        (c.identify_version(), b"AT+GMR\r"),
        (c.identify_software(), b"ATI9\r"),
        (c.local_address(), b"AT+UMLA=1\r"),
        (c.enable_angles(True), b"AT+UDFENABLE=1\r"),
        (c.enable_angles(False), b"AT+UDFENABLE=0\r"),
        (c.set_config(1, 100), b"AT+UDFCFG=1,100\r"),
        (c.set_config(2, "dock A"), b'AT+UDFCFG=2,"dock A"\r'),
        (c.read_config(5), b"AT+UDFCFG=5\r"),
        (c.read_config(), b"AT+UDFCFG?\r"),
        (c.set_filter(c.FILTER_INSTANCE, c.FILTER_APPEND, ("ccf9578e0d8a", "CCF9578E0D8B")),
         b'AT+UDFFILT=2,2,"CCF9578E0D8A","CCF9578E0D8B"\r'),
        (c.set_filter(c.FILTER_INSTANCE, c.FILTER_CLEAR), b"AT+UDFFILT=2,1\r"),
        (c.read_filter(c.FILTER_NAMESPACE), b"AT+UDFFILT=1\r"),
        (c.set_serial(1000000, False), b"AT+UMRS=1000000,2\r"),  # u-connect: 2 = flow control off
        (c.set_serial(115200, True), b"AT+UMRS=115200,1\r"),
        (c.read_serial(), b"AT+UMRS?\r"),
        (c.store(), b"AT&W\r"),
        (c.restart(), b"AT+CPWROFF\r"),
        (c.factory_defaults(), b"AT+UFACTORY\r"),
    ],
)
def test_builders_write_the_documented_command(command: c.Command, wire: bytes) -> None:
    assert command.wire == wire


@pytest.mark.parametrize(
    ("build", "words"),
    [
        (lambda: c.set_config(1, 10001), "0..10000"),
        (lambda: c.set_config(42, 1), "unknown AT\\+UDFCFG tag 42"),
        (lambda: c.set_config(2, "x" * 31), "at most 30"),
        (lambda: c.set_filter(2, 2, ("XYZ",)), "12 hex digits"),
        (lambda: c.set_filter(1, 2, ("CCF9578E0D8A",)), "20 hex digits"),
        (lambda: c.set_filter(3, 1), "filter type"),
        (lambda: c.set_filter(2, 1, ("CCF9578E0D8A",)), "takes no ids"),
        (lambda: c.set_filter(2, 2, tuple(f"{i:012X}" for i in range(101))), "at most 100"),
        (lambda: c.set_serial(1234, True), "not supported"),
        (lambda: c.set_config(2, 'a"b'), "without quotes"),
        (lambda: c.set_config(2, "\xff"), "printable ASCII"),
        (lambda: c.set_config(6, 2), "0..1"),  # 1.x: track unlimited tags, 0/1 (UBX-21004616 A.3.3)
        (lambda: c.set_config(10, 1, "1.x"), "does not exist on 1.x"),
        (lambda: c.set_config(7, 2, "2.x"), "0..1"),
        (lambda: c.set_config(121, 1, "2.x"), "only embed"),
    ],
)
def test_builders_refuse_bad_arguments(build, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        build()


def test_udfcfg_table_per_family() -> None:
    assert c.accepts("1.x", 6, 1) and not c.accepts("1.x", 6, 2)
    assert c.accepts("2.x", 10, 99) and not c.accepts("2.x", 10, 100) and not c.accepts("1.x", 10, 0)
    assert c.accepts("2.x", 13, 1) and c.accepts("embed", 7, 2) and not c.accepts("1.x", 7, 2)
    assert not c.accepts("1.x", 2, 'a"b') and not c.accepts("1.x", 2, "\xff") and c.accepts("1.x", 2, "a,b")
    assert c.set_config(10, 50, "2.x").wire == b"AT+UDFCFG=10,50\r"


def test_protocol_md_shows_the_udfcfg_table_of_the_code() -> None:
    doc = (Path(__file__).parents[1] / "docs" / "protocol.md").read_text()
    doc = doc[doc.index("### `AT+UDFCFG` per firmware family"):]
    for tag, entry in c.UDFCFG.items():
        row = next(line for line in doc.splitlines() if line.startswith(f"| {tag} |"))
        cells = [cell.strip() for cell in row.split("|")[3:6]]
        for fam, cell in zip(c.FAMILIES, cells):
            valid = entry.ranges.get(fam, "absent")
            expected = "—" if valid == "absent" else "≤ 30 chars" if valid is None else f"{valid.start}–{valid.stop - 1}"
            assert cell == expected, (tag, fam)


def run(matcher: CommandMatcher, stream: bytes) -> tuple[list, list]:
    responses, urcs = [], []
    for item in UConnectDecoder().feed(stream):
        response = matcher.on_item(item)
        if response is not None:
            responses.append(response)
        elif item.kind in ("angle", "tag_data"):
            urcs.append(item)
    return responses, urcs


def test_answer_paired_while_urcs_arrive() -> None:
    m = CommandMatcher()
    wire = m.send(c.local_address())
    stream = wire + OFFICIAL + b"\r\n+UMLA:CCF9578E0D89\r\n" + OFFICIAL + b"OK\r\n"
    (response,), urcs = run(m, stream)
    assert response.ok and response.echoed and response.info == ["+UMLA:CCF9578E0D89"]
    assert len(urcs) == 2 and m.pending is None


def test_error_answer_and_one_command_at_a_time() -> None:
    m = CommandMatcher()
    m.send(c.read_config(9))
    with pytest.raises(RuntimeError, match="still waiting"):
        m.send(c.at())
    (response,), _ = run(m, b"AT+UDFCFG=9\r" + encode_answer(ok=False))
    assert not response.ok and response.info == []


def test_reboot_mid_command_ends_it() -> None:
    m = CommandMatcher()
    m.send(c.at())
    (response,), _ = run(m, b"AT\r" + encode_startup())
    assert response.restarted and not response.ok


def test_answer_without_echo_still_pairs() -> None:
    m = CommandMatcher()
    m.send(c.identify_version())
    (response,), _ = run(m, encode_answer(['"2.1.0-010"']))
    assert response.ok and not response.echoed and response.info == ['"2.1.0-010"']


def test_stray_lines_are_counted_not_guessed() -> None:
    m = CommandMatcher()
    run(m, b"\r\nOK\r\n+UMLA:CCF9578E0D89\r\n")
    assert m.counters["unexpected_final"] == 1 and m.counters["unexpected_info"] == 1
    m.send(c.at())
    m.cancel()
    assert m.pending is None and m.counters["timeout"] == 1
