"""An MCAP file cut short (a recorder killed by power loss: no summary, no index at the end)
read up to its last whole chunk: the file is walked record by record from the start, each
whole chunk decompressed once (CRC checked) for its schemas, channels and messages' log
times, and a summary rebuilt from them (:func:`recover_summary`) so that
:class:`IndexedReader` seeks messages as in a complete file. The walk stops at the first
record that runs past the end of the file or does not read (zeros, garbage, a bad CRC).

Messages written outside chunks (an unchunked file) are not read this way: ``mcap recover``
(the ``mcap`` CLI) rebuilds such a file.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, Message, Schema
from mcap.stream_reader import ReadDataStream, breakup_chunk
from mcap.summary import Summary

MAGIC_SIZE = 8
#: Opcode (1 byte) and length (8 bytes) before every record's body.
RECORD_HEAD = struct.Struct("<BQ")
#: What a damaged record raises inside the mcap library and its decompressors.
_RECORD_ERRORS = (McapError, EOFError, struct.error, ValueError, KeyError, MemoryError)


@dataclass
class Recovered:
    """A summary rebuilt from the whole chunks of a cut file, the log times (ns) of each
    channel's messages, and the byte where the readable part ends."""

    summary: Summary
    times: dict[int, list[int]]
    end: int

    @property
    def messages(self) -> int:
        """Number of whole messages read."""
        return sum(len(t) for t in self.times.values())


class IndexedReader(SeekingReader):
    """A :class:`~mcap.reader.SeekingReader` over a file whose summary was rebuilt."""

    def __init__(self, stream: IO[bytes], summary: Summary, **kwargs: Any) -> None:
        super().__init__(stream, **kwargs)
        self._given = summary

    def get_summary(self) -> Summary:
        """The rebuilt summary (the file has none)."""
        return self._given


def _chunk_index(chunk: Chunk, offset: int, length: int) -> ChunkIndex:
    """The index record of a chunk read at ``offset`` (``length`` bytes with its head); no
    message index offsets: a reader scans the chunk for its topics."""
    return ChunkIndex(
        chunk_length=length,
        chunk_start_offset=offset,
        compression=chunk.compression,
        compressed_size=len(chunk.data),
        message_end_time=chunk.message_end_time,
        message_index_length=0,
        message_index_offsets={},
        message_start_time=chunk.message_start_time,
        uncompressed_size=chunk.uncompressed_size,
    )


def _add(summary: Summary, times: dict[int, list[int]], record: Any) -> None:
    """Enter a schema, channel or message record into the rebuilt summary and times."""
    if isinstance(record, Schema):
        summary.schemas[record.id] = record
    elif isinstance(record, Channel):
        summary.channels[record.id] = record
        times.setdefault(record.id, [])
    elif isinstance(record, Message):
        times.setdefault(record.channel_id, []).append(record.log_time)


def recover_summary(stream: IO[bytes]) -> Recovered:
    """The summary of the whole chunks of ``stream`` (an MCAP file without a usable summary).
    McapError where a message lies outside a chunk."""
    size = stream.seek(0, io.SEEK_END)
    summary, times, pos = Summary(), {}, MAGIC_SIZE
    while pos + RECORD_HEAD.size <= size:
        stream.seek(pos)
        opcode, length = RECORD_HEAD.unpack(stream.read(RECORD_HEAD.size))
        end = pos + RECORD_HEAD.size + length
        if end > size or opcode not in Opcode.__members__.values():
            break  # cut inside this record, or not a record (zeros, garbage)
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            break
        if opcode == Opcode.MESSAGE:
            raise McapError(f"a message outside chunks at byte {pos}")
        if opcode in (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL):
            body = ReadDataStream(io.BytesIO(stream.read(length)))
            try:
                if opcode == Opcode.CHUNK:
                    chunk = Chunk.read(body)
                    records = breakup_chunk(chunk, validate_crc=True)
                    summary.chunk_indexes.append(_chunk_index(chunk, pos, end - pos))
                else:
                    records = [(Schema if opcode == Opcode.SCHEMA else Channel).read(body)]
            except _RECORD_ERRORS:
                break
            for record in records:
                _add(summary, times, record)
        pos = end
    return Recovered(summary, times, min(pos, size))
