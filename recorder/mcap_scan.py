"""A minimal, fast MCAP record scanner for reading recordings back.

The `mcap` package parses every record field by field in Python; reading thousands of runs
needs only channels, metadata and the messages of a few topics. This scanner walks the records
with `struct.unpack_from` over one buffer, opens chunks (zstd, lz4 or uncompressed), and stops
quietly at a truncated tail, so it also reads files whose writer was killed. `indexed_metadata`
reads only the footer and the summary section of a closed file, and the metadata records it
indexes. Record layouts: https://mcap.dev/spec.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_METADATA, OP_METADATA_INDEX = 0x02, 0x04, 0x05, 0x06, 0x0C, 0x0D

_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_RECORD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, crc
_FOOTER = struct.Struct("<BQQQI")  # opcode, record length, summary start, summary offset start, summary crc
_INDEX = struct.Struct("<QQ")  # offset of the indexed record, its length (opcode and length prefix included)


class NotMcap(ValueError):
    """The file does not start with the MCAP magic."""


@dataclass
class Scan:
    """What `scan` found. messages: {topic: [(log_time, data)]} for the wanted topics, in file order."""

    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    footer: bool = False  # the file ends with a footer record: it was closed


def _string(buf, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def _string_map(buf, pos: int) -> dict[str, str]:
    (n,) = _U32.unpack_from(buf, pos)
    end, pos, out = pos + 4 + n, pos + 4, {}
    while pos < end:
        key, pos = _string(buf, pos)
        out[key], pos = _string(buf, pos)
    return out


def _decompress(compression: str, data, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported MCAP chunk compression {compression!r}")


def _walk(buf, pos: int, end: int, topics: set[str], channels: dict[int, str], out: Scan) -> None:
    """Read records in buf[pos:end]; a record cut off by the end of the data ends the walk."""
    while pos + _RECORD.size <= end:
        op, length = _RECORD.unpack_from(buf, pos)
        start, pos = pos + _RECORD.size, pos + _RECORD.size + length
        if pos > end:
            return
        if op == OP_MESSAGE:
            channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(buf, start)
            topic = channels.get(channel_id)
            if topic is not None:
                out.messages[topic].append((log_time, bytes(buf[start + _MESSAGE_HEAD.size:pos])))
        elif op == OP_CHUNK:
            _, _, size, _ = _CHUNK_HEAD.unpack_from(buf, start)
            compression, p = _string(buf, start + _CHUNK_HEAD.size)
            (n,) = _U64.unpack_from(buf, p)
            data = _decompress(compression, buf[p + 8:p + 8 + n], size)
            _walk(memoryview(data), 0, len(data), topics, channels, out)
        elif op == OP_CHANNEL:
            (channel_id,) = _U16.unpack_from(buf, start)
            topic, _ = _string(buf, start + 4)
            if topic in topics:
                channels[channel_id] = topic
        elif op == OP_METADATA:
            name, p = _string(buf, start)
            out.metadata[name] = _string_map(buf, p)
        elif op == OP_FOOTER:
            out.footer = True


def scan(path: Path, topics) -> Scan:
    """Metadata records, the messages of `topics`, and whether the file was closed (footer present)."""
    data = Path(path).read_bytes()
    if not data.startswith(MAGIC):
        raise NotMcap(f"{path} does not start with the MCAP magic")
    out = Scan(messages={t: [] for t in topics})
    _walk(memoryview(data), len(MAGIC), len(data), set(topics), {}, out)
    return out


def indexed_metadata(path: Path) -> dict[str, dict[str, str]] | None:
    """The metadata records that a closed file's summary section indexes, {name: {key: value}}, read
    without opening a chunk; None when the file has no footer (not closed) or no summary section."""
    with open(path, "rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise NotMcap(f"{path} does not start with the MCAP magic")
        size = f.seek(0, 2)
        footer = size - _FOOTER.size - len(MAGIC)
        if footer < len(MAGIC):
            return None
        f.seek(footer)
        tail = f.read()
        op, length, start, offsets, _ = _FOOTER.unpack_from(tail)
        if tail[_FOOTER.size:] != MAGIC or op != OP_FOOTER or length != _FOOTER.size - _RECORD.size or start == 0:
            return None
        f.seek(start)
        buf = f.read((offsets or footer) - start)
        records, pos = [], 0
        while pos + _RECORD.size <= len(buf):
            op, length = _RECORD.unpack_from(buf, pos)
            if op == OP_METADATA_INDEX:
                records.append(_INDEX.unpack_from(buf, pos + _RECORD.size))
            pos += _RECORD.size + length
        out = {}
        for offset, length in records:
            f.seek(offset)
            record = f.read(length)
            if len(record) != length or record[0] != OP_METADATA:
                raise ValueError(f"metadata index points at offset {offset}, which holds no metadata record")
            name, p = _string(record, _RECORD.size)
            out[name] = _string_map(record, p)
    return out
