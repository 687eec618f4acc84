"""The binary input encoding of recording format 2: ``cablesvc.InputBlock`` (protobuf).

One MCAP message holds a *block* of consecutive ticks as packed little-endian arrays, so
a reader turns a block into numpy arrays with a handful of ``np.frombuffer`` calls instead
of parsing one JSON object per tick. The message is plain protobuf (proto3) and the file
stores its ``FileDescriptorSet`` as the MCAP schema (schema encoding ``protobuf``, message
encoding ``protobuf``), so Foxglove, the ``mcap`` CLI and any protobuf library decode it
with no cablesvc code. The schema (docs/recording-format.md, section 2.2)::

    syntax = "proto3";
    package cablesvc;
    message InputBlock {
      uint32 cables = 1;                 // m >= 1
      uint32 ticks = 2;                  // n >= 1, ticks in this block
      repeated sfixed64 seq = 3;         // n
      repeated double t = 4;             // n, s
      repeated double motor_length = 5;  // n * m, row-major (tick by tick)
      repeated double position = 6;      // n * 3 or empty (no tick of the block has a pose)
      repeated double orientation = 7;   // n * 4 or empty, [qx, qy, qz, qw] per tick
      repeated double force = 8;         // n * m or empty
      repeated double temperature = 9;   // n or empty
    }

Missing values are NaN (IEEE 754 quiet NaN); every other float64, infinities included, is
stored exactly. This module encodes and decodes the protobuf wire format itself (fixed-
width packed fields are raw little-endian bytes), so cablesvc needs no protobuf runtime;
the tests check the bytes against the ``protobuf`` package's own decoder.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from cablesvc.errors import RecordingError

SCHEMA_NAME = "cablesvc.InputBlock"
SCHEMA_ENCODING = "protobuf"
MESSAGE_ENCODING = "protobuf"
PROTO_FILE = "cablesvc/input_block.proto"

PROTO_TEXT = """\
syntax = "proto3";
package cablesvc;

// A block of consecutive control ticks of one cable robot (cablesvc recording format 2).
// SI units; cable i is the i-th cable of the robot file; NaN = missing value.
message InputBlock {
  uint32 cables = 1;                 // m >= 1
  uint32 ticks = 2;                  // n >= 1, ticks in this block
  repeated sfixed64 seq = 3;         // n
  repeated double t = 4;             // n, controller clock, s
  repeated double motor_length = 5;  // n * m, row-major, metres
  repeated double position = 6;      // n * 3 or empty (no tick of the block has a pose), metres
  repeated double orientation = 7;   // n * 4 or empty, [qx, qy, qz, qw] per tick
  repeated double force = 8;         // n * m or empty, N
  repeated double temperature = 9;   // n or empty, deg C
}
"""

# field number -> (name, numpy dtype, values per tick: None = m)
FIELDS: dict[int, tuple[str, str, Optional[int]]] = {
    3: ("seq", "<i8", 1),
    4: ("t", "<f8", 1),
    5: ("motor_length", "<f8", None),
    6: ("position", "<f8", 3),
    7: ("orientation", "<f8", 4),
    8: ("force", "<f8", None),
    9: ("temperature", "<f8", 1),
}
_CABLES, _TICKS = 1, 2


# ===================================================================== wire format helpers
def _varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _len_field(field: int, data: bytes) -> bytes:
    return _key(field, 2) + _varint(len(data)) + data


def _int_field(field: int, v: int) -> bytes:
    return _key(field, 0) + _varint(v)


def _descriptor_set() -> bytes:
    """The FileDescriptorSet (google/protobuf/descriptor.proto) of ``PROTO_TEXT``."""
    # FieldDescriptorProto: name=1, number=3, label=4 (1 optional, 3 repeated),
    # type=5 (1 double, 13 uint32, 16 sfixed64), json_name=10
    def field(name: str, number: int, label: int, ftype: int, json_name: str) -> bytes:
        return (_len_field(1, name.encode()) + _int_field(3, number) + _int_field(4, label)
                + _int_field(5, ftype) + _len_field(10, json_name.encode()))

    fields = [field("cables", 1, 1, 13, "cables"), field("ticks", 2, 1, 13, "ticks"),
              field("seq", 3, 3, 16, "seq"), field("t", 4, 3, 1, "t"),
              field("motor_length", 5, 3, 1, "motorLength"), field("position", 6, 3, 1, "position"),
              field("orientation", 7, 3, 1, "orientation"), field("force", 8, 3, 1, "force"),
              field("temperature", 9, 3, 1, "temperature")]
    # DescriptorProto: name=1, field=2
    message = _len_field(1, b"InputBlock") + b"".join(_len_field(2, f) for f in fields)
    # FileDescriptorProto: name=1, package=2, message_type=4, syntax=12
    file = (_len_field(1, PROTO_FILE.encode()) + _len_field(2, b"cablesvc") + _len_field(4, message)
            + _len_field(12, b"proto3"))
    return _len_field(1, file)  # FileDescriptorSet: file=1


#: The schema data stored in the MCAP file (a serialized ``FileDescriptorSet``).
SCHEMA_DATA = _descriptor_set()


# ===================================================================== encode
def encode_block(seq: np.ndarray, t: np.ndarray, motor_length: np.ndarray,
                 position: Optional[np.ndarray] = None, orientation: Optional[np.ndarray] = None,
                 force: Optional[np.ndarray] = None, temperature: Optional[np.ndarray] = None) -> bytes:
    """One ``InputBlock`` message: ``n`` ticks, arrays shaped (n,), (n, m), (n, 3), (n, 4).

    A part that is None (or all NaN) is left empty (absent in every tick of the block)."""
    n, m = motor_length.shape
    parts = [_int_field(_CABLES, m), _int_field(_TICKS, n),
             _len_field(3, np.ascontiguousarray(seq, dtype="<i8").tobytes()),
             _len_field(4, np.ascontiguousarray(t, dtype="<f8").tobytes()),
             _len_field(5, np.ascontiguousarray(motor_length, dtype="<f8").tobytes())]
    if position is not None and orientation is not None and not (
            np.isnan(position).all() and np.isnan(orientation).all()):
        parts.append(_len_field(6, np.ascontiguousarray(position, dtype="<f8").tobytes()))
        parts.append(_len_field(7, np.ascontiguousarray(orientation, dtype="<f8").tobytes()))
    for number, a in ((8, force), (9, temperature)):
        if a is not None and not np.isnan(a).all():
            parts.append(_len_field(number, np.ascontiguousarray(a, dtype="<f8").tobytes()))
    return b"".join(parts)


# ===================================================================== decode
class BlockError(RecordingError, ValueError):
    """An ``InputBlock`` message that is not valid protobuf or breaks the schema's rules
    (the MCAP reader turns it into a ``RecordingError`` naming the file and message)."""

    def __init__(self, field: str, reason: str):
        super().__init__(field, reason)
        self.field = field
        self.reason = reason


def _read_varint(buf: bytes, pos: int) -> tuple[int, int]:
    v = shift = 0
    end = len(buf)
    while True:
        if pos >= end:
            raise BlockError("", "message ends inside a varint")
        b = buf[pos]
        pos += 1
        v |= (b & 0x7F) << shift
        if not b & 0x80:
            return v, pos
        shift += 7
        if shift >= 70:
            raise BlockError("", "varint longer than 10 bytes")


def decode_block(data: bytes, n_cables: Optional[int] = None) -> dict:
    """Decode one ``InputBlock``: a dict with ``n``, ``m`` and the arrays ``seq`` (n,) int64,
    ``t`` (n,), ``motor_length`` (n, m), ``position`` (n, 3) / ``orientation`` (n, 4) /
    ``force`` (n, m) / ``temperature`` (n,) or None when empty. Accepts everything a protobuf
    writer may produce for this schema (packed or unpacked repeated fields, fields in any
    order, fields split over several records, unknown fields, which are skipped).
    ``n_cables``: the cable count the block must have. Raises :class:`BlockError`."""
    buf = bytes(data) if not isinstance(data, bytes) else data
    pieces: dict[int, list[bytes]] = {}
    scalars = {_CABLES: 0, _TICKS: 0}
    pos, end = 0, len(buf)
    while pos < end:
        key, pos = _read_varint(buf, pos)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise BlockError("", f"field number 0 at byte {pos}")
        if wire == 0:
            v, pos = _read_varint(buf, pos)
            if number in scalars:
                scalars[number] = v & 0xFFFFFFFF
            elif number in FIELDS:
                raise BlockError(FIELDS[number][0], "varint where the schema has a fixed-width field")
        elif wire == 2:
            ln, pos = _read_varint(buf, pos)
            if pos + ln > end:
                raise BlockError(FIELDS.get(number, (f"field {number}",))[0],
                                 f"length {ln} runs past the end of the message ({end - pos} bytes left)")
            if number in FIELDS:
                pieces.setdefault(number, []).append(buf[pos:pos + ln])
            elif number in scalars:
                raise BlockError(("cables", "ticks")[number - 1], "expected a varint, got a length-delimited field")
            pos += ln
        elif wire == 1:
            if pos + 8 > end:
                raise BlockError("", "message ends inside a 64-bit field")
            if number in FIELDS:  # an unpacked repeated element
                pieces.setdefault(number, []).append(buf[pos:pos + 8])
            elif number in scalars:
                raise BlockError(("cables", "ticks")[number - 1], "expected a varint, got a 64-bit field")
            pos += 8
        elif wire == 5:
            if number in FIELDS:
                raise BlockError(FIELDS[number][0], "32-bit field where the schema has 64-bit values")
            if number in scalars:
                raise BlockError(("cables", "ticks")[number - 1], "expected a varint, got a 32-bit field")
            if pos + 4 > end:
                raise BlockError("", "message ends inside a 32-bit field")
            pos += 4
        else:
            raise BlockError("", f"wire type {wire} (groups) at byte {pos} is not valid here")
    n, m = scalars[_TICKS], scalars[_CABLES]
    if n < 1:
        raise BlockError("ticks", f"must be >= 1, got {n}")
    if m < 1:
        raise BlockError("cables", f"must be >= 1 (a robot has at least 1 cable), got {m}")
    if n_cables is not None and m != n_cables:
        raise BlockError("cables", f"is {m}, expected {n_cables}")
    out: dict = {"n": n, "m": m}
    for number, (name, dtype, width) in FIELDS.items():
        p = pieces.get(number)
        raw = b"" if not p else (p[0] if len(p) == 1 else b"".join(p))
        w = m if width is None else width
        if not raw:
            if name in ("seq", "t", "motor_length"):
                raise BlockError(name, f"is empty; it needs {n * w} values ({n} ticks)")
            out[name] = None
            continue
        if len(raw) != 8 * n * w:
            have = len(raw) / 8
            raise BlockError(name, f"has {have:g} values, expected {n * w} ({n} ticks x {w})"
                             if w > 1 else f"has {have:g} values, expected {n} (one per tick)")
        a = np.frombuffer(raw, dtype=dtype)
        out[name] = a if width == 1 else a.reshape(n, w)
    if (out["position"] is None) != (out["orientation"] is None):
        have = "position" if out["position"] is not None else "orientation"
        raise BlockError(have, "is given without "
                         + ("orientation" if have == "position" else "position") + " (a pose needs both)")
    return out
