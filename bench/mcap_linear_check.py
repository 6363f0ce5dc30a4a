"""An MCAP log as a linear reader sees it -- the mcap library's NonSeekingReader, what reads a
crashed file -- with mcap_ros2's decoder, nothing of rfhoming's: messages behind the log time of
one read before them (and by how much), chunks whose time ranges overlap the next one's, scans
holding a range outside their own [range_min, range_max] (REP 117 wants +-inf there).

    python bench/mcap_linear_check.py FILE.mcap [--json]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory


def check(path: Path) -> dict[str, int | float]:
    late, worst, last, scans, outside = 0, 0, 0, 0, 0
    with path.open("rb") as f:
        reader = NonSeekingReader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            if message.log_time < last:
                late, worst = late + 1, max(worst, last - message.log_time)
            last = max(last, message.log_time)
            if channel.topic == "/scan":
                scans += 1
                outside += any(math.isfinite(r) and not decoded.range_min <= r <= decoded.range_max
                               for r in decoded.ranges)
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset) if summary else []
    overlapping = sum(a.message_end_time > b.message_start_time for a, b in zip(chunks, chunks[1:]))
    return {"out_of_order": late, "worst_ms": worst / 1e6, "chunks": len(chunks), "overlapping_chunk_pairs": overlapping,
            "scans": scans, "scans_out_of_range": outside}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mcap", type=Path)
    p.add_argument("--json", action="store_true", help="one JSON object")
    args = p.parse_args()
    result = check(args.mcap)
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))


if __name__ == "__main__":
    main()
