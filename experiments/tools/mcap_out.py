"""An MCAP file written for Foxglove: protobuf messages whose schema is registered from their
class (``mcap-protobuf-support``), JSON messages with a JSON schema, and a bag's own
messages copied with their own schemas and channels (``--keep-topics``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Any

from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema
from zstandard import ZstdError

from ttc.io.frame_errors import FrameDataError

#: The library named in the file's header.
LIBRARY = "ttc-bench export"


class McapOut:
    """One MCAP file being written (zstd chunks); :meth:`finish` writes its index and footer.
    Each topic has one channel, registered with its first message."""

    def __init__(self, stream: IO[bytes], chunk_size: int = 4 * 1024 * 1024) -> None:
        self.writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=LIBRARY)
        self.channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def _add(self, topic: str, data: bytes, log_ns: int) -> None:
        self.writer.add_message(channel_id=self.channels[topic], log_time=int(log_ns),
                                data=data, publish_time=int(log_ns),
                                sequence=self.counts.get(topic, 0))  # fmt: skip
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def proto(self, topic: str, message: Any, log_ns: int) -> None:
        """Write a protobuf ``message`` on ``topic`` at ``log_ns`` (ns since 1970)."""
        if topic not in self.channels:
            schema = register_schema(self.writer, type(message))
            self.channels[topic] = self.writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema
            )
        self._add(topic, message.SerializeToString(), log_ns)

    def json(
        self, topic: str, schema: dict[str, Any], message: dict[str, Any], log_ns: int
    ) -> None:
        """Write ``message`` as JSON on ``topic``; ``schema`` (a JSON schema whose ``title``
        names it) is registered with the topic's first message."""
        if topic not in self.channels:
            schema_id = self.writer.register_schema(
                name=schema["title"], encoding=SchemaEncoding.JSONSchema,
                data=json.dumps(schema).encode(),
            )  # fmt: skip
            self.channels[topic] = self.writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.JSON, schema_id=schema_id
            )
        self._add(topic, json.dumps(message, allow_nan=False).encode(), log_ns)

    def copy_messages(self, files: list[Path]) -> int:
        """Every message of the MCAP ``files`` (a bag's, in order) copied as it is, with its
        schema, channel (topic, encoding, metadata) and times; returns how many. A file that
        cannot be read whole (a damaged chunk) is a :class:`FrameDataError` naming it."""
        copied, schemas, channels = 0, {}, {}
        for path in files:
            mine: dict[int, int] = {}  # this file's channel id -> ours
            try:
                with Path(path).open("rb") as f:
                    for schema, channel, message in make_reader(f).iter_messages(
                        log_time_order=False
                    ):
                        if channel.id not in mine:
                            mine[channel.id] = self._copied_channel(
                                schema, channel, schemas, channels
                            )
                        self.writer.add_message(channel_id=mine[channel.id], log_time=message.log_time,
                                                data=message.data, publish_time=message.publish_time,
                                                sequence=message.sequence)  # fmt: skip
                        copied += 1
            except (ZstdError, RuntimeError, ValueError, EOFError, OSError) as exc:
                raise FrameDataError(path, f"its topics cannot be copied whole: {exc} "
                                     "(export without --keep-topics)") from None  # fmt: skip
        return copied

    def _copied_channel(self, schema: Any, channel: Any, schemas: dict, channels: dict) -> int:
        """Our channel id for a copied ``channel`` (its schema registered once by content)."""
        schema_id = 0
        if schema is not None:
            key = (schema.name, schema.encoding, schema.data)
            if key not in schemas:
                schemas[key] = self.writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            schema_id = schemas[key]
        key = (channel.topic, channel.message_encoding, schema_id)
        if key not in channels:
            if channel.topic in self.channels:
                raise ValueError(f"the bag's topic {channel.topic} is also an exported topic")
            channels[key] = self.writer.register_channel(
                topic=channel.topic, message_encoding=channel.message_encoding,
                schema_id=schema_id, metadata=dict(channel.metadata),
            )  # fmt: skip
        return channels[key]

    def finish(self) -> None:
        """Write the summary (index, statistics) and the footer."""
        self.writer.finish()
