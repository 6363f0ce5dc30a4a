"""Malformed captures: the reader names the byte offset and the problem, never a traceback;
``rfhoming replay`` exits 2 with one line, or replays what came before with --partial."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest

from rfhoming.protocol import pcapng

RFHOMING = [sys.executable, "-m", "rfhoming"]
SHB = pcapng.section_header()
AOA = pcapng.interface("/dev/ttyACM0", "protocol=ublox-aoa", pcapng.LINKTYPE_UCONNECT)
RSS = pcapng.interface("/dev/ttyUSB0", "protocol=rss", pcapng.LINKTYPE_FRAMES)
LINE = b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869\r\n'


def block(kind: int, body: bytes) -> bytes:
    return struct.pack("<II", kind, 12 + len(body)) + body + struct.pack("<I", 12 + len(body))


def pkt(iface: int = 0, data: bytes = LINE, t: float = 1.0) -> bytes:
    return pcapng.packet(iface, t, data, pcapng.INBOUND)


def option(code: int, value: bytes) -> bytes:
    return struct.pack("<HH", code, len(value)) + value + b"\0" * (-len(value) % 4) + struct.pack("<HH", 0, 0)


GOOD = SHB + AOA + pkt()
# name -> (file, offset of the bad block, words the error must contain)
BAD = {
    "empty": (b"", 0, "empty file"),
    "short": (SHB[:11], 0, "11 bytes"),
    "torn section header": (SHB[:20], 0, "no complete section header"),
    "header only": (SHB, len(SHB), "no interface"),
    "idb body < 2": (GOOD + block(pcapng.IDB, b""), len(GOOD), "interface description body is 0 bytes"),
    "epb body < 20": (GOOD + block(pcapng.EPB, b"\0" * 8), len(GOOD), "enhanced packet body is 8 bytes"),
    "epb_flags not 4 bytes": (GOOD + block(pcapng.EPB, struct.pack("<IIIII", 0, 0, 1, 0, 0)
                                           + option(pcapng.OPT_EPB_FLAGS, b"\x01\x00")),
                              len(GOOD), "epb_flags option is 2 bytes"),
    "if_tsresol empty": (GOOD + block(pcapng.IDB, struct.pack("<HHI", 147, 0, 0) + option(pcapng.OPT_IF_TSRESOL, b"")),
                         len(GOOD), "if_tsresol option is 0 bytes"),
    "caplen beyond block": (GOOD + block(pcapng.EPB, struct.pack("<IIIII", 0, 0, 1, 400, 400) + b"abcd"),
                            len(GOOD), "captured length 400 exceeds its block"),
    "second section has fewer interfaces": (SHB + AOA + RSS + pkt(1) + SHB + AOA + pkt(1),
                                            2 * len(SHB) + 2 * len(AOA) + len(RSS) + len(pkt(1)),
                                            "interface 1, which this section has not declared"),
    "trailer differs": (GOOD + pkt()[:-4] + b"\xff\0\0\0", len(GOOD), "does not match its trailing copy"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_malformed_capture_names_offset_and_problem(name: str) -> None:
    data, offset, words = BAD[name]
    with pytest.raises(pcapng.CaptureFormatError) as info:
        pcapng.read_all(data)
    assert info.value.offset == offset and f"offset {offset}:" in str(info.value)
    assert words in str(info.value)


def test_items_before_the_bad_block_are_kept() -> None:
    data = SHB + AOA + pkt(t=1.0) + pkt(t=2.0) + block(pcapng.EPB, b"\0" * 8)
    with pytest.raises(pcapng.CaptureFormatError) as info:
        pcapng.read_all(data)
    assert [i.t for i in info.value.items if isinstance(i, pcapng.Packet)] == [1.0, 2.0]


def test_interface_ids_are_per_section() -> None:
    """`cat a.pcapng b.pcapng`: b's packet 0 belongs to b's interface 0, not a's."""
    a = SHB + AOA + pkt(0, b"from a")
    b = SHB + RSS + pkt(0, b"\0from b\0")
    interfaces, packets, torn = pcapng.read_all(a + b)
    assert [i.name for i in interfaces] == ["/dev/ttyACM0", "/dev/ttyUSB0"] and torn == 0
    assert [(interfaces[p.interface_id].name, p.data) for p in packets] == [
        ("/dev/ttyACM0", b"from a"), ("/dev/ttyUSB0", b"\0from b\0")]


@pytest.mark.parametrize("name", sorted(BAD))
def test_replay_gives_one_line_and_exit_2(tmp_path: Path, name: str) -> None:
    path = tmp_path / "bad.pcapng"
    path.write_bytes(BAD[name][0])
    done = subprocess.run([*RFHOMING, "replay", str(path), "--json"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert f"offset {BAD[name][1]}:" in done.stderr


def test_replay_partial_replays_what_came_before(tmp_path: Path) -> None:
    path = tmp_path / "bad.pcapng"
    path.write_bytes(SHB + AOA + b"".join(pkt(t=1.0 + 0.1 * k) for k in range(5)) + block(pcapng.EPB, b"\0" * 8))
    done = subprocess.run([*RFHOMING, "replay", str(path), "--json", "--partial"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count('"kind": "angle"') == 5
    assert "offset" in done.stderr and "Traceback" not in done.stderr


def test_replay_pty_refuses_an_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.pcapng"
    path.write_bytes(b"")
    done = subprocess.run([*RFHOMING, "replay", str(path), "--pty", "--link-dir", str(tmp_path),
                           "--start-delay", "0"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "offset 0: empty file" in done.stderr and "Traceback" not in done.stderr


# -- edges mutation testing found untested -----------------------------------------------------
def test_timestamps_beyond_32_bits_of_microseconds_round_trip() -> None:
    """A capture's time stamps are wall-clock µs: far beyond 2^32 (71 minutes)."""
    t = 1_795_998_957.775595
    _, packets, _ = pcapng.read_all(SHB + AOA + pkt(t=t))
    assert packets[0].t == t


def test_minimal_section_header_without_options_is_read() -> None:
    shb = block(pcapng.SHB, struct.pack("<IHHq", pcapng.BYTE_ORDER_MAGIC, 1, 0, -1))  # 16-byte body
    interfaces, packets, torn = pcapng.read_all(shb + AOA + pkt())
    assert len(interfaces) == 1 and len(packets) == 1 and torn == 0


def test_options_end_with_opt_endofopt_as_the_spec_writes_it() -> None:
    """draft-ietf-opsawg-pcapng: options end with opt_endofopt, code 0 length 0."""
    data = pcapng.packet(0, 1.0, b"ab", pcapng.OUTBOUND, comment="x")
    options = data[8 + 20 + 4 : -4]  # after the header, the 20-byte EPB fields and the padded data
    # epb_flags (2), opt_comment (1), opt_endofopt (0)
    assert options == struct.pack("<HHI", 2, 4, 2) + struct.pack("<HH", 1, 1) + b"x\0\0\0" + struct.pack("<HH", 0, 0)
    assert SHB[8 + 16 : 8 + 20] == struct.pack("<HH", 4, len(b"rfhoming"))  # shb_userappl (4)
