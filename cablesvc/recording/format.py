"""Recording formats 1 and 2 (specified in ``docs/recording-format.md``): what both file
formats share.

A recording holds what a cable robot's controller saw, one record per control tick. This
module holds the format versions, the in-memory :class:`Recording` (columnar numpy arrays
for a whole file) and :class:`TickColumns` (its builder), the tick type and the error type.
It imports no other module of the package: the MCAP topics and their JSON schemas are in
``schemas.py``, the readers and writers in ``csv_io.py``, ``mcap_reader.py`` and
``mcap_writer.py``, the suffix dispatch (:func:`read_recording`, ...) in ``files.py``.

A *tick* (what the streaming readers yield and what ``McapRecordingWriter.write_input``
takes) is a dict with the keys ``seq`` (int), ``t`` (float, s), ``position`` ((3,) array or
None), ``orientation`` ((4,) array ``[qx, qy, qz, qw]`` or None), ``motor_length`` ((m,)
array, m), ``force`` ((m,) array, N, or None) and ``temperature`` (float, deg C, or None).

Absent parts: a tick has no pose / no force when all of its values are NaN (MCAP: null,
CSV: empty cells); a column of :class:`Recording` (``position``/``orientation``, ``force``,
``temperature``) is None when *no* tick has that part, otherwise the ticks without it are
NaN rows. Both readers and both writers follow that one rule, so MCAP -> CSV -> MCAP keeps
the data.
"""

from __future__ import annotations

import builtins
import math
from dataclasses import dataclass, field
from os import PathLike
from typing import Any, BinaryIO, Iterable, Iterator, Optional, TypedDict, Union

import numpy as np

from cablesvc.errors import RecordingError

PathArg = Union[str, "PathLike[str]"]

#: Version of CSV files and of MCAP files with JSON inputs (what version 1 readers read).
FORMAT_VERSION = 1
#: Version of MCAP files whose inputs use the binary block encoding (``cablesvc.InputBlock``,
#: protobuf; ``protobuf_block.py``). Version 2 = version 1 + that encoding.
BLOCK_FORMAT_VERSION = 2
#: The ``format`` values the MCAP reader accepts.
MCAP_FORMAT_VERSIONS = (FORMAT_VERSION, BLOCK_FORMAT_VERSION)
#: Input encodings of the MCAP writers: ``protobuf`` (one binary message per block of ticks,
#: format 2, the default) and ``json`` (one JSON message per tick, format 1).
ENCODINGS = ("protobuf", "json")
METADATA_NAME = "cablesvc"


class Tick(TypedDict):
    """One control tick as yielded by ``iter_mcap_inputs`` / ``iter_csv_inputs``."""

    seq: int
    t: float
    position: Optional[np.ndarray]
    orientation: Optional[np.ndarray]
    motor_length: np.ndarray
    force: Optional[np.ndarray]
    temperature: Optional[float]


#: the range of ``seq`` (a signed 64-bit integer in every format and encoding)
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def check_seq(seq: Any) -> int:
    """A writer's ``seq`` as a Python int; not an integer (a bool is not) is a TypeError,
    one beyond 64 bits a ValueError."""
    if type(seq) is not int:
        if isinstance(seq, (bool, np.bool_)) or not isinstance(seq, (int, np.integer)):
            raise TypeError(f"seq must be an integer, got {type(seq).__name__}")
        seq = int(seq)
    if not INT64_MIN <= seq <= INT64_MAX:
        raise ValueError(f"seq = {seq} does not fit in a signed 64-bit integer")
    return seq


def open_recording(path: PathArg) -> BinaryIO:
    """The file at ``path`` opened for binary reading; a missing or unreadable file is a
    :class:`RecordingError` naming it."""
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise RecordingError(path, "file", "no such file") from None
    except OSError as e:
        raise RecordingError(path, "file", f"cannot open: {e.strerror or e}") from None


class RecordingTruncatedWarning(UserWarning):
    """Emitted when a recording was read from a file that lost data (e.g. writer killed)."""


@dataclass(frozen=True)
class Truncation:
    """What an incomplete MCAP file (no summary/footer) lost; see ``message``."""

    file_bytes: int
    usable_bytes: int
    complete_chunks: int
    data_complete: bool
    partial_record: Optional[str]
    lost_t_range: Optional[tuple[float, float]]
    message: str

    def __str__(self) -> str:
        return self.message


def _f64(a: Any) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def _f64_opt(a: Any) -> Optional[np.ndarray]:
    return None if a is None else _f64(a)


@dataclass(eq=False)
class Recording:
    """A whole recording as columnar numpy arrays (N ticks, m cables).

    ``metadata`` holds the key/values of the ``cablesvc`` metadata record (MCAP) or the
    ``# key: value`` lines (CSV) *other than* ``robot`` and ``format``: ``robot`` is its own
    field and ``format`` is fixed by the writer. ``extra`` maps a kept non-input topic to its
    decoded JSON payloads in file order (``read_mcap(..., keep_topics=...)``).
    ``truncation`` is set when the file was incomplete (see :class:`Truncation`).
    """

    robot: str
    metadata: dict[str, str]
    t: np.ndarray
    seq: np.ndarray
    motor_length: np.ndarray
    position: Optional[np.ndarray] = None
    orientation: Optional[np.ndarray] = None
    force: Optional[np.ndarray] = None
    temperature: Optional[np.ndarray] = None
    extra: dict[str, list] = field(default_factory=dict)
    truncation: Optional[Truncation] = None

    def __post_init__(self) -> None:
        if not isinstance(self.robot, str):
            raise TypeError(f"robot must be a str, got {type(self.robot).__name__}")
        self.metadata = dict(self.metadata)
        for k, v in self.metadata.items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise TypeError(f"metadata must map str to str, got {k!r}: {v!r}")
        self.t = _f64(self.t)
        seq = np.asarray(self.seq)
        if seq.size and seq.dtype.kind not in "iu":
            raise TypeError(f"seq must be integers, got dtype {seq.dtype}")
        self.seq = seq.astype(np.int64, copy=False)
        self.motor_length = _f64(self.motor_length)
        if self.motor_length.ndim == 1 and self.motor_length.size == 0:
            self.motor_length = self.motor_length.reshape(0, 0)
        self.position = _f64_opt(self.position)
        self.orientation = _f64_opt(self.orientation)
        self.force = _f64_opt(self.force)
        self.temperature = _f64_opt(self.temperature)
        self.extra = dict(self.extra)

    # ----------------------------------------------------------------- properties
    @property
    def n_ticks(self) -> int:
        return int(self.t.shape[0]) if self.t.ndim else 0

    @property
    def n_cables(self) -> int:
        return int(self.motor_length.shape[1]) if self.motor_length.ndim == 2 else 0

    @property
    def has_pose(self) -> bool:
        return self.position is not None and self.orientation is not None

    @property
    def has_force(self) -> bool:
        return self.force is not None

    @property
    def has_temperature(self) -> bool:
        return self.temperature is not None

    # ----------------------------------------------------------------- methods
    def slice(self, start: Optional[int], stop: Optional[int] = None) -> "Recording":
        """Ticks ``start:stop`` (Python slice semantics) as a new Recording of views.

        ``extra`` payloads are kept when their ``seq`` is one of the kept ticks' seq, or,
        without an integer ``seq``, when their ``t`` lies within the kept ticks' times.
        """
        s = builtins.slice(start, stop)

        def cut(a: Optional[np.ndarray]) -> Optional[np.ndarray]:
            return None if a is None else a[s]

        seq = self.seq[s]
        t = self.t[s]
        extra: dict[str, list] = {}
        if self.extra:
            seqs = set(seq.tolist())
            t_lo, t_hi = (float(np.min(t)), float(np.max(t))) if t.size else (1.0, 0.0)
            for topic, payloads in self.extra.items():
                kept = []
                for p in payloads:
                    ps = p.get("seq") if isinstance(p, dict) else None
                    pt = p.get("t") if isinstance(p, dict) else None
                    if isinstance(ps, int) and not isinstance(ps, bool):
                        if ps in seqs:
                            kept.append(p)
                    elif isinstance(pt, (int, float)) and t_lo <= pt <= t_hi:
                        kept.append(p)
                extra[topic] = kept
        return Recording(
            robot=self.robot,
            metadata=dict(self.metadata),
            t=t,
            seq=seq,
            motor_length=self.motor_length[s],
            position=cut(self.position),
            orientation=cut(self.orientation),
            force=cut(self.force),
            temperature=cut(self.temperature),
            extra=extra,
        )

    def shape_problems(self) -> list[str]:
        """Array shape/consistency problems only (what a writer cannot write)."""
        out: list[str] = []
        if self.t.ndim != 1:
            return [f"t must be 1-D (N,), has shape {self.t.shape}"]
        n = self.t.shape[0]
        if self.seq.shape != (n,):
            out.append(f"seq has shape {self.seq.shape}, expected ({n},)")
        ml = self.motor_length
        if ml.ndim != 2 or ml.shape[0] != n:
            out.append(f"motor_length has shape {ml.shape}, expected ({n}, m)")
            m = None
        else:
            m = ml.shape[1]
            if m < 1 and n > 0:
                out.append("motor_length has no cables (m = 0)")
        if (self.position is None) != (self.orientation is None):
            out.append("position and orientation must both be arrays or both be None")
        if self.position is not None and self.position.shape != (n, 3):
            out.append(f"position has shape {self.position.shape}, expected ({n}, 3)")
        if self.orientation is not None and self.orientation.shape != (n, 4):
            out.append(f"orientation has shape {self.orientation.shape}, expected ({n}, 4)")
        if self.force is not None and m is not None and self.force.shape != (n, m):
            out.append(f"force has shape {self.force.shape}, expected ({n}, {m})")
        if self.temperature is not None and self.temperature.shape != (n,):
            out.append(f"temperature has shape {self.temperature.shape}, expected ({n},)")
        return out

    def validate(self) -> list[str]:
        """Check the recording; return a list of problems (empty when fine), never raise.

        Checks shapes, finite and strictly increasing ``t``, ``seq`` strictly +1 per tick,
        finite motor lengths, pose rows either complete or absent, unit quaternions (to 1e-3).
        """
        problems = self.shape_problems()
        if problems:
            return problems
        n = self.n_ticks
        if n == 0:
            return ["recording has no ticks"]
        bad_t = ~np.isfinite(self.t)
        if bad_t.any():
            problems.append(
                f"t is not finite at {int(bad_t.sum())} ticks (first at index "
                f"{int(np.argmax(bad_t))})"
            )
        elif n > 1:
            dt = np.diff(self.t)
            bad = dt <= 0
            if bad.any():
                i = int(np.argmax(bad))
                problems.append(
                    f"t does not increase at {int(bad.sum())} places (first: index {i} -> "
                    f"{i + 1}, t {self.t[i]!r} -> {self.t[i + 1]!r})"
                )
        if n > 1:
            ds = np.diff(self.seq)
            bad = ds != 1
            if bad.any():
                idx = np.flatnonzero(bad)
                shown = ", ".join(
                    f"index {i} -> {i + 1} (seq {self.seq[i]} -> {self.seq[i + 1]})"
                    for i in idx[:3].tolist()
                )
                more = f" and {idx.size - 3} more" if idx.size > 3 else ""
                problems.append(f"seq is not +1 per tick at {idx.size} places: {shown}{more}")
        bad_ml = ~np.isfinite(self.motor_length)
        if bad_ml.any():
            rows = np.flatnonzero(bad_ml.any(axis=1))
            problems.append(
                f"motor_length is not finite at {rows.size} ticks (first at index {rows[0]})"
            )
        if self.position is not None and self.orientation is not None:
            pose = np.concatenate([self.position, self.orientation], axis=1)
            nan = np.isnan(pose)
            partial = nan.any(axis=1) & ~nan.all(axis=1)
            if partial.any():
                problems.append(
                    f"pose is partly missing at {int(partial.sum())} ticks (first at index "
                    f"{int(np.argmax(partial))}); a tick has all 7 pose values or none"
                )
            full = ~nan.any(axis=1)
            if full.any():
                norm = np.linalg.norm(self.orientation[full], axis=1)
                off = np.abs(norm - 1.0) > 1e-3
                if off.any():
                    first = int(np.flatnonzero(full)[np.argmax(off)])
                    problems.append(
                        f"orientation is not a unit quaternion at {int(off.sum())} ticks "
                        f"(first at index {first}, norm {float(norm[np.argmax(off)]):.6g})"
                    )
        return problems

    def iter_ticks(self) -> Iterator[Tick]:
        """Yield the ticks as dicts (row views; None for absent parts, see module doc)."""
        pos, ori, force, temp = self.position, self.orientation, self.force, self.temperature
        for i in range(self.n_ticks):
            p = q = None
            if pos is not None and ori is not None:
                p, q = pos[i], ori[i]
                if np.isnan(p).all() and np.isnan(q).all():
                    p = q = None
            f = None
            if force is not None:
                f = force[i]
                if np.isnan(f).all():
                    f = None
            tmp = None
            if temp is not None:
                v = float(temp[i])
                tmp = None if math.isnan(v) else v
            yield Tick(
                seq=int(self.seq[i]),
                t=float(self.t[i]),
                position=p,
                orientation=q,
                motor_length=self.motor_length[i],
                force=f,
                temperature=tmp,
            )

    def equals(self, other: "Recording") -> bool:
        """Exact equality of the data: robot, metadata, arrays (NaN equal to NaN), extra.

        ``truncation`` (how the file was read) is not compared."""

        def same(a: Optional[np.ndarray], b: Optional[np.ndarray]) -> bool:
            if a is None or b is None:
                return a is None and b is None
            if a.shape != b.shape:
                return False
            if a.dtype.kind == "f" or b.dtype.kind == "f":
                return bool(np.array_equal(a, b, equal_nan=True))
            return bool(np.array_equal(a, b))

        return (
            self.robot == other.robot
            and self.metadata == other.metadata
            and same(self.t, other.t)
            and same(self.seq, other.seq)
            and same(self.motor_length, other.motor_length)
            and same(self.position, other.position)
            and same(self.orientation, other.orientation)
            and same(self.force, other.force)
            and same(self.temperature, other.temperature)
            and self.extra == other.extra
        )

    @classmethod
    def from_ticks(
        cls,
        robot: str,
        ticks: Iterable[dict],
        metadata: Optional[dict[str, str]] = None,
        n_cables: Optional[int] = None,
    ) -> "Recording":
        """Build a Recording from tick dicts (keys as :class:`Tick`; missing parts None)."""
        cols = TickColumns(n_cables)
        for tick in ticks:
            cols.append(
                int(tick["seq"]),
                float(tick["t"]),
                _row(tick.get("position")),
                _row(tick.get("orientation")),
                _row(tick["motor_length"]),
                _row(tick.get("force")),
                tick.get("temperature"),
            )
        return cols.build(robot, metadata or {})


def _row(v: Any) -> Optional[list]:
    if v is None:
        return None
    if isinstance(v, np.ndarray):
        return v.astype(np.float64, copy=False).tolist()
    return [float(x) for x in v]


_NAN3 = [math.nan] * 3
_NAN4 = [math.nan] * 4


class TickColumns:
    """Accumulates ticks (lists of floats; None elements become NaN) and blocks of ticks
    (arrays, :meth:`add_block`) into a Recording, in the order they were added.

    The columns are numpy arrays grown by doubling their capacity (the part not yet
    filled is never touched, so it takes no memory), and single ticks are kept as Python
    lists only up to ``BATCH`` ticks: memory stays near the arrays' own size for any length
    of recording. The Recording's arrays are views of the first ``n`` rows."""

    BATCH = 65536
    _WIDTH = {"seq": 1, "t": 1, "motor_length": None, "position": 3, "orientation": 4,
              "force": None, "temperature": 1}

    def __init__(self, n_cables: Optional[int] = None):
        self.n_cables = n_cables
        self._cols: dict[str, np.ndarray] = {}
        self._n = 0
        self._cap = 0
        self._new_lists()

    def _new_lists(self) -> None:
        self.seq: list[int] = []
        self.t: list[float] = []
        self.position: list[Optional[list]] = []
        self.orientation: list[Optional[list]] = []
        self.motor_length: list[list] = []
        self.force: list[Optional[list]] = []
        self.temperature: list[Optional[float]] = []
        self._any_pose = self._any_force = self._any_temp = False

    def __len__(self) -> int:
        return self._n + len(self.t)

    def append(self, seq, t, position, orientation, motor_length, force, temperature) -> None:
        if self.n_cables is None:
            self.n_cables = len(motor_length)
        if len(motor_length) != self.n_cables:
            raise ValueError(
                f"tick {len(self)}: {len(motor_length)} motor lengths, expected {self.n_cables}"
            )
        if force is not None and len(force) != self.n_cables:
            raise ValueError(f"tick {len(self)}: {len(force)} forces, expected {self.n_cables}")
        self.seq.append(seq)
        self.t.append(t)
        self.motor_length.append(motor_length)
        if position is not None and orientation is not None:
            self._any_pose = True
        self.position.append(position)
        self.orientation.append(orientation)
        if force is not None:
            self._any_force = True
        self.force.append(force)
        if temperature is not None:
            self._any_temp = True
        self.temperature.append(temperature)
        if len(self.t) >= self.BATCH:
            self._seal()

    def add_block(self, block: dict[str, Any]) -> None:
        """Add ``n`` ticks as arrays: a dict with ``n``, ``seq`` (n,), ``t`` (n,),
        ``motor_length`` (n, m) and ``position`` (n, 3), ``orientation`` (n, 4), ``force``
        (n, m), ``temperature`` (n,), each None when no tick of the block has it."""
        m = block["motor_length"].shape[1]
        if self.n_cables is None:
            self.n_cables = m
        if m != self.n_cables:
            raise ValueError(f"tick {len(self)}: {m} motor lengths, expected {self.n_cables}")
        self._seal()
        self._put(block)

    def reserve(self, n_ticks: int) -> None:
        """Make room for ``n_ticks`` ticks in all (a hint: more are still accepted; room
        never filled costs address space, not memory)."""
        if n_ticks > self._cap:
            try:
                self._grow(n_ticks)
            except MemoryError:  # a hint from a file's statistics, which may be wrong
                pass

    # ----------------------------------------------------------------- column store
    def _grow(self, cap: int) -> None:
        n0 = self._n
        for name, old in self._cols.items():
            new = np.empty(self._shape(name, cap), dtype=old.dtype)
            new[:n0] = old[:n0]
            self._cols[name] = new
        self._cap = cap

    def _shape(self, name: str, rows: int) -> tuple[int, ...]:
        w = self._WIDTH[name]
        if w == 1:
            return (rows,)
        return (rows, self.n_cables or 0) if w is None else (rows, w)

    def _put(self, block: dict[str, Any]) -> None:
        n0, k = self._n, int(block["n"])
        n1 = n0 + k
        if n1 > self._cap:
            self._grow(max(n1, 2 * self._cap, 1024))
        for name in self._WIDTH:
            a = block[name]
            col = self._cols.get(name)
            if a is None:
                if col is not None:
                    col[n0:n1] = np.nan
                continue
            if col is None:
                dtype = np.int64 if name == "seq" else np.float64
                try:
                    col = np.empty(self._shape(name, self._cap), dtype=dtype)
                except MemoryError:  # a reserve() hint too large: grow as needed instead
                    if self._cap <= n1 or self._cols:
                        raise
                    self._cap = n1
                    col = np.empty(self._shape(name, self._cap), dtype=dtype)
                self._cols[name] = col
                if n0:  # an optional part seen for the first time: the ticks before lack it
                    col[:n0] = np.nan
            col[n0:n1] = a
        self._n = n1

    def _seal(self) -> None:
        """The listed ticks into the column store."""
        n = len(self.t)
        if not n:
            return
        m = self.n_cables or 0
        part: dict[str, Any] = {
            "n": n,
            "seq": np.array(self.seq, dtype=np.int64),
            "t": np.array(self.t, dtype=np.float64),
            "motor_length": np.array(self.motor_length, dtype=np.float64).reshape(n, m),
            "position": None, "orientation": None, "force": None, "temperature": None,
        }
        if self._any_pose:
            part["position"] = np.array(
                [p if p is not None else _NAN3 for p in self.position], dtype=np.float64
            )
            part["orientation"] = np.array(
                [q if q is not None else _NAN4 for q in self.orientation], dtype=np.float64
            )
        if self._any_force:
            nanm = [math.nan] * m
            part["force"] = np.array(
                [f if f is not None else nanm for f in self.force], dtype=np.float64
            )
        if self._any_temp:
            part["temperature"] = np.array(self.temperature, dtype=np.float64)
        self._new_lists()
        self._put(part)

    def build(self, robot: str, metadata: dict[str, str], **kw: Any) -> Recording:
        self._seal()
        n, cols = self._n, self._cols
        self._cols, self._n, self._cap = {}, 0, 0

        def col(name: str) -> Optional[np.ndarray]:
            a = cols.get(name)
            return None if a is None else a[:n]

        if "t" in cols:
            t, seq, ml = col("t"), col("seq"), col("motor_length")
        else:
            t = np.zeros(0)
            seq = np.zeros(0, dtype=np.int64)
            ml = np.zeros((0, self.n_cables or 0))
        position, orientation = col("position"), col("orientation")
        if position is not None and orientation is not None and (
            np.isnan(position).all() and np.isnan(orientation).all()
        ):
            position = orientation = None
        force = col("force")
        if force is not None and np.isnan(force).all():
            force = None
        temperature = col("temperature")
        if temperature is not None and np.isnan(temperature).all():
            temperature = None
        return Recording(
            robot=robot,
            metadata=metadata,
            t=t,
            seq=seq,
            motor_length=ml,
            position=position,
            orientation=orientation,
            force=force,
            temperature=temperature,
            **kw,
        )
