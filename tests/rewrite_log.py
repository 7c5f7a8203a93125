"""Re-writes an mjsafe log with Python's `mcap` Writer in another valid layout: the same
schemas, channels, messages (same order and times) and metadata, with another chunk
compression, chunk size and metadata position. No mjsafe code involved. DROP (optional,
comma-separated) leaves topics (`/barrier`) or metadata records (`mjsafe_status`) out, as a
topic filter would: a dropped topic has no channel and no messages in the copy. ORDER
(optional) writes the messages out of log-time order, which MCAP allows: `halves` (the second
half of the messages first, split where the log time changes), `by_topic` (each channel's messages in turn), `reverse` (last
first, the messages of one log time too); with `-noindex` (`halves-noindex`) the copy has no
chunk or message indexes, so a reader cannot tell the order from them, and with `-nosummary`
no summary section at all (no indexes, no statistics, no repeated schemas and channels).

usage: rewrite_log.py IN OUT COMPRESSION(zstd|lz4|none) CHUNK_SIZE METADATA(first|last) [DROP] [ORDER]"""
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer


def main(src, dst, compression, chunk_size, metadata_at, drop="", order="file"):
    drop = set(filter(None, drop.split(",")))
    with open(src, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        metadata = [m for m in reader.iter_metadata() if m.name not in drop]
        messages = list(reader.iter_messages(log_time_order=False))
    order, _, index = order.partition("-")
    if order == "halves":
        # Split at the first change of log time from the middle on: the messages of one log
        # time stay together, in their order (which readers keep for messages of one time).
        half = len(messages) // 2
        while 0 < half < len(messages) and messages[half][2].log_time == messages[half - 1][2].log_time:
            half += 1
        messages = messages[half:] + messages[:half]
    elif order == "by_topic":
        messages.sort(key=lambda m: m[1].id)
    elif order == "reverse":
        messages.reverse()
    else:
        assert order == "file", order
    with open(dst, "wb") as out:
        writer = Writer(
            out,
            chunk_size=int(chunk_size),
            compression={"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression],
            index_types=IndexType.NONE if index in ("noindex", "nosummary") else IndexType.ALL,
            repeat_channels=index != "nosummary",
            repeat_schemas=index != "nosummary",
            use_statistics=index != "nosummary",
            use_summary_offsets=index != "nosummary",
        )
        writer.start(profile="", library="rewrite_log.py")
        schema_ids, channel_ids = {}, {}
        for schema in summary.schemas.values():
            schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
        for channel in summary.channels.values():
            if channel.topic in drop:
                continue
            channel_ids[channel.id] = writer.register_channel(
                channel.topic, channel.message_encoding, schema_ids[channel.schema_id], channel.metadata
            )
        if metadata_at == "first":
            for m in metadata:
                writer.add_metadata(m.name, dict(m.metadata))
        for schema, channel, message in messages:
            if channel.topic in drop:
                continue
            writer.add_message(
                channel_ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence
            )
        if metadata_at == "last":
            for m in metadata:
                writer.add_metadata(m.name, dict(m.metadata))
        writer.finish()


if __name__ == "__main__":
    main(*sys.argv[1:])
