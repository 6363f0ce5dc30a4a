"""rfhoming's COBS-framed binary records: RSS nodes and the robot base (docs/protocol.md §2)."""

from rfhoming.protocol.frames.codec import MAX_ENCODED, FrameDecoder, encode_frame, encode_inner
from rfhoming.protocol.frames.records import (
    MAX_INNER,
    RECORD_TYPES,
    AdvReport,
    AntennaReading,
    AntennaSet,
    LogText,
    NodeCommand,
    Odometry,
    RangeScan,
    RangeScanV2,
    RfFrame,
    Status,
    VelocityCommand,
    build_inner,
    crc16,
    parse_inner,
)

__all__ = [
    "MAX_ENCODED",
    "MAX_INNER",
    "RECORD_TYPES",
    "AdvReport",
    "AntennaReading",
    "AntennaSet",
    "FrameDecoder",
    "LogText",
    "NodeCommand",
    "Odometry",
    "RangeScan",
    "RangeScanV2",
    "RfFrame",
    "Status",
    "VelocityCommand",
    "build_inner",
    "crc16",
    "encode_frame",
    "encode_inner",
    "parse_inner",
]
