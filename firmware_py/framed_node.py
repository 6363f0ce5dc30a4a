"""What every rfhoming binary-framed device shares: a bounded TX buffer of COBS frames,
the per-node record counter, 1 Hz status (0x10), log text (0x7F) and host commands (0x80)."""

from __future__ import annotations

from typing import Any

from rfhoming.protocol.frames import FrameDecoder, LogText, NodeCommand, Status, encode_frame

TX_BUFFER = 16384
STATUS_PERIOD_US = 1_000_000


class FramedNode:
    """Base of the node models. Subclasses set DEVICE_KIND and FIRMWARE and handle commands."""

    DEVICE_KIND = 0
    FIRMWARE = (1, 0, 0)

    def __init__(self, node_id: int) -> None:
        self.node_id = node_id
        self.counters: dict[str, int] = {"tx_dropped": 0, "rx_errors": 0}
        self._seq = 0
        self._now_us = 0
        self._next_status_us = 0
        self._out = bytearray()
        self._decoder = FrameDecoder()

    def tick(self, now_us: int) -> None:
        self._now_us = now_us
        if now_us >= self._next_status_us:
            self._next_status_us = now_us + STATUS_PERIOD_US
            self.send_status()

    def receive(self, data: bytes) -> None:
        """Host bytes: every decoded 0x80 goes to :meth:`command`; drops are counted."""
        for item in self._decoder.feed(data):
            if item.kind == "drop":
                self.counters["rx_errors"] += 1
            elif isinstance(item, NodeCommand):
                self.command(item)
            else:
                self.counters["rx_errors"] += 1

    def command(self, cmd: NodeCommand) -> None:
        self.log(f"unknown command {cmd.command}")

    def read(self) -> bytes:
        data = bytes(self._out)
        self._out.clear()
        return data

    def next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        return self._seq

    def send_status(self) -> None:
        self.send(Status(self.node_id, self.next_seq(), self._now_us & 0xFFFFFFFF, self.DEVICE_KIND,
                         *self.FIRMWARE, (self._now_us // 1000) & 0xFFFFFFFF,
                         min(self.counters["tx_dropped"], 0xFFFF),
                         min(self.counters["rx_errors"], 0xFFFF)))

    def log(self, text: str) -> None:
        self.send(LogText(self.node_id, self.next_seq(), self._now_us & 0xFFFFFFFF, text))

    def send(self, record: Any) -> None:
        frame = encode_frame(record)
        if len(self._out) + len(frame) > TX_BUFFER:
            self.counters["tx_dropped"] += 1
            return
        self._out += frame
