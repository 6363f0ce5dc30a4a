"""Outputs become the command's only once its inputs gave them something, and nothing stale is
found only at the end: a capture is a run's once a device answered (rfhoming's own heartbeats
and AT commands do not count); a demo and a campaign refuse a stale ``NAME.part`` before they
start anything, naming every one; the benches' figures are replaced whole.

Each test fails on the code before: a capture was owned on any packet, so a run with a typo in
one port replaced the user's capture with the other port's outbound heartbeats; a demo named
one stale ``.part`` at a time, after its emulator had started; a killed emulator's truth was
read from the previous run's file; a campaign refused its ``.json.part`` only after every job."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from rfhoming.cli.main import main
from rfhoming.host import outputs
from rfhoming.host.capture import CaptureWriter

OLD = "the user's only copy\n"


def test_a_capture_is_the_runs_once_a_device_answered_and_keeps_what_was_sent_before(tmp_path: Path) -> None:
    from rfhoming.protocol import pcapng

    path = tmp_path / "c.pcapng"
    path.write_text(OLD)
    writer = CaptureWriter(path)
    writer.describe("base", kind="base")
    writer.tap("base", "out", 1.0, b"a heartbeat")
    writer.tap("base", "sniffed-out", 1.1, b"AT\r\n")
    writer.tap("base", "lost", 1.2, b"")
    writer.close()  # the device never answered
    assert path.read_text() == OLD and not outputs.part_of(path).exists()
    assert writer.said() == f"no device answered: {path} is as it was (the 3 chunks rfhoming sent are not kept)"
    for answer in ("in", "sniffed-in"):
        writer = CaptureWriter(path)
        writer.describe("aoa", kind="xplr-aoa")
        writer.tap("aoa", "out", 1.0, b"AT\r\n")
        writer.tap("aoa", answer, 1.1, b"OK\r\n")
        writer.close()
        _interfaces, packets, _torn = pcapng.read_sections(path.read_bytes(), pcapng.Reader())
        assert [p.data for p in packets] == [b"AT\r\n", b"OK\r\n"], answer
        assert writer.said() == f"captured 2 chunks to {path}"


def test_a_run_with_a_typo_in_one_port_leaves_the_old_capture_and_says_so(tmp_path: Path, capsys) -> None:
    """The MAVLink base sends its heartbeats the moment it opens; the typo'd AoA port then
    fails the run: the capture held only rfhoming's heartbeats and replaced the user's."""
    pytest.importorskip("pymavlink")
    capture = tmp_path / "c.pcapng"
    capture.write_text(OLD)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:  # a vehicle that never answers
        silent.bind(("127.0.0.1", 0))
        assert main(["run", "--aoa", f"xplr-aoa:{tmp_path / 'typo'}", "--base",
                     f"mavlink:udpout:127.0.0.1:{silent.getsockname()[1]},arm=1", "--capture", str(capture)]) == 2
    err = capsys.readouterr().err
    assert capture.read_text() == OLD and not outputs.part_of(capture).exists()
    said = [line for line in err.splitlines() if "c.pcapng" in line]
    assert len(said) == 1 and said[0].startswith(f"rfhoming run: no device answered: {capture} is as it was ("), err


def test_serve_whose_vehicle_never_answers_leaves_the_old_capture_and_says_so(tmp_path: Path, capsys) -> None:
    pytest.importorskip("pymavlink")
    capture = tmp_path / "served.pcapng"
    capture.write_text(OLD)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        assert main(["serve", f"mavlink:udpout:127.0.0.1:{silent.getsockname()[1]}", "--port", "0", "-o", str(capture),
                     "--duration", "1"]) == 0
    err = capsys.readouterr().err
    assert capture.read_text() == OLD and not outputs.part_of(capture).exists()
    assert err.startswith(f"rfhoming serve: no device answered: {capture} is as it was (the ") and err.count("\n") == 1, err


def test_a_demo_names_every_stale_part_in_its_folder_before_it_starts(tmp_path: Path, capsys) -> None:
    """A killed demo leaves several: the next one named the first it met, after its emulator
    had started, and the user removed them one run at a time."""
    import shlex

    out = tmp_path / "rfhoming-demo"
    out.mkdir()
    stale = [out / "capture.pcapng.part", out / "truth.jsonl.part"]  # in the order the demo names its files
    for part in stale:
        part.write_text("a killed demo's\n")
    assert main(["demo", "--scenario", "s0-open", "--in-process", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"rfhoming demo: {stale[0]}, {stale[1]} exist: "), err
    assert f"(rm -- {shlex.join(map(str, stale))})" in err, err
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in stale)  # nothing started, nothing written


def test_a_demo_whose_emulator_is_killed_summarises_this_runs_truth(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    """An emulator that outlives its grace is killed before it renames truth.jsonl.part: the
    summary and the plot were made from the previous run's truth.jsonl, without a word."""
    import json
    import logging

    from rfhoming import demo
    from rfhoming.host.homing.config import load

    def killed(proc, grace_s: float) -> None:  # the grace ran out
        proc.kill()
        proc.wait()

    monkeypatch.setattr(demo, "stop_emulator", killed)
    out = tmp_path / "demo"
    out.mkdir()
    old = {"scenario": "a previous run", "bounds": [0, 0, 1, 1], "obstacles": []}
    (out / "truth.jsonl").write_text(json.dumps(old) + "\n")
    caplog.set_level(logging.WARNING)
    summary = demo.run_demo("s0-open", 3, out, load(None), None)
    header, states = demo.read_truth(out / "truth.jsonl")
    assert summary["scenario"] == header["scenario"] == "s0-open" and states
    assert sorted(p.name for p in out.iterdir()) == sorted(demo.FILES)  # no .part left to block the next demo
    said = [r.getMessage() for r in caplog.records if "killed" in r.getMessage()]
    assert len(said) == 1 and str(out / "truth.jsonl") in said[0], said


def test_a_campaign_names_every_stale_part_before_its_first_job(tmp_path: Path, capsys) -> None:
    """It found its NAME.json.part only when it wrote NAME.json, after every job (hours of
    them), and its NAME.png.part after that."""
    stale = [tmp_path / "s3-arena.json.part", tmp_path / "s3-arena.png.part"]
    for part in stale:
        part.write_text("a killed campaign's\n")
    assert main(["campaign", "s3-arena", "--runs", "1", "--workers", "1", "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"rfhoming campaign: {stale[0]}, {stale[1]} exist: "), err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in stale)  # no job ran: no checkpoint


ROOT = Path(__file__).resolve().parent.parent


def test_a_bench_figure_that_fails_midway_leaves_the_old_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """bench/locate_figure.py saved its figure in place: a plot that failed (a full disk)
    halfway left a torn PNG where the documentation's figure was."""
    import errno
    import os
    import runpy
    import sys

    from matplotlib.figure import Figure

    def torn(self: Figure, fname: object, **kwargs: object) -> None:
        if isinstance(fname, (str, os.PathLike)):
            with open(fname, "wb") as file:
                file.write(b"\x89PNG torn")
        else:
            fname.write(b"\x89PNG torn")  # type: ignore[attr-defined]
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    figure = tmp_path / "locate-geometry.png"
    figure.write_bytes(b"the documentation's figure")
    monkeypatch.setattr(Figure, "savefig", torn)
    monkeypatch.setattr(sys, "argv", ["locate_figure.py", "-o", str(figure)])
    monkeypatch.chdir(ROOT)  # it reads docs/sites/kit-room.toml
    with pytest.raises(OSError, match="No space left"):
        runpy.run_path(str(ROOT / "bench" / "locate_figure.py"), run_name="__main__")
    assert figure.read_bytes() == b"the documentation's figure" and not outputs.part_of(figure).exists()


def test_every_figure_is_saved_through_outputs() -> None:
    """Whatever draws a figure for a user (the demo, campaigns, the benches' documentation
    figures) saves it with host/outputs.py's save_figure, never in place."""
    import ast

    in_place = []
    for folder in ("rfhoming", "host", "campaigns", "emulator", "bench", "protocol", "firmware_py"):
        for source in sorted((ROOT / folder).rglob("*.py")):
            if source == ROOT / "host" / "outputs.py":
                continue
            for node in ast.walk(ast.parse(source.read_text(), str(source))):
                if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "savefig":
                    in_place.append(f"{source.relative_to(ROOT)}:{node.lineno}")
    assert in_place == []
