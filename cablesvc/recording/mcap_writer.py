"""MCAP side of recording formats 1 and 2, writing: :class:`McapRecordingWriter` (tick by
tick, for the live service, the simulator and convert) and :func:`write_mcap` (a whole
:class:`~cablesvc.recording.format.Recording`).

Input encodings
    ``protobuf`` (format 2, the default): one ``cablesvc.InputBlock`` message per block of
    up to 1000 ticks, packed little-endian arrays (``protobuf_block.py``); the writer holds
    the block in progress and writes it when full, on ``flush()`` and on ``close()``.
    ``json`` (format 1): one JSON message per tick (``mcap_json.py``).

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
    The reading side is ``mcap_reader.py``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Optional

import numpy as np
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .. import __version__
from . import protobuf_block as pb
from .format import (BLOCK_FORMAT_VERSION, ENCODINGS, FORMAT_VERSION, INT64_MAX, METADATA_NAME, PathArg, Recording,
                     check_seq)
from .mcap_json import encode_input, encode_payload, float_list
from .schemas import (
    INPUT_JSON_SCHEMA,
    INPUT_SCHEMA_NAME,
    INPUT_TOPIC,
    MESSAGE_ENCODING,
    OUTPUT_TOPICS,
    SCHEMA_ENCODING,
)

#: Default chunk size (uncompressed bytes). At 1 kHz with 8 cables (~300 B per tick) a chunk
#: fills in about 0.9 s, which bounds what a kill -9 loses when nobody calls ``flush()``.
DEFAULT_CHUNK_SIZE = 256 * 1024
LOG_TIME_MAX_S = (2**64 - 1) / 1e9
_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}

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


def _log_time(t: float) -> int:
    ns = round(t * 1e9) if 0.0 <= t <= LOG_TIME_MAX_S else -1
    if not 0 <= ns < 2**64:  # t at the very top rounds up to 2**64
        raise ValueError(
            f"t = {t!r} s cannot be an MCAP log_time (unsigned 64-bit ns): need 0 <= t < "
            f"{LOG_TIME_MAX_S:.4g} and finite"
        )
    return ns



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
    def write_input(self, seq: int, t: float, motor_length: Any, force: Any = None, position: Any = None,
                    orientation: Any = None, temperature: Optional[float] = None) -> None:
        """Write one tick on ``/cablesvc/input`` (log_time = t in ns).

        Arrays may be numpy arrays or sequences; non-finite values are written as null,
        and a pose (force) whose values are all non-finite as a null pose (force).
        ``position`` and ``orientation`` ([qx, qy, qz, qw]) go together (both or neither).
        ``seq`` must fit in a signed 64-bit integer.
        The first tick fixes the cable count; later ticks must match it.
        """
        self._check_open()
        seq = check_seq(seq)
        t = float(t)
        log_time = _log_time(t)
        if self.encoding == "protobuf":
            self._buffer_tick(seq, t, motor_length, force, position, orientation, temperature)
            return
        ml = float_list(motor_length, "motor_length", self._n_cables)
        if self._n_cables is None:
            if not ml:
                raise ValueError("motor_length is empty: a robot has at least one cable")
            self._n_cables = len(ml)
        data = encode_input(seq, t, ml, force, position, orientation, temperature, self._n_cables)
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

    def write_inputs(self, seq: Any, t: Any, motor_length: Any, force: Any = None, position: Any = None,
                     orientation: Any = None, temperature: Any = None) -> None:
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
        ok = np.isfinite(t) & (t >= 0.0) & (t <= LOG_TIME_MAX_S)
        if not ok.all():
            i = int(np.argmin(ok))
            _log_time(float(t[i]))  # raises the writer's message
            raise ValueError(f"t[{i}] = {t[i]!r} s cannot be an MCAP log_time")
        if seq_a.dtype.kind == "u" and n and int(seq_a.max()) > INT64_MAX:
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
        self._writer.add_message(channel, log_time, encode_payload(payload), log_time)

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

