"""The record structure of an MCAP file, read without the mcap library's parser: whether
the file is complete (footer and closing magic present) and, when it is not (writer
killed, disk full, copy cut short), where its last complete record ends and what the
partial record at the end was (:func:`layout`). :class:`Bounded` lets the streaming
reader read only the complete prefix."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import BinaryIO, Optional

from mcap.opcode import Opcode

MCAP_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD_BYTES = 1 + 8 + 8 + 8 + 4


class Bounded:
    """A read-only view of ``f`` ending at ``limit`` (the end of the last complete record)."""

    def __init__(self, f: BinaryIO, start: int, limit: int):
        f.seek(start)
        self._f = f
        self.pos = start
        self.limit = limit

    def read(self, n: int = -1) -> bytes:
        remaining = self.limit - self.pos
        if n is None or n < 0 or n > remaining:
            n = remaining
        if n <= 0:
            return b""
        data = self._f.read(n)
        self.pos += len(data)
        return data


@dataclass
class Layout:
    size: int
    usable: int  # end of the last complete record; == size for a complete file
    complete: bool  # footer and closing magic present
    data_end_seen: bool = True
    chunks: int = 0
    partial: Optional[str] = None
    partial_t_ns: Optional[tuple[int, int]] = None


def _record_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.replace("_", " ").title().replace(" ", "")
    except ValueError:
        return f"opcode 0x{opcode:02x}"


def layout(f: BinaryIO, size: int) -> Layout:
    """Find whether the file is complete; if not, where its last complete record ends."""
    if size >= 8 + 9 + _FOOTER_RECORD_BYTES + 8:
        f.seek(size - 8)
        if f.read(8) == MCAP_MAGIC:
            f.seek(size - 8 - _FOOTER_RECORD_BYTES)
            opcode, length = struct.unpack("<BQ", f.read(9))
            if opcode == Opcode.FOOTER and length == _FOOTER_RECORD_BYTES - 9:
                return Layout(size=size, usable=size, complete=True)
    pos = 8
    data_end = False
    chunks = 0
    while True:
        if pos == size:
            return Layout(size, pos, False, data_end, chunks)
        if pos + 9 > size:
            return Layout(
                size, pos, False, data_end, chunks,
                f"a partial record header at byte {pos:,} ({size - pos} of 9 bytes present)",
            )
        f.seek(pos)
        opcode, length = struct.unpack("<BQ", f.read(9))
        end = pos + 9 + length
        if end > size:
            t_ns = None
            if opcode == Opcode.CHUNK and size - pos >= 9 + 16:
                t_ns = struct.unpack("<QQ", f.read(16))
            return Layout(
                size, pos, False, data_end, chunks,
                f"a partial {_record_name(opcode)} record at byte {pos:,} "
                f"({size - pos:,} of {9 + length:,} bytes present)",
                t_ns,
            )
        if opcode == Opcode.CHUNK:
            chunks += 1
        elif opcode == Opcode.DATA_END:
            data_end = True
        elif opcode == Opcode.FOOTER:
            # Footer complete but the closing magic is missing or cut.
            return Layout(size, end, False, True, chunks)
        pos = end
