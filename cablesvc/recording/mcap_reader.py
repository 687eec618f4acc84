"""MCAP side of recording formats 1 and 2, reading: :func:`read_mcap`,
:func:`iter_mcap_inputs`, :func:`read_mcap_metadata` and :class:`McapSource` (an open file,
its metadata and a file-order message iterator; :mod:`.chunks` reads through it too).

Input encodings
    ``protobuf`` (format 2): ``cablesvc.InputBlock`` messages (``protobuf_block.py``);
    ``json`` (format 1): one JSON message per tick (``mcap_json.py``). The reader tells them
    apart by the input channel's message encoding and reads both, also in one file.

Reading
    A complete file (footer and closing magic present) is read with its summary: the
    ``cablesvc`` metadata record is found through the metadata index and the channel table
    says up front whether ``/cablesvc/input`` exists. The messages are then read in *file
    order* with mcap's streaming ``StreamReader``, one chunk in memory at a time. (mcap's
    ``SeekingReader.iter_messages`` either re-sorts by log time, which is not file order
    when ``t`` is not monotonic, or, with ``log_time_order=False``, decompresses every chunk
    before yielding the first message.)

    A file without footer (writer killed, disk full, copy cut short) is walked record by
    record from the start to find the end of the last complete record (``mcap_layout.py``);
    the complete prefix is read the same way and :class:`~cablesvc.recording.format.Truncation`
    (also issued as a :class:`~cablesvc.recording.format.RecordingTruncatedWarning`) says
    what was lost: the partial chunk's time range, when its header survived, and an estimate
    of its ticks. The writing side is ``mcap_writer.py``.
"""

from __future__ import annotations

import json
import os
import struct
import warnings
from collections import defaultdict
from typing import Any, BinaryIO, Iterable, Iterator, Optional

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from mcap.records import Channel, DataEnd, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from . import protobuf_block as pb
from .format import (
    BLOCK_FORMAT_VERSION,
    FORMAT_VERSION,
    MCAP_FORMAT_VERSIONS,
    METADATA_NAME,
    PathArg,
    Recording,
    RecordingError,
    RecordingTruncatedWarning,
    Tick,
    TickColumns,
    Truncation,
    open_recording,
)
from .mcap_json import BadField, parse_input
from .mcap_layout import MCAP_MAGIC, Bounded, layout
from .schemas import INPUT_TOPIC, MESSAGE_ENCODING

#: ``messages()`` yields ``(BLOCK, decoded block)`` for a ``cablesvc.InputBlock`` message.
BLOCK = "\x00block"


class McapSource:
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
        self._f: BinaryIO = open_recording(path)
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
            self.layout = layout(self._f, size)
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

    def _records(self, end_ok: bool, end_what: str, bounded: Optional[Bounded] = None,
                 **stream_opts: bool) -> Iterator[Any]:
        """The records of the file's usable part in file order (mcap's ``StreamReader`` with
        ``stream_opts``). Damaged bytes are a :class:`RecordingError` naming the byte; so is
        an end of data inside a record, unless it is where the usable part ends and
        ``end_ok``."""
        if bounded is None:
            bounded = Bounded(self._f, 0, self.layout.usable)
        records = StreamReader(bounded, **stream_opts).records  # type: ignore[arg-type]
        while True:
            try:
                rec = next(records)
            except StopIteration:
                return
            except EndOfFile:
                if bounded.pos >= bounded.limit and end_ok:
                    return
                raise self._corrupt(bounded.pos, EOFError(end_what)) from None
            except Exception as e:  # the library's parser on damaged bytes
                raise self._corrupt(bounded.pos, e) from e
            yield rec

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
        out: list[Metadata] = []
        for rec in self._records(True, "unexpected end", emit_chunks=True):
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
        bounded = Bounded(self._f, 0, self.layout.usable)
        channels: dict[int, Channel] = {}
        schemas: dict[int, Schema] = {}
        input_ids: set[int] = set()
        block_ids: set[int] = set()
        blocks = 0
        keep_ids: dict[int, str] = {}
        kept_index: dict[str, int] = defaultdict(int)
        k = 0
        for rec in self._records(not self.layout.complete, "unexpected end of data", bounded,
                                 validate_crcs=True):
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
            parsed = parse_input(data, self.n_cables, self.robot_cables)
        except BadField as e:
            reason = f"field {e.name!r}: {e.reason}" if e.name else e.reason
            raise RecordingError(self.path, f"message {k} on {INPUT_TOPIC}", reason) from None
        seq, t = parsed[0], parsed[1]
        if self.n_cables is None:
            self.n_cables = len(parsed[4])
        if self.first is None:
            self.first = (seq, t)
        self.last = (seq, t)
        self.n_inputs += 1
        return parsed

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
    src = McapSource(path, robot_cables, keep_topics)
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
    src = McapSource(path, robot_cables)
    return _iter_ticks(src)


def _iter_ticks(src: McapSource) -> Iterator[Tick]:
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
    src = McapSource(path)
    src.close()
    return dict(src.metadata)
