"""The recorder's output: one MCAP file, or a numbered series of them when splitting.

Naming follows rosbag2: without splitting the file is exactly ``--out``; with ``--split-size`` or
``--split-duration`` the parts are ``STEM_0.mcap``, ``STEM_1.mcap``, ... beside it (``--out
run.mcap`` gives ``run_0.mcap``, ``run_1.mcap``). Every part is a complete recording on its own:
it carries the configuration metadata and gets its summary when the next part starts. A part
exceeds the size limit by at most one chunk, because only finished chunks are counted.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from common.recording import RecordingWriter

log = logging.getLogger(__name__)

Describe = Callable[[RecordingWriter, int], None]


def part_path(out: Path, index: int, splitting: bool) -> Path:
    """Where part ``index`` of a recording to ``out`` goes."""
    return out.with_name(f"{out.stem}_{index}{out.suffix}") if splitting else out


class RecordingParts:
    """Writes messages to the current part and starts the next one when a limit is reached."""

    def __init__(
        self,
        out: Path,
        compression: str,
        chunk_size: int,
        split_bytes: int = 0,
        split_s: float = 0.0,
        describe: Describe | None = None,
    ) -> None:
        self.out = out
        self.splitting = split_bytes > 0 or split_s > 0
        self._compression = compression
        self._chunk_size = chunk_size
        self._split_bytes = split_bytes
        self._split_ns = int(split_s * 1e9)
        self._describe = describe
        self.paths: list[Path] = []
        self.messages_written = 0
        self.bytes_written = 0
        self._writer = self._open(0)  # fails here, before anything subscribes, if the path is unwritable

    @property
    def path(self) -> Path:
        """The part being written."""
        return self.paths[-1]

    def _open(self, index: int) -> RecordingWriter:
        path = part_path(self.out, index, self.splitting)
        writer = RecordingWriter(path, compression=self._compression, chunk_size=self._chunk_size)
        self.paths.append(path)
        if self._describe is not None:
            self._describe(writer, index)
        self._started_ns = time.time_ns()
        return writer

    def _due(self, log_ns: int) -> bool:
        if self._writer.messages_written == 0:
            return False
        if self._split_bytes and self._writer.file_bytes >= self._split_bytes:
            return True
        return bool(self._split_ns) and log_ns - self._started_ns >= self._split_ns

    def write(self, key: str, data: bytes, log_ns: int, publish_ns: int) -> None:
        """Append raw payload bytes as received; starts a new part first when one is due."""
        if self.splitting and self._due(log_ns):
            done = self._writer
            done.close()
            log.info("recorder: finished %s (%d messages)", self.path, done.messages_written)
            self._writer = self._open(len(self.paths))
        self._writer.write(key, data, log_ns, publish_ns)
        self.messages_written += 1
        self.bytes_written += len(data)

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> None:
        """Finish the current part (summary written)."""
        self._writer.close()

    def abort(self) -> None:
        """Give up on the current part after an I/O error; what was flushed stays readable."""
        self._writer.abort()
