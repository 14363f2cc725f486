"""Recording files on their own: round trips, damaged files, the stamp peek the recorder relies on."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from fake_recording import CALIB, PERIOD_NS, START_NS, frame, ground_truth, write_recording
from mcap.reader import make_reader

from common.codec import encode
from common.config import Config
from common.errors import RecordingError
from common.messages import StereoFrame, key_for
from common.recording import RecordingReader, RecordingWriter, open_recording, peek_stamp


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
def test_round_trip_keeps_messages_times_and_metadata(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "rec.mcap"
    write_recording(path, 5, compression=compression)
    reader = open_recording(path)
    rng = np.random.default_rng(7)
    frames = [m for _, m in reader.messages(topics=["camera/stereo"])]
    assert [f.frame_id for f in frames] == list(range(5))
    for f in frames:
        expected = frame(f.frame_id, rng)
        assert isinstance(f, StereoFrame)
        np.testing.assert_array_equal(f.left, expected.left)
        np.testing.assert_array_equal(f.right, expected.right)
        assert f.calib.fx == CALIB.fx and f.stamp_ns == expected.stamp_ns
    raws = list(reader.raw())
    assert len(raws) == 15 and reader.truncated is None
    assert {r.schema for r in raws} == {"stereovox.StereoFrame/1", "stereovox.GroundTruthEgo/1",
                                        "stereovox.GroundTruthObjects/1"}
    assert all(r.publish_time_ns == START_NS + PERIOD_NS * (i // 3) for i, r in enumerate(raws))
    assert raws[1].data == encode(ground_truth(0)[0])  # stored bytes are exactly the encoded message
    assert reader.info()["frames"] == 5
    assert reader.config_dict() == Config().to_dict()
    assert reader.keys() == [key_for("camera/stereo"), key_for("groundtruth/ego"), key_for("groundtruth/objects")]
    objs = reader.by_topic("groundtruth/objects")
    assert objs[4].objects[0].center[0] == pytest.approx(9.2)


def test_peek_stamp_reads_the_header_only() -> None:
    rng = np.random.default_rng(1)
    for msg in (frame(12, rng), frame(13, rng, "png"), *ground_truth(3)):
        assert peek_stamp(encode(msg)) == (msg.frame_id, msg.stamp_ns)
    assert peek_stamp(b"\x93\x01\x02\x03") is None  # an array, not a map
    assert peek_stamp(b"") is None
    assert peek_stamp(b"\x81\xa4body\x81\xa8frame_id\x05") is None  # no stamp


def test_file_without_summary_reads_every_flushed_message(tmp_path: Path) -> None:
    """A recorder killed after its last flush: no summary, every message still there."""
    path = tmp_path / "killed.mcap"
    w = RecordingWriter(path, compression="zstd")
    w.describe({"bus": {"vehicle": "ego"}}, {"source": "synthetic", "frames": 10})
    for i in range(10):
        w.write(key_for("groundtruth/ego"), ground_truth(i)[0])
    w.flush()
    w.abort()  # what SIGKILL leaves: no DataEnd, no summary, no footer
    reader = open_recording(path)
    assert reader.info() == {"source": "synthetic", "frames": 10}  # no summary index: found by streaming
    assert [m.frame_id for _, m in reader.messages()] == list(range(10))
    assert reader.truncated is not None and str(path) in str(reader.truncated)
    with open(path, "rb") as f, pytest.raises(Exception):  # noqa: B017 - the seeking reader needs the summary
        make_reader(f).get_summary()


def test_unflushed_chunk_is_all_a_crash_loses(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    snapshot = tmp_path / "snapshot.mcap"
    w = RecordingWriter(path, compression="none", chunk_size=10 * 1024 * 1024)
    for i in range(8):
        w.write(key_for("groundtruth/ego"), ground_truth(i)[0])
    w.flush()
    for i in range(8, 12):
        w.write(key_for("groundtruth/ego"), ground_truth(i)[0])
    shutil.copyfile(path, snapshot)  # the disk as a SIGKILL right now would leave it
    w.close()
    assert [m.frame_id for _, m in open_recording(snapshot).messages()] == list(range(8))
    assert len(list(open_recording(path).messages())) == 12


def test_truncated_file_reports_where_it_stops(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    write_recording(path, 20, chunk_size=30_000)  # about one frame (18 KB) and its ground truth per chunk
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.truncate(size // 2)
    reader = open_recording(path)
    got = list(reader.raw())
    assert 3 <= len(got) < 60
    err = reader.truncated
    assert err is not None and err.path == str(path)
    assert err.offset is not None and 0 < err.offset <= size // 2
    assert f"at byte {err.offset}" in str(err) and str(path) in str(err)
    frame_ids = sorted({r.publish_time_ns for r in got})
    assert frame_ids[0] == START_NS  # what was read is the beginning, in order


@pytest.mark.parametrize("content", [b"", b"hello, not a recording\n", b"\x89PNG\r\n\x1a\n" + bytes(100)])
def test_not_mcap_is_refused_naming_the_file(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "notes.mcap"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match="not an MCAP file") as info:
        RecordingReader(path)
    assert str(path) in str(info.value)
    with pytest.raises(RecordingError, match="no such recording"):
        open_recording(tmp_path / "absent.mcap")


def test_unwritable_path_names_it(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(RecordingError, match="cannot write") as info:
        RecordingWriter(blocker / "out.mcap")
    assert str(blocker / "out.mcap") in str(info.value)


def test_a_full_disk_while_the_configuration_is_written_names_the_file() -> None:
    # /dev/full refuses every write; a configuration bigger than the file's buffer reaches it at once
    writer = RecordingWriter("/dev/full")
    with pytest.raises(RecordingError, match="/dev/full: cannot write: No space left on device"):
        writer.describe({"padding": "x" * 20_000})
