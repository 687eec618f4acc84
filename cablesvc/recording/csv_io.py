"""CSV side of recording format 1: :func:`read_csv`, :func:`write_csv`,
:func:`iter_csv_inputs`.

Layout (spec): optional ``# key: value`` metadata lines, then the header
``t,seq,x,y,z,qx,qy,qz,qw,l0,l1,...,f0,f1,...,temperature``, then one line per tick.
Pose columns are empty when a tick has no pose; force columns and ``temperature`` may be
absent. cablesvc writes ``# robot: <name>`` and ``# format: 1`` first, then the other
metadata, and floats with ``repr`` (shortest string that reads back to the same double,
so a round trip is exact). A NaN is written as an empty cell; +-inf as ``inf``/``-inf``.

Reading is by column name (any column order; duplicates and unknown names are errors),
with ``t``, ``seq`` and ``l0`` required, the seven pose columns all or none, ``f0..`` as
many as ``l0..``. An empty cell is NaN except in ``t`` and ``seq``. Errors name the line
(1-based, as an editor shows it) and the column.
"""

from __future__ import annotations

import csv
import math
import os
import re
from typing import Any, BinaryIO, Callable, Iterator, Optional

import numpy as np

from .format import (
    FORMAT_VERSION,
    INT64_MAX,
    INT64_MIN,
    PathArg,
    Recording,
    RecordingError,
    Tick,
    check_seq,
    open_recording,
)

POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
_CABLE_COLUMN = re.compile(r"^([lf])(0|[1-9][0-9]*)$")
_NAN = math.nan
_BOM = b"\xef\xbb\xbf"
# a number as format 1 writes it (Python repr of a float, or an integer): what int() and
# float() read, less the digit separators and non-ASCII digits they also accept
_PLAIN_NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf|infinity|nan)",
                           re.IGNORECASE)


def csv_header(n_cables: int, has_force: bool, has_temperature: bool) -> list[str]:
    """The column names cablesvc writes, in the spec's order."""
    cols = ["t", "seq", *POSE_COLUMNS]
    cols += [f"l{i}" for i in range(n_cables)]
    if has_force:
        cols += [f"f{i}" for i in range(n_cables)]
    if has_temperature:
        cols.append("temperature")
    return cols


def _check_meta(what: str, text: str, key: bool) -> None:
    if "\n" in text or "\r" in text:
        raise ValueError(f"CSV metadata {what} {text!r} contains a line break")
    if text != text.strip():
        raise ValueError(f"CSV metadata {what} {text!r} has surrounding spaces (not kept)")
    if key and (not text or ":" in text):
        raise ValueError(f"CSV metadata key {text!r} must be non-empty and contain no ':'")


def _fmt(v: float) -> str:
    return "" if v != v else repr(v)


def _meta_lines(robot: str, metadata: dict[str, str]) -> list[tuple[str, str]]:
    """The ``# key: value`` lines cablesvc writes: robot (when known), format, the rest."""
    meta: list[tuple[str, str]] = []
    if robot:
        _check_meta("value", robot, key=False)
        meta.append(("robot", robot))
    meta.append(("format", str(FORMAT_VERSION)))
    for k, v in metadata.items():
        if k in ("robot", "format"):
            raise ValueError(f"metadata key {k!r} is reserved (robot is Recording.robot)")
        _check_meta("key", k, key=True)
        _check_meta("value", v, key=False)
        meta.append((k, v))
    return meta


def write_csv(path: PathArg, rec: Recording) -> None:
    """Write ``rec`` as a format-1 CSV file (``rec.extra`` is not written: CSV has no topics)."""
    problems = rec.shape_problems()
    if problems:
        raise ValueError(f"{path}: cannot write recording: " + "; ".join(problems))
    if not np.isfinite(rec.t).all():
        raise ValueError(f"{path}: t must be finite at every tick")
    meta = _meta_lines(rec.robot, rec.metadata)
    n, m = rec.n_ticks, rec.n_cables
    blocks = []
    if rec.position is not None and rec.orientation is not None:
        blocks += [rec.position, rec.orientation]
    else:
        blocks.append(np.full((n, 7), np.nan))
    blocks.append(rec.motor_length)
    if rec.force is not None:
        blocks.append(rec.force)
    if rec.temperature is not None:
        blocks.append(rec.temperature.reshape(n, 1))
    values = np.hstack(blocks).tolist() if n else []
    t = rec.t.tolist()
    seq = rec.seq.tolist()
    header = csv_header(m, rec.force is not None, rec.temperature is not None)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        for k, v in meta:
            f.write(f"# {k}: {v}\n")
        f.write(",".join(header) + "\n")
        write = f.write
        for i in range(n):
            write(f"{t[i]!r},{seq[i]},{','.join(map(_fmt, values[i]))}\n")


def _cells(x: Any, n: int, name: str) -> list[str]:
    """``n`` cells of a part of a tick (None: all empty), NaN as an empty cell."""
    if x is None:
        return [""] * n
    vals = np.asarray(x, dtype=np.float64).reshape(-1).tolist()
    if len(vals) != n:
        raise ValueError(f"{name} has {len(vals)} values, expected {n}")
    return [_fmt(v) for v in vals]


class CsvRecordingWriter:
    """Write a format-1 CSV recording tick by tick (the live service's ``--record x.csv``).

    The same ``write_input`` as :class:`~cablesvc.recording.McapRecordingWriter`; CSV has no
    topics, so it holds the inputs only (forces and alarms need MCAP). The header is written
    with the first tick (it fixes the cable count) and always has the force and temperature
    columns: a tick without force or temperature leaves them empty, which a reader takes as
    absent, so nothing is lost and nothing is invented. Metadata values must be one line.
    ``overwrite=False`` refuses an existing file (``FileExistsError``) instead of replacing it.
    Not thread-safe: call from one thread.
    """

    has_topics = False

    def __init__(self, path: PathArg, robot: str, metadata: Optional[dict[str, str]] = None,
                 *, overwrite: bool = True):
        if not isinstance(robot, str) or not robot:
            raise ValueError("robot must be a non-empty str (the robot's name)")
        meta = _meta_lines(robot, dict(metadata or {}))
        self.path = path
        self._f = open(path, "w" if overwrite else "x", encoding="utf-8", newline="\n")
        try:
            self._f.write("".join(f"# {k}: {v}\n" for k, v in meta))
        except BaseException:
            self._f.close()
            raise
        self._n_cables: Optional[int] = None
        self._closed = False
        self.n_inputs = 0
        """Number of ticks written so far."""

    def __enter__(self) -> "CsvRecordingWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def write_input(self, seq: int, t: float, motor_length: Any, force: Any = None, position: Any = None,
                    orientation: Any = None, temperature: Optional[float] = None) -> None:
        """One line; arguments as :meth:`McapRecordingWriter.write_input`."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        seq = check_seq(seq)
        t = float(t)
        if not math.isfinite(t):
            raise ValueError(f"t must be finite, got {t!r}")
        ml = np.asarray(motor_length, dtype=np.float64).reshape(-1)
        if self._n_cables is None:
            if not ml.size:
                raise ValueError("motor_length is empty: a robot has at least one cable")
            self._n_cables = int(ml.size)
            self._f.write(",".join(csv_header(self._n_cables, True, True)) + "\n")
        m = self._n_cables
        if (position is None) != (orientation is None):
            raise ValueError("position and orientation must be given together")
        temp = "" if temperature is None else _fmt(float(temperature))
        line = ",".join([repr(t), str(seq), *_cells(position, 3, "position"),
                         *_cells(orientation, 4, "orientation"), *_cells(ml, m, "motor_length"),
                         *_cells(force, m, "force"), temp])
        self._f.write(line + "\n")
        self.n_inputs += 1

    def flush(self, fsync: bool = False) -> None:
        """Hand the lines written so far to the OS (``fsync``: also to the disk)."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        self._f.flush()
        if fsync:
            os.fsync(self._f.fileno())

    def close(self) -> None:
        """Flush and close the file. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._f.close()

    @property
    def closed(self) -> bool:
        return self._closed


class _CsvSource:
    """An open CSV recording: metadata and header parsed, rows streamed."""

    def __init__(self, path: PathArg, robot_cables: Optional[int] = None):
        self.path = str(path)
        # Binary, decoded line by line: a decode error names the physical line (a text
        # wrapper decodes blocks ahead of the line being parsed).
        self._f: BinaryIO = open_recording(path)
        self._lines = self._physical_lines()
        try:
            self._read_head(robot_cables)
        except BaseException:
            self._f.close()
            raise

    def close(self) -> None:
        self._f.close()

    def _physical_lines(self) -> Iterator[tuple[int, "str | RecordingError"]]:
        """Yield ``(line number, text without line end)``; ``\n``, ``\r\n`` and ``\r``
        end a line (as in an editor). A UTF-8 BOM at the start is skipped. A line that is
        not UTF-8 is yielded as its :class:`RecordingError` (the lines after it still come)."""
        lineno = 0
        first = True
        for raw in self._f:
            if first:
                first = False
                if raw.startswith(_BOM):
                    raw = raw[3:]
            parts = raw.splitlines() if b"\r" in raw else (raw.rstrip(b"\n"),)
            for b in parts:
                lineno += 1
                try:
                    text = b.decode("utf-8")
                except UnicodeDecodeError as e:
                    yield lineno, self._err(
                        lineno, None, f"not UTF-8 text: byte {b[e.start]:#04x} at column "
                        f"{len(b[:e.start].decode('utf-8', 'replace')) + 1} ({e.reason})"
                    )
                    continue
                yield lineno, text

    def _split(self, line: str, lineno: int) -> list[str]:
        """The fields of one line: a plain split, or the csv module when there are quotes
        (a third-party CSV writer quotes names or empty cells, e.g. QUOTE_NONNUMERIC)."""
        if '"' not in line:
            return line.split(",")
        try:
            return next(csv.reader((line,), strict=True))
        except csv.Error as e:
            raise self._err(lineno, None, f"malformed CSV quoting: {e}") from None

    def _err(self, line: int, column: Optional[str], reason: str) -> RecordingError:
        where = f"line {line}" if column is None else f"line {line}, column {column}"
        return RecordingError(self.path, where, reason)

    def _read_head(self, robot_cables: Optional[int]) -> None:
        self.metadata: dict[str, str] = {}
        lineno = 0
        header_line: Optional[str] = None
        for lineno, line in self._lines:
            if isinstance(line, RecordingError):
                raise line
            stripped = line.strip()
            if not stripped:
                continue
            if stripped.startswith('"#'):  # a metadata line quoted by a CSV writer
                fields = self._split(stripped, lineno)
                if len(fields) == 1 and fields[0].startswith("#"):
                    stripped = fields[0].strip()
            if stripped.startswith("#"):
                body = stripped[1:]
                if ":" in body:
                    key, value = body.split(":", 1)
                    key, value = key.strip(), value.strip()
                    if key:
                        self.metadata[key] = value
                        if key == "format" and value != str(FORMAT_VERSION):
                            raise self._err(
                                lineno,
                                None,
                                f"format {value!r} is not supported: this cablesvc reads "
                                f"format {FORMAT_VERSION}",
                            )
                continue
            header_line = line
            break
        if header_line is None:
            what = "empty file" if lineno == 0 else "no header line (only metadata/blank lines)"
            raise RecordingError(
                self.path, "file" if lineno == 0 else f"line {lineno}", f"{what}: expected "
                "the header t,seq,x,y,z,qx,qy,qz,qw,l0,...[,f0,...][,temperature]",
            )
        self.header_lineno = lineno
        self.lineno = lineno
        names = [c.strip() for c in self._split(header_line, lineno)]
        self.names = names
        self._parse_header(names, lineno, robot_cables)

    def _parse_header(self, names: list[str], h: int, robot_cables: Optional[int]) -> None:
        index: dict[str, int] = {}
        ls: dict[int, int] = {}
        fs: dict[int, int] = {}
        for j, name in enumerate(names):
            if name in index:
                raise self._err(h, name, f"duplicate column (also column {index[name] + 1})")
            index[name] = j
            m = _CABLE_COLUMN.match(name)
            if m:
                (ls if m.group(1) == "l" else fs)[int(m.group(2))] = j
            elif name not in ("t", "seq", "temperature") and name not in POSE_COLUMNS:
                raise self._err(
                    h,
                    repr(name) if name else f"{j + 1} (empty name)",
                    "unknown column; the header is t,seq,x,y,z,qx,qy,qz,qw,l0,l1,...,"
                    "f0,f1,...,temperature (the first line not starting with '#' must be "
                    "the header)",
                )
        for req in ("t", "seq", "l0"):
            if req not in index:
                raise self._err(
                    h, None, f"missing required column {req!r} (header: {','.join(names)})"
                )
        m = len(ls)
        if sorted(ls) != list(range(m)):
            gap = min(set(range(m)) - set(ls))
            raise self._err(h, None, f"missing column 'l{gap}' (have {m} l columns, "
                            f"up to l{max(ls)})")
        if fs:
            if sorted(fs) != list(range(len(fs))):
                gap = min(set(range(len(fs))) - set(fs))
                raise self._err(h, None, f"missing column 'f{gap}' (have {len(fs)} f columns, "
                                f"up to f{max(fs)})")
            if len(fs) != m:
                raise self._err(
                    h,
                    None,
                    f"cable count inconsistency: {m} motor-length columns (l0..l{m - 1}) but "
                    f"{len(fs)} force columns (f0..f{len(fs) - 1})",
                )
        if robot_cables is not None and m != robot_cables:
            raise self._err(
                h, None, f"{m} motor-length columns but the robot has {robot_cables} cables"
            )
        pose_present = [c for c in POSE_COLUMNS if c in index]
        if pose_present and len(pose_present) != len(POSE_COLUMNS):
            missing = [c for c in POSE_COLUMNS if c not in index]
            raise self._err(h, None, f"pose columns {missing} missing (pose needs all of "
                            f"{','.join(POSE_COLUMNS)}, or none)")
        self.n_cables = m
        self.n_fields = len(names)
        self.seq_col = index["seq"]
        # Float columns in a fixed order: t, pose (7), l (m), f (m), temperature.
        order = [index["t"]]
        self.pose_slice = None
        if pose_present:
            self.pose_slice = slice(1, 8)
            order += [index[c] for c in POSE_COLUMNS]
        self.l_slice = slice(len(order), len(order) + m)
        order += [ls[i] for i in range(m)]
        self.f_slice = None
        if fs:
            self.f_slice = slice(len(order), len(order) + m)
            order += [fs[i] for i in range(m)]
        self.temp_col = None
        if "temperature" in index:
            self.temp_col = len(order)
            order.append(index["temperature"])
        self.float_cols = order
        self.float_names = [names[j] for j in order]

    def rows(self, on_error: Optional[Callable[[RecordingError], None]] = None
             ) -> Iterator[tuple[int, list[float]]]:
        """Yield ``(seq, floats)`` per tick; floats in the order of ``float_cols``.

        A bad line (wrong number of fields, a field that is not a number, no ``t`` or
        ``seq``, not UTF-8, ...) raises its :class:`RecordingError`, naming line and column;
        with ``on_error`` it is handed to ``on_error`` instead and skipped, and the lines
        after it are read (one damaged line costs one tick, not the rest of the file)."""
        lineno = self.lineno
        try:
            for lineno, line in self._lines:
                try:
                    if isinstance(line, RecordingError):
                        raise line
                    row = self._row(lineno, line)
                except RecordingError as e:
                    if on_error is None:
                        raise
                    on_error(e)
                    continue
                if row is not None:
                    yield row
        finally:
            self.lineno = lineno

    def _row(self, lineno: int, line: str) -> Optional[tuple[int, list[float]]]:
        """``(seq, floats)`` of one data line; None for a blank line; RecordingError if bad."""
        if not line.strip():
            return None
        if line.lstrip().startswith("#"):
            raise self._err(
                lineno, None, "'#' line after the header (metadata lines must come before it)"
            )
        parts = line.split(",") if '"' not in line else self._split(line, lineno)
        if len(parts) != self.n_fields:
            raise self._err(
                lineno,
                None,
                f"wrong number of fields: {len(parts)}, the header (line "
                f"{self.header_lineno}) has {self.n_fields}",
            )
        if "_" in line or not line.isascii():
            self._plain_numbers(parts, lineno)
        s = parts[self.seq_col]
        try:
            seq = int(s)
        except ValueError:
            what = "empty (seq is required)" if not s.strip() else (
                f"{s.strip()!r} is not an integer")
            raise self._err(lineno, "seq", what) from None
        if not INT64_MIN <= seq <= INT64_MAX:
            raise self._err(lineno, "seq", f"{seq} does not fit in a signed 64-bit integer")
        vals = []
        for j, name in zip(self.float_cols, self.float_names):
            s = parts[j]
            try:
                vals.append(float(s))
            except ValueError:
                if s.strip():
                    raise self._err(lineno, name, f"{s.strip()!r} is not a number") from None
                vals.append(_NAN)
        if not math.isfinite(vals[0]):
            t_cell = parts[self.float_cols[0]].strip()
            raise self._err(
                lineno, "t", "empty (t is required)" if not t_cell
                else f"t must be finite, got {t_cell!r}"
            )
        return seq, vals

    def _plain_numbers(self, parts: list[str], lineno: int) -> None:
        """Python's ``int`` and ``float`` also read ``1_000`` (as 1000) and non-ASCII digits
        (``'\u0661'`` as 1): neither is a number in a format-1 CSV file. Refuse the first such
        field, naming its column (only lines with ``_`` or non-ASCII text get here)."""
        for j, cell in enumerate(parts):
            c = cell.strip()
            if c and not _PLAIN_NUMBER.fullmatch(c):
                if "_" in c and _PLAIN_NUMBER.fullmatch(c.replace("_", "")):
                    what = " (digit separators '_' are not allowed)"
                elif not c.isascii():
                    what = " (only ASCII digits are numbers here)"
                else:
                    what = ""
                name = self.names[j] if j < len(self.names) else str(j + 1)
                raise self._err(lineno, name, f"{c!r} is not a number{what}")

    def tick(self, seq: int, v: list[float]) -> Tick:
        position = orientation = None
        if self.pose_slice is not None:
            pose = v[self.pose_slice]
            if not all(x != x for x in pose):
                position = np.array(pose[:3])
                orientation = np.array(pose[3:])
        force = None
        if self.f_slice is not None:
            fv = v[self.f_slice]
            if not all(x != x for x in fv):
                force = np.array(fv)
        temp = None
        if self.temp_col is not None and v[self.temp_col] == v[self.temp_col]:
            temp = v[self.temp_col]
        return Tick(
            seq=seq,
            t=v[0],
            position=position,
            orientation=orientation,
            motor_length=np.array(v[self.l_slice]),
            force=force,
            temperature=temp,
        )

    def full_metadata(self) -> dict[str, str]:
        md = dict(self.metadata)
        md.setdefault("robot", "")
        md.setdefault("format", str(FORMAT_VERSION))
        return md


def read_csv(path: PathArg, *, robot_cables: Optional[int] = None) -> Recording:
    """Read a format-1 CSV recording. ``robot`` is ``""`` when the file has no
    ``# robot:`` line. Raises :class:`RecordingError` naming line and column.

    Bad data lines are an error here, not skipped: offline use (identification, discovery,
    convert) must not fit a model to a file with holes it did not ask for. The whole file
    is read first, so the error names the first bad line *and* counts all of them
    (``line 12, column f3: 'x' is not a number (and 2 more bad lines: 40, 97)``); a live
    replay (``iter_csv_inputs(..., on_error=...)``) skips and counts them instead.
    """
    src = _CsvSource(path, robot_cables)
    seqs: list[int] = []
    rows: list[list[float]] = []
    bad: list[RecordingError] = []
    try:
        for seq, vals in src.rows(on_error=bad.append):
            seqs.append(seq)
            rows.append(vals)
    finally:
        src.close()
    if bad:
        first = bad[0]
        if len(bad) > 1:
            more = ", ".join(e.location.split(",")[0].removeprefix("line ") for e in bad[1:6])
            more += ", ..." if len(bad) > 6 else ""
            s = "" if len(bad) == 2 else "s"
            raise RecordingError(first.path, first.location,
                                 f"{first.reason} (and {len(bad) - 1} more bad line{s}: {more})")
        raise first
    n, m = len(rows), src.n_cables
    F = np.array(rows, dtype=np.float64).reshape(n, len(src.float_cols))

    def part(a: np.ndarray) -> Optional[np.ndarray]:
        return None if np.isnan(a).all() else np.ascontiguousarray(a)

    position = orientation = force = temperature = None
    if src.pose_slice is not None and n:
        pose = F[:, src.pose_slice]
        if not np.isnan(pose).all():
            position = np.ascontiguousarray(pose[:, :3])
            orientation = np.ascontiguousarray(pose[:, 3:])
    if src.f_slice is not None and n:
        force = part(F[:, src.f_slice])
    if src.temp_col is not None and n:
        temperature = part(F[:, src.temp_col])
    meta = {k: v for k, v in src.metadata.items() if k not in ("robot", "format")}
    return Recording(
        robot=src.metadata.get("robot", ""),
        metadata=meta,
        t=np.ascontiguousarray(F[:, 0]),
        seq=np.array(seqs, dtype=np.int64),
        motor_length=np.ascontiguousarray(F[:, src.l_slice]).reshape(n, m),
        position=position,
        orientation=orientation,
        force=force,
        temperature=temperature,
    )


def iter_csv_inputs(path: PathArg, *, robot_cables: Optional[int] = None,
                    on_error: Optional[Callable[[RecordingError], None]] = None) -> Iterator[Tick]:
    """Stream the ticks of a CSV recording in file order (header checked before return).

    A bad data line raises its :class:`RecordingError` (which ends the iteration), or, with
    ``on_error``, is handed to it and skipped: the ticks after it still come."""
    src = _CsvSource(path, robot_cables)
    return _iter(src, on_error)


def _iter(src: _CsvSource, on_error: Optional[Callable[[RecordingError], None]]) -> Iterator[Tick]:
    try:
        for seq, vals in src.rows(on_error):
            yield src.tick(seq, vals)
    finally:
        src.close()


def read_csv_metadata(path: PathArg) -> dict[str, str]:
    """The ``# key: value`` metadata, with ``robot`` ("" if absent) and ``format``."""
    src = _CsvSource(path)
    src.close()
    return src.full_metadata()


__all__ = [
    "CsvRecordingWriter",
    "POSE_COLUMNS",
    "csv_header",
    "iter_csv_inputs",
    "read_csv",
    "read_csv_metadata",
    "write_csv",
]
