"""The bulk MCAP writer writes the file mcap's own Writer writes, and mcap's reader reads it back."""

from __future__ import annotations

import io

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from teleop.mcap_io.bulk import BulkMcapWriter

STEPS = 400
CHANNEL_ORDER = np.array([3, 2, 1])  # a step's messages, in reverse channel-id order


def messages(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[bytes]]:
    """Three channels' messages a step, of random sizes (empty ones included), in file order."""
    rng = np.random.default_rng(seed)
    channels = np.tile(CHANNEL_ORDER, STEPS)
    times = np.repeat(np.arange(STEPS, dtype=np.int64) * 15_000_000, len(CHANNEL_ORDER))
    sequences = np.repeat(np.arange(STEPS), len(CHANNEL_ORDER))
    data = [rng.bytes(int(size)) for size in rng.integers(0, 2_000, len(channels))]
    return channels, times, sequences, data


def write(writer: Writer | BulkMcapWriter, batches: list[slice]) -> None:
    """The same file through either writer: the bulk one gets the messages in `batches`."""
    channels, times, sequences, data = messages()
    writer.start(profile="test", library="test")
    schemas = [writer.register_schema(name, "protobuf", name.encode() * 3) for name in ("a.A", "b.B")]
    for topic, schema in (("/scene", schemas[0]), ("/step", schemas[1]), ("/tf", schemas[0])):
        writer.register_channel(topic, "protobuf", schema)
    writer.add_attachment(create_time=0, log_time=0, name="model.xml", media_type="application/xml", data=b"<mujoco/>")
    writer.add_metadata("episode", {"seed": "7"})
    if isinstance(writer, BulkMcapWriter):
        for batch in batches:
            writer.add_messages(channels[batch], times[batch], times[batch], sequences[batch], data[batch])
    else:
        for i in range(sum(len(channels[batch]) for batch in batches)):
            writer.add_message(
                int(channels[i]),
                log_time=int(times[i]),
                data=data[i],
                publish_time=int(times[i]),
                sequence=int(sequences[i]),
            )
    writer.finish()


@pytest.mark.parametrize("chunk_size", [1024 * 1024, 50_000, 1], ids=["one chunk", "several chunks", "a chunk each"])
@pytest.mark.parametrize(
    ("compression", "zstd_level"),
    [(CompressionType.ZSTD, 3), (CompressionType.NONE, None)],
    ids=["zstd", "uncompressed"],
)
def test_same_bytes_as_mcap_writer(chunk_size: int, compression: CompressionType, zstd_level: int | None) -> None:
    """Given the same records, both writers produce identical files, whatever the chunking."""
    batches = [slice(0, 1), slice(1, 500), slice(500, None)]
    reference, bulk = io.BytesIO(), io.BytesIO()
    write(Writer(reference, chunk_size=chunk_size, compression=compression), batches)
    write(BulkMcapWriter(bulk, chunk_size=chunk_size, zstd_level=zstd_level), batches)
    assert bulk.getvalue() == reference.getvalue()


def test_file_without_messages_matches_mcap_writer() -> None:
    """With no messages, no chunk is written and the summary still lists the schemas and channels."""
    reference, bulk = io.BytesIO(), io.BytesIO()
    write(Writer(reference), [])
    write(BulkMcapWriter(bulk, zstd_level=3), [slice(0, 0)])
    assert bulk.getvalue() == reference.getvalue()


def test_fast_zstd_file_reads_back_with_valid_crcs() -> None:
    """A file at the default (fast) zstd level reads back, CRCs checked, message for message."""
    stream = io.BytesIO()
    write(BulkMcapWriter(stream, chunk_size=100_000), [slice(0, None)])
    stream.seek(0)
    reader = make_reader(stream, validate_crcs=True)
    assert all(chunk.compression == "zstd" for chunk in reader.get_summary().chunk_indexes)
    read = [
        (channel.id, message.log_time, message.sequence, message.data)
        for _, channel, message in reader.iter_messages(log_time_order=False)
    ]
    channels, times, sequences, data = messages()
    assert read == list(zip(channels.tolist(), times.tolist(), sequences.tolist(), data, strict=True))
