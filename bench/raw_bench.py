"""What carrying raw bytes costs: a protocol's decoder alone (its batched path, the C
accelerator where built) against rfhoming.reader.Framer (one unit at a time, each item with its
bytes), on the same stream in 4 KiB reads, in CPU time of this process, best of ``--repeat``.

    python bench/raw_bench.py [--items 200000] [--repeat 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from rfhoming.protocol.accel import ACCEL
from rfhoming.protocol.frames import encode_frame
from rfhoming.protocol.frames.records import AntennaReading, AntennaSet
from rfhoming.reader import Framer, new_decoder

ROOT = Path(__file__).resolve().parent.parent


def streams(items: int) -> dict[str, bytes]:
    line = b'\r\n+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869\r\n'
    frame = encode_frame(AntennaSet(0, 1, 20_000, 7, 5, 0, -99, 15, tuple(AntennaReading(40, 200, 10) for _ in range(4))))
    return {"uconnect": line * items, "frames": frame * items}


def best(decode, reads: list[bytes], repeat: int) -> float:
    """The least CPU time of ``repeat`` passes of ``decode(chunk)`` over the reads."""
    times = []
    for _ in range(repeat):
        start = time.process_time()
        for chunk in reads:
            decode(chunk)
        times.append(time.process_time() - start)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--items", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    out = {"accelerator": ACCEL is not None, "items": args.items}
    for protocol, data in streams(args.items).items():
        reads = [data[i:i + 4096] for i in range(0, len(data), 4096)]
        assert len(Framer(protocol).feed(data)) == args.items  # whole units: every item decoded
        alone = best(new_decoder(protocol).feed, reads, args.repeat)
        with_raw = best(Framer(protocol).feed, reads, args.repeat)
        out[protocol] = {"decoder_items_per_s": round(args.items / alone), "framer_items_per_s": round(args.items / with_raw),
                         "slowdown": round(with_raw / alone, 2)}
    if args.json:
        print(json.dumps(out))
        return
    for protocol in ("uconnect", "frames"):
        r = out[protocol]
        print(f"{protocol:<9} decoder {r['decoder_items_per_s']:>10,} items/s   with raw {r['framer_items_per_s']:>10,} "
              f"items/s   x{r['slowdown']} the CPU time (accelerator: {out['accelerator']})")


if __name__ == "__main__":
    main()
