"""MCAP side of recording formats 1 and 2: :class:`McapRecordingWriter`, :func:`read_mcap`,
:func:`iter_mcap_inputs`.

Input encodings
    ``protobuf`` (format 2, the default): one ``cablesvc.InputBlock`` message per block of
    up to 1000 ticks, packed little-endian arrays (``protobuf_block.py``); the writer holds
    the block in progress and writes it when full, on ``flush()`` and on ``close()``.
    ``json`` (format 1): one JSON message per tick. The reader tells them apart by the input
    channel's message encoding and reads both, also in one file.

Writing
    One MCAP file: the header, the ``cablesvc`` metadata record (written straight away, so
    it is at the start of the file), then zstd chunks holding the input schema, the
    ``/cablesvc/input`` channel and the input messages; ``close()`` writes the
    summary (chunk, metadata indexes, statistics) and footer. The file is opened unbuffered:
    every record batch mcap's writer hands over (a finished chunk with its message indexes,
    the metadata, the summary) reaches the operating system in one ``write``. So a process
    killed with ``kill -9`` keeps every *finished* chunk; it loses the chunk in progress,
    which is at most ``chunk_size`` bytes of uncompressed messages (and, with binary
    inputs, the block in progress, which is never larger than a chunk). ``flush()`` finishes the
    chunk in progress (``mcap.writer.Writer.flush``, mcap >= 1.6) so a caller that flushes on
    a timer bounds the loss by time; ``flush(fsync=True)`` also survives power loss.

Reading
    A complete file (footer and closing magic present) is read with its summary: the
    ``cablesvc`` metadata record is found through the metadata index and the channel table
    says up front whether ``/cablesvc/input`` exists. The messages are then read in *file
    order* with mcap's streaming ``StreamReader``, one chunk in memory at a time. (mcap's
    ``SeekingReader.iter_messages`` either re-sorts by log time, which is not file order
    when ``t`` is not monotonic, or, with ``log_time_order=False``, decompresses every chunk
    before yielding the first message.)

    A file without footer (writer killed, disk full, copy cut short) is walked record by
    record from the start to find the end of the last complete record; the complete prefix
    is read the same way and :class:`~cablesvc.recording.format.Truncation` (also issued as
    a :class:`~cablesvc.recording.format.RecordingTruncatedWarning`) says what was lost:
    the partial chunk's time range, when its header survived, and an estimate of its ticks.
"""

from __future__ import annotations

import json
import math
import os
import struct
import warnings
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Iterable, Iterator, Optional

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, DataEnd, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .. import __version__
from ..jsonable import jsonable
from . import protobuf_block as pb
from .format import (
    BLOCK_FORMAT_VERSION,
    ENCODINGS,
    FORMAT_VERSION,
    MCAP_FORMAT_VERSIONS,
    INPUT_JSON_SCHEMA,
    INPUT_SCHEMA_NAME,
    INPUT_TOPIC,
    MESSAGE_ENCODING,
    METADATA_NAME,
    OUTPUT_TOPICS,
    SCHEMA_ENCODING,
    PathArg,
    Recording,
    RecordingError,
    RecordingTruncatedWarning,
    Tick,
    TickColumns,
    Truncation,
)

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Default chunk size (uncompressed bytes). At 1 kHz with 8 cables (~300 B per tick) a chunk
#: fills in about 0.9 s, which bounds what a kill -9 loses when nobody calls ``flush()``.
DEFAULT_CHUNK_SIZE = 256 * 1024
_FOOTER_RECORD_BYTES = 1 + 8 + 8 + 8 + 4
_LOG_TIME_MAX_S = (2**64 - 1) / 1e9
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}

_ENCODER = json.JSONEncoder(allow_nan=False, separators=(",", ":"))
#: Ticks per ``cablesvc.InputBlock`` message (protobuf encoding) at most; fewer when one
#: block of the robot's ticks would not fit in ``chunk_size`` (see ``_block_ticks``).
DEFAULT_BLOCK_TICKS = 1000
#: What the writers write unless told otherwise: the binary block encoding (format 2).
DEFAULT_ENCODING = "protobuf"


def _block_ticks(block_ticks: int, chunk_size: int, m: int) -> int:
    """Ticks per block: ``block_ticks``, but a block never larger than a chunk, so what a
    kill -9 loses stays bounded by ``chunk_size`` as with JSON (block in progress + chunk in
    progress)."""
    per_tick = 8 * (2 + 2 * m + 7 + 1)
    return max(1, min(block_ticks, chunk_size // per_tick))


def _check_encoding(encoding: str) -> str:
    if encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {list(ENCODINGS)}, got {encoding!r}")
    return encoding


def _row64(x: Any, name: str, n: Optional[int]) -> np.ndarray:
    """A 1-D float64 array of ``n`` values (the binary writer's check of one tick part)."""
    if isinstance(x, np.ndarray) and x.dtype == np.float64:
        a = x
    else:
        try:
            a = np.asarray(x, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f"{name} must be numbers: {e}") from None
    if a.ndim != 1:
        raise ValueError(f"{name} must be 1-D, has shape {a.shape}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} has {a.shape[0]} values, expected {n}")
    return a


# ===================================================================== writing helpers
def _float_list(x: Any, name: str, n: Optional[int] = None) -> list:
    """A 1-D sequence of numbers as a list of Python floats, non-finite values as None."""
    if isinstance(x, np.ndarray):
        if x.ndim != 1:
            raise ValueError(f"{name} must be 1-D, has shape {x.shape}")
        if x.dtype != np.float64:
            x = x.astype(np.float64)
        lst = x.tolist()
    else:
        lst = [float(v) for v in x]
    if n is not None and len(lst) != n:
        raise ValueError(f"{name} has {len(lst)} values, expected {n}")
    if not all(map(math.isfinite, lst)):
        lst = [v if math.isfinite(v) else None for v in lst]
    return lst


def _encode_payload(payload: dict) -> bytes:
    try:
        return _ENCODER.encode(payload).encode()
    except (TypeError, ValueError):
        return _ENCODER.encode(jsonable(payload)).encode()


def _log_time(t: float) -> int:
    ns = round(t * 1e9) if 0.0 <= t <= _LOG_TIME_MAX_S else -1
    if not 0 <= ns < 2**64:  # t at the very top rounds up to 2**64
        raise ValueError(
            f"t = {t!r} s cannot be an MCAP log_time (unsigned 64-bit ns): need 0 <= t < "
            f"{_LOG_TIME_MAX_S:.4g} and finite"
        )
    return ns


def _part_or_null(lst: list) -> Optional[list]:
    """``None`` (JSON null) for a part whose values are all non-finite (already None)."""
    return None if all(v is None for v in lst) else lst


class _DirectFile:
    """Unbuffered output for mcap's Writer: each batch it writes goes to the OS at once."""

    def __init__(self, path: Path, overwrite: bool = True):
        self._f = open(path, "wb" if overwrite else "xb", buffering=0)
        self._pos = 0

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        total = len(view)
        while view:
            n = self._f.write(view)
            view = view[n:]
        self._pos += total
        return total

    def tell(self) -> int:
        """Bytes written (counted, not asked of the OS: the file may be a pipe)."""
        return self._pos

    def flush(self) -> None:
        """Nothing is buffered here (mcap's Writer calls this from its ``flush()``)."""

    def fsync(self) -> None:
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


class McapRecordingWriter:
    """Write an MCAP recording tick by tick (the live service, simulator, convert).

    ``robot`` is the robot's name; ``metadata`` are further key/values for the ``cablesvc``
    metadata record (str to str; ``robot`` and ``format`` are set by the writer).
    ``encoding`` is the input encoding: ``"protobuf"`` (default; format 2: the ticks are
    buffered and written as one ``cablesvc.InputBlock`` message per ``block_ticks`` ticks,
    fewer when a block would be larger than ``chunk_size``; ``flush()`` and ``close()``
    write the block in progress) or ``"json"`` (format 1: one JSON message per tick).
    ``chunk_size`` is the uncompressed chunk size in bytes; ``compression`` is ``"zstd"``,
    ``"lz4"`` or ``"none"``. ``overwrite=False`` refuses an existing file
    (``FileExistsError``) instead of replacing it. Use as a context manager; the file is closed (summary written)
    even when the block raises. Not thread-safe: call from one thread.
    """

    def __init__(
        self,
        path: PathArg,
        robot: str,
        metadata: Optional[dict[str, str]] = None,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        *,
        overwrite: bool = True,
        encoding: str = DEFAULT_ENCODING,
        block_ticks: int = DEFAULT_BLOCK_TICKS,
    ):
        if not isinstance(robot, str) or not robot:
            raise ValueError("robot must be a non-empty str (the robot's name)")
        self.encoding = _check_encoding(encoding)
        if block_ticks < 1:
            raise ValueError("block_ticks must be >= 1")
        binary = encoding == "protobuf"
        md = {"robot": robot, "format": str(BLOCK_FORMAT_VERSION if binary else FORMAT_VERSION)}
        for k, v in (metadata or {}).items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise TypeError(f"metadata must map str to str, got {k!r}: {v!r}")
            if k in md:
                raise ValueError(
                    f"metadata key {k!r} is set by the writer (robot via the robot argument, "
                    "format is fixed)"
                )
            md[k] = v
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}")
        if chunk_size < 1:
            raise ValueError("chunk_size must be >= 1")
        self.path = Path(path)
        self._file = _DirectFile(self.path, overwrite)
        self._closed = False
        try:
            self._writer = Writer(
                self._file,  # type: ignore[arg-type]
                chunk_size=chunk_size,
                compression=_COMPRESSION[compression],
            )
            self._writer.start(
                profile="", library=f"cablesvc/{__version__} ({LIBRARY_IDENTIFIER})"
            )
            self._writer.add_metadata(METADATA_NAME, md)
            if binary:
                schema_id = self._writer.register_schema(
                    pb.SCHEMA_NAME, pb.SCHEMA_ENCODING, pb.SCHEMA_DATA
                )
                self._input_channel = self._writer.register_channel(
                    INPUT_TOPIC, pb.MESSAGE_ENCODING, schema_id
                )
            else:
                schema_id = self._writer.register_schema(
                    INPUT_SCHEMA_NAME, SCHEMA_ENCODING, json.dumps(INPUT_JSON_SCHEMA).encode()
                )
                self._input_channel = self._writer.register_channel(
                    INPUT_TOPIC, MESSAGE_ENCODING, schema_id
                )
        except BaseException:
            self._file.close()
            self._closed = True
            raise
        self._channels: dict[str, int] = {INPUT_TOPIC: self._input_channel}
        self._schemas: dict[str, tuple[str, bytes]] = {}
        self._n_cables: Optional[int] = None
        self._chunk_size = chunk_size
        self._block_ticks = block_ticks
        self._block: Optional[dict[str, np.ndarray]] = None  # protobuf: the block in progress
        self._bn = 0  # ticks in the block in progress
        self._b_any = [False, False, False]  # pose, force, temperature in the block
        self.n_inputs = 0
        """Number of ticks written so far (protobuf: including the block in progress)."""

    # ------------------------------------------------------------------ context
    def __enter__(self) -> "McapRecordingWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")

    # ------------------------------------------------------------------ input
    def write_input(
        self,
        seq: int,
        t: float,
        motor_length: Any,
        force: Any = None,
        position: Any = None,
        orientation: Any = None,
        temperature: Optional[float] = None,
    ) -> None:
        """Write one tick on ``/cablesvc/input`` (log_time = t in ns).

        Arrays may be numpy arrays or sequences; non-finite values are written as null,
        and a pose (force) whose values are all non-finite as a null pose (force).
        ``position`` and ``orientation`` ([qx, qy, qz, qw]) go together (both or neither).
        ``seq`` must fit in a signed 64-bit integer.
        The first tick fixes the cable count; later ticks must match it.
        """
        self._check_open()
        if type(seq) is not int:
            if isinstance(seq, (bool, np.bool_)) or not isinstance(seq, (int, np.integer)):
                raise TypeError(f"seq must be an integer, got {type(seq).__name__}")
            seq = int(seq)
        if not _INT64_MIN <= seq <= _INT64_MAX:
            raise ValueError(f"seq = {seq} does not fit in a signed 64-bit integer")
        t = float(t)
        log_time = _log_time(t)
        if self.encoding == "protobuf":
            self._buffer_tick(seq, t, motor_length, force, position, orientation, temperature)
            return
        ml = _float_list(motor_length, "motor_length", self._n_cables)
        if self._n_cables is None:
            if not ml:
                raise ValueError("motor_length is empty: a robot has at least one cable")
            self._n_cables = len(ml)
        f = None if force is None else _part_or_null(
            _float_list(force, "force", self._n_cables)
        )
        if position is None and orientation is None:
            pose = None
        elif position is None or orientation is None:
            raise ValueError("position and orientation must be given together")
        else:
            pos = _float_list(position, "position", 3)
            ori = _float_list(orientation, "orientation", 4)
            # All non-finite: no pose (null), as write_mcap and the readers treat it.
            pose = None if _part_or_null(pos + ori) is None else {
                "position": pos, "orientation": ori
            }
        temp = None
        if temperature is not None:
            temp = float(temperature)
            if not math.isfinite(temp):
                temp = None
        data = _ENCODER.encode(
            {
                "seq": seq,
                "t": t,
                "pose": pose,
                "motor_length": ml,
                "force": f,
                "temperature": temp,
            }
        ).encode()
        self._writer.add_message(
            self._input_channel, log_time, data, log_time, seq & 0xFFFFFFFF
        )
        self.n_inputs += 1

    # ------------------------------------------------------------------ binary blocks
    def _new_block(self, m: int) -> None:
        b = _block_ticks(self._block_ticks, self._chunk_size, m)
        self._block = {
            "seq": np.empty(b, dtype=np.int64),
            "t": np.empty(b),
            "motor_length": np.empty((b, m)),
            "position": np.full((b, 3), np.nan),
            "orientation": np.full((b, 4), np.nan),
            "force": np.full((b, m), np.nan),
            "temperature": np.full(b, np.nan),
        }

    def _buffer_tick(self, seq, t, motor_length, force, position, orientation, temperature) -> None:
        """protobuf encoding: one tick into the block in progress (checked first, so a bad
        tick changes nothing); a full block is written."""
        ml = _row64(motor_length, "motor_length", self._n_cables)
        m = ml.shape[0]
        if m == 0:
            raise ValueError("motor_length is empty: a robot has at least one cable")
        f = None if force is None else _row64(force, "force", m)
        if (position is None) != (orientation is None):
            raise ValueError("position and orientation must be given together")
        pos = ori = None
        if position is not None:
            pos = _row64(position, "position", 3)
            ori = _row64(orientation, "orientation", 4)
        temp = None if temperature is None else float(temperature)
        if self._n_cables is None:
            self._n_cables = m
        if self._block is None:
            self._new_block(m)
        blk = self._block
        assert blk is not None
        i = self._bn
        blk["seq"][i] = seq
        blk["t"][i] = t
        blk["motor_length"][i] = ml
        if pos is not None:
            blk["position"][i] = pos
            blk["orientation"][i] = ori
            self._b_any[0] = True
        if f is not None:
            blk["force"][i] = f
            self._b_any[1] = True
        if temp is not None:
            blk["temperature"][i] = temp
            self._b_any[2] = True
        self._bn = i + 1
        self.n_inputs += 1
        if self._bn == blk["t"].shape[0]:
            self._emit_block()

    def _emit_block(self) -> None:
        """Write the block in progress (if any) as one message and start an empty one."""
        n, blk = self._bn, self._block
        if not n or blk is None:
            return
        any_pose, any_force, any_temp = self._b_any
        self._add_block(
            blk["seq"][:n], blk["t"][:n], blk["motor_length"][:n],
            blk["position"][:n] if any_pose else None,
            blk["orientation"][:n] if any_pose else None,
            blk["force"][:n] if any_force else None,
            blk["temperature"][:n] if any_temp else None,
        )
        if any_pose:
            blk["position"][:n] = np.nan
            blk["orientation"][:n] = np.nan
        if any_force:
            blk["force"][:n] = np.nan
        if any_temp:
            blk["temperature"][:n] = np.nan
        self._bn = 0
        self._b_any = [False, False, False]

    def _add_block(self, seq, t, ml, pos, ori, force, temp) -> None:
        log_time = round(float(t[0]) * 1e9)
        data = pb.encode_block(seq, t, ml, pos, ori, force, temp)
        self._writer.add_message(
            self._input_channel, log_time, data, log_time, int(seq[0]) & 0xFFFFFFFF
        )

    def write_inputs(
        self,
        seq: Any,
        t: Any,
        motor_length: Any,
        force: Any = None,
        position: Any = None,
        orientation: Any = None,
        temperature: Any = None,
    ) -> None:
        """Write ``N`` ticks at once from columns: ``seq`` (N,) integers, ``t`` (N,),
        ``motor_length`` (N, m), ``force`` (N, m), ``position`` (N, 3), ``orientation``
        (N, 4), ``temperature`` (N,); a part may be None (absent in every tick); NaN means
        missing, a row of a part that is all NaN is that part absent in that tick.

        protobuf encoding: the block in progress is written first, then whole blocks
        straight from the arrays (no per-tick Python work). json: one ``write_input`` per tick.
        """
        self._check_open()
        t = np.asarray(t, dtype=np.float64)
        seq_a = np.asarray(seq)
        ml = np.asarray(motor_length, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t must be 1-D (N,), has shape {t.shape}")
        n = t.shape[0]
        if seq_a.shape != (n,) or (n and seq_a.dtype.kind not in "iu"):
            raise ValueError(f"seq must be ({n},) integers, has shape {seq_a.shape}, dtype {seq_a.dtype}")
        if ml.ndim != 2 or ml.shape[0] != n:
            raise ValueError(f"motor_length has shape {ml.shape}, expected ({n}, m)")
        if n == 0:
            return
        m = ml.shape[1]
        if m == 0:
            raise ValueError("motor_length is empty: a robot has at least one cable")
        if self._n_cables is not None and m != self._n_cables:
            raise ValueError(f"motor_length has {m} values per tick, expected {self._n_cables}")
        if (position is None) != (orientation is None):
            raise ValueError("position and orientation must be given together")

        def col(a: Any, name: str, w: Optional[int]) -> Optional[np.ndarray]:
            if a is None:
                return None
            a = np.asarray(a, dtype=np.float64)
            want = (n,) if w is None else (n, w)
            if a.shape != want:
                raise ValueError(f"{name} has shape {a.shape}, expected {want}")
            return a

        f = col(force, "force", m)
        pos, ori = col(position, "position", 3), col(orientation, "orientation", 4)
        temp = col(temperature, "temperature", None)
        ok = np.isfinite(t) & (t >= 0.0) & (t <= _LOG_TIME_MAX_S)
        if not ok.all():
            i = int(np.argmin(ok))
            _log_time(float(t[i]))  # raises the writer's message
            raise ValueError(f"t[{i}] = {t[i]!r} s cannot be an MCAP log_time")
        if seq_a.dtype.kind == "u" and n and int(seq_a.max()) > _INT64_MAX:
            raise ValueError("seq does not fit in a signed 64-bit integer")
        seq_a = seq_a.astype(np.int64, copy=False)
        if self.encoding == "json":
            for i in range(n):
                p = q = None
                if pos is not None and not (np.isnan(pos[i]).all() and np.isnan(ori[i]).all()):
                    p, q = pos[i], ori[i]
                fi = None if f is None or np.isnan(f[i]).all() else f[i]
                ti = None if temp is None else float(temp[i])
                self.write_input(int(seq_a[i]), float(t[i]), ml[i], fi, p, q, ti)
            return
        self._emit_block()
        if self._n_cables is None:
            self._n_cables = m
        b = _block_ticks(self._block_ticks, self._chunk_size, m)
        for i in range(0, n, b):
            j = min(i + b, n)
            self._add_block(
                seq_a[i:j], t[i:j], ml[i:j],
                None if pos is None else pos[i:j], None if ori is None else ori[i:j],
                None if f is None else f[i:j], None if temp is None else temp[i:j],
            )
            self.n_inputs += j - i

    # ------------------------------------------------------------------ other topics
    def register_topic(
        self,
        topic: str,
        schema_name: Optional[str] = None,
        json_schema: Optional[dict] = None,
    ) -> int:
        """Register a JSON topic besides the input; return its channel id.

        For the documented output topics (``OUTPUT_TOPICS``: ``/cablesvc/forces``,
        ``/cablesvc/alarms``) schema name and schema may be left out. Registering a topic
        again with the same schema returns the same channel id.
        """
        self._check_open()
        if topic == INPUT_TOPIC:
            raise ValueError(f"{INPUT_TOPIC} is written with write_input()")
        if schema_name is None and json_schema is None and topic in OUTPUT_TOPICS:
            schema_name, json_schema = OUTPUT_TOPICS[topic]
        if not schema_name or json_schema is None:
            raise ValueError(f"topic {topic!r} needs a schema name and a JSON schema")
        if not isinstance(json_schema, dict):
            raise TypeError("json_schema must be a dict (a JSON Schema document)")
        data = json.dumps(json_schema).encode()
        if topic in self._channels:
            if self._schemas[topic] != (schema_name, data):
                raise ValueError(f"topic {topic!r} is already registered with another schema")
            return self._channels[topic]
        schema_id = self._writer.register_schema(schema_name, SCHEMA_ENCODING, data)
        channel_id = self._writer.register_channel(topic, MESSAGE_ENCODING, schema_id)
        self._channels[topic] = channel_id
        self._schemas[topic] = (schema_name, data)
        return channel_id

    def write(self, topic: str, t: float, payload: dict) -> None:
        """Write a JSON message on a registered topic (log_time = t in ns).

        The documented output topics are registered on first use. numpy arrays and scalars
        in ``payload`` are converted; non-finite floats are written as null.
        """
        self._check_open()
        channel = self._channels.get(topic)
        if channel is None or topic == INPUT_TOPIC:
            if topic == INPUT_TOPIC:
                raise ValueError(f"{INPUT_TOPIC} is written with write_input()")
            if topic not in OUTPUT_TOPICS:
                raise KeyError(f"topic {topic!r} is not registered (use register_topic)")
            channel = self.register_topic(topic)
        if not isinstance(payload, dict):
            raise TypeError("payload must be a dict (a JSON object)")
        log_time = _log_time(float(t))
        self._writer.add_message(channel, log_time, _encode_payload(payload), log_time)

    # ------------------------------------------------------------------ durability
    def flush(self, fsync: bool = False) -> None:
        """Finish the chunk in progress and hand everything written so far to the OS.

        After it returns, a ``kill -9`` of this process keeps every tick written before
        the call (the file then has no summary/footer; :func:`read_mcap` reads it and
        reports the loss). ``fsync=True`` also forces the data to the disk (survives power
        loss; costs a disk sync). Each flush closes a chunk, so flushing much more often
        than once a second makes the file larger (less compression, more index records).
        """
        self._check_open()
        flush = getattr(self._writer, "flush", None)
        if flush is None:  # mcap < 1.6 has no public way to finish a chunk
            raise RuntimeError("McapRecordingWriter.flush() needs mcap >= 1.6 (Writer.flush)")
        self._emit_block()
        flush()
        if fsync:
            self._file.fsync()

    def close(self) -> None:
        """Finish the last chunk, write the summary and footer, close the file. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            try:
                self._emit_block()
            finally:
                self._writer.finish()
        finally:
            self._file.close()

    @property
    def closed(self) -> bool:
        return self._closed


def write_mcap(
    path: PathArg,
    rec: Recording,
    *,
    robot: Optional[str] = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    encoding: str = DEFAULT_ENCODING,
    block_ticks: int = DEFAULT_BLOCK_TICKS,
) -> None:
    """Write a whole :class:`Recording` as MCAP.

    ``robot`` overrides ``rec.robot`` (needed when it is empty, e.g. a CSV without
    metadata). ``encoding``: ``"protobuf"`` (binary blocks, format 2, the default) or
    ``"json"`` (format 1). ``rec.extra`` payloads are written on their topics with log_time
    from their ``t`` field, each topic's payloads in their list order (the order a reader
    finds them in): a payload goes after the input tick (json) or block (protobuf) holding
    the same or the next smaller ``t``, but never before the payloads listed before it on
    its topic. The documented output topics get their schema, other topics a plain
    ``{"type": "object"}``.
    """
    _check_encoding(encoding)
    problems = rec.shape_problems()
    if problems:
        raise ValueError(f"{path}: cannot write recording: " + "; ".join(problems))
    robot = robot or rec.robot
    if not robot:
        raise ValueError(f"{path}: the recording has no robot name; pass robot=...")
    # One queue per topic, in the topic's own order (never re-sorted: a reader gets each
    # topic's payloads back in file order, so sorting by t would reorder them).
    queues: list[tuple[str, list[tuple[float, dict]]]] = []
    for topic, payloads in rec.extra.items():
        q = []
        for p in payloads:
            pt = p.get("t") if isinstance(p, dict) else None
            if not isinstance(pt, (int, float)) or isinstance(pt, bool):
                raise ValueError(f"{path}: extra payload on {topic} has no numeric 't'")
            q.append((float(pt), p))
        if q:
            queues.append((topic, q))
    heads = [0] * len(queues)

    if encoding == "protobuf":
        with McapRecordingWriter(path, robot, rec.metadata, chunk_size=chunk_size,
                                 encoding=encoding, block_ticks=block_ticks) as w:
            for topic in rec.extra:
                if topic in OUTPUT_TOPICS:
                    w.register_topic(topic)
                else:
                    w.register_topic(topic, topic, {"type": "object"})
            n = rec.n_ticks
            b = _block_ticks(block_ticks, chunk_size, max(rec.n_cables, 1))
            for i in range(0, n, b):
                j = min(i + b, n)
                w.write_inputs(
                    rec.seq[i:j], rec.t[i:j], rec.motor_length[i:j],
                    None if rec.force is None else rec.force[i:j],
                    None if not rec.has_pose else rec.position[i:j],  # type: ignore[index]
                    None if not rec.has_pose else rec.orientation[i:j],  # type: ignore[index]
                    None if rec.temperature is None else rec.temperature[i:j],
                )
                t_last = float(rec.t[j - 1])
                for k, (topic, q) in enumerate(queues):
                    h = heads[k]
                    while h < len(q) and q[h][0] <= t_last:
                        w.write(topic, q[h][0], q[h][1])
                        h += 1
                    heads[k] = h
            _write_rest(w, queues, heads)
        return

    n = rec.n_ticks
    t = rec.t.tolist()
    seq = rec.seq.tolist()
    ml = rec.motor_length.tolist()
    pos = rec.position.tolist() if rec.position is not None else None
    ori = rec.orientation.tolist() if rec.orientation is not None else None
    force = rec.force.tolist() if rec.force is not None else None
    temp = rec.temperature.tolist() if rec.temperature is not None else None

    def all_nan(row: list) -> bool:
        return all(v != v for v in row)

    with McapRecordingWriter(path, robot, rec.metadata, chunk_size=chunk_size, encoding="json") as w:
        for topic in rec.extra:
            if topic in OUTPUT_TOPICS:
                w.register_topic(topic)
            else:
                w.register_topic(topic, topic, {"type": "object"})
        for i in range(n):
            p = q = None
            if pos is not None and ori is not None and not (
                all_nan(pos[i]) and all_nan(ori[i])
            ):
                p, q = pos[i], ori[i]
            f = None
            if force is not None and not all_nan(force[i]):
                f = force[i]
            w.write_input(
                seq[i], t[i], ml[i], f, p, q, None if temp is None else temp[i]
            )
            for k, (topic, q) in enumerate(queues):
                h = heads[k]
                while h < len(q) and q[h][0] <= t[i]:
                    w.write(topic, q[h][0], q[h][1])
                    h += 1
                heads[k] = h
        _write_rest(w, queues, heads)


def _write_rest(w: McapRecordingWriter, queues: list, heads: list) -> None:
    """The extra payloads after the last input, merged by t at the heads of the queues."""
    while True:
        live = [k for k in range(len(queues)) if heads[k] < len(queues[k][1])]
        if not live:
            break
        k = min(live, key=lambda k: queues[k][1][heads[k]][0])
        pt, payload = queues[k][1][heads[k]]
        w.write(queues[k][0], pt, payload)
        heads[k] += 1


# ===================================================================== reading helpers
class _Bounded:
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
class _Layout:
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


def _layout(f: BinaryIO, size: int) -> _Layout:
    """Find whether the file is complete; if not, where its last complete record ends."""
    if size >= 8 + 9 + _FOOTER_RECORD_BYTES + 8:
        f.seek(size - 8)
        if f.read(8) == MCAP_MAGIC:
            f.seek(size - 8 - _FOOTER_RECORD_BYTES)
            opcode, length = struct.unpack("<BQ", f.read(9))
            if opcode == Opcode.FOOTER and length == _FOOTER_RECORD_BYTES - 9:
                return _Layout(size=size, usable=size, complete=True)
    pos = 8
    data_end = False
    chunks = 0
    while True:
        if pos == size:
            return _Layout(size, pos, False, data_end, chunks)
        if pos + 9 > size:
            return _Layout(
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
            return _Layout(
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
            return _Layout(size, end, False, True, chunks)
        pos = end


def _jtype(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "an object"
    return type(v).__name__


class _BadField(Exception):
    def __init__(self, name: str, reason: str):
        super().__init__(name, reason)
        self.name = name
        self.reason = reason


def _numbers(v: Any, name: str, n: Optional[int], why: str = "") -> list:
    if type(v) is not list:
        raise _BadField(name, f"expected an array of numbers, got {_jtype(v)}")
    if n is not None and len(v) != n:
        raise _BadField(name, f"has {len(v)} values, expected {n}{why}")
    for i, x in enumerate(v):
        tx = type(x)
        if tx is int:
            v[i] = _to_float(x, f"{name}[{i}]")
        elif tx is not float and x is not None:
            raise _BadField(f"{name}[{i}]", f"expected a number or null, got {_jtype(x)}")
    return v


def _to_float(x: int, name: str) -> float:
    """A JSON integer literal as a float; one beyond the float range is a bad field."""
    try:
        return float(x)
    except OverflowError:
        raise _BadField(
            name, f"integer of {x.bit_length()} bits is too large for a 64-bit float "
            "(beyond +-1.8e308)"
        ) from None


def _absent(v: list) -> bool:
    return all(x is None or x != x for x in v)


_MISSING = object()
#: ``messages()`` yields ``(BLOCK, decoded block)`` for a ``cablesvc.InputBlock`` message.
BLOCK = "\x00block"


class _McapSource:
    """An open MCAP recording: layout, metadata, and a file-order message iterator."""

    def __init__(
        self,
        path: PathArg,
        robot_cables: Optional[int] = None,
        keep_topics: Iterable[str] = (),
    ):
        self.path = str(path)
        self.robot_cables = robot_cables
        self.keep_topics = frozenset(keep_topics) - {INPUT_TOPIC}
        self.summary_topics: Optional[set[str]] = None
        # input messages per encoding from the summary statistics (a capacity hint only)
        self.summary_inputs: dict[str, int] = {}
        try:
            self._f: BinaryIO = open(path, "rb")
        except FileNotFoundError:
            raise RecordingError(path, "file", "no such file") from None
        except OSError as e:
            raise RecordingError(path, "file", f"cannot open: {e.strerror or e}") from None
        try:
            size = os.fstat(self._f.fileno()).st_size
            if size == 0:
                raise RecordingError(path, "file", "empty file (0 bytes): not an MCAP file")
            head = self._f.read(8)
            if head != MCAP_MAGIC:
                hint = ""
                if head and all(32 <= b < 127 or b in (9, 10, 13) for b in head):
                    hint = " (it looks like text; CSV recordings need the .csv suffix)"
                raise RecordingError(
                    path,
                    "byte 0",
                    f"not an MCAP file: it starts with {head!r}, not the MCAP magic "
                    f"{MCAP_MAGIC!r}{hint}",
                )
            self.layout = _layout(self._f, size)
            self.metadata = self._read_metadata()
        except BaseException:
            self._f.close()
            raise
        self.robot = self.metadata["robot"]
        self.other_metadata = {
            k: v for k, v in self.metadata.items() if k not in ("robot", "format")
        }
        self.n_cables = robot_cables
        self.input_channels = 0
        self.topics: set[str] = set()
        self.n_inputs = 0
        self.first: Optional[tuple[int, float]] = None
        self.last: Optional[tuple[int, float]] = None

    def close(self) -> None:
        self._f.close()

    def _truncated_hint(self) -> str:
        L = self.layout
        if L.complete:
            return ""
        return f" (the file is incomplete: only {L.usable:,} of {L.size:,} bytes are usable)"

    def _corrupt(self, pos: int, e: BaseException) -> RecordingError:
        return RecordingError(
            self.path, f"near byte {pos:,}", f"corrupt MCAP data: {type(e).__name__}: {e}"
        )

    def _read_metadata(self) -> dict[str, str]:
        records: list[Metadata] = []
        if self.layout.complete:
            try:
                self._f.seek(0)
                reader = make_reader(self._f)
                summary = reader.get_summary()
                if summary is not None:
                    if summary.channels:
                        self.summary_topics = {c.topic for c in summary.channels.values()}
                        counts = (
                            summary.statistics.channel_message_counts
                            if summary.statistics is not None else {}
                        )
                        for c in summary.channels.values():
                            if c.topic == INPUT_TOPIC and c.id in counts:
                                enc = c.message_encoding
                                self.summary_inputs[enc] = (
                                    self.summary_inputs.get(enc, 0) + counts[c.id]
                                )
                    if summary.metadata_indexes:
                        records = list(reader.iter_metadata())
            except (McapError, struct.error, ValueError, OSError):
                records = []  # a damaged summary: fall back to the linear scan below
                self.summary_topics = None
                self.summary_inputs = {}
        if not any(r.name == METADATA_NAME for r in records):
            records = self._scan_metadata()
        found = [r for r in records if r.name == METADATA_NAME]
        if not found:
            names = sorted({r.name for r in records})
            have = (
                f"its metadata records are named {names}"
                if names
                else "it has no metadata records"
            )
            raise RecordingError(
                self.path,
                "metadata",
                f"no metadata record named {METADATA_NAME!r} ({have}); formats "
                f"{FORMAT_VERSION} and {BLOCK_FORMAT_VERSION} require one with 'robot' and 'format'"
                + self._truncated_hint(),
            )
        md = dict(found[0].metadata)
        where = f"metadata record {METADATA_NAME!r}"
        for key in ("robot", "format"):
            if key not in md:
                raise RecordingError(
                    self.path, where, f"missing key {key!r} (it has {sorted(md)})"
                )
        if md["format"] not in {str(v) for v in MCAP_FORMAT_VERSIONS}:
            raise RecordingError(
                self.path,
                f"{where}, key 'format'",
                f"format {md['format']!r} is not supported: this cablesvc reads formats "
                + " and ".join(str(v) for v in MCAP_FORMAT_VERSIONS),
            )
        if (
            self.summary_topics is not None
            and INPUT_TOPIC not in self.summary_topics
        ):
            raise RecordingError(
                self.path,
                INPUT_TOPIC,
                f"no channel on topic {INPUT_TOPIC} (topics in the file: "
                f"{sorted(self.summary_topics)})",
            )
        return md

    def _scan_metadata(self) -> list[Metadata]:
        """Linear scan for metadata records (chunks are skipped, not decompressed)."""
        bounded = _Bounded(self._f, 0, self.layout.usable)
        out: list[Metadata] = []
        records = StreamReader(bounded, emit_chunks=True).records  # type: ignore[arg-type]
        while True:
            try:
                rec = next(records)
            except StopIteration:
                break
            except EndOfFile:
                if bounded.pos >= bounded.limit:
                    break
                raise self._corrupt(bounded.pos, EOFError("unexpected end")) from None
            except Exception as e:  # the library's parser on damaged bytes
                raise self._corrupt(bounded.pos, e) from e
            if isinstance(rec, Metadata):
                out.append(rec)
                if rec.name == METADATA_NAME:
                    break
            elif isinstance(rec, DataEnd):
                break
        return out

    # ---------------------------------------------------------------- messages
    def messages(self) -> Iterator[tuple[Optional[str], Any]]:
        """Yield ``(None, parsed input tuple)`` (json), ``(BLOCK, decoded block)``
        (protobuf) and ``(topic, payload)`` in file order."""
        bounded = _Bounded(self._f, 0, self.layout.usable)
        records = StreamReader(bounded, validate_crcs=True).records  # type: ignore[arg-type]
        channels: dict[int, Channel] = {}
        schemas: dict[int, Schema] = {}
        input_ids: set[int] = set()
        block_ids: set[int] = set()
        blocks = 0
        keep_ids: dict[int, str] = {}
        kept_index: dict[str, int] = defaultdict(int)
        k = 0
        while True:
            try:
                rec = next(records)
            except StopIteration:
                break
            except EndOfFile:
                if bounded.pos >= bounded.limit and not self.layout.complete:
                    break
                raise self._corrupt(bounded.pos, EOFError("unexpected end of data")) from None
            except Exception as e:  # the library's parser on damaged bytes
                raise self._corrupt(bounded.pos, e) from e
            if isinstance(rec, Message):
                cid = rec.channel_id
                if cid in block_ids:
                    blk = self._parse_block(rec.data, k, blocks)
                    k += blk["n"]
                    blocks += 1
                    yield BLOCK, blk
                elif cid in input_ids:
                    tick = self._parse_input(rec.data, k)
                    k += 1
                    yield None, tick
                elif cid in keep_ids:
                    topic = keep_ids[cid]
                    i = kept_index[topic]
                    kept_index[topic] += 1
                    try:
                        payload = json.loads(rec.data)
                    except ValueError as e:
                        raise RecordingError(
                            self.path, f"message {i} on {topic}", f"not valid JSON: {e}"
                        ) from None
                    except RecursionError:
                        raise RecordingError(
                            self.path, f"message {i} on {topic}", "JSON nested too deeply"
                        ) from None
                    yield topic, payload
                elif cid not in channels:
                    raise RecordingError(
                        self.path,
                        f"near byte {bounded.pos:,}",
                        f"message on channel id {cid}, which has no channel record before it",
                    )
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
                self.topics.add(rec.topic)
                if rec.topic == INPUT_TOPIC and rec.message_encoding == pb.MESSAGE_ENCODING:
                    self._check_block_channel(rec, schemas.get(rec.schema_id))
                    block_ids.add(rec.id)
                    self.input_channels += 1
                elif rec.topic == INPUT_TOPIC or rec.topic in self.keep_topics:
                    if rec.message_encoding != MESSAGE_ENCODING:
                        also = (
                            f" (inputs: or {pb.MESSAGE_ENCODING!r} with schema "
                            f"{pb.SCHEMA_NAME!r}, format {BLOCK_FORMAT_VERSION})"
                            if rec.topic == INPUT_TOPIC else ""
                        )
                        raise RecordingError(
                            self.path,
                            f"channel {rec.id} ({rec.topic})",
                            f"message encoding {rec.message_encoding!r}; format "
                            f"{FORMAT_VERSION} uses {MESSAGE_ENCODING!r}{also}",
                        )
                    if rec.topic == INPUT_TOPIC:
                        input_ids.add(rec.id)
                        self.input_channels += 1
                    else:
                        keep_ids[rec.id] = rec.topic
            elif isinstance(rec, DataEnd):
                break

    def _check_block_channel(self, ch: Channel, schema: Optional[Schema]) -> None:
        where = f"channel {ch.id} ({ch.topic})"
        if self.metadata["format"] != str(BLOCK_FORMAT_VERSION):
            raise RecordingError(
                self.path, where,
                f"message encoding {ch.message_encoding!r} needs format "
                f"{BLOCK_FORMAT_VERSION}, but the file says format {self.metadata['format']!r} "
                f"(format {FORMAT_VERSION} inputs are {MESSAGE_ENCODING!r})",
            )
        if schema is None or schema.name != pb.SCHEMA_NAME or schema.encoding != pb.SCHEMA_ENCODING:
            have = (
                "no schema record before it" if schema is None
                else f"schema {schema.name!r} ({schema.encoding!r})"
            )
            raise RecordingError(
                self.path, where,
                f"{pb.MESSAGE_ENCODING!r} inputs need the schema {pb.SCHEMA_NAME!r} with "
                f"encoding {pb.SCHEMA_ENCODING!r}; the channel has {have}",
            )

    def _parse_block(self, data: bytes, k: int, b: int) -> dict:
        try:
            blk = pb.decode_block(data, self.n_cables)
        except pb.BlockError as e:
            if e.field == "cables" and self.n_cables is not None:
                why = (
                    f" (the robot has {self.n_cables} cables)"
                    if self.robot_cables is not None
                    else " (the first block fixed the cable count)"
                )
                e = pb.BlockError(e.field, e.reason + why)
            reason = f"field {e.field!r}: {e.reason}" if e.field else e.reason
            raise RecordingError(
                self.path, f"message {k} on {INPUT_TOPIC}",
                f"block {b} is not a valid {pb.SCHEMA_NAME}: {reason}",
            ) from None
        t = blk["t"]
        fin = np.isfinite(t)
        if not fin.all():
            i = int(np.argmin(fin))
            raise RecordingError(
                self.path, f"message {k + i} on {INPUT_TOPIC}",
                f"field 't': must be finite, got {float(t[i])!r} (block {b}, tick {i})",
            )
        if self.n_cables is None:
            self.n_cables = blk["m"]
        if self.first is None:
            self.first = (int(blk["seq"][0]), float(t[0]))
        self.last = (int(blk["seq"][-1]), float(t[-1]))
        self.n_inputs += blk["n"]
        return blk

    def _parse_input(self, data: bytes, k: int) -> tuple:
        try:
            try:
                obj = json.loads(data)
            except ValueError as e:
                raise _BadField("", f"not valid JSON: {e}") from None
            except RecursionError:
                raise _BadField("", "not valid JSON for format 1: nested too deeply") from None
            if type(obj) is not dict:
                raise _BadField("", f"expected a JSON object, got {_jtype(obj)}")
            seq = obj.get("seq", _MISSING)
            if seq is _MISSING:
                raise _BadField("seq", "missing required field")
            if type(seq) is not int:
                raise _BadField("seq", f"expected an integer, got {_jtype(seq)} ({seq!r})")
            if not _INT64_MIN <= seq <= _INT64_MAX:
                raise _BadField("seq", f"{seq} does not fit in 64 bits")
            t = obj.get("t", _MISSING)
            if t is _MISSING:
                raise _BadField("t", "missing required field")
            if type(t) is int:
                t = _to_float(t, "t")
            elif type(t) is not float:
                raise _BadField("t", f"expected a number, got {_jtype(t)}")
            if not math.isfinite(t):
                raise _BadField("t", f"must be finite, got {t!r}")
            ml = obj.get("motor_length", _MISSING)
            if ml is _MISSING:
                raise _BadField("motor_length", "missing required field")
            if self.n_cables is None:
                ml = _numbers(ml, "motor_length", None)
                if not ml:
                    raise _BadField("motor_length", "is empty (a robot has at least 1 cable)")
                self.n_cables = len(ml)
            else:
                why = (
                    f" (the robot has {self.n_cables} cables)"
                    if self.robot_cables is not None
                    else f" (message 0 had {self.n_cables})"
                )
                ml = _numbers(ml, "motor_length", self.n_cables, why)
            pose = obj.get("pose")
            position = orientation = None
            if pose is not None:
                if type(pose) is not dict:
                    raise _BadField("pose", f"expected an object or null, got {_jtype(pose)}")
                for part in ("position", "orientation"):
                    if part not in pose:
                        raise _BadField(
                            f"pose.{part}", "missing (pose needs position and orientation)"
                        )
                position = _numbers(pose["position"], "pose.position", 3)
                orientation = _numbers(pose["orientation"], "pose.orientation", 4)
                if _absent(position) and _absent(orientation):
                    position = orientation = None
            force = obj.get("force")
            if force is not None:
                force = _numbers(
                    force, "force", self.n_cables, " (one per cable, like motor_length)"
                )
                if _absent(force):
                    force = None
            temp = obj.get("temperature")
            if temp is not None:
                if type(temp) is not float and type(temp) is not int:
                    raise _BadField(
                        "temperature", f"expected a number or null, got {_jtype(temp)}"
                    )
                temp = _to_float(temp, "temperature") if type(temp) is int else temp
                if temp != temp:
                    temp = None
        except _BadField as e:
            reason = f"field {e.name!r}: {e.reason}" if e.name else e.reason
            raise RecordingError(self.path, f"message {k} on {INPUT_TOPIC}", reason) from None
        if self.first is None:
            self.first = (seq, t)
        self.last = (seq, t)
        self.n_inputs += 1
        return seq, t, position, orientation, ml, force, temp

    def check_input_channel(self) -> None:
        """A complete file must have the input channel; an incomplete one may have lost it."""
        if self.input_channels == 0 and self.layout.complete:
            raise RecordingError(
                self.path,
                INPUT_TOPIC,
                f"no channel on topic {INPUT_TOPIC} (topics in the file: {sorted(self.topics)})",
            )

    def truncation(self) -> Optional[Truncation]:
        L = self.layout
        if L.complete:
            return None
        lost_range = None
        if L.partial_t_ns is not None:
            lost_range = (L.partial_t_ns[0] / 1e9, L.partial_t_ns[1] / 1e9)
        parts = [
            f"{self.path} is incomplete: it has no summary/footer (the writer did not close "
            "it: process killed, disk full or copy cut short).",
            f"Read {L.usable:,} of {L.size:,} bytes ({L.chunks} complete chunks);"
            f" recovered {self.n_inputs} ticks",
        ]
        if self.first is not None and self.last is not None:
            parts[-1] += (
                f" (seq {self.first[0]}..{self.last[0]}, t {self.first[1]:.6g}.."
                f"{self.last[1]:.6g} s)."
            )
        else:
            parts[-1] += "."
        if L.data_end_seen:
            parts.append(
                "All data records are complete (only the summary/footer is missing or cut): "
                "no ticks were lost."
            )
        elif L.partial is not None:
            lost = f"Lost: {L.partial}"
            if lost_range is not None:
                lost += f", holding ticks with t {lost_range[0]:.6g}..{lost_range[1]:.6g} s"
                if self.first is not None and self.last is not None and self.n_inputs > 1:
                    dt = (self.last[1] - self.first[1]) / (self.n_inputs - 1)
                    if dt > 0:
                        est = round((lost_range[1] - lost_range[0]) / dt) + 1
                        lost += f" (about {est} ticks)"
            parts.append(lost + ", and anything the writer wrote after it.")
        else:
            parts.append(
                "The file ends after a complete record (the writer stopped after a flush or "
                "a finished chunk): ticks it had not yet written out were lost; the file "
                "does not record how many."
            )
        return Truncation(
            file_bytes=L.size,
            usable_bytes=L.usable,
            complete_chunks=L.chunks,
            data_complete=L.data_end_seen,
            partial_record=L.partial,
            lost_t_range=lost_range,
            message=" ".join(parts),
        )


def _as_tick(parsed: tuple) -> Tick:
    seq, t, position, orientation, ml, force, temp = parsed
    f64 = np.float64
    return Tick(
        seq=seq,
        t=t,
        position=None if position is None else np.array(position, dtype=f64),
        orientation=None if orientation is None else np.array(orientation, dtype=f64),
        motor_length=np.array(ml, dtype=f64),
        force=None if force is None else np.array(force, dtype=f64),
        temperature=temp,
    )


def _block_ticks_of(blk: dict) -> Iterator[Tick]:
    """The ticks of a decoded block, as the JSON reader yields them (own arrays; an
    all-NaN pose/force/temperature is None)."""
    n = blk["n"]
    seq = blk["seq"].tolist()
    t = blk["t"].tolist()
    ml = blk["motor_length"]
    pos, ori, force, temp = blk["position"], blk["orientation"], blk["force"], blk["temperature"]
    has_pose = has_force = [False] * n
    if pos is not None:
        has_pose = (~(np.isnan(pos).all(axis=1) & np.isnan(ori).all(axis=1))).tolist()
    if force is not None:
        has_force = (~np.isnan(force).all(axis=1)).tolist()
    temps: list = [None] * n
    if temp is not None:
        temps = [None if v != v else v for v in temp.tolist()]
    for i in range(n):
        yield Tick(
            seq=seq[i],
            t=t[i],
            position=pos[i].copy() if has_pose[i] else None,
            orientation=ori[i].copy() if has_pose[i] else None,
            motor_length=ml[i].copy(),
            force=force[i].copy() if has_force[i] else None,
            temperature=temps[i],
        )


# ===================================================================== public readers
def read_mcap(
    path: PathArg,
    *,
    robot_cables: Optional[int] = None,
    keep_topics: Iterable[str] = (),
) -> Recording:
    """Read a format-1 MCAP recording into a :class:`Recording`.

    ``robot_cables``: when given, every tick must have that many cables. ``keep_topics``:
    other JSON topics to decode into ``Recording.extra`` (all other topics are ignored).
    An incomplete file is read up to its last complete record; ``Recording.truncation``
    describes the loss and a :class:`RecordingTruncatedWarning` is issued.
    Raises :class:`RecordingError` naming the file, the place and the reason.
    """
    src = _McapSource(path, robot_cables, keep_topics)
    try:
        cols = TickColumns(robot_cables)
        extra: dict[str, list] = {topic: [] for topic in sorted(src.keep_topics)}
        append = cols.append
        hinted = False
        for topic, item in src.messages():
            if topic is None:
                if not hinted:
                    hinted = True
                    cols.reserve(src.summary_inputs.get(MESSAGE_ENCODING, 0))
                append(*item)
            elif topic is BLOCK:
                if not hinted:
                    # one allocation of the right size instead of growing the columns (fresh
                    # memory is what costs: every byte of a grown copy is faulted in again);
                    # the statistics count messages, so blocks like the first one are assumed
                    hinted = True
                    cols.reserve(
                        src.summary_inputs.get(MESSAGE_ENCODING, 0)
                        + src.summary_inputs.get(pb.MESSAGE_ENCODING, 0) * item["n"]
                    )
                cols.add_block(item)
            else:
                extra[topic].append(item)
        src.check_input_channel()
        if cols.n_cables is None and src.n_cables is not None:
            cols.n_cables = src.n_cables
        trunc = src.truncation()
    finally:
        src.close()
    rec = cols.build(src.robot, src.other_metadata, extra=extra, truncation=trunc)
    if trunc is not None:
        warnings.warn(RecordingTruncatedWarning(trunc.message), stacklevel=2)
    return rec


def iter_mcap_inputs(path: PathArg, *, robot_cables: Optional[int] = None) -> Iterator[Tick]:
    """Stream the ticks of ``/cablesvc/input`` in file order (one chunk in memory at a time).

    The file, its metadata and format are checked before this returns; message errors
    are raised while iterating. An incomplete file ends with a
    :class:`RecordingTruncatedWarning` after its last complete tick.
    """
    src = _McapSource(path, robot_cables)
    return _iter_ticks(src)


def _iter_ticks(src: _McapSource) -> Iterator[Tick]:
    try:
        for topic, item in src.messages():
            if topic is None:
                yield _as_tick(item)
            elif topic is BLOCK:
                yield from _block_ticks_of(item)
        src.check_input_channel()
        trunc = src.truncation()
    finally:
        src.close()
    if trunc is not None:
        warnings.warn(RecordingTruncatedWarning(trunc.message), stacklevel=2)


def read_mcap_metadata(path: PathArg) -> dict[str, str]:
    """The ``cablesvc`` metadata record (including ``robot`` and ``format``), checked."""
    src = _McapSource(path)
    src.close()
    return dict(src.metadata)
