"""numpy arrays and images on the wire: a whitelist of dtypes, size limits checked before allocating.

Arrays travel as ``{dtype, shape, bytes}``; a StereoFrame's images may instead travel as PNG or
JPEG. Everything a payload declares (dtype, number of dimensions, byte count, an encoded image's
pixel size) is checked against the limits before any memory is allocated for it, so a hostile or
corrupt message fails with :class:`DecodeError` instead of taking gigabytes.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import DecodeError

NDArray = npt.NDArray[Any]

#: dtypes an array may have on the wire; anything else is refused.
DTYPES: frozenset[str] = frozenset(
    {"uint8", "uint16", "int16", "int32", "int64", "float32", "float64", "bool"}
)
#: largest single array accepted (bytes): a 4K RGB image is 25 MB, a 1M-point cloud 12 MB.
MAX_ARRAY_BYTES: int = 64 * 1024 * 1024
#: largest number of dimensions an array may declare.
MAX_NDIM: int = 4
#: image encodings a StereoFrame may travel with.
IMAGE_FORMATS: tuple[str, ...] = ("raw", "png", "jpeg")


_ND = "__nd__"
_IMG = "__img__"


def pack_array(arr: NDArray) -> dict[str, Any]:
    arr = np.ascontiguousarray(arr)
    if arr.dtype.name not in DTYPES:
        raise DecodeError(f"dtype {arr.dtype.name} cannot be sent; allowed: {sorted(DTYPES)}")
    # a flat byte view: memoryview.cast refuses arrays with a zero in their shape (an empty cloud)
    data = memoryview(arr.reshape(-1).view(np.uint8))
    return {_ND: True, "dtype": arr.dtype.name, "shape": list(arr.shape), "data": data}


def pack_image(arr: NDArray, fmt: str) -> Any:
    if fmt == "raw":
        return pack_array(arr)
    if fmt not in IMAGE_FORMATS:
        raise DecodeError(f"image format {fmt!r} unknown; allowed: {IMAGE_FORMATS}")
    ext = ".png" if fmt == "png" else ".jpg"
    ok, buf = cv2.imencode(ext, cv2.cvtColor(np.ascontiguousarray(arr), cv2.COLOR_RGB2BGR))
    if not ok:
        raise DecodeError(f"could not encode image as {fmt}")
    return {_IMG: fmt, "data": buf.tobytes()}


def unpack_array(value: Any, where: str, dtype: str | None, shape: tuple[int | None, ...] | None) -> NDArray:
    if not isinstance(value, dict) or not value.get(_ND):
        raise DecodeError(f"{where}: expected an array, got {type(value).__name__}")
    name, dims, data = value.get("dtype"), value.get("shape"), value.get("data")
    if name not in DTYPES:
        raise DecodeError(f"{where}: dtype {name!r} not allowed")
    if dtype is not None and name != dtype:
        raise DecodeError(f"{where}: dtype {name} where {dtype} is required")
    if not isinstance(dims, list) or len(dims) > MAX_NDIM or not all(
        isinstance(d, int) and not isinstance(d, bool) and 0 <= d <= MAX_ARRAY_BYTES for d in dims
    ):
        raise DecodeError(f"{where}: shape {dims!r} is not a list of at most {MAX_NDIM} sizes")
    if shape is not None and (
        len(dims) != len(shape) or any(s is not None and s != d for s, d in zip(shape, dims, strict=False))
    ):
        raise DecodeError(f"{where}: shape {tuple(dims)} does not fit {shape}")
    if not isinstance(data, (bytes, bytearray)):
        raise DecodeError(f"{where}: array data is {type(data).__name__}, not bytes")
    itemsize = np.dtype(name).itemsize
    expected = math.prod(dims) * itemsize
    if expected > MAX_ARRAY_BYTES:
        raise DecodeError(f"{where}: {expected} bytes declared, limit {MAX_ARRAY_BYTES}")
    if len(data) != expected:
        raise DecodeError(f"{where}: {len(data)} bytes where shape {tuple(dims)} {name} needs {expected}")
    return np.frombuffer(data, dtype=name).reshape(dims)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic): they carry the size.
_JPEG_SOF = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})


def _encoded_size(data: bytes, fmt: str, where: str) -> tuple[int, int]:
    """Width and height from a PNG or JPEG header, read before decoding.

    A few hundred bytes of PNG can declare a 40000 x 40000 image: decoding first would allocate
    gigabytes, so the declared size is checked against the array limit before OpenCV sees it.
    """
    if fmt == "png":
        if len(data) < 24 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
            raise DecodeError(f"{where}: data is not png (no PNG signature and IHDR header)")
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not data.startswith(b"\xff\xd8"):
        raise DecodeError(f"{where}: data is not jpeg (no start-of-image marker)")
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        length = int.from_bytes(data[i + 2 : i + 4], "big")
        if marker in _JPEG_SOF and i + 9 <= len(data):
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        i += 2 + length
    raise DecodeError(f"{where}: jpeg data has no start-of-frame header with the image size")


def unpack_image(value: Any, where: str) -> NDArray:
    if isinstance(value, dict) and _IMG in value:
        data = value.get("data")
        if value[_IMG] not in ("png", "jpeg") or not isinstance(data, (bytes, bytearray)):
            raise DecodeError(f"{where}: bad encoded image")
        if len(data) > MAX_ARRAY_BYTES:
            raise DecodeError(f"{where}: encoded image of {len(data)} bytes over the limit")
        width, height = _encoded_size(bytes(data), value[_IMG], where)
        if width * height * 3 > MAX_ARRAY_BYTES:
            raise DecodeError(
                f"{where}: {value[_IMG]} declares {width}x{height} pixels, over the limit of {MAX_ARRAY_BYTES} bytes"
            )
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if img is None or img.ndim != 3 or img.shape[2] != 3:
            raise DecodeError(f"{where}: {value[_IMG]} data does not decode to a colour image")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return unpack_array(value, where, "uint8", (None, None, 3))
