"""The XPLR-AOA model, spoken to through the u-connectLocate codec as a host would."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.firmware.xplr_aoa import (
    RESTART_MS,
    TAG_TIMEOUT_MS,
    C209_NAMESPACE,
    Advertisement,
    XplrAoaFirmware,
)
from rfhoming.protocol.uconnect import CommandMatcher, Dialect, Response, UConnectDecoder
from rfhoming.protocol.uconnect import commands as c


class Host:
    """A minimal host: sends one command, returns its paired answer and the URCs seen."""

    def __init__(self, fw: XplrAoaFirmware) -> None:
        self.fw = fw
        self.decoder = UConnectDecoder()
        self.matcher = CommandMatcher()
        self.urcs: list = []

    def drain(self) -> list[Response]:
        responses = []
        for item in self.decoder.feed(self.fw.read()):
            response = self.matcher.on_item(item)
            if response is not None:
                responses.append(response)
            elif item.kind in ("angle", "startup", "tag_data"):
                self.urcs.append(item)
        return responses

    def send(self, command: c.Command) -> Response:
        self.fw.receive(self.matcher.send(command))
        (response,) = self.drain()
        return response

    def restart(self, now_ms: int = 1000) -> None:
        """AT+CPWROFF at ``now_ms``; returns once the board listens again."""
        self.fw.tick(now_ms)
        assert self.send(c.restart()).ok
        self.fw.tick(now_ms + RESTART_MS)
        self.drain()


def adv(tag: str = "CCF9578E0D8A", az: float = 12.4, rssi: float = -55.0) -> Advertisement:
    return Advertisement(tag, C209_NAMESPACE, az, 0.0, rssi, rssi - 1)


@pytest.fixture
def host() -> Host:
    h = Host(XplrAoaFirmware(dialect=Dialect.V1_2))
    h.drain()
    return h


def test_boot_banner_then_echo_info_ok(host: Host) -> None:
    assert [u.kind for u in host.urcs] == ["startup"]
    r = host.send(c.identify_manufacturer())
    assert r.ok and r.echoed and r.info == ['"u-blox"']
    assert host.send(c.local_address()).info == ["+UMLA:CCF9578E0D89"]


def test_echo_bytes_exactly_then_answer() -> None:
    fw = XplrAoaFirmware()
    fw.read()
    fw.receive(b"AT\r")
    assert fw.read() == b"AT\r\r\nOK\r\n"


@pytest.mark.parametrize("line", [b"AT+NOPE\r", b"AT+UDFCFG=1,99999\r", b"AT+UDFCFG=42,1\r",
                                  b"AT+UDFFILT=2,2,\"XYZ\"\r", b"AT+UMRS=1234,1\r", b"AT+UDFENABLE=2\r"])
def test_bad_commands_answer_error(host: Host, line: bytes) -> None:
    host.fw.receive(line)
    (response,) = [i for i in host.decoder.feed(host.fw.read()) if i.kind == "final"]
    assert not response.ok


def test_identity_per_dialect() -> None:
    seen = set()
    for dialect in Dialect:
        h = Host(XplrAoaFirmware(dialect=dialect))
        h.drain()
        seen.add((h.send(c.identify_model()).info[0], h.send(c.identify_version()).info[0],
                  h.send(c.identify_software()).info[0]))
    assert len(seen) == 4


def test_settings_lost_without_store_kept_with_it(host: Host) -> None:
    assert host.send(c.set_config(2, "dock")).ok
    assert host.send(c.read_config(2)).info == ['+UDFCFG:2,"dock"']
    host.restart()
    assert host.send(c.read_config(2)).info == ['+UDFCFG:2,""']
    host.send(c.set_config(2, "dock"))
    assert host.send(c.store()).ok
    host.restart(5000)
    assert host.send(c.read_config(2)).info == ['+UDFCFG:2,"dock"']
    assert [u.kind for u in host.urcs].count("startup") == 3


def test_config_takes_effect_only_after_restart(host: Host) -> None:
    host.send(c.set_config(2, "new"))
    host.fw.on_advertisement(adv())
    host.drain()
    assert host.urcs[-1].user_str == ""
    host.send(c.store())
    host.restart()
    host.fw.on_advertisement(adv())
    host.drain()
    assert host.urcs[-1].user_str == "new"


def test_udfenable_acts_at_once_and_is_not_stored(host: Host) -> None:
    host.send(c.enable_angles(False))
    host.fw.on_advertisement(adv())
    assert host.drain() == [] and host.urcs[-1].kind == "startup"
    host.send(c.store())
    host.restart()
    host.fw.on_advertisement(adv())
    host.drain()
    assert host.urcs[-1].kind == "angle"


def test_angle_event_fields(host: Host) -> None:
    host.fw.tick(1234)
    host.fw.on_advertisement(adv(az=-33.6, rssi=-61.4))
    host.drain()
    event = host.urcs[-1]
    assert (event.azimuth, event.rssi1, event.timestamp_ms) == (-34, -61, 1234)
    assert event.channel in (37, 38, 39) and event.anchor_id == "CCF9578E0D89"


def test_rate_limited_by_tag_1_interval(host: Host) -> None:
    host.send(c.set_config(1, 100))
    host.send(c.store())
    host.restart(1000)
    for ms in range(2300, 3300, 20):  # 50 advertisements at 20 ms
        host.fw.tick(ms)
        host.fw.on_advertisement(adv())
    host.drain()
    assert sum(1 for u in host.urcs if u.kind == "angle") == 10


def test_instance_filter(host: Host) -> None:
    host.send(c.set_filter(c.FILTER_INSTANCE, c.FILTER_APPEND, ("AAAAAAAAAAAA",)))
    assert host.send(c.read_filter(c.FILTER_INSTANCE)).info == ['+UDFFILT:2,"AAAAAAAAAAAA"']
    host.send(c.store())
    host.restart()
    for tag in ("AAAAAAAAAAAA", "BBBBBBBBBBBB"):
        host.fw.on_advertisement(adv(tag))
    host.drain()
    assert [u.instance_id for u in host.urcs if u.kind == "angle"] == ["AAAAAAAAAAAA"]


@pytest.mark.parametrize(("dialect", "limit"), [(Dialect.V1_0, 5), (Dialect.V1_2, 20)])
def test_tag_limit_and_five_second_drop(dialect: Dialect, limit: int) -> None:
    h = Host(XplrAoaFirmware(dialect=dialect))
    for i in range(limit + 3):
        h.fw.on_advertisement(adv(f"{i:012X}"))
    h.drain()
    assert len({u.instance_id for u in h.urcs if u.kind == "angle"}) == limit
    h.fw.tick(TAG_TIMEOUT_MS + 1)
    assert h.fw.tags == {}
    h.fw.on_advertisement(adv("FFFFFFFFFFFF"))
    h.drain()
    assert h.urcs[-1].instance_id == "FFFFFFFFFFFF"


@pytest.mark.parametrize(("dialect", "fields"), [(Dialect.V1_0, 9), (Dialect.V1_2, 9), (Dialect.V2, 10)])
def test_dialect_field_count_on_the_wire(dialect: Dialect, fields: int) -> None:
    fw = XplrAoaFirmware(dialect=dialect)
    fw.read()
    fw.on_advertisement(adv())
    line = fw.read().strip()
    assert line.startswith(b"+UUDF:") and line.count(b",") + 1 == fields


def test_embed_raw_angles_only_with_tag_121() -> None:
    h = Host(XplrAoaFirmware(dialect=Dialect.EMBED))
    h.fw.on_advertisement(adv())
    h.drain()
    assert h.urcs[-1].azimuth_raw is None and h.urcs[-1].seq == 1
    h.send(c.set_config(121, 1))
    h.send(c.store())
    h.restart()
    h.fw.on_advertisement(adv(az=40))
    h.drain()
    assert h.urcs[-1].azimuth_raw == 40


def test_later_dialect_tags_rejected_by_1x(host: Host) -> None:
    assert not host.send(c.read_config(9)).ok
    assert not host.send(c.read_config(121)).ok


def test_umrs_changes_baud_only_after_store_and_restart(host: Host) -> None:
    assert host.send(c.set_serial(1000000, False)).ok
    assert host.send(c.read_serial()).info == ["+UMRS:1000000,2,8,1,1,1"]
    assert host.fw.baud == 115200
    host.send(c.store())
    host.restart()
    assert host.fw.baud == 1000000


def test_meas_format_is_detectable(host: Host) -> None:
    host.send(c.set_config(7, 1))
    host.send(c.store())
    host.restart()
    host.fw.on_advertisement(adv())
    items = host.decoder.feed(host.fw.read())
    assert items[-1].kind == "unknown" and "unsupported output format" in items[-1].note


def test_tx_buffer_is_bounded() -> None:
    fw = XplrAoaFirmware()
    for i in range(2000):
        fw.tick(i * 10)
        fw.on_advertisement(adv(f"{i % 20:012X}"))
    assert len(fw.read()) <= 8192 and fw.counters["tx_overflow"] > 0


# -- AT syntax as the firmware documents it: no string the board cannot print, no loose integers ---
def finals(host: Host, line: bytes) -> list[bool]:
    """Send raw bytes; the final codes that came back (responses are not paired here)."""
    host.fw.receive(line)
    return [i.ok for i in host.decoder.feed(host.fw.read()) if i.kind == "final"]


@pytest.mark.parametrize("line", [b'AT+UDFCFG=2,"a"b"\r', b'AT+UDFCFG=2,"\xff"\r', b'AT+UDFCFG=4,"\x01"\r',
                                  b'AT+UDFCFG=2,"' + b"x" * 31 + b'"\r', b'AT+UDFCFG=2,abc\r'])
def test_a_string_setting_the_board_cannot_print_is_refused(host: Host, line: bytes) -> None:
    assert finals(host, line) == [False]
    assert host.send(c.store()).ok
    host.restart()
    for read in (c.read_config(2), c.read_config(), c.read_filter(2)):  # always a final code
        assert host.send(read).ok
    host.fw.on_advertisement(adv())
    host.drain()
    assert host.urcs[-1].kind == "angle" and host.urcs[-1].user_str == ""


def test_a_string_with_a_comma_is_a_valid_setting(host: Host) -> None:
    assert finals(host, b'AT+UDFCFG=2,"59.3,18.1"\r') == [True]
    assert host.send(c.read_config(2)).info == ['+UDFCFG:2,"59.3,18.1"']


def test_an_overflowed_line_is_discarded_whole() -> None:
    h = Host(XplrAoaFirmware())
    h.drain()
    h.fw.receive(b"x" * 512 + b"AT+GMM\r")
    items = h.decoder.feed(h.fw.read())
    assert [i.ok for i in items if i.kind == "final"] == [False]
    assert not [i for i in items if i.kind == "info"] and h.fw.counters["rx_overflow"] == 1
    assert h.send(c.identify_model()).ok  # the next line is a command again


@pytest.mark.parametrize("line", [b"AT+UDFCFG=1,1_000\r", b"AT+UDFCFG=1, 5\r", b"AT+UDFCFG=1,+5\r",
                                  b"AT+UDFCFG=1,0005\r", b"AT+UDFCFG=1,\r", b"AT+UDFCFG=1,5,\r",
                                  b"AT+UDFCFG= 1\r", b"AT+UDFENABLE=01\r", b"AT+UDFCFG=1,-0\r",
                                  b'AT+UDFFILT=2,2,"GGGGGGGGGGGG"\r', b"AT+UDFFILT=2,2,CCF9578E0D8A\r",
                                  b"AT+UDFCFG\r", b"AT+UMRS=115200,0\r", b"AT+UDFCFG=10,5\r"])
def test_at_syntax_the_board_refuses(host: Host, line: bytes) -> None:
    before = (dict(host.fw.pending.udfcfg), {k: list(v) for k, v in host.fw.pending.filters.items()})
    assert finals(host, line) == [False]
    assert (host.fw.pending.udfcfg, host.fw.pending.filters) == before


def test_deafness_after_startup_is_a_fault_option_off_by_default() -> None:
    """No source says the board ignores the host after +STARTUP (docs/protocol.md): the
    default board answers at once; ``deaf_after_boot_ms`` models it as a fault."""
    fw = XplrAoaFirmware()
    fw.read()
    fw.receive(b"AT\r")
    fw.tick(1)
    fw.receive(b"AT+CPWROFF\r")
    assert fw.read() == b"AT\r\r\nOK\r\nAT+CPWROFF\r\r\nOK\r\n"
    fw.tick(1 + RESTART_MS)
    fw.receive(b"AT\r")
    assert fw.read() == b"\r\n+STARTUP\r\nAT\r\r\nOK\r\n" and fw.counters["rx_ignored"] == 0
    deaf = XplrAoaFirmware(deaf_after_boot_ms=1000)
    deaf.read()
    deaf.receive(b"AT\r")  # the power-up boot is never deaf: the board was on before the host
    assert deaf.read() == b"AT\r\r\nOK\r\n"
    deaf.receive(b"AT+CPWROFF\r")
    deaf.tick(RESTART_MS)
    deaf.tick(RESTART_MS + 500)
    deaf.receive(b"AT\r")
    assert deaf.read().endswith(b"\r\n+STARTUP\r\n") and deaf.counters["rx_ignored"] == 3


@pytest.mark.parametrize(("dialect", "live"), [(Dialect.V1_2, False), (Dialect.V2, True), (Dialect.EMBED, True)])
def test_udfcfg_live_or_at_restart_per_family(dialect: Dialect, live: bool) -> None:
    h = Host(XplrAoaFirmware(dialect=dialect))
    h.drain()
    assert h.send(c.set_config(2, "new")).ok
    h.fw.on_advertisement(adv())
    h.drain()
    assert h.urcs[-1].user_str == ("new" if live else "")


def test_2x_has_a_nonzero_reserved_field_and_its_own_tags() -> None:
    h = Host(XplrAoaFirmware(dialect=Dialect.V2))
    h.drain()
    for ms in range(1000, 1100, 20):
        h.fw.tick(ms)
        h.fw.on_advertisement(adv())
    h.drain()
    assert {u.reserved for u in h.urcs if u.kind == "angle"} <= {-43, 6, 8} and h.urcs[-1].reserved != 0
    assert h.send(c.set_config(10, 50, "2.x")).ok and h.send(c.set_config(13, 1, "2.x")).ok
    assert not h.send(c.set_config(121, 1)).ok  # u-locateEmbed only


def test_answers_queue_behind_output_already_sent() -> None:
    """A saturated 115,200 Bd link delays answers: they leave after what the board queued
    before the command, as a serial line does; nothing is torn."""
    fw = XplrAoaFirmware(paced=True)
    fw.tick(1000)
    fw.read()
    for i in range(20):
        fw.on_advertisement(adv(f"{i:012X}"))
    queued = len(fw._out)
    fw.receive(b"AT\r")
    out = b""
    for ms in range(1010, 1300, 10):
        fw.tick(ms)
        out += fw.read()
    assert out.index(b"AT\r\r\nOK\r\n") == queued  # the echo and answer come after all 20 lines
    items = UConnectDecoder().feed(out)
    assert sum(i.kind == "angle" for i in items) == 20 and not any(i.kind == "drop" for i in items)


def test_torn_answers_are_a_fault_option() -> None:
    fw = XplrAoaFirmware(paced=True, torn_answers=True)
    fw.tick(1000)
    fw.read()
    for i in range(20):  # 20 tags heard at once: ~1.3 kB queued
        fw.on_advertisement(adv(f"{i:012X}"))
    fw.tick(1010)  # 10 ms at 115200 Bd: 115 bytes
    first = fw.read()
    assert len(first) == 115
    fw.receive(b"AT\r")
    fw.tick(1020)
    second = fw.read()
    assert second.startswith(b"AT\r\r\nOK\r\n")  # mid-line: the event line resumes after it
    rest = b""
    for ms in range(1030, 1300, 10):
        fw.tick(ms)
        rest += fw.read()
    decoder = UConnectDecoder()
    items = decoder.feed(first + second + rest)
    assert sum(i.kind == "angle" for i in items) == 19 and any(i.kind == "final" for i in items)


def test_9_field_lines_carry_reserved_values_not_zero() -> None:
    """Field 5 of 1.2 lines is "reserved"; real 9-field lines carry 6 and 8 there (item 3)."""
    h = Host(XplrAoaFirmware(dialect=Dialect.V1_2))
    h.drain()
    for ms in range(1000, 1100, 20):
        h.fw.tick(ms)
        h.fw.on_advertisement(adv())
    h.drain()
    assert {u.reserved for u in h.urcs if u.kind == "angle"} - {-43, 6, 8} == set()


def test_embed_ignores_other_namespaces_until_the_filter_is_cleared() -> None:
    """u-locateEmbed ships with the NINA-B4TAG namespace filter (item 1); 1.x and 2.x have none."""
    other = Advertisement("CCF9578E0D8A", "00112233445566778899", 5.0, 0.0, -50, -51)
    h = Host(XplrAoaFirmware(dialect=Dialect.EMBED))
    h.drain()
    h.fw.on_advertisement(other)
    h.drain()
    assert not [u for u in h.urcs if u.kind == "angle"]
    assert h.send(c.read_filter(c.FILTER_NAMESPACE)).info == [f'+UDFFILT:1,"{C209_NAMESPACE}"']
    assert h.send(c.set_filter(c.FILTER_NAMESPACE, c.FILTER_CLEAR)).ok and h.send(c.store()).ok
    h.restart()
    h.fw.tick(2000)
    h.fw.on_advertisement(other)
    h.drain()
    assert [u.instance_id for u in h.urcs if u.kind == "angle"] == ["CCF9578E0D8A"]
    v2 = Host(XplrAoaFirmware(dialect=Dialect.V2))
    v2.drain()
    v2.fw.on_advertisement(other)
    v2.drain()
    assert [u.kind for u in v2.urcs if u.kind == "angle"] == ["angle"]


def test_event_counter_is_the_tags_and_has_gaps() -> None:
    """Field 10 is the tag's periodic-advertising event counter: missed packets leave gaps."""
    h = Host(XplrAoaFirmware(dialect=Dialect.V2))
    h.drain()
    for ms, counter in ((1000, 7), (1100, 9), (1200, 13)):
        h.fw.tick(ms)
        h.fw.on_advertisement(Advertisement("CCF9578E0D8A", C209_NAMESPACE, 1.0, 0.0, -50, -51, counter))
    h.drain()
    assert [u.seq for u in h.urcs if u.kind == "angle"] == [7, 9, 13]


def test_five_parameter_umrs_of_public_clients_is_accepted(host: Host) -> None:
    assert finals(host, b"AT+UMRS=115200,2,8,1,1\r") == [True]


AT_WORDS = [b"AT", b"+UDFCFG", b"+UDFFILT", b"+UMRS", b"+UDFENABLE", b"=", b"?", b",", b'"', b"1", b"0", b"-",
            b"2", b"121", b"CCF9578E0D8A", b"\xff", b" ", b"_", b"+", b"&W", b"x" * 300]


@given(st.lists(st.lists(st.sampled_from(AT_WORDS) | st.binary(max_size=4), max_size=12).map(b"".join),
                min_size=1, max_size=8))
def test_any_command_line_gets_one_final_code_and_events_keep_coming(lines: list[bytes]) -> None:
    """Hostile input: whatever the lines, AT&W and a restart after them, every line
    gets exactly one final code and the board still encodes its events."""
    h = Host(XplrAoaFirmware(dialect=Dialect.V2))
    h.drain()
    for line in lines:
        line = line.replace(b"\r", b"").replace(b"\n", b"")
        if line in (b"OK", b"ERROR"):  # its echo is a final code itself: only its sender
            continue  # can tell the two apart, and no host sends one
        h.fw.receive(line + b"\r")
        finals = [i for i in h.decoder.feed(h.fw.read()) if i.kind == "final"]
        assert len(finals) == (1 if line.strip() else 0)
    h.fw.receive(b"AT+UDFENABLE=1\rAT&W\r")
    h.fw.read()
    h.restart(5000)
    h.send(c.enable_angles(True))
    h.fw.on_advertisement(adv())
    h.drain()
    assert h.urcs[-1].kind == "angle"
