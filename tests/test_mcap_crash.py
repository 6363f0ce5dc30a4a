"""A recorder killed with SIGKILL leaves an MCAP that loses at most the last 1.5 s: every
message older than FLUSH_S + REORDER_S (of message time: a second between flushes, half a
second held to write in log-time order) before the last one made is on disk, readable
by the mcap library's linear reader although the file has no summary. Counted in message
time, so a slow machine cannot fail it (host-time flushes only add data). What a kill leaves
is RUN.mcap.part (host/outputs.py): RUN.mcap is as it was."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
import rigs
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader
from rosbags.highlevel import AnyReader, AnyReaderError

from rfhoming.host.export.recorder import FLUSH_S, REORDER_S
from rfhoming.host.outputs import part_of

WRITER = """
import sys, time
from rfhoming.host.export.recorder import McapRecorder
recorder = McapRecorder(sys.argv[1], clock="host")
for i in range(200):  # 10 s of message time, written as fast as the machine goes
    recorder.on_runlog({"kind": "event", "t": i * 0.05, "what": f"e{i}"})
print("written", flush=True)
time.sleep(600)
"""


def killed_recording(path: Path) -> Path:
    """The file a recording to ``path`` killed with SIGKILL leaves (``path`` is not written)."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert rigs.readline(proc, "stdout", 120).strip() == "written"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert not path.exists()
    return part_of(path)


def linear_read(path: Path) -> list[tuple[int, bytes]]:
    """(log time ns, data) of every event message before the file's end, in file order (the
    /tf_static written first is left out). A file cut short ends without its summary and
    footer: the reader raises EndOfFile there."""
    out = []
    with path.open("rb") as f:
        try:
            for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                if channel.topic == "/rfhoming/events":
                    out.append((message.log_time, message.data))
        except EndOfFile:
            pass
    return out


def test_sigkill_loses_at_most_the_last_one_and_a_half_seconds(tmp_path: Path) -> None:
    got = linear_read(killed_recording(tmp_path / "run.mcap"))
    times = [t / 1e9 for t, _ in got]
    last_written = 199 * 0.05
    assert times == pytest.approx([i * 0.05 for i in range(len(times))])  # a prefix, in order
    assert times and times[-1] >= last_written - FLUSH_S - REORDER_S - 1e-9, times[-1:]
    assert b"e0" in got[0][1] and f"e{len(got) - 1}".encode() in got[-1][1]


def test_rosbags_needs_the_summary_a_killed_file_lacks(tmp_path: Path) -> None:
    """rosbags reads only finished files (it checks the end magic): `mcap recover` (the mcap
    CLI) rewrites a killed file into one it reads. A file closed normally it reads at once."""
    path = tmp_path / "run.mcap"
    killed_recording(path).rename(path)  # what a user who wants it does first
    with pytest.raises(AnyReaderError, match="magic"), AnyReader([path]) as reader:
        list(reader.messages())
