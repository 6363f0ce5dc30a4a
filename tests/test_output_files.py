"""Files: a torn last run-log line is skipped with one warning (as a torn last pcapng block is);
a write that fails (a full disk, here /dev/full or a file object that says ENOSPC) names the
file and what it kept, and leaves no empty file behind."""

from __future__ import annotations

import errno
import io
import json
import logging
import subprocess
import sys
from pathlib import Path

import pytest

from rfhoming.host import outputs
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.homing.loop import RunLog

RFHOMING = [sys.executable, "-m", "rfhoming"]
FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not FULL.exists(), reason="no /dev/full here")


class FullDisk(io.RawIOBase):
    """A file that takes ``room`` bytes, then says ENOSPC (what a full disk says)."""

    def __init__(self, path: Path, room: int = 0) -> None:
        self.name = str(path)
        self._file = open(path, "wb", buffering=0)
        self.room = room

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:  # as a file on a disk is (the mcap writer asks where it is)
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._file.seek(offset, whence)

    def write(self, data) -> int:
        if len(data) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= len(data)
        return self._file.write(data)

    def close(self) -> None:
        self._file.close()
        super().close()


def _runlog_lines(n: int) -> list[str]:
    return [json.dumps({"kind": "event", "t": k * 0.1, "what": f"e{k}"}) for k in range(n)]


def test_export_skips_a_torn_last_run_log_line_with_one_warning(tmp_path, caplog):
    """Old code: refused the whole run log (``run.jsonl:6: not a run log line``)."""
    pytest.importorskip("mcap_ros2")
    from rfhoming.host.export.recorder import RunLogError, export

    log = tmp_path / "run.jsonl"
    log.write_text("\n".join(_runlog_lines(5)) + '\n{"kind": "command", "t": 0.6, "v": 0.')
    caplog.set_level(logging.WARNING)
    summary = export(tmp_path / "run.mcap", runlog=log)
    torn = [r.getMessage() for r in caplog.records if "torn" in r.getMessage()]
    assert len(torn) == 1 and "run.jsonl:6" in torn[0] and "5 lines" in torn[0]
    assert summary["messages"] >= 0 and (tmp_path / "run.mcap").stat().st_size > 0
    lines = _runlog_lines(5)
    log.write_text("\n".join([*lines[:2], '{"kind": "ev', *lines[2:]]) + "\n")  # torn in the middle: an error
    with pytest.raises(RunLogError, match=r"run.jsonl:3: not a run log line"):
        export(tmp_path / "run2.mcap", runlog=log)


def _capture(path: Path) -> None:
    writer = CaptureWriter(path)
    writer.describe("west", kind="xplr-aoa")
    for k in range(200):
        line = f'+UUDF:CCF9578E0D8A,-42,{k % 40},-10,-43,37,"CCF9578E0A01","",{k * 50}\r\n'
        writer.tap("west", "in", 1000.0 + k * 0.05, line.encode())
    writer.close()


@needs_dev_full
def test_export_to_a_full_disk_names_the_file(tmp_path):
    """Old code: ``rfhoming export: [Errno 28] No space left on device``, no file named."""
    pytest.importorskip("mcap_ros2")
    _capture(tmp_path / "in.pcapng")
    cli = subprocess.run([*RFHOMING, "export", str(tmp_path / "in.pcapng"), "-o", str(FULL)],
                         capture_output=True, text=True, timeout=60)
    assert cli.returncode == 2
    last = cli.stderr.strip().splitlines()[-1]
    assert last.startswith("rfhoming export: cannot write /dev/full: No space left on device;"), cli.stderr
    assert "Errno" not in cli.stderr and "Traceback" not in cli.stderr


def test_an_export_that_fails_leaves_the_old_file_and_no_part(tmp_path, monkeypatch):
    """Old code: a raw OSError and a 0-byte MCAP left behind; then, with the raw error named, a
    failed export still truncated the old file and left its torn start there. Now the export is
    written to OUT.part and renamed only when whole: the old file stays, no .part is left."""
    pytest.importorskip("mcap_ros2")
    from rfhoming.host.export import recorder

    _capture(tmp_path / "in.pcapng")
    out = tmp_path / "out.mcap"
    out.write_bytes(b"the old export")
    for room in (0, 3000):
        monkeypatch.setattr(outputs, "open", lambda path, mode, room=room: io.BufferedWriter(FullDisk(Path(path), room), 64),
                            raising=False)
        with pytest.raises(outputs.WriteFailed, match=rf"cannot write {out}: No space left on device; nothing of it "
                                                      rf"is kept \({out} is as it was\)"):
            recorder.export(out, capture=tmp_path / "in.pcapng")
        assert out.read_bytes() == b"the old export" and not outputs.part_of(out).exists()
    monkeypatch.undo()
    recorder.export(out, capture=tmp_path / "in.pcapng")  # a whole export replaces it
    assert out.read_bytes().startswith(b"\x89MCAP") and not outputs.part_of(out).exists()


@needs_dev_full
def test_a_capture_to_a_full_disk_names_the_file(tmp_path):
    """Old code: ``rfhoming capture: No space left on device``, no file named."""
    _capture(tmp_path / "in.pcapng")
    cli = subprocess.run([*RFHOMING, "capture", f"capture:{tmp_path / 'in.pcapng'}", "-o", str(FULL)],
                         capture_output=True, text=True, timeout=60)
    assert cli.returncode == 2
    assert "cannot write /dev/full: No space left on device" in cli.stderr, cli.stderr


def test_a_capture_that_fills_the_disk_midway_says_what_it_kept_and_spares_the_devices(tmp_path, caplog):
    """Old code: the OSError went up into whoever tapped the port (a driver's reader)."""
    path = tmp_path / "cap.pcapng"
    writer = CaptureWriter(path)
    writer.describe("west", kind="xplr-aoa")
    writer.tap("west", "in", 1000.0, b"+STARTUP\r\n")
    writer.flush()
    writer._file = io.BufferedWriter(FullDisk(tmp_path / "other.bin"))  # the disk is full from here on
    caplog.set_level(logging.ERROR)
    writer.tap("west", "in", 1000.5, b"x" * 10_000)  # must not raise
    writer.tap("west", "in", 1001.0, b"more")
    writer.close()
    assert writer.error is not None
    said = [r.getMessage() for r in caplog.records if str(path) in r.getMessage()]
    assert len(said) == 1 and "No space left on device" in said[0] and "packets up to t = 1000.000000" in said[0]


def test_a_run_log_that_cannot_be_written_names_the_file_and_the_records_kept(tmp_path):
    """Old code: ``No space left on device`` from deep in the loop, no file named."""
    path = tmp_path / "run.jsonl"
    out = io.TextIOWrapper(io.BufferedWriter(FullDisk(path, 200), 16), write_through=True)
    log = RunLog(out)
    with pytest.raises(outputs.WriteFailed) as failed:
        for k in range(100):
            log.write("event", k * 0.1, what=f"e{k}")
    message = str(failed.value)
    assert message.startswith(f"cannot write {path}: No space left on device; its ")
    assert f"the run's first {log.written} records" in message and 0 < log.written < 10
    empty = tmp_path / "empty.jsonl"
    log = RunLog(io.TextIOWrapper(io.BufferedWriter(FullDisk(empty)), write_through=True))
    with pytest.raises(outputs.WriteFailed, match="nothing was written, and the empty file is removed"):
        log.write("event", 0.0)
    assert not empty.exists()


@needs_dev_full
def test_a_run_log_on_a_full_disk(tmp_path):
    log = RunLog(open(FULL, "w"))
    with pytest.raises(outputs.WriteFailed, match="cannot write /dev/full: No space left on device; nothing of it"):
        log.write("event", 0.0)


def test_a_live_recording_on_a_full_disk_stops_feeding_the_mcap_writer(tmp_path, caplog):
    """A run goes on when its MCAP cannot be written; the recorder must then hand the mcap
    writer nothing more. Old code: every later message went into the writer's open chunk (which
    its failed write never reset) and every second's flush compressed that ever-growing chunk
    again: memory without bound and a loop that slows for the rest of the run. The close ends
    without raising and the messages are counted as skipped."""
    pytest.importorskip("mcap_ros2")
    from rfhoming.host.export.recorder import McapRecorder

    recorder = McapRecorder(FullDisk(tmp_path / "run.mcap", 20_000), clock="host")
    handed = {"add_message": 0, "flush": 0}
    for name in handed:
        real = getattr(recorder.writer, name)

        def counting(*args, _real=real, _name=name, **kwargs):
            handed[_name] += 1
            return _real(*args, **kwargs)

        setattr(recorder.writer, name, counting)
    record = {"kind": "measurement", "source": "aoa", "theta": 0.3, "azimuth": 12, "rssi": -50}
    with caplog.at_level(logging.ERROR):
        k = 0
        while recorder.write_error is None:
            recorder.on_runlog({**record, "t": k * 0.01})
            k += 1
            assert k < 100_000, "the file never filled"
        handed_at_error = dict(handed)
        for j in range(k, k + 2000):  # 20 s more of the run
            recorder.on_runlog({**record, "t": j * 0.01})
        assert handed == handed_at_error
        recorder.close()  # ends the run's recording without raising
    assert recorder.summary()["skipped"]["write error"] >= 2000
    assert sum("cannot write" in r.getMessage() for r in caplog.records) == 1
