"""The codec: every message round-trips, and no bytes whatever raise anything but DecodeError."""

from __future__ import annotations

import dataclasses
import struct
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.codec import decode, encode
from common.errors import DecodeError
from common.messages import (
    MESSAGE_TYPES,
    Calibration,
    Cluster,
    Clusters,
    Disparity,
    EgoMotion,
    GroundTruthDisparity,
    GroundTruthEgo,
    GroundTruthObject,
    GroundTruthObjects,
    Health,
    Message,
    Obstacle,
    Obstacles,
    PointCloud,
    StereoFrame,
    VehicleMotion,
    merged_trail,
    stamp_output,
)
from common.wire_arrays import MAX_ARRAY_BYTES

RNG = np.random.default_rng(7)
TRAIL = [("camera_replay", 100, 100), ("stereo_depth", 120, 180)]


def f64(*shape: int) -> np.ndarray:
    return RNG.normal(size=shape)


def f32(*shape: int) -> np.ndarray:
    return RNG.random(shape, dtype=np.float32)


def calib() -> Calibration:
    c2v = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.65], [0, 0, 0, 1]], dtype=np.float64)
    return Calibration(fx=721.5, fy=721.5, cx=609.6, cy=172.9, baseline=0.54, width=64, height=48, cam_to_vehicle=c2v)


def image(h: int = 48, w: int = 64) -> np.ndarray:
    # smooth content, so JPEG stays close to the original
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 255 // w, y * 255 // h, (x + y) * 255 // (w + h)], axis=-1).astype(np.uint8)


def cluster(i: int) -> Cluster:
    return Cluster(id=i, voxels=RNG.integers(-50, 50, (5, 3), dtype=np.int32), voxel_count=5,
                   color_mean_rgb=f32(3), color_var_rgb=f32(3), color_mean_hsl=f32(3), color_var_hsl=f32(3),
                   bbox_min=f64(3), bbox_max=f64(3), centroid=f64(3), density=0.4, volume=0.078)


def obstacle(i: int) -> Obstacle:
    return Obstacle(id=i, state="tracked", centroid=f64(3), bbox_min=f64(3), bbox_max=f64(3), volume=3.2,
                    velocity=f64(3), velocity_rel=f64(3), speed=1.5, moving=True, position_cov=f64(3, 3),
                    velocity_cov=f64(3, 3), age=12, color_rgb=f32(3))


def examples() -> list[Message]:
    """One filled-in instance of every message type (plus empty variants where lists may be empty)."""
    disparity = f32(48, 64)
    disparity[0, :5] = np.nan
    base = {"frame_id": 42, "stamp_ns": 1_700_000_000_123_456_789, "timing": list(TRAIL)}
    return [
        StereoFrame(**base, left=image(), right=image()[:, ::-1].copy(), calib=calib()),
        PointCloud(**base, points=f32(100, 3), colors=RNG.integers(0, 255, (100, 3), dtype=np.uint8)),
        PointCloud(**base, points=np.zeros((0, 3), np.float32), colors=np.zeros((0, 3), np.uint8)),
        Disparity(**base, disparity=disparity, calib=calib()),
        EgoMotion(**base, pose=f64(4, 4), delta=f64(4, 4), inliers=350, inlier_ratio=0.7, valid=True,
                  covariance=f64(6, 6), world_epoch=1_795_000_000_000),
        Clusters(**base, clusters=[cluster(i) for i in range(3)], voxel_edge=0.25, world_epoch=3,
                 ego_pose=f64(4, 4), voxel_count=812),
        Clusters(**base, voxel_edge=0.25),
        Obstacles(**base, obstacles=[obstacle(i) for i in range(2)], world_epoch=3, ego_pose=f64(4, 4)),
        VehicleMotion(**base, speed_mps=10.5, yaw_rate_rps=-0.02, source="oxts"),
        GroundTruthEgo(**base, pose=f64(4, 4), velocity=f64(3)),
        GroundTruthObjects(**base, objects=[GroundTruthObject(id=1, cls="Car", center=f64(3), size=f64(3), yaw=0.3,
                                                              velocity=f64(3), moving=False, visible_pixels=1200,
                                                              visible_fraction=0.8)],
                           dontcare=f32(2, 4), gt_complete=True),
        GroundTruthDisparity(**base, disparity=disparity, sparse=True),
        Health(**base, service="tracker", frames_in=10, frames_out=9, dropped=1, decode_errors=2, errors=0,
               p50_ms=3.5, p95_ms=7.25, uptime_s=12.0, detail={"join_evicted": 1, "inputs": {"a": {"received": 3}}}),
    ]


def assert_same(a: Any, b: Any, where: str = "msg") -> None:
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def test_every_message_type_has_an_example() -> None:
    assert {type(m) for m in examples()} == set(MESSAGE_TYPES)


@pytest.mark.parametrize("msg", examples(), ids=lambda m: type(m).__name__)
def test_round_trip(msg: Message) -> None:
    back = decode(encode(msg), type(msg))
    assert_same(msg, back)
    assert back.timing == [tuple(t) for t in TRAIL]


def test_decoded_arrays_are_read_only() -> None:
    cloud = decode(encode(examples()[1]), PointCloud)
    with pytest.raises(ValueError):
        cloud.points[0, 0] = 1.0


def test_png_is_lossless_and_jpeg_close() -> None:
    frame = examples()[0]
    for fmt in ("png", "jpeg"):
        sent = dataclasses.replace(frame, image_format=fmt)
        data = encode(sent)
        back = decode(data, StereoFrame)
        assert back.image_format == fmt and back.left.shape == frame.left.shape and back.left.dtype == np.uint8
        if fmt == "png":
            assert_same(dataclasses.replace(back, image_format="raw"), frame)
        else:
            assert len(data) < len(encode(frame))
            diff = np.abs(back.left.astype(int) - frame.left.astype(int))
            assert diff.mean() < 4, diff.mean()


def test_stamp_output_keeps_ids_and_unions_trails() -> None:
    points = PointCloud(frame_id=5, stamp_ns=9, points=f32(1, 3), colors=np.zeros((1, 3), np.uint8),
                        timing=[("camera_replay", 1, 1), ("stereo_depth", 2, 5)])
    ego = EgoMotion(frame_id=5, stamp_ns=9, timing=[("camera_replay", 1, 1), ("odometry", 2, 3)])
    out = stamp_output(Clusters(frame_id=0, stamp_ns=0, voxel_edge=0.25), [points, ego], "voxel_mapper", 6)
    assert (out.frame_id, out.stamp_ns) == (5, 9)
    assert [t[0] for t in out.timing] == ["camera_replay", "odometry", "stereo_depth", "voxel_mapper"]
    assert out.timing[-1][1] == 6 and out.timing[-1][2] >= 6
    assert merged_trail(points, points) == points.timing


# ----------------------------------------------------------------------------- hostile bytes

ENCODED = [encode(m) for m in examples()] + [encode(dataclasses.replace(examples()[0], image_format="png"))]


def decodes_or_refuses(data: bytes) -> None:
    """The one promise: a message, or DecodeError — never another exception."""
    try:
        msg = decode(data)
    except DecodeError:
        return
    assert isinstance(msg, Message)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=4096))
def test_random_bytes_only_raise_decode_error(data: bytes) -> None:
    decodes_or_refuses(data)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(ENCODED), st.integers(min_value=0), st.integers(0, 255), st.sampled_from(["cut", "flip", "ins"]))
def test_mutated_messages_only_raise_decode_error(data: bytes, pos: int, byte: int, how: str) -> None:
    i = pos % len(data)
    if how == "cut":
        mutated = data[:i]
    elif how == "flip":
        mutated = data[:i] + bytes([byte]) + data[i + 1 :]
    else:
        mutated = data[:i] + bytes([byte]) + data[i:]
    decodes_or_refuses(mutated)


WIRE_INTS = st.integers(min_value=-(2**63), max_value=2**64 - 1)  # what msgpack can carry
HOSTILE_VALUES = st.one_of(
    st.none(), st.booleans(), WIRE_INTS, st.floats(allow_nan=True),
    st.text(max_size=8), st.binary(max_size=16), st.lists(WIRE_INTS, max_size=3),
    st.dictionaries(st.text(max_size=4), WIRE_INTS, max_size=2),
    st.just({"__nd__": True, "dtype": "float64", "shape": [2**20, 2**20], "data": b""}),
    st.just({"__nd__": True, "dtype": "object", "shape": [1], "data": b"\0" * 8}),
    st.just({"__img__": "png", "data": b"\x89PNG\r\n\x1a\n"}),
)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


def _replace(node: Any, path: tuple[Any, ...], value: Any) -> Any:
    if not path:
        return value
    copy = dict(node) if isinstance(node, dict) else list(node)
    copy[path[0]] = _replace(node[path[0]], path[1:], value)
    return copy


SMALL = [encode(m) for m in examples()[1:]]  # the structure of everything but the big raw image


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(SMALL), st.integers(min_value=0), HOSTILE_VALUES)
def test_structurally_wrong_messages_only_raise_decode_error(data: bytes, which: int, value: Any) -> None:
    tree = msgpack.unpackb(data, raw=False)
    paths = _paths(tree)
    mutated = _replace(tree, paths[which % len(paths)], value)
    decodes_or_refuses(msgpack.packb(mutated, use_bin_type=True))


def _with_body(data: bytes, **changes: Any) -> bytes:
    tree = msgpack.unpackb(data, raw=False)
    tree["body"].update(changes)
    return msgpack.packb(tree, use_bin_type=True)


def _array(dtype: str, shape: list[Any], data: Any) -> dict[str, Any]:
    return {"__nd__": True, "dtype": dtype, "shape": shape, "data": data}


def _png_header(width: int, height: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + b"\0\0\0\0"


def _jpeg_header(width: int, height: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, height, width, 3) + b"\x01\x22\x00" * 3
    return b"\xff\xd8" + b"\xff\xe0" + struct.pack(">H", 4) + b"\0\0" + sof + b"\xff\xd9"


CLOUD = encode(examples()[1])
FRAME_PNG = ENCODED[-1]


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "not a msgpack"),
        (CLOUD[:-10], "not a msgpack"),
        (msgpack.packb([1, 2, 3]), "envelope is list"),
        (msgpack.packb({"schema": "Nope", "v": 1, "body": {}}), "unknown schema"),
        (msgpack.packb({"schema": "PointCloud", "v": 2, "body": {}}), "version 2"),
        (msgpack.packb({"schema": "PointCloud", "v": True, "body": {}}), "version True"),
        (msgpack.packb({"schema": "PointCloud", "v": 1, "body": []}), "expected a map"),
        (_with_body(CLOUD, points=_array("float32", [10, 3], b"\0" * 12)), "12 bytes where"),
        (_with_body(CLOUD, points=_array("float32", [4, 4], b"\0" * 64)), "does not fit"),
        (_with_body(CLOUD, points=_array("float64", [1, 3], b"\0" * 24)), "float32 is required"),
        (_with_body(CLOUD, points=_array("float32", [2**25, 3], b"")), "limit"),
        (_with_body(CLOUD, points=_array("float32", [-1, 3], b"")), "shape"),
        (_with_body(CLOUD, points=_array("float32", [1, 1, 1, 1, 1], b"\0" * 4)), "shape"),
        (_with_body(CLOUD, points=_array("float32", [True, 3], b"\0" * 12)), "shape"),
        (_with_body(CLOUD, points=_array("float32", [1, 3], "text")), "not bytes"),
        (_with_body(CLOUD, points=_array("object", [1, 3], b"\0" * 24)), "not allowed"),
        (_with_body(CLOUD, frame_id="42"), "expected int"),
        (_with_body(CLOUD, frame_id=True), "expected int"),
        (_with_body(CLOUD, timing=[["a", 1]]), "3-tuple"),
        (_with_body(CLOUD, timing=[[1, 2, 3]]), "expected str"),
        (_with_body(encode(examples()[-1]), detail={"a": 1, "b": [1, 2]}, service=3), "expected str"),
        (_with_body(FRAME_PNG, left={"__img__": "png", "data": _png_header(40000, 40000)}), "limit"),
        (_with_body(FRAME_PNG, left={"__img__": "jpeg", "data": _jpeg_header(60000, 60000)}), "limit"),
        (_with_body(FRAME_PNG, left={"__img__": "jpeg", "data": FRAME_PNG[:0] + _png_header(4, 4)}), "not jpeg"),
        (_with_body(FRAME_PNG, left={"__img__": "gif", "data": b"GIF89a"}), "bad encoded image"),
        (_with_body(FRAME_PNG, left={"__img__": "png", "data": b""}), "png"),
    ],
)
def test_known_bad_payloads_are_refused_with_a_reason(data: bytes, reason: str) -> None:
    with pytest.raises(DecodeError, match=reason):
        decode(data)


def test_wrong_message_type_for_the_key_is_refused() -> None:
    with pytest.raises(DecodeError, match="got PointCloud where EgoMotion was expected"):
        decode(CLOUD, EgoMotion)


def test_encode_refuses_arrays_that_cannot_travel() -> None:
    bad = PointCloud(frame_id=1, stamp_ns=1, points=np.zeros((1, 3), np.complex64), colors=np.zeros((1, 3), np.uint8))
    with pytest.raises(DecodeError, match="complex64"):
        encode(bad)
    assert MAX_ARRAY_BYTES >= 640 * 480 * 3
