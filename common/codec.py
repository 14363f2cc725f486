"""The one msgpack codec for every message in :mod:`common.messages`.

Arrays and images travel as :mod:`common.wire_arrays` packs them, within its limits; decoding
checks every field against the dataclass's type hints, so a hostile or corrupt payload fails with
:class:`DecodeError` instead of producing a wrongly typed or shaped value deep inside a stage.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any

import msgpack
import numpy as np

from common.errors import DecodeError
from common.message_checks import check_consistent, check_finite
from common.messages import SCHEMAS, M, Message, StereoFrame, Timing
from common.wire_arrays import MAX_ARRAY_BYTES, pack_array, pack_image, unpack_array, unpack_image


def _to_wire(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        fmt = getattr(obj, "image_format", "raw")
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if "dtype" in f.metadata and isinstance(obj, StereoFrame) and f.name in ("left", "right"):
                out[f.name] = pack_image(value, fmt)
            else:
                out[f.name] = _to_wire(value)
        return out
    if isinstance(obj, np.ndarray):
        return pack_array(obj)
    if isinstance(obj, (list, tuple)):
        return [_to_wire(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): _to_wire(v) for k, v in obj.items()}
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def encode(msg: Message) -> bytes:
    """Serialise a message: ``{"schema": "PointCloud", "v": 1, "body": {...}}`` in msgpack."""
    body = _to_wire(msg)
    return msgpack.packb({"schema": msg.SCHEMA, "v": msg.VERSION, "body": body}, use_bin_type=True)


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _check_scalar(value: Any, hint: Any, where: str) -> Any:
    if hint is bool:
        if not isinstance(value, bool):
            raise DecodeError(f"{where}: expected bool, got {type(value).__name__}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise DecodeError(f"{where}: expected int, got {type(value).__name__}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DecodeError(f"{where}: expected float, got {type(value).__name__}")
        if not math.isfinite(value):
            raise DecodeError(f"{where}: {value} is not a finite number")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise DecodeError(f"{where}: expected str, got {type(value).__name__}")
        return value
    return _MISSING


_MISSING = object()


def _from_wire(cls: type, value: Any, where: str) -> Any:
    if not isinstance(value, dict):
        raise DecodeError(f"{where}: expected a map for {cls.__name__}, got {type(value).__name__}")
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name not in value:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise DecodeError(f"{where}.{f.name}: missing")
            continue
        raw = value[f.name]
        sub = f"{where}.{f.name}"
        if "dtype" in f.metadata:
            if cls is StereoFrame and f.name in ("left", "right"):
                kwargs[f.name] = unpack_image(raw, sub)
            else:
                kwargs[f.name] = unpack_array(raw, sub, f.metadata["dtype"], f.metadata["shape"])
                check_finite(kwargs[f.name], f.name, sub)
            continue
        kwargs[f.name] = _convert(hints[f.name], raw, sub)
    return cls(**kwargs)


def _convert(hint: Any, raw: Any, where: str) -> Any:
    scalar = _check_scalar(raw, hint, where)
    if scalar is not _MISSING:
        return scalar
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if dataclasses.is_dataclass(hint):
        return _from_wire(hint, raw, where)
    if origin is list:
        if not isinstance(raw, list):
            raise DecodeError(f"{where}: expected a list, got {type(raw).__name__}")
        return [_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(raw)]
    if origin is tuple:
        if not isinstance(raw, list) or len(raw) != len(args):
            raise DecodeError(f"{where}: expected a {len(args)}-tuple")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, raw, strict=True)))
    if origin is dict:
        if not isinstance(raw, dict) or not all(isinstance(k, str) for k in raw):
            raise DecodeError(f"{where}: expected a map with string keys")
        return raw
    if hint is Timing or hint == tuple[str, int, int]:
        return _convert(tuple[str, int, int], raw, where)
    raise DecodeError(f"{where}: cannot decode type {hint!r}")


def decode(data: bytes | bytearray | memoryview, expected: type[M] | None = None) -> M:
    """Parse bytes into a message; anything malformed raises :class:`DecodeError` only."""
    try:
        envelope = msgpack.unpackb(bytes(data), raw=False, strict_map_key=True, max_bin_len=MAX_ARRAY_BYTES)
    except DecodeError:
        raise
    except Exception as exc:  # msgpack raises a zoo of types on bad bytes
        raise DecodeError(f"not a msgpack message: {type(exc).__name__}: {exc}") from None
    if not isinstance(envelope, dict):
        raise DecodeError(f"envelope is {type(envelope).__name__}, not a map")
    schema, version, body = envelope.get("schema"), envelope.get("v"), envelope.get("body")
    cls = SCHEMAS.get(schema) if isinstance(schema, str) else None
    if cls is None:
        raise DecodeError(f"unknown schema {schema!r}; known: {sorted(SCHEMAS)}")
    if isinstance(version, bool) or version != cls.VERSION:
        raise DecodeError(f"{schema} version {version!r}, this build reads version {cls.VERSION}")
    if expected is not None and cls is not expected:
        raise DecodeError(f"got {schema} where {expected.SCHEMA} was expected")
    try:
        msg = _from_wire(cls, body, schema)
        check_consistent(msg, schema)
    except DecodeError:
        raise
    except Exception as exc:  # a value the dataclass or numpy refuses
        raise DecodeError(f"{schema}: {type(exc).__name__}: {exc}") from None
    return typing.cast(M, msg)
