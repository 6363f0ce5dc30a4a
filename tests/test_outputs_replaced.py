"""Files are replaced, never truncated: every output is written to NAME.part
and renamed over NAME when done (host/outputs.py), only once the command's inputs gave it
something; device and link names are plain names.

Each test fails on the code before: calibrate opened the site file with truncation, then
wrote it, so a kill between the two left it empty; ``locate -o`` (and every other ``-o``, log,
capture and truth) truncated the old file before its inputs were opened; a scenario device
named ``../victim.txt`` made ``rfhoming emulate`` replace a file outside ``--link-dir``."""

from __future__ import annotations

import os
import select
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rfhoming.cli.main import main
from rfhoming.host import outputs

RFHOMING = [sys.executable, "-m", "rfhoming"]
SAFETY_S = 120  # a hang guard, not a speed check
OLD = "the user's only copy\n"

HOLD_THE_FIRST_WRITE = textwrap.dedent('''\
    """rfhoming, whose first write to a file in FOLDER says so on fd SIGNAL and then waits to be
    killed: the moment between opening an output and its bytes, made to last."""
    import builtins, io, os, sys

    folder, signal_fd = os.path.realpath(sys.argv[1]), int(sys.argv[2])

    class Held:
        def __init__(self, file):
            self._file = file
        def write(self, data):
            os.write(signal_fd, b"writing\\n")
            os.read(0, 1)  # stdin is never written: this waits for the kill
            return self._file.write(data)
        def __getattr__(self, name):
            return getattr(self._file, name)
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            return self._file.__exit__(*exc)

    def holding(real):
        def opened(file, mode="r", *args, **kwargs):
            handle = real(file, mode, *args, **kwargs)
            if (isinstance(file, (str, os.PathLike)) and set(mode) & set("wxa")
                    and os.path.dirname(os.path.realpath(file)) == folder):
                return Held(handle)
            return handle
        return opened

    builtins.open, io.open = holding(builtins.open), holding(io.open)
    from rfhoming.cli.main import main
    sys.exit(main(sys.argv[3:]))
''')


def _calibration_inputs(tmp_path: Path) -> tuple[Path, Path]:
    """A recording of one tag carried over three known points (the kit room's anchors) and its points file."""
    from test_locate import SITE
    from test_locate_robust import TAG, _capture_of, _carried, synthetic

    from rfhoming.host import site as sites

    site = sites.load(SITE)
    where = [(2.0, 1.5, 0.8), (6.0, 3.0, 0.3), (10.0, 4.5, 1.2)]
    path, duration = _carried(where)
    truth = {a.id: (a.rotation(), 0.93, -3.0) for a in site.anchors}
    capture = tmp_path / "inputs" / "cal.pcapng"
    capture.parent.mkdir()
    _capture_of(synthetic(site, path, duration, noise_deg=1.0, true=truth), capture, site)
    points = tmp_path / "inputs" / "points.toml"
    points.write_text("".join(f'[[dwell]]\ntag = "{TAG}"\nposition = [{x}, {y}, {z}]\n\n' for x, y, z in where))
    return capture, points


def test_a_kill_while_calibrate_writes_leaves_the_old_site_file(tmp_path: Path) -> None:
    from test_locate import SITE

    capture, points = _calibration_inputs(tmp_path)
    folder = tmp_path / "site"
    folder.mkdir()
    site = folder / "site.toml"
    site.write_text(SITE.read_text())
    old = site.read_bytes()
    hook = tmp_path / "hold.py"
    hook.write_text(HOLD_THE_FIRST_WRITE)
    said, signal_fd = os.pipe()
    child = subprocess.Popen([sys.executable, str(hook), str(folder), str(signal_fd), "calibrate", str(site),
                              "--points", str(points), "--azimuth-only", "--from", f"capture:{capture}"],
                             stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             pass_fds=[signal_fd])
    os.close(signal_fd)
    try:
        ready, _, _ = select.select([said], [], [], SAFETY_S)
        assert ready and os.read(said, 64) == b"writing\n", "calibrate never wrote the site file"
        child.send_signal(signal.SIGKILL)  # between opening its output and writing it
    finally:
        child.kill()
        child.wait(SAFETY_S)
        child.stderr.close()
        child.stdin.close()
        os.close(said)
    assert site.read_bytes() == old
    assert sorted(p.name for p in folder.iterdir()) == ["site.toml", "site.toml.part"]  # what a kill leaves, named so
    again = subprocess.run([*RFHOMING, "calibrate", str(site), "--points", str(points), "--azimuth-only",
                            "--from", f"capture:{capture}"], capture_output=True, text=True, timeout=SAFETY_S)
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "site.toml.part exists" in again.stderr
    (folder / "site.toml.part").unlink()
    done = subprocess.run([*RFHOMING, "calibrate", str(site), "--points", str(points), "--azimuth-only",
                           "--from", f"capture:{capture}"], capture_output=True, text=True, timeout=SAFETY_S)
    assert done.returncode == 0, done.stderr
    assert site.read_bytes() != old and "calibration" in site.read_text()
    assert sorted(p.name for p in folder.iterdir()) == ["site.toml"]


def test_a_failed_locate_o_leaves_the_old_output(tmp_path: Path, capsys) -> None:
    from test_locate import SITE

    previous = tmp_path / "prev.jsonl"
    previous.write_text(OLD)
    for source in (f"capture:{tmp_path / 'typo.pcapng'}", f"xplr-aoa:{tmp_path / 'no-such-device'}"):
        assert main(["locate", str(SITE), "-o", str(previous), "--from", source]) == 2
        assert previous.read_text() == OLD and not outputs.part_of(previous).exists()
        assert "rfhoming locate:" in capsys.readouterr().err


def test_a_locate_interrupted_while_its_sources_open_leaves_the_old_outputs(tmp_path: Path, capsys,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C that lands before the event loop's own handler (or while the anchors' ports open)
    comes out of the command as KeyboardInterrupt: ``-o``'s and ``--capture``'s NAME.part were
    left behind, and the next ``locate -o NAME`` refused to run until they were removed."""
    from test_locate import SITE

    from rfhoming.cli import site_sources

    async def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(site_sources, "open_drivers", interrupted)
    previous, capture = tmp_path / "prev.jsonl", tmp_path / "prev.pcapng"
    for path in (previous, capture):
        path.write_text(OLD)
    assert main(["locate", str(SITE), "-o", str(previous), "--capture", str(capture)]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert previous.read_text() == OLD and capture.read_text() == OLD
    assert sorted(p.name for p in tmp_path.iterdir()) == ["prev.jsonl", "prev.pcapng"]  # no .part


def test_every_output_of_a_command_whose_input_does_not_open_is_left_as_it_was(tmp_path: Path, capsys) -> None:
    """run --log/--capture, capture -o, serve -o, locate --capture, emulate --truth."""
    from test_locate import SITE

    names = ["run.jsonl", "run.pcapng", "cap.pcapng", "served.pcapng", "located.pcapng", "truth.jsonl"]
    for name in names:
        (tmp_path / name).write_text(OLD)
    nowhere = str(tmp_path / "no-such-device")
    assert main(["run", "--aoa", f"xplr-aoa:{nowhere}", "--base", f"base:{nowhere}", "--log",
                 str(tmp_path / "run.jsonl"), "--capture", str(tmp_path / "run.pcapng")]) == 2
    assert main(["capture", f"xplr-aoa:{nowhere}", "-o", str(tmp_path / "cap.pcapng"), "--duration", "5"]) == 2
    assert main(["serve", f"xplr-aoa:{nowhere}", "--port", "0", "-o", str(tmp_path / "served.pcapng"),
                 "--duration", "5"]) == 2
    assert main(["locate", str(SITE), "--from", f"xplr-aoa:{nowhere}", "--capture",
                 str(tmp_path / "located.pcapng")]) == 2
    assert main(["emulate", "s0-open", "--fault", "unplug@nosuch:at=1", "--truth", str(tmp_path / "truth.jsonl")]) == 2
    capsys.readouterr()
    for name in names:
        assert (tmp_path / name).read_text() == OLD, name
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)  # no .part left either


def test_a_run_whose_devices_never_connect_leaves_the_old_run_log(tmp_path: Path, capsys) -> None:
    """The loop writes records of its own before any device answers -- "no brake mode: speed
    bounded" as it is built (a MAVLink base), "stall" on a loaded machine -- and the first of
    them made the run log the run's: a typo in --aoa replaced the user's log with that line."""
    pytest.importorskip("pymavlink")
    import socket

    log = tmp_path / "run.jsonl"
    log.write_text(OLD)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:  # a vehicle that never answers
        silent.bind(("127.0.0.1", 0))
        assert main(["run", "--aoa", f"xplr-aoa:{tmp_path / 'no-such-device'}", "--base",
                     f"mavlink:udpout:127.0.0.1:{silent.getsockname()[1]},arm=1", "--log", str(log)]) == 2
    assert "no-such-device" in capsys.readouterr().err
    assert log.read_text() == OLD and not outputs.part_of(log).exists()


def test_an_emulator_that_cannot_start_leaves_the_old_truth_file(tmp_path: Path, capsys) -> None:
    """The world is built but a device's link cannot be made (a folder where the link goes):
    the truth file was replaced by an empty one."""
    links = tmp_path / "links"
    (links / "aoa" / "in-the-way").mkdir(parents=True)
    truth = tmp_path / "truth.jsonl"
    truth.write_text(OLD)
    assert main(["emulate", "s0-open", "--link-dir", str(links), "--truth", str(truth), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "aoa" in err, err
    assert truth.read_text() == OLD and not outputs.part_of(truth).exists()


def test_a_demo_whose_run_log_cannot_be_written_leaves_no_capture_part(tmp_path: Path, capsys) -> None:
    """A killed demo's run.jsonl.part in its folder: the next demo says so, and must not leave a
    capture.pcapng.part of its own (the user removed the one named, and was then refused again)."""
    (tmp_path / "run.jsonl.part").write_text("a killed demo's\n")
    assert main(["demo", "--scenario", "s0-open", "--in-process", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "run.jsonl.part exists" in err, err
    assert not (tmp_path / "capture.pcapng.part").exists() and not (tmp_path / "capture.pcapng").exists()


def test_a_dissector_whose_part_is_there_says_so(tmp_path: Path, capsys) -> None:
    """It said "cannot write rfhoming.lua: None" (a WriteFailed has no strerror)."""
    lua = tmp_path / "rfhoming.lua"
    outputs.part_of(lua).write_text("a killed writer's\n")
    assert main(["dissector", "-o", str(lua)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rfhoming.lua.part exists" in err and "None" not in err, err


def test_an_output_replaces_its_file_whole_and_keeps_its_permissions(tmp_path: Path) -> None:
    site = tmp_path / "site.toml"
    site.write_text(OLD)
    site.chmod(0o640)
    outputs.replace_text(site, "new\n")
    assert site.read_text() == "new\n" and stat.S_IMODE(site.stat().st_mode) == 0o640
    link = tmp_path / "link.toml"
    link.symlink_to(site)
    outputs.replace_text(link, "through the link\n")
    assert link.is_symlink() and site.read_text() == "through the link\n"
    with pytest.raises(ZeroDivisionError), outputs.Output(site) as out:  # a writer that fails
        out.write("torn")
        raise ZeroDivisionError
    assert site.read_text() == "through the link\n" and not outputs.part_of(site).exists()
    outputs.replace_text("/dev/null", "a device is written as it is\n")
    site.chmod(0o440)
    if os.geteuid() != 0:  # root may write anything
        with pytest.raises(PermissionError):
            outputs.replace_text(site, "not over a read-only file\n")


def test_a_device_named_outside_the_link_folder_is_refused(tmp_path: Path, capsys) -> None:
    links = tmp_path / "links"
    links.mkdir()
    victim = tmp_path / "x"
    victim.write_text(OLD)
    for name in ("../x", "..", "", "a\\u0000b"):
        scenario = tmp_path / "evil.toml"
        scenario.write_text(f'bounds = [0, 0, 10, 10]\n[devices."{name}"]\ntype = "xplr-aoa"\n'
                            '[devices.base]\ntype = "base"\n')
        assert main(["emulate", str(scenario), "--link-dir", str(links), "--duration", "1"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is not a plain name" in err, err
    assert victim.read_text() == OLD and list(links.iterdir()) == []


async def test_a_recorded_interface_named_dot_dot_is_served_as_if0(tmp_path: Path) -> None:
    """replay --pty names each pty after its interface: '..' would be the link folder's parent."""
    import io

    from rfhoming.emulator.playback import serve
    from rfhoming.host.capture import CaptureWriter

    writer = CaptureWriter(tmp_path / "odd.pcapng")
    writer.describe("..", kind="xplr-aoa")
    writer.tap("..", "in", 1.0, b"+STARTUP\r\n")
    writer.close()
    links = tmp_path / "links"
    links.mkdir()
    shown = io.StringIO()
    await serve(tmp_path / "odd.pcapng", links, start_delay=0, out=shown)
    assert '"path": "' + str(links / "if0") + '"' in shown.getvalue()
