"""A seeded generator of payloads every stereovox key must refuse: the hostile-input test's ammunition.

Each payload starts from a *valid* message of the key's type (taken from a real run, shrunk so a
thousand a second stay a few MB/s) and breaks it one way: random bytes, truncated msgpack, a
valid message of another type, a broken envelope, a huge declared array, a NaN or inf, images
or arrays of the wrong size, a field of the wrong type. Every one of them is invalid by the
contract (common/messages.py), so a service must count each as a decode error, never process it.
Mutations that keep a message valid (a flipped pixel) are deliberately absent: no decoder can
tell them from real data; keeping such messages off the bus is what authentication is for.
"""

from __future__ import annotations

import copy
import dataclasses
import random
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import numpy as np

from common.codec import encode
from common.messages import (
    HEALTH_TOPIC_PREFIX,
    TOPICS,
    Calibration,
    Clusters,
    Disparity,
    GroundTruthDisparity,
    Health,
    Message,
    PointCloud,
    StereoFrame,
)

Wire = dict[str, Any]
#: fields where a non-finite float is a value (see message_checks.NAN_FIELDS / INF_FIELDS).
NON_FINITE_OK = {"disparity", "covariance", "position_cov", "velocity_cov"}
CROP = (96, 128)  # rows, columns of the shrunk images


def message_type(topic: str) -> type[Message]:
    return Health if topic.startswith(HEALTH_TOPIC_PREFIX) else TOPICS[topic]


def _crop_calib(calib: Calibration) -> Calibration:
    return dataclasses.replace(calib, height=CROP[0], width=CROP[1])


def shrink(msg: Message) -> Message:
    """A small valid copy: images cropped (calibration to match), clouds and cluster lists cut."""
    rows, cols = CROP
    if isinstance(msg, StereoFrame):
        return dataclasses.replace(msg, left=np.ascontiguousarray(msg.left[:rows, :cols]),
                                   right=np.ascontiguousarray(msg.right[:rows, :cols]),
                                   calib=_crop_calib(msg.calib), image_format="raw")
    if isinstance(msg, Disparity):
        return dataclasses.replace(msg, disparity=np.ascontiguousarray(msg.disparity[:rows, :cols]),
                                   calib=_crop_calib(msg.calib))
    if isinstance(msg, GroundTruthDisparity):
        return dataclasses.replace(msg, disparity=np.ascontiguousarray(msg.disparity[:rows, :cols]))
    if isinstance(msg, PointCloud):
        return dataclasses.replace(msg, points=msg.points[:400], colors=msg.colors[:400])
    if isinstance(msg, Clusters):
        return dataclasses.replace(msg, clusters=msg.clusters[:3])
    return msg


def _wire(msg: Message) -> Wire:
    return msgpack.unpackb(encode(msg), raw=False)


def _pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def _walk(obj: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[tuple[Any, ...], Any]]:
    """Every (path, value) below ``obj``; arrays on the wire are leaves."""
    yield path, obj
    if isinstance(obj, dict) and "__nd__" not in obj:
        for k, v in obj.items():
            yield from _walk(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _walk(v, (*path, i))


def _parent(env: Wire, path: tuple[Any, ...]) -> Any:
    node: Any = env
    for step in path[:-1]:
        node = node[step]
    return node


def _arrays(env: Wire) -> list[tuple[Any, ...]]:
    return [p for p, v in _walk(env["body"], ("body",)) if isinstance(v, dict) and "__nd__" in v]


def _float_arrays(env: Wire) -> list[tuple[Any, ...]]:
    return [p for p in _arrays(env) if _parent(env, p)[p[-1]]["dtype"].startswith("float")
            and p[-1] not in NON_FINITE_OK and _parent(env, p)[p[-1]]["shape"] and
            all(_parent(env, p)[p[-1]]["shape"])]


def _float_scalars(env: Wire) -> list[tuple[Any, ...]]:
    return [p for p, v in _walk(env["body"], ("body",)) if isinstance(v, float) and "detail" not in p
            and "timing" not in p]


# ----------------------------------------------------------------------------- the mutations


def random_bytes(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    return rng.randbytes(rng.randrange(0, 600))


def truncated(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    good = _pack(env)
    return good[: rng.randrange(0, len(good))]


def foreign(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    """A valid message of another type: right bytes, wrong key."""
    return rng.choice(others)


def broken_envelope(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    env = copy.deepcopy(env)
    choice = rng.randrange(6)
    if choice == 0:
        env["schema"] = rng.choice(["Obstacle", "", "stereovox.Obstacles/1", "Clusterz"])
    elif choice == 1:
        env["v"] = rng.choice([0, 2, 99, True, "1"])
    elif choice == 2:
        env["body"] = rng.choice([[], None, 7, "body"])
    elif choice == 3:
        del env["body"]
    elif choice == 4:
        return _pack([env["schema"], env["v"], env["body"]])
    else:
        return _pack(env) + b"\x00trailing"
    return _pack(env)


def huge_declared(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    """Sizes that would take gigabytes if believed: array shapes, msgpack bin/array headers."""
    arrays = _arrays(env)
    if not arrays or rng.random() < 0.3:
        header = rng.choice([b"\xdd\xff\xff\xff\xff", b"\xc6\xff\xff\xff\xf0", b"\xdf\x7f\xff\xff\xff"])
        return header + rng.randbytes(rng.randrange(0, 64))
    env = copy.deepcopy(env)
    path = rng.choice(arrays)
    arr = _parent(env, path)[path[-1]]
    big = rng.choice([1 << 20, 1 << 30, 1 << 26])
    arr["shape"] = [big, *arr["shape"][1:]] if arr["shape"] else [big]
    if rng.random() < 0.5:
        arr["shape"] = [big] * 4 + [3]  # more dimensions than allowed, too
    return _pack(env)


def non_finite(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    env = copy.deepcopy(env)
    bad = rng.choice([float("nan"), float("inf"), float("-inf")])
    arrays, scalars = _float_arrays(env), _float_scalars(env)
    if arrays and (not scalars or rng.random() < 0.6):
        path = rng.choice(arrays)
        arr = _parent(env, path)[path[-1]]
        values = np.frombuffer(arr["data"], dtype=arr["dtype"]).copy()
        values[rng.randrange(values.size)] = bad
        arr["data"] = values.tobytes()
    elif scalars:
        path = rng.choice(scalars)
        _parent(env, path)[path[-1]] = bad
    else:
        env["body"]["frame_id"] = -1 - rng.randrange(1000)
    return _pack(env)


def wrong_size(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    """Images that do not fit their calibration, clouds without colours, arrays of the wrong shape."""
    env = copy.deepcopy(env)
    body = env["body"]
    if env["schema"] == "StereoFrame":
        side = rng.choice(["left", "right", "calib"])
        if side == "calib":
            body["calib"]["width"] = CROP[1] * 5
        else:
            rows, cols = rng.randrange(8, CROP[0]), rng.randrange(8, CROP[1])
            body[side] = {"__nd__": True, "dtype": "uint8", "shape": [rows, cols, 3], "data": bytes(rows * cols * 3)}
        return _pack(env)
    if env["schema"] == "PointCloud":
        colors = body["colors"]
        colors["shape"][0] -= 1
        colors["data"] = colors["data"][: colors["shape"][0] * 3]
        return _pack(env)
    arrays = _arrays(env)
    if not arrays:
        return wrong_type(env, rng, others)
    path = rng.choice(arrays)
    arr = _parent(env, path)[path[-1]]
    arr["shape"] = [*arr["shape"], 1, 1, 1]  # same bytes, one dimension too many for its pattern
    return _pack(env)


def wrong_type(env: Wire, rng: random.Random, others: list[bytes]) -> bytes:
    env = copy.deepcopy(env)
    body = env["body"]
    name = rng.choice(["frame_id", "stamp_ns", "timing", "missing"])
    if name == "missing":
        del body[rng.choice(["frame_id", "stamp_ns"])]
    else:
        body[name] = rng.choice(["7", 7.5, {"x": 1}, None]) if name != "timing" else [["stage", "start", 1]]
    return _pack(env)


MUTATIONS: dict[str, Callable[[Wire, random.Random, list[bytes]], bytes]] = {
    "random_bytes": random_bytes,
    "truncated": truncated,
    "foreign_type": foreign,
    "broken_envelope": broken_envelope,
    "huge_declared": huge_declared,
    "non_finite": non_finite,
    "wrong_size": wrong_size,
    "wrong_type": wrong_type,
}


def bad_payloads(templates: dict[str, Message], per_topic: int, seed: int) -> dict[str, list[tuple[str, bytes]]]:
    """``per_topic`` (mutation, payload) pairs per topic, the mutations in turn; deterministic in ``seed``."""
    rng = random.Random(seed)
    wires = {topic: _wire(msg) for topic, msg in templates.items()}
    encoded = {topic: encode(msg) for topic, msg in templates.items()}
    out: dict[str, list[tuple[str, bytes]]] = {}
    names = list(MUTATIONS)
    for topic, env in wires.items():
        own = message_type(topic)
        others = [data for t, data in encoded.items() if message_type(t) is not own]
        out[topic] = [(names[i % len(names)], MUTATIONS[names[i % len(names)]](env, rng, others))
                      for i in range(per_topic)]
    return out
