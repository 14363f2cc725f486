"""Reading and writing stereovox MCAP recordings: the one place that touches the MCAP library.

Layout (ARCHITECTURE.md): one channel per key, ``message_encoding = "msgpack"``, the schema named
after the message type (``stereovox.PointCloud/1``), ``log_time`` = when the message was written
or received, ``publish_time`` = its capture stamp. The effective configuration and the
recording's own facts (source, ground truth completeness, volume of interest) are MCAP metadata.

The reader always streams records from the start, so a file without a summary (a recorder killed
with SIGKILL) or one cut short still yields every complete message; where it stopped is reported.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import mcap.writer
import msgpack
import zstandard
from mcap.reader import make_reader
from mcap.records import Channel, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from common.codec import decode, encode
from common.errors import DecodeError, RecordingError
from common.messages import HEALTH_TOPIC_PREFIX, SCHEMAS, TOPICS, Health, Message, topic_of

MESSAGE_ENCODING = "msgpack"
PROFILE = "stereovox"
CONFIG_METADATA = "stereovox.config"
INFO_METADATA = "stereovox.info"
COMPRESSIONS = {"none": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: zstd level of every chunk. mcap's writer calls ``zstandard.compress`` at its level 3, which
#: compresses 640x480 camera frames at ~155 MB/s (ratio 1.29); level 1 runs at ~440 MB/s for a
#: ratio of 1.24 (KITTI images, measured here), which keeps a 30 Hz stereo stream far from the limit.
ZSTD_LEVEL = 1


class _ZstdAtLevel:
    """Stands in for the ``zstandard`` module inside ``mcap.writer`` so chunks use :data:`ZSTD_LEVEL`."""

    @staticmethod
    def compress(data: bytes) -> bytes:
        return zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(data)


mcap.writer.zstandard = _ZstdAtLevel  # type: ignore[attr-defined]


def message_type_for_key(key: str) -> type[Message] | None:
    """The message type a key carries, or None for keys stereovox does not define."""
    topic = topic_of(key)
    if topic.startswith(HEALTH_TOPIC_PREFIX):
        return Health
    return TOPICS.get(topic)


def peek_stamp(data: bytes) -> tuple[int, int] | None:
    """``(frame_id, stamp_ns)`` of an encoded message without decoding it, or None if absent.

    The recorder needs the capture stamp for ``publish_time`` but must not unpack a 1.8 MB
    image to get it: the envelope's ``body`` map starts with ``frame_id`` and ``stamp_ns``
    (the base fields of every message), so reading a few bytes suffices (~2 µs against
    ~160 µs for a full decode of a 640x480 stereo frame).
    """
    unpacker = msgpack.Unpacker(io.BytesIO(data), raw=False, read_size=256)
    try:
        for _ in range(unpacker.read_map_header()):
            if unpacker.unpack() != "body":
                unpacker.skip()
                continue
            found: dict[str, int] = {}
            for _ in range(unpacker.read_map_header()):
                name = unpacker.unpack()
                if name not in ("frame_id", "stamp_ns"):
                    unpacker.skip()
                    continue
                value = unpacker.unpack()
                if not isinstance(value, int) or isinstance(value, bool):
                    return None
                found[name] = value
                if len(found) == 2:
                    return found["frame_id"], found["stamp_ns"]
            return None
    except Exception:  # anything malformed: the caller falls back to the receive time
        return None
    return None


def _json_schema(cls: type[Message]) -> bytes:
    """A small JSON schema naming the fields, so tools that list schemas show something useful."""
    props = {f.name: {} for f in dataclasses.fields(cls)}
    return json.dumps({"title": cls.schema_id(), "type": "object", "properties": props}).encode()


class RecordingWriter:
    """An MCAP file being written; a context manager so it is finished on errors and Ctrl-C.

    With ``atomic=True`` the file is written under a temporary name and renamed on a clean
    close, so a crashed importer never leaves a half-written file that looks complete.
    """

    def __init__(
        self,
        path: str | Path,
        compression: str = "zstd",
        chunk_size: int = 1024 * 1024,
        atomic: bool = False,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise RecordingError(f"compression {compression!r} unknown; choose from {sorted(COMPRESSIONS)}")
        self.path = Path(path)
        self._atomic = atomic
        self._target = self.path.with_name(self.path.name + ".part") if atomic else self.path
        with self._writing():
            self._target.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[bytes] = open(self._target, "wb")  # noqa: SIM115 - closed in close()
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=COMPRESSIONS[compression])
            self._writer.start(profile=PROFILE, library="stereovox")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self.messages_written = 0
        self.bytes_written = 0
        self._closed = False

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(success=exc_type is None)

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """A failed open or write (no such directory, a full disk) as an error naming the file.

        Metadata goes straight to the file: once the file's buffer fills, the header and the
        configuration already reach the disk while the writer is being opened.
        """
        try:
            yield
        except OSError as exc:
            raise RecordingError(f"cannot write: {exc.strerror or exc}", str(self.path)) from None

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """Store a named mapping; values that are not strings are stored as JSON."""
        with self._writing():
            self._writer.add_metadata(name, {k: v if isinstance(v, str) else json.dumps(v) for k, v in data.items()})

    def describe(self, config: dict[str, Any] | None, info: dict[str, Any] | None = None) -> None:
        """Store the effective configuration and the recording's facts (source, gt_complete, ...)."""
        if config is not None:
            self.add_metadata(CONFIG_METADATA, {"json": json.dumps(config, sort_keys=True)})
        if info:
            self.add_metadata(INFO_METADATA, info)

    def _channel(self, key: str, cls: type[Message] | None) -> int:
        channel = self._channels.get(key)
        if channel is None:
            schema_id = 0
            if cls is not None:
                name = cls.schema_id()
                schema_id = self._schemas.get(name, 0)
                if not schema_id:
                    schema_id = self._writer.register_schema(name, "jsonschema", _json_schema(cls))
                    self._schemas[name] = schema_id
            channel = self._writer.register_channel(key, MESSAGE_ENCODING, schema_id)
            self._channels[key] = channel
            self._sequence[key] = 0
        return channel

    def write(
        self,
        key: str,
        msg: Message | bytes,
        log_time_ns: int | None = None,
        publish_time_ns: int | None = None,
    ) -> None:
        """Append one message; raw bytes (as received from the bus) are written untouched."""
        if isinstance(msg, Message):
            data, cls, stamp = encode(msg), type(msg), msg.stamp_ns
        else:
            data, cls, stamp = bytes(msg), message_type_for_key(key), None
        log_time = time.time_ns() if log_time_ns is None else log_time_ns
        publish = publish_time_ns if publish_time_ns is not None else (stamp if stamp is not None else log_time)
        channel = self._channel(key, cls)
        seq = self._sequence[key]
        self._sequence[key] = seq + 1
        self._writer.add_message(channel, log_time, data, max(0, int(publish)), sequence=seq)
        self.messages_written += 1
        self.bytes_written += len(data)

    @property
    def file_bytes(self) -> int:
        """Bytes handed to the file so far (the open chunk not included): what splitting counts."""
        return self._file.tell()

    def flush(self) -> None:
        """Finish the open chunk and push it to the operating system.

        A process killed after this loses nothing written before it: the reader streams whole
        chunks, so flushing once a second bounds a SIGKILL's loss to that second's chunk.
        """
        self._writer.flush()

    def abort(self) -> None:
        """Close without writing a summary, swallowing I/O errors (a full disk, a vanished path).

        What was flushed stays readable; an atomic file is removed.
        """
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(OSError):
            self._file.close()
        if self._atomic:
            self._target.unlink(missing_ok=True)

    def close(self, success: bool = True) -> None:
        """Write the summary and close; an atomic file is renamed into place only on success."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()
        if self._atomic:
            if success:
                os.replace(self._target, self.path)
            else:
                self._target.unlink(missing_ok=True)


@dataclass
class RawRecord:
    """One message as stored: key, schema name, payload bytes and both times."""

    key: str
    schema: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int


class RecordingReader:
    """A recording opened for reading; iterate :meth:`messages` or :meth:`raw`.

    After an iteration, :attr:`truncated` holds the error describing where a damaged file
    stopped (None when it ended cleanly) and :attr:`decode_errors` counts payloads skipped.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingError("no such recording", str(self.path))
        with open(self.path, "rb") as f:
            magic = f.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            raise RecordingError("not an MCAP file (bad magic at the start)", str(self.path), 0)
        self.truncated: RecordingError | None = None
        self.decode_errors = 0
        self._metadata: dict[str, dict[str, str]] | None = None

    def _records(self) -> Iterator[Any]:
        self.truncated = None
        with open(self.path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            reader = StreamReader(f, skip_magic=False)
            good = 0  # end of the last complete record (a chunk counts as one)
            try:
                for record in reader.records:
                    good = f.tell()
                    yield record
            except Exception as exc:  # the reader raises McapError, EOFError, struct and zstd errors
                self.truncated = RecordingError(
                    f"recording ends early after {good} of {size} bytes ({type(exc).__name__}: {exc}); "
                    "every message before that point was read",
                    str(self.path),
                    good,
                )

    def raw(self, keys: Iterable[str] | None = None) -> Iterator[RawRecord]:
        """Every stored message in file order, optionally only those on ``keys``."""
        wanted = set(keys) if keys is not None else None
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, str]] = {}
        metadata: dict[str, dict[str, str]] = {}
        for record in self._records():
            if isinstance(record, Schema):
                schemas[record.id] = record.name
            elif isinstance(record, Channel):
                channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
            elif isinstance(record, Metadata):
                metadata[record.name] = dict(record.metadata)
            elif isinstance(record, McapMessage):
                key, schema = channels.get(record.channel_id, ("", ""))
                if wanted is None or key in wanted:
                    yield RawRecord(key, schema, bytes(record.data), record.log_time, record.publish_time)
        self._metadata = metadata

    def messages(
        self, keys: Iterable[str] | None = None, topics: Iterable[str] | None = None
    ) -> Iterator[tuple[str, Message]]:
        """Decoded messages ``(key, message)``; filter by full keys or by topic (``odometry/ego``).

        Payloads that do not decode are counted in :attr:`decode_errors` and skipped.
        """
        wanted_topics = set(topics) if topics is not None else None
        for rec in self.raw(keys):
            if wanted_topics is not None and topic_of(rec.key) not in wanted_topics:
                continue
            try:
                yield rec.key, decode(rec.data, message_type_for_key(rec.key))  # wrong type on a key: bad input
            except DecodeError:
                self.decode_errors += 1

    def by_topic(self, topic: str) -> dict[int, Message]:
        """Messages of one topic keyed by frame id (the last one wins)."""
        return {m.frame_id: m for _, m in self.messages(topics=[topic])}

    def metadata(self) -> dict[str, dict[str, str]]:
        """Every metadata record, by name.

        From the summary's metadata index when the file has one (no chunk is decompressed, so a
        multi-gigabyte recording answers at once); otherwise by reading the file through once.
        """
        if self._metadata is None:
            self._metadata = self._indexed_metadata()
        if self._metadata is None:
            for _ in self.raw(keys=()):
                pass
        return dict(self._metadata or {})

    def _indexed_metadata(self) -> dict[str, dict[str, str]] | None:
        try:
            with open(self.path, "rb") as f:
                reader = make_reader(f)
                summary = reader.get_summary()
                if summary is None or not summary.metadata_indexes:
                    return None
                return {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except Exception:  # no footer, a damaged summary: the streaming path copes and reports
            return None

    def info(self) -> dict[str, Any]:
        """The recording's own facts (``stereovox.info``), JSON values decoded."""
        return {k: _maybe_json(v) for k, v in self.metadata().get(INFO_METADATA, {}).items()}

    def config_dict(self) -> dict[str, Any] | None:
        """The effective configuration that made the recording, if stored."""
        raw = self.metadata().get(CONFIG_METADATA)
        if not raw or "json" not in raw:
            return None
        return json.loads(raw["json"])

    def has_topic(self, topic: str) -> bool:
        """Whether any key of ``topic`` has a channel: from the summary when the file has one (no chunk
        is decompressed), otherwise by reading the file through."""
        try:
            with open(self.path, "rb") as f:
                summary = make_reader(f).get_summary()
            if summary is not None and summary.channels:
                return any(topic_of(c.topic) == topic for c in summary.channels.values())
        except Exception:  # no footer, a damaged summary: the streaming path copes and reports
            pass
        return any(topic_of(key) == topic for key in self.keys())

    def keys(self) -> list[str]:
        """Keys with at least one message, in order of first appearance."""
        seen: dict[str, None] = {}
        for rec in self.raw():
            seen.setdefault(rec.key, None)
        return list(seen)


def _maybe_json(value: str) -> Any:
    try:
        return json.loads(value)
    except (ValueError, TypeError):
        return value


def open_recording(path: str | Path) -> RecordingReader:
    """Open a recording for reading; raises :class:`RecordingError` naming the file if it is not MCAP."""
    return RecordingReader(path)


def schema_for(name: str) -> type[Message] | None:
    """Message type of an MCAP schema name such as ``stereovox.PointCloud/1``."""
    base = name.removeprefix("stereovox.").split("/", 1)[0]
    return SCHEMAS.get(base)
