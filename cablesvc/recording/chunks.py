"""Recordings in chunks: :func:`iter_chunks` yields a long recording as a sequence of
:class:`~cablesvc.recording.Recording` pieces of about ``ticks`` ticks each, in file order,
with one piece in memory at a time (plus the reader's one MCAP chunk).

Offline analyses that carry their own state across the pieces (the discovery's streamed
path, :mod:`cablesvc.discover.stream`) use this instead of :func:`read_recording`, whose
result grows with the recording (a 1 kHz, 8-cable hour is 3.6 M ticks, some 600 MB of
arrays before any analysis). Both encodings of MCAP and CSV files are read; a binary block
(format 2) is never split, so a piece may be up to one block longer than ``ticks``.
"""

from __future__ import annotations

import warnings
from typing import Iterator, Optional

from .csv_io import iter_csv_inputs, read_csv_metadata
from .files import check_suffix
from .format import Recording, RecordingTruncatedWarning, TickColumns
from .mcap_reader import BLOCK, McapSource

__all__ = ["iter_chunks"]


def iter_chunks(path, ticks: int = 65536, *, robot_cables: Optional[int] = None) -> Iterator[Recording]:
    """The recording at ``path`` (``.mcap`` or ``.csv``) in pieces of about ``ticks`` ticks.

    Errors are the readers' own (:class:`RecordingError` naming the file and place); an
    incomplete file ends after its last complete tick with a
    :class:`RecordingTruncatedWarning`, as :func:`read_recording` does."""
    if ticks < 1:
        raise ValueError(f"ticks must be >= 1, got {ticks}")
    if check_suffix(path) == ".mcap":
        yield from _mcap_chunks(path, ticks, robot_cables)
    else:
        yield from _csv_chunks(path, ticks, robot_cables)


def _mcap_chunks(path, ticks: int, robot_cables: Optional[int]) -> Iterator[Recording]:
    src = McapSource(path, robot_cables)
    trunc = None
    try:
        cols = TickColumns(robot_cables)
        for topic, item in src.messages():
            if topic is None:
                cols.append(*item)
            elif topic is BLOCK:
                cols.add_block(item)
            if len(cols) >= ticks:
                n_c = cols.n_cables
                yield cols.build(src.robot, src.other_metadata)
                cols = TickColumns(n_c if robot_cables is None else robot_cables)
        src.check_input_channel()
        trunc = src.truncation()
        if len(cols):
            yield cols.build(src.robot, src.other_metadata)
    finally:
        src.close()
    if trunc is not None:
        warnings.warn(RecordingTruncatedWarning(trunc.message), stacklevel=2)


def _csv_chunks(path, ticks: int, robot_cables: Optional[int]) -> Iterator[Recording]:
    meta = read_csv_metadata(path)
    robot = meta.get("robot", "")
    other = {k: v for k, v in meta.items() if k not in ("robot", "format")}
    cols = TickColumns(robot_cables)
    for tk in iter_csv_inputs(path, robot_cables=robot_cables):
        cols.append(tk["seq"], tk["t"], tk["position"], tk["orientation"], tk["motor_length"], tk["force"],
                    tk["temperature"])
        if len(cols) >= ticks:
            n_c = cols.n_cables
            yield cols.build(robot, other)
            cols = TickColumns(n_c)
    if len(cols):
        yield cols.build(robot, other)
