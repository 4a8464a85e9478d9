"""An MCAP writer that takes a whole episode's messages in one call: the file `mcap.Writer` writes.

`mcap.Writer.add_message` builds each message record field by field in Python: with three messages
a step, a noticeable share of the time it takes to simulate the step (docs/decisions/mcap-writing.md).
This writer takes the messages as arrays and builds their records, the chunks and the chunks'
message indexes with NumPy. Everything else (header, schemas, channels, attachments, metadata, the
summary section) is written through `mcap.records`, with the same layout and chunking rule as
`mcap.Writer` (a chunk closes once it holds more than `chunk_size` bytes; schemas and channels go
into the first chunk). A test checks that both writers produce the same bytes.

The one deliberate difference is the zstd level: -1 (a fast mode) instead of zstandard's default 3.
Recorded episodes are mostly floating-point numbers, which no level compresses much, so the fast
level loses little size and saves most of the time (docs/decisions/mcap-writing.md).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from typing import BinaryIO

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC

FAST_ZSTD_LEVEL = -1  # zstd's fast mode; see the module's docstring
DEFAULT_CHUNK_SIZE = 1024 * 1024  # mcap.Writer's

# A message record up to its data: opcode, record length, channel, sequence, log and publish times.
_MESSAGE_HEAD = np.dtype(
    [
        ("opcode", "u1"),
        ("length", "<u8"),
        ("channel", "<u2"),
        ("sequence", "<u4"),
        ("log_time", "<u8"),
        ("publish_time", "<u8"),
    ]
)
_MESSAGE_FIELDS_SIZE = _MESSAGE_HEAD.itemsize - 9  # what the record length counts besides the data
_MESSAGE_INDEX_START = struct.Struct("<BQHI")


class BulkMcapWriter:
    """Writes one MCAP file to `stream`; call `start`, register, add, then `finish` once."""

    def __init__(
        self, stream: BinaryIO, chunk_size: int = DEFAULT_CHUNK_SIZE, zstd_level: int | None = FAST_ZSTD_LEVEL
    ) -> None:
        self._stream = stream
        self._chunk_size = chunk_size
        self._compressor = None if zstd_level is None else zstandard.ZstdCompressor(level=zstd_level)
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._message_counts: dict[int, int] = {}
        self._message_times: list[int] = []  # first and last log times seen, as min/max
        self._chunk = _OpenChunk()

    def start(self, profile: str = "", library: str = "") -> None:
        self._stream.write(MCAP0_MAGIC)
        self._write(Header(profile, library))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas.append(schema)
        self._chunk.add_record(schema)
        return schema.id

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str] | None = None
    ) -> int:
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=metadata or {},
        )
        self._channels.append(channel)
        self._chunk.add_record(channel)
        return channel.id

    def add_attachment(self, create_time: int, log_time: int, name: str, media_type: str, data: bytes) -> None:
        attachment = Attachment(create_time=create_time, log_time=log_time, name=name, media_type=media_type, data=data)
        offset, length = self._write(attachment)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=length,
                create_time=create_time,
                log_time=log_time,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        offset, length = self._write(Metadata(name=name, metadata=data))
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))

    def add_messages(
        self,
        channels: np.ndarray,
        log_times: np.ndarray,
        publish_times: np.ndarray,
        sequences: np.ndarray,
        data: Sequence[bytes],
    ) -> None:
        """Messages in file order: message i is (channels[i], ..., data[i])."""
        count = len(data)
        if count == 0:
            return
        sizes = np.fromiter(map(len, data), np.int64, count)
        heads = np.empty(count, _MESSAGE_HEAD)
        heads["opcode"] = Opcode.MESSAGE
        heads["length"] = sizes + _MESSAGE_FIELDS_SIZE
        heads["channel"], heads["sequence"] = channels, sequences
        heads["log_time"], heads["publish_time"] = log_times, publish_times
        width = _MESSAGE_HEAD.itemsize
        head_bytes = heads.tobytes()
        records: list[bytes] = [b""] * (2 * count)
        records[0::2] = [head_bytes[i * width : (i + 1) * width] for i in range(count)]
        records[1::2] = data
        record_ends = np.cumsum(sizes + width)
        record_starts = record_ends - (sizes + width)
        for channel, channel_count in _in_order_of_first_use(channels):
            self._message_counts[channel] = self._message_counts.get(channel, 0) + channel_count
        self._message_times += [int(log_times.min()), int(log_times.max())]

        first = 0
        while first < count:
            # mcap.Writer closes a chunk after the first message that takes it past chunk_size.
            room = self._chunk_size - self._chunk.size + record_starts[first]
            last = max(first, min(int(np.searchsorted(record_ends, room, side="right")), count - 1))
            self._chunk.add_messages(
                b"".join(records[2 * first : 2 * last + 2]),
                channels[first : last + 1],
                log_times[first : last + 1],
                self._chunk.size + record_starts[first : last + 1] - record_starts[first],
            )
            if self._chunk.size > self._chunk_size:
                self._close_chunk()
            first = last + 1

    def finish(self) -> None:
        """Close the last chunk and write the summary section and footer (the stream stays open)."""
        if self._chunk.has_messages:
            self._close_chunk()
        self._write(DataEnd(0))
        summary_start = self._stream.tell()
        summary = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: Sequence) -> None:
            start = summary.count
            for record in records:
                record.write(summary)
            offsets.append(
                SummaryOffset(
                    group_opcode=opcode, group_start=summary_start + start, group_length=summary.count - start
                )
            )

        times = self._message_times or [0]
        statistics = Statistics(
            attachment_count=len(self._attachment_indexes),
            channel_count=len(self._channels),
            channel_message_counts=self._message_counts,
            chunk_count=len(self._chunk_indexes),
            message_count=sum(self._message_counts.values()),
            metadata_count=len(self._metadata_indexes),
            message_start_time=min(times),
            message_end_time=max(times),
            schema_count=len(self._schemas),
        )
        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [statistics])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        summary_bytes = summary.end()
        # The footer's CRC covers the summary section and the footer up to the CRC itself.
        footer_start = struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start)
        self._stream.write(summary_bytes)
        self._write(
            Footer(
                summary_start=summary_start,
                summary_offset_start=summary_offset_start,
                summary_crc=zlib.crc32(footer_start, zlib.crc32(summary_bytes)),
            )
        )
        self._stream.write(MCAP0_MAGIC)

    def _write(self, record: McapRecord) -> tuple[int, int]:
        """Write one record to the stream; its offset and length."""
        builder = RecordBuilder()
        record.write(builder)
        offset = self._stream.tell()
        self._stream.write(builder.end())
        return offset, self._stream.tell() - offset

    def _close_chunk(self) -> None:
        chunk, self._chunk = self._chunk, _OpenChunk()
        records = chunk.records()
        compressed = records if self._compressor is None else self._compressor.compress(records)
        start_time, end_time = chunk.time_range()
        record = Chunk(
            compression="" if self._compressor is None else "zstd",
            data=compressed,
            message_start_time=start_time,
            message_end_time=end_time,
            uncompressed_crc=zlib.crc32(records),
            uncompressed_size=len(records),
        )
        chunk_offset, chunk_length = self._write(record)
        index_offset = self._stream.tell()
        message_index_offsets = {}
        for channel, index_record in chunk.message_indexes():
            message_index_offsets[channel] = self._stream.tell()
            self._stream.write(index_record)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start_time,
                message_end_time=end_time,
                chunk_start_offset=chunk_offset,
                chunk_length=chunk_length,
                message_index_offsets=message_index_offsets,
                message_index_length=self._stream.tell() - index_offset,
                compression=record.compression,
                compressed_size=len(compressed),
                uncompressed_size=len(records),
            )
        )


class _OpenChunk:
    """The records of the chunk being filled, and where each message record starts in it."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []
        self.size = 0
        self._channels: list[np.ndarray] = []
        self._log_times: list[np.ndarray] = []
        self._offsets: list[np.ndarray] = []

    @property
    def has_messages(self) -> bool:
        return bool(self._channels)

    def add_record(self, record: Schema | Channel) -> None:
        builder = RecordBuilder()
        record.write(builder)
        self._parts.append(builder.end())
        self.size += len(self._parts[-1])

    def add_messages(self, records: bytes, channels: np.ndarray, log_times: np.ndarray, offsets: np.ndarray) -> None:
        self._parts.append(records)
        self.size += len(records)
        self._channels.append(np.asarray(channels))
        self._log_times.append(np.asarray(log_times, np.uint64))
        self._offsets.append(np.asarray(offsets, np.uint64))

    def records(self) -> bytes:
        return b"".join(self._parts)

    def time_range(self) -> tuple[int, int]:
        times = np.concatenate(self._log_times)
        return int(times.min()), int(times.max())

    def message_indexes(self) -> list[tuple[int, bytes]]:
        """Each channel's message index record, channels in order of their first message in the chunk."""
        channels, times, offsets = (np.concatenate(parts) for parts in (self._channels, self._log_times, self._offsets))
        indexes = []
        for channel, _ in _in_order_of_first_use(channels):
            mine = channels == channel
            entries = np.stack([times[mine], offsets[mine]], axis=1).astype("<u8").tobytes()
            head = _MESSAGE_INDEX_START.pack(Opcode.MESSAGE_INDEX, 2 + 4 + len(entries), channel, len(entries))
            indexes.append((channel, head + entries))
        return indexes


def _in_order_of_first_use(channels: np.ndarray) -> list[tuple[int, int]]:
    """(channel, message count) pairs, in the order the channels first appear (mcap.Writer's dict order)."""
    unique, first, counts = np.unique(channels, return_index=True, return_counts=True)
    order = np.argsort(first)
    return list(zip(unique[order].tolist(), counts[order].tolist(), strict=True))
