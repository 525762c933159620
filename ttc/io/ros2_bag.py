"""A ROS 2 bag (MCAP storage) read lazily through its index: which topics it holds, and any
one message of a topic decoded on demand.

A bag is an ``.mcap`` file or a rosbag2 folder whose ``metadata.yaml`` lists its ``.mcap``
files (a split bag: several). Read with the ``mcap`` library and ``mcap-ros2-support``
(messages decoded from the schema stored in the file: no ROS installation, no type store).
Nothing is read in full: :func:`bag_index` reads each file's summary (channels, schemas,
chunk indexes) and the chunks' message indexes (each message's log time), and
:func:`read_message` seeks the chunk holding one message. A 10 GB bag costs its summary and
the chunks of the frames taken. Every failure is a
:class:`~ttc.io.frame_errors.FrameDataError` naming the file.

rosbag2's SQLite storage (``.db3``, the default before ROS 2 Iron) is refused with the
command that converts it (``ros2 bag convert``).
"""

from __future__ import annotations

import os
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import MessageIndex
from mcap.stream_reader import ReadDataStream
from mcap.summary import Summary
from mcap_ros2.decoder import DecoderFactory
from zstandard import ZstdError  # mcap's own dependency: its chunks' compression

from ttc.io.frame_errors import FrameDataError
from ttc.io.mcap_recovery import IndexedReader, recover_summary
from ttc.io.ros2_msgs import stamp_ns

METADATA = "metadata.yaml"
#: What a damaged file raises inside the mcap library besides its own errors.
_READ_ERRORS = (McapError, EOFError, struct.error, ValueError, KeyError, OSError, MemoryError)
#: What a chunk whose compressed bytes are damaged raises: zstandard's error, lz4's RuntimeError.
_CHUNK_ERRORS = (ZstdError, RuntimeError)


@dataclass(frozen=True)
class BagSource:
    """A bag recording and how to read it: the topics (empty: found from the message types
    when the bag has exactly one of each), the largest camera-to-scan stamp difference that
    still pairs them (None: half the lidar's median period) and the camera frame convention
    (:mod:`ttc.io.bag_recording`). ``os.fspath`` gives the bag's path."""

    path: Path
    image_topic: str = ""
    camera_info_topic: str = ""
    lidar_topic: str = ""
    scan_tolerance_s: float | None = None
    camera_frame: str = "optical"

    def __fspath__(self) -> str:
        return str(self.path)

    def __str__(self) -> str:
        return str(self.path)


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag: the ``position``-th of ``topic`` in log-time order. Stands where
    a folder recording has a file path (:class:`ttc.io.frames.FrameFiles`)."""

    source: BagSource
    topic: str
    position: int

    def __fspath__(self) -> str:
        return str(self.source.path)

    def __str__(self) -> str:
        return f"{self.source.path} [{self.topic} #{self.position}]"


def is_bag(path: Any) -> bool:
    """True for a :class:`BagSource`, an ``.mcap`` file or a folder with ``metadata.yaml``."""
    if isinstance(path, BagSource):
        return True
    if not isinstance(path, str | Path):
        return False
    path = Path(path)
    return path.suffix == ".mcap" or (path / METADATA).is_file()


def bag_files(path: Path) -> list[Path]:
    """The ``.mcap`` files of a bag (one for a file; a rosbag2 folder's, in its order)."""
    path = Path(path)
    if not path.exists():
        raise FrameDataError(path, "bag not found")
    if path.is_file():
        return [path]
    meta_path = path / METADATA
    try:
        meta = yaml.safe_load(meta_path.read_text())["rosbag2_bagfile_information"]
        storage, names = meta.get("storage_identifier", ""), meta["relative_file_paths"]
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise FrameDataError(meta_path, f"unreadable rosbag2 metadata ({exc})") from None
    if storage != "mcap" or not all(str(n).endswith(".mcap") for n in names):
        raise FrameDataError(
            meta_path,
            f"storage {storage!r} is not read (only MCAP): convert the bag with "
            "'ros2 bag convert' to storage_id mcap",
        )
    return [path / name for name in names]


@dataclass
class TopicIndex:
    """Every message of one topic in log-time order: its type, log times (ns) and file."""

    name: str
    type: str
    log_ns: np.ndarray
    file_no: np.ndarray

    def __len__(self) -> int:
        return len(self.log_ns)


@dataclass
class BagIndex:
    """A bag's files and topics (:func:`bag_index`); decoders and stamps are kept here."""

    files: list[Path]
    topics: dict[str, TopicIndex]
    decoders: dict[tuple[int, int], Any] = field(default_factory=dict)
    stamps: dict[tuple[str, int], int] = field(default_factory=dict)
    readers: dict[tuple[int, int], SeekingReader] = field(default_factory=dict)
    #: The rebuilt summaries of files cut short (:mod:`ttc.io.mcap_recovery`), by file number.
    recovered: dict[int, Summary] = field(default_factory=dict)

    def reader(self, file_no: int) -> SeekingReader:
        """An open reader of file ``file_no`` whose summary is read once (one per process:
        a forked worker opens its own, so no two processes share a file position)."""
        key = (os.getpid(), file_no)
        if key not in self.readers:
            stream, factories = self.files[file_no].open("rb"), [DecoderFactory()]
            if file_no in self.recovered:
                reader = IndexedReader(stream, self.recovered[file_no], decoder_factories=factories)
            else:
                reader = SeekingReader(stream, decoder_factories=factories)
            self.readers[key] = reader
        return self.readers[key]

    def topic(self, name: str) -> TopicIndex:
        """The topic ``name``; a FrameDataError naming the topics the bag holds."""
        if name not in self.topics:
            raise FrameDataError(self.files[0], f"no topic {name!r}; {self.listing()}")
        return self.topics[name]

    def of_type(self, type_name: str) -> list[str]:
        """The topics whose message type is ``type_name``."""
        return [t.name for t in self.topics.values() if t.type == type_name]

    def listing(self) -> str:
        """The topics with their types and message counts, in one line."""
        rows = [f"{t.name} ({t.type}, {len(t)})" for t in self.topics.values()]
        return "topics: " + (", ".join(rows) if rows else "none")


def _message_times(stream, chunk_indexes, channel_ids: set[int]) -> dict[int, list[int]]:
    """Log times (ns) of every message of ``channel_ids`` from the chunks' message indexes."""
    out: dict[int, list[int]] = {c: [] for c in channel_ids}
    for chunk in chunk_indexes:
        for channel, offset in chunk.message_index_offsets.items():
            if channel in out:
                stream.seek(offset + 1 + 8)
                out[channel] += [t for t, _ in MessageIndex.read(ReadDataStream(stream)).records]
    return out


def _summary_and_times(path: Path) -> tuple[Summary, dict[int, list[int]], Summary | None]:
    """(summary, {channel id: log times ns}, the summary when it was rebuilt from a file cut
    short, else None) of one ``.mcap`` file."""
    with path.open("rb") as stream:
        reader = SeekingReader(stream)  # checks the magic: not an MCAP file at all is refused
        try:
            summary = reader.get_summary()
        except _READ_ERRORS:  # no footer: cut short
            summary = None
        if summary is None or not summary.chunk_indexes:
            recovered = recover_summary(stream)
            if not recovered.messages:
                raise McapError(f"no whole message in its {recovered.end} readable bytes")
            return recovered.summary, recovered.times, recovered.summary
        if all(c.message_index_offsets for c in summary.chunk_indexes):
            return (
                summary,
                _message_times(stream, summary.chunk_indexes, set(summary.channels)),
                None,
            )
        stream.seek(0)  # no message indexes: read the chunks once for the log times
        times: dict[int, list[int]] = {c: [] for c in summary.channels}
        for _, channel, message in SeekingReader(stream).iter_messages():
            times[channel.id].append(message.log_time)
        return summary, times, None


def _file_topics(path: Path) -> tuple[dict[str, tuple[str, list[int]]], Summary | None]:
    """({topic: (type, log times)}, the rebuilt summary of a file cut short or None) of one
    ``.mcap`` file, from its summary and indexes."""
    try:
        summary, times, recovered = _summary_and_times(path)
    except _READ_ERRORS as exc:
        raise FrameDataError(
            path,
            f"not a readable MCAP file ({type(exc).__name__}: {exc}); 'mcap recover' "
            "(the mcap CLI) rebuilds what a damaged file still holds",
        ) from None
    out: dict[str, tuple[str, list[int]]] = {}
    for cid, channel in summary.channels.items():
        schema = summary.schemas.get(channel.schema_id)
        kind = schema.name if schema is not None else ""
        prev = out.get(channel.topic, (kind, []))[1]
        out[channel.topic] = (kind, prev + times[cid])
    return out, recovered


_INDEXES: dict[tuple, BagIndex] = {}


def file_identities(path: Path) -> tuple:
    """(resolved path, size, mtime ns) of each file of a bag: its content's identity."""
    out = []
    for f in bag_files(path):
        try:
            st = f.stat()
        except OSError as exc:
            raise FrameDataError(f, f"cannot read ({exc.strerror})") from None
        out.append((str(f.resolve()), st.st_size, st.st_mtime_ns))
    return tuple(out)


def bag_index(path: Path | BagSource) -> BagIndex:
    """The index of a bag (kept per process and file identity)."""
    path = Path(path)
    ident = file_identities(path)
    if ident not in _INDEXES:
        files = bag_files(path)
        merged: dict[str, tuple[str, list[int], list[int]]] = {}
        recovered: dict[int, Summary] = {}
        for no, f in enumerate(files):
            file_topics, rebuilt = _file_topics(f)
            for topic, (kind, times) in file_topics.items():
                entry = merged.setdefault(topic, (kind, [], []))
                entry[1].extend(times)
                entry[2].extend([no] * len(times))
            if rebuilt is not None:
                recovered[no] = rebuilt
                _warn_cut_short(f, sum(len(t) for _, t in file_topics.values()))
        topics = {}
        for topic, (kind, times, nos) in sorted(merged.items()):
            order = np.argsort(np.asarray(times, dtype=np.int64), kind="stable")
            log = np.asarray(times, dtype=np.int64)[order]
            topics[topic] = TopicIndex(topic, kind, log, np.asarray(nos, dtype=np.int64)[order])
        _INDEXES[ident] = BagIndex(files, topics, recovered=recovered)
    return _INDEXES[ident]


def _warn_cut_short(path: Path, messages: int) -> None:
    """The one warning for a file read without its summary (cut short)."""
    warnings.warn(
        f"{path}: no summary or index (cut short, as a recorder stopped mid-write leaves it): "
        f"read its {messages} whole messages up to the cut; what was written after is lost",
        RuntimeWarning,
        stacklevel=4,
    )


def read_message(index: BagIndex, topic: str, position: int) -> Any:
    """The ``position``-th message of ``topic`` (log-time order), decoded from its schema:
    only the chunk(s) at its log time are read. FrameDataError naming the file when the
    message is missing or cannot be decoded."""
    entry = index.topic(topic)
    if not 0 <= position < len(entry):
        raise FrameDataError(index.files[0], f"{topic} has no message #{position}")
    log = int(entry.log_ns[position])
    nth = position - int(np.searchsorted(entry.log_ns, log, side="left"))
    file_no = int(entry.file_no[position])
    path = index.files[file_no]
    try:
        found = index.reader(file_no).iter_messages(topics=[topic], starting_at=log, ending_at=log)
        for k, (schema, channel, message) in enumerate(found):
            if k == nth:
                key = (file_no, channel.schema_id)
                if key not in index.decoders:
                    index.decoders[key] = DecoderFactory().decoder_for("cdr", schema)
                return index.decoders[key](message.data)
    except (*_READ_ERRORS, *_CHUNK_ERRORS, IndexError, TypeError) as exc:
        raise FrameDataError(
            path,
            f"{topic} #{position}: undecodable ({type(exc).__name__}: {exc})"
            + damaged_chunk(index, file_no, topic, log, exc),
        ) from None
    raise FrameDataError(path, f"{topic} #{position} not found at log time {log}")


def damaged_chunk(index: BagIndex, file_no: int, topic: str, log_ns: int, exc: Exception) -> str:
    """Where a decompression error ``exc`` of a ``topic`` message logged at ``log_ns`` lies:
    the chunk holding that topic at that time (its number in the file, byte offsets, log-time
    range in seconds) whose bytes are damaged, and what that costs; empty for any other error."""
    if not isinstance(exc, _CHUNK_ERRORS):
        return ""
    try:
        summary = index.recovered.get(file_no) or index.reader(file_no).get_summary()
    except (*_READ_ERRORS, *_CHUNK_ERRORS):
        summary = None
    if summary is None:
        return ": a damaged chunk"
    channels = {cid for cid, c in summary.channels.items() if c.topic == topic}
    for k, c in enumerate(summary.chunk_indexes):
        indexed = not c.message_index_offsets or channels & c.message_index_offsets.keys()
        if indexed and c.message_start_time <= log_ns <= c.message_end_time:
            return (
                f": chunk {k} of the file (bytes {c.chunk_start_offset}-"
                f"{c.chunk_start_offset + c.chunk_length}, log time "
                f"{c.message_start_time / 1e9:.3f}-{c.message_end_time / 1e9:.3f} s) is damaged; "
                "the messages logged in it are lost, the rest of the bag is read"
            )
    return ": a damaged chunk"


def header_stamp_ns(index: BagIndex, topic: str, position: int) -> int:
    """The header stamp (ns) of a message with a ``std_msgs/Header`` (kept once read)."""
    key = (topic, position)
    if key not in index.stamps:
        index.stamps[key] = stamp_ns(read_message(index, topic, position).header)
    return index.stamps[key]


def read_range(index: BagIndex, topic: str, start_ns: int, end_ns: int) -> list[tuple[int, Any]]:
    """``(log time, decoded message)`` of every message of ``topic`` logged in
    ``start_ns..end_ns`` (inclusive), for small topics (``/tf``, odometry)."""
    entry = index.topic(topic)
    out = []
    for no in sorted(set(entry.file_no.tolist())):
        path = index.files[no]
        try:
            for _, _, message, decoded in index.reader(no).iter_decoded_messages(
                topics=[topic], starting_at=start_ns, ending_at=end_ns
            ):
                out.append((message.log_time, decoded))
        except (*_READ_ERRORS, *_CHUNK_ERRORS, IndexError, TypeError) as exc:
            raise FrameDataError(
                path,
                f"{topic}: unreadable ({type(exc).__name__}: {exc})"
                + damaged_chunk(index, no, topic, start_ns, exc),
            ) from None
    return out


def read_all(index: BagIndex, topic: str) -> list[Any]:
    """Every message of a small topic (``/tf_static``), decoded."""
    entry = index.topic(topic)
    if not len(entry):
        return []
    return [m for _, m in read_range(index, topic, int(entry.log_ns[0]), int(entry.log_ns[-1]))]
