"""Building and running the C reference (c_reference/) beside the Python decoder, for the tests
and bench/fuzz.py: both decoders' results in one comparable form.

A result is one word per frame end, the words tests/rfh_harness.c prints: ``D<n>`` a drop
(n = rfh_drop_t: 1 oversize, 2 cobs, 3 short, 4 crc, 5 version), ``T<hex>`` a checked frame of
unknown type, ``L<hex>`` one its type's parser rejects, ``F<hex>`` one parsed and encoded again.
The C reference does no range checks (docs/protocol.md: a node acts only on commands, whose
fields have none), so Python's ``field`` drop is an ``F`` word.
"""

from __future__ import annotations

import shutil
import struct
import subprocess
import sysconfig
from pathlib import Path

from cobs import cobs

from rfhoming.protocol.frames import FrameDecoder, encode_frame

ROOT = Path(__file__).resolve().parent.parent
SOURCE = ROOT / "c_reference"
HARNESS = ROOT / "tests" / "rfh_harness.c"
STRICT = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror"]
SANITIZE = ["-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"]
DROP_CODES = {"oversize": 1, "cobs": 2, "short": 3, "crc": 4, "version": 5}


def compiler() -> str | None:
    for cc in ((sysconfig.get_config_var("CC") or "").split()[:1] + ["cc", "gcc", "clang"]):
        if cc and shutil.which(cc):
            return cc
    return None


def build_harness(cc: str, out: Path, sanitize: bool) -> Path:
    """Compile the harness with the C reference; ``sanitize``: ASan + UBSan, any report fatal."""
    flags = SANITIZE if sanitize else ["-O2"]
    subprocess.run([cc, *STRICT, *flags, f"-I{SOURCE}", "-o", str(out), str(HARNESS), str(SOURCE / "rfh_frames.c")],
                   check=True, capture_output=True, text=True, timeout=300)
    return out


def run_harness(exe: Path, inputs: list[bytes]) -> list[list[str]]:
    """Each input through a fresh C decoder; its words. A sanitizer report fails the run."""
    data = b"".join(struct.pack("<I", len(x)) + x for x in inputs)
    done = subprocess.run([str(exe)], input=data, capture_output=True,
                          env={"ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"}, timeout=300)
    if done.returncode != 0:
        raise AssertionError(f"the C harness exited {done.returncode}: {done.stderr.decode(errors='replace')[-3000:]}")
    lines = done.stdout.decode().split("\n")[: len(inputs)]
    return [line.split() for line in lines]


def python_words(data: bytes) -> list[str]:
    """The same input through ``FrameDecoder`` (pure Python), in the harness's words."""
    words = []
    for item in FrameDecoder(pure=True).feed(data):
        if item.kind != "drop":
            words.append("F" + encode_frame(item).hex())
        elif item.reason in DROP_CODES:
            words.append(f"D{DROP_CODES[item.reason]}")
        elif item.reason == "type":
            words.append("T" + item.raw.hex())
        elif item.reason in ("length", "text"):
            words.append("L" + item.raw.hex())
        else:  # field: a range the C side does not check; it parses and re-encodes the frame
            words.append("F" + (b"\0" + cobs.encode(item.raw) + b"\0").hex())
    return words
