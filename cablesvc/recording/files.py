"""Reading and writing a recording by its file name: the suffix (``.mcap`` or ``.csv``)
picks the reader or writer (``mcap_reader.py``, ``mcap_writer.py``, ``csv_io.py``)."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Iterator, Optional

from .csv_io import iter_csv_inputs, read_csv, read_csv_metadata, write_csv
from .format import ENCODINGS, PathArg, Recording, RecordingError, Tick
from .mcap_reader import iter_mcap_inputs, read_mcap, read_mcap_metadata
from .mcap_writer import DEFAULT_ENCODING, write_mcap

__all__ = ["check_suffix", "iter_inputs", "read_metadata", "read_recording", "write_recording"]


def check_suffix(path: PathArg) -> str:
    """``".mcap"`` or ``".csv"`` (any case); another suffix is a :class:`RecordingError`."""
    suffix = Path(path).suffix.lower()
    if suffix not in (".mcap", ".csv"):
        raise RecordingError(path, "file name", f"unknown suffix {suffix!r}: expected .mcap or .csv")
    return suffix


def read_recording(
    path: PathArg, *, robot_cables: Optional[int] = None, keep_topics: Iterable[str] = ()
) -> Recording:
    """Read a ``.mcap`` or ``.csv`` recording (dispatch on the suffix).

    ``robot_cables``: the robot's cable count; when given, every tick must have that many
    motor lengths (and forces). ``keep_topics``: MCAP topics besides the input to decode
    into ``Recording.extra`` (ignored for CSV, which has none).
    """
    if check_suffix(path) == ".mcap":
        return read_mcap(path, robot_cables=robot_cables, keep_topics=keep_topics)
    return read_csv(path, robot_cables=robot_cables)


def write_recording(path: PathArg, rec: Recording, *, encoding: Optional[str] = None) -> None:
    """Write ``rec`` as ``.mcap`` or ``.csv`` (dispatch on the suffix).

    ``encoding`` (MCAP only): ``"protobuf"`` (binary blocks, format 2; the default) or
    ``"json"`` (one JSON message per tick, format 1). A CSV file ignores it."""
    suffix = Path(path).suffix.lower()
    if encoding is not None and encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {list(ENCODINGS)}, got {encoding!r}")
    if suffix == ".mcap":
        write_mcap(path, rec, encoding=encoding or DEFAULT_ENCODING)
        return
    if suffix == ".csv":
        write_csv(path, rec)
        return
    raise ValueError(f"{path}: unknown suffix {suffix!r}: expected .mcap or .csv")


def iter_inputs(path: PathArg, *, robot_cables: Optional[int] = None) -> Iterator[Tick]:
    """Stream the ticks of a ``.mcap`` or ``.csv`` recording in file order."""
    if check_suffix(path) == ".mcap":
        return iter_mcap_inputs(path, robot_cables=robot_cables)
    return iter_csv_inputs(path, robot_cables=robot_cables)


def read_metadata(path: PathArg) -> dict[str, str]:
    """The file's metadata including ``robot`` and ``format`` (cheap; reads no ticks)."""
    if check_suffix(path) == ".mcap":
        return read_mcap_metadata(path)
    return read_csv_metadata(path)
