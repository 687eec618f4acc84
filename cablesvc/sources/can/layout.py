"""A DBC read and checked against the cablesvc conventions (:class:`CanLayout`), and the
frames of one tick from it (:func:`encode_tick`).

:func:`load_can_layout` reads a DBC with cantools, checks it (one SYNC message with ``seq``
and ``t``; a ``tick_counter`` in every data frame; motor lengths for every cable; all
forces or none; a whole pose or none; known signal names; frame lengths that fit classic
CAN or CAN FD; no shared ids) and raises every problem at once as
:class:`~cablesvc.sources.base.SourceConfigError`, naming file, message and signal.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import can
import cantools
from cantools.database.can import Database as CanDatabase

from cablesvc.sources.base import SourceConfigError
from cablesvc.sources.can.codec import FrameCodec, Signal, TickCodec, signal_of
from cablesvc.sources.can.dbc import FD_LENGTHS, POSE_SIGNALS

__all__ = ["CanLayout", "as_layout", "encode_tick", "load_can_layout"]

_CABLE_RE = re.compile(r"^(motor_length|force)_(\d+)$")


@dataclass
class CanLayout:
    """A DBC checked against the cablesvc conventions (see the module docstring and
    :mod:`cablesvc.sources.can.dbc`).

    ``n_cables``; ``sync``: the SYNC codec; ``data``: the data-frame codecs in sending
    order (every one of them must arrive for a tick to complete); ``counter_bits``,
    ``seq_bits``; ``has_force``/``has_pose``/``has_temperature``: which quantities the DBC
    carries; ``fd``: some message is a CAN FD frame (the bus must be opened with fd=True).
    """

    path: str
    db: CanDatabase
    n_cables: int
    sync: FrameCodec
    data: list[FrameCodec]
    counter_bits: int
    seq_bits: int
    has_force: bool
    has_pose: bool
    has_temperature: bool
    by_id: dict[tuple[int, bool], FrameCodec] = field(default_factory=dict)
    #: signal name -> (message codec, index in its signals)
    where: dict[str, tuple[FrameCodec, int]] = field(default_factory=dict)
    fd: bool = False
    #: the whole tick compiled into one plan (set by :func:`load_can_layout`)
    tick: Any = field(default=None, repr=False)

    @property
    def data_names(self) -> list[str]:
        return [c.name for c in self.data]

    @property
    def frames(self) -> list[FrameCodec]:
        """Every message of a tick in sending order (data frames, then SYNC)."""
        return [*self.data, self.sync]

    @property
    def frames_per_tick(self) -> int:
        return len(self.data) + 1

    @property
    def bytes_per_tick(self) -> int:
        """Data bytes per tick (sum of the DLC lengths)."""
        return sum(c.length for c in self.frames)

    def signal(self, name: str) -> Signal:
        codec, k = self.where[name]
        return codec.signals[k]


# a layout compiled from a cantools Database object is kept on that object (it lives as
# long as the database), so encode_tick(db, ...) compiles once per database
_CACHE_ATTR = "_cablesvc_layouts"
_DATA_NAMES_HELP = ("motor_length_<i>, force_<i>, position_x/y/z, orientation_qx/qy/qz/qw, temperature, "
                    "tick_counter")


def load_can_layout(dbc: Union[str, os.PathLike[str], CanDatabase], n_cables: Optional[int] = None) -> CanLayout:
    """Read (or take) a DBC and check it against the cablesvc conventions.

    ``n_cables``: the robot's cable count (None: taken from the DBC). Every problem found is
    raised at once as :class:`SourceConfigError` naming the file, message and signal.
    """
    if isinstance(dbc, CanDatabase):
        db, path = dbc, "<database>"
        cached = getattr(db, _CACHE_ATTR, {}).get(-1 if n_cables is None else n_cables)
        if cached is not None:
            return cached
    else:
        path = os.fspath(dbc)
        if not Path(path).is_file():
            raise SourceConfigError(f"{path}: DBC file not found")
        try:
            db = cantools.database.load_file(path, database_format="dbc", strict=True)
        except Exception as exc:  # cantools raises several parser error types
            raise SourceConfigError(f"{path}: not a readable DBC file: {exc}") from None
    problems: list[str] = []
    sync: Optional[FrameCodec] = None
    data: list[FrameCodec] = []
    where: dict[str, tuple[FrameCodec, int]] = {}
    counter_bits: set[int] = set()
    cables: dict[str, set[int]] = {"motor_length": set(), "force": set()}
    any_fd = False
    for msg in db.messages:
        mwhere = f"{path}: message {msg.name} (0x{msg.frame_id:X})"
        if msg.is_fd:
            any_fd = True
            if msg.length not in FD_LENGTHS:
                problems.append(f"{mwhere}: {msg.length} bytes is not a CAN FD frame length "
                                f"({', '.join(map(str, FD_LENGTHS))})")
        elif msg.length > 8:
            problems.append(f"{mwhere}: {msg.length} bytes in a classic CAN frame (at most 8; a longer frame "
                            f"must be a CAN FD frame: VFrameFormat StandardCAN_FD)")
        sigs = [signal_of(s, mwhere, problems) for s in msg.signals]
        try:
            codec = FrameCodec(msg, sigs)
        except ValueError as exc:
            problems.append(f"{mwhere}: {exc}")
            continue
        names = {s.name for s in sigs}
        is_sync = "seq" in names or "t" in names
        if is_sync:
            if sync is not None:
                problems.append(f"{mwhere}: a second SYNC message (signals seq, t); {sync.name} is the first")
            if not {"seq", "t"} <= names:
                problems.append(f"{mwhere}: the SYNC message needs both signals seq and t")
            if "tick_counter" in names:
                problems.append(f"{mwhere}: the SYNC message carries seq; it has no tick_counter")
            sync = codec
        else:
            if "tick_counter" not in names:
                problems.append(f"{mwhere}: data frame without a tick_counter signal")
            data.append(codec)
        for k, s in enumerate(sigs):
            if s.name == "tick_counter":
                counter_bits.add(s.length)
                if s.signed or s.is_float or s.scale != 1 or s.offset != 0:
                    problems.append(f"{mwhere}: tick_counter must be an unsigned integer with scale 1, offset 0")
                continue
            if is_sync and s.name in ("seq", "t"):
                where[s.name] = (codec, k)
                continue
            mt = _CABLE_RE.match(s.name)
            if mt:
                cables[mt.group(1)].add(int(mt.group(2)))
            elif s.name not in POSE_SIGNALS and s.name != "temperature":
                problems.append(f"{mwhere}: unknown signal {s.name!r} (known: {_DATA_NAMES_HELP}"
                                f"{'; and seq, t in the SYNC' if is_sync else ''})")
                continue
            if s.name in where:
                problems.append(f"{mwhere}: signal {s.name} also in message {where[s.name][0].name}")
            where[s.name] = (codec, k)
    if sync is None:
        problems.append(f"{path}: no SYNC message (a message with signals seq and t)")
    if len(counter_bits) > 1:
        problems.append(f"{path}: tick_counter has different widths {sorted(counter_bits)}; use one width")
    cbits = min(counter_bits) if counter_bits else 8
    seq_bits = 0
    if sync is not None and "seq" in sync.index:
        s = sync.signals[sync.index["seq"]]
        seq_bits = s.length
        if s.signed or s.is_float or s.scale != 1 or s.offset != 0:
            problems.append(f"{path}: SYNC.seq must be an unsigned integer with scale 1, offset 0")
        if seq_bits < cbits:
            problems.append(f"{path}: SYNC.seq has {seq_bits} bits, fewer than tick_counter ({cbits})")
        if seq_bits > 53:
            problems.append(f"{path}: SYNC.seq has {seq_bits} bits; at most 53 are supported")
    ml = cables["motor_length"]
    m = n_cables if n_cables is not None else len(ml)
    if ml != set(range(m)):
        problems.append(
            f"{path}: motor_length signals for cables {sorted(ml)}; the robot has {m} cables "
            f"(motor_length_0..motor_length_{m - 1} needed)"
        )
    fs = cables["force"]
    if fs and fs != set(range(m)):
        problems.append(f"{path}: force signals for cables {sorted(fs)}; give force_0..force_{m - 1} or none")
    for i in range(m):
        loc = where.get(f"motor_length_{i}")
        if loc is not None and loc[0].signals[loc[1]].not_available is not None:
            problems.append(f"{path}: motor_length_{i} has a not_available value; motor lengths are always required")
    pose = [n for n in POSE_SIGNALS if n in where]
    if pose and len(pose) != len(POSE_SIGNALS):
        missing = [n for n in POSE_SIGNALS if n not in where]
        problems.append(f"{path}: pose signals {missing} are missing; give all seven or none")
    ids: dict[tuple[int, bool], str] = {}
    for codec in ([sync] if sync else []) + data:
        key = (codec.frame_id, codec.is_extended)
        if key in ids:
            problems.append(f"{path}: messages {ids[key]} and {codec.name} share id 0x{codec.frame_id:X}")
        ids[key] = codec.name
    if problems:
        raise SourceConfigError(f"DBC {path}: {len(problems)} problem(s):\n" + "\n".join(problems))
    assert sync is not None
    layout = CanLayout(
        path=path, db=db, n_cables=m, sync=sync, data=data, counter_bits=cbits, seq_bits=seq_bits,
        has_force=bool(fs), has_pose=bool(pose), has_temperature="temperature" in where,
        by_id={(c.frame_id, c.is_extended): c for c in [sync, *data]}, where=where, fd=any_fd,
    )
    layout.tick = TickCodec(layout)
    if isinstance(dbc, CanDatabase):
        cache = getattr(db, _CACHE_ATTR, None)
        if cache is None:
            cache = {}
            try:
                setattr(db, _CACHE_ATTR, cache)
            except AttributeError:  # a database class with __slots__: just do not cache
                pass
        cache[-1 if n_cables is None else n_cables] = layout
    return layout


def as_layout(db: Union[CanLayout, CanDatabase, str, os.PathLike[str]]) -> CanLayout:
    """``db`` itself when it is a :class:`CanLayout`, else :func:`load_can_layout` of it."""
    return db if isinstance(db, CanLayout) else load_can_layout(db)


def encode_tick(db: Union[CanLayout, CanDatabase, str, os.PathLike[str]], tick: Any) -> list[can.Message]:
    """The frames of one tick, in sending order (data frames, then SYNC).

    ``db``: a :class:`CanLayout`, a cantools database or a DBC path. ``tick``: anything
    with the :class:`~cablesvc.sources.base.TickInput` fields (attributes or dict keys:
    seq, t [s], motor_length [m], position [m], orientation, force [N], temperature
    [deg C]); None (or NaN) for a part is sent as ``not_available``. ``seq`` is sent
    modulo 2**seq_bits. Raises ValueError naming the signal when a value does not fit.
    Pure: no bus, no clock. CAN FD messages come out with ``is_fd`` (and
    ``bitrate_switch`` from the DBC's CANFD_BRS, default on).
    """
    tc: TickCodec = as_layout(db).tick
    return tc.messages(tc.encode(tick).tobytes())
