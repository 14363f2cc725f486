"""Test-side readers of what Foxglove receives, from the standard library alone.

Neither ``websockets`` nor ``google.protobuf`` is installed, so this holds a minimal RFC 6455
client (enough for the ``foxglove.sdk.v1`` subprotocol: text JSON control frames, binary
message data) and a strict protobuf decoder driven by the schema's own FileDescriptorSet: an
unknown field number or a wire type the schema does not allow fails, so "decodes" means decodes.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import socket
import struct
import time
from typing import Any

GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


class WebSocket:
    """A blocking WebSocket client: handshake, masked sends, reassembled receives."""

    def __init__(self, host: str, port: int, subprotocol: str, timeout: float = 10.0) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        request = (
            f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {subprotocol}\r\n\r\n"
        )
        self.sock.sendall(request.encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(1)
            if not chunk:
                raise ConnectionError(f"server closed during the handshake: {head!r}")
            head += chunk
        status, *lines = head.decode().split("\r\n")
        if " 101 " not in status:
            raise ConnectionError(f"handshake refused: {status}")
        headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines if line)}
        expected = base64.b64encode(hashlib.sha1((key + GUID).encode()).digest()).decode()
        if headers.get("sec-websocket-accept") != expected:
            raise ConnectionError("bad Sec-WebSocket-Accept")
        self.subprotocol = headers.get("sec-websocket-protocol", "")

    def _exact(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("connection closed")
            data += chunk
        return data

    def recv(self) -> tuple[int, bytes]:
        """One whole message: (opcode, payload); pings are answered on the way."""
        opcode, payload = 0, b""
        while True:
            b0, b1 = self._exact(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._exact(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._exact(8))[0]
            data = self._exact(n)
            op = b0 & 0x0F
            if op == 0x9:
                self.send(data, opcode=0xA)
                continue
            if op != 0:
                opcode = op
            payload += data
            if b0 & 0x80:
                return opcode, payload

    def send(self, payload: bytes, opcode: int = 0x1) -> None:
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 65536:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def send_json(self, obj: Any) -> None:
        self.send(json.dumps(obj).encode())

    def recv_until(self, predicate: Any, timeout: float) -> tuple[int, bytes]:
        """Receive until ``predicate(opcode, payload)`` holds; fail after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.sock.settimeout(max(0.1, deadline - time.monotonic()))
            opcode, payload = self.recv()
            if predicate(opcode, payload):
                return opcode, payload
        raise TimeoutError("no matching WebSocket message in time")

    def close(self) -> None:
        self.sock.close()


# ----------------------------------------------------------------------------- protobuf

#: field type -> wire types allowed (packed repeated scalars arrive length-delimited, 2).
_WIRE = {1: {1}, 2: {5}, 3: {0}, 4: {0}, 5: {0}, 6: {1}, 7: {5}, 8: {0}, 9: {2}, 11: {2}, 12: {2}, 13: {0},
         14: {0}, 15: {5}, 16: {1}, 17: {0}, 18: {0}}


#: fixed-width field types -> struct format.
_FIXED = {1: "<d", 2: "<f", 6: "<Q", 7: "<I", 15: "<i", 16: "<q"}


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        if i >= len(buf):
            raise ValueError("truncated varint")
        b = buf[i]
        value |= (b & 0x7F) << shift
        i += 1
        if not b & 0x80:
            return value, i
        shift += 7


def wire_fields(buf: bytes) -> list[tuple[int, int, Any]]:
    """(field number, wire type, raw value) of every field; raises on malformed bytes."""
    out, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wt = key >> 3, key & 7
        if wt == 0:
            value, i = _varint(buf, i)
        elif wt == 1:
            value, i = buf[i : i + 8], i + 8
        elif wt == 5:
            value, i = buf[i : i + 4], i + 4
        elif wt == 2:
            n, i = _varint(buf, i)
            value, i = buf[i : i + n], i + n
        else:
            raise ValueError(f"wire type {wt} not supported")
        if i > len(buf) or number == 0:
            raise ValueError("truncated or invalid field")
        out.append((number, wt, value))
    return out


def _first(fields: list[tuple[int, int, Any]], number: int, default: Any = None) -> Any:
    return next((v for n, _, v in fields if n == number), default)


def descriptors(file_descriptor_set: bytes) -> dict[str, dict[int, tuple[str, int, str, int]]]:
    """Message full name -> {number: (field name, type, type name, label)} from a FileDescriptorSet."""
    messages: dict[str, dict[int, tuple[str, int, str, int]]] = {}

    def add(prefix: str, proto: bytes) -> None:
        fields = wire_fields(proto)
        name = f"{prefix}.{_first(fields, 1, b'').decode()}"
        table = messages.setdefault(name, {})
        for n, _, value in fields:
            if n == 2:
                f = wire_fields(value)
                table[_first(f, 3)] = (_first(f, 1, b"").decode(), _first(f, 5), _first(f, 6, b"").decode(),
                                       _first(f, 4, 1))
            elif n == 3:
                add(name, value)

    for n, _, file_bytes in wire_fields(file_descriptor_set):
        if n != 1:
            continue
        f = wire_fields(file_bytes)
        package = _first(f, 2, b"").decode()
        for m, _, proto in f:
            if m == 4:
                add(package, proto)
    return messages


def decode(messages: dict[str, dict[int, tuple[str, int, str, int]]], name: str, buf: bytes) -> dict[str, list[Any]]:
    """Decode ``buf`` as message ``name``: field name -> values (nested messages as dicts)."""
    table = messages[name.lstrip(".")]
    out: dict[str, list[Any]] = {}
    for number, wt, value in wire_fields(buf):
        if number not in table:
            raise ValueError(f"{name}: field number {number} is not in the schema")
        field, ftype, type_name, label = table[number]
        packed = wt == 2 and label == 3 and ftype not in (9, 11, 12)
        if wt not in _WIRE[ftype] and not packed:
            raise ValueError(f"{name}.{field}: wire type {wt} for field type {ftype}")
        if ftype == 11:
            value = decode(messages, type_name, value)
        elif ftype == 9:
            value = value.decode()
        elif ftype in _FIXED and not packed:
            value = struct.unpack(_FIXED[ftype], value)[0]
        out.setdefault(field, []).append(value)
    return out
