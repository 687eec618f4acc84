"""Frames in, complete ticks out: :class:`TickAssembler`.

Frames are grouped by their rolling ``tick_counter``, so frames of different ticks never
mix, and the SYNC frame closes the tick (the SYNC may carry data signals itself). A tick is
delivered only when every data frame of the DBC arrived before its SYNC; otherwise, or when
no SYNC comes within ``deadline_s`` of its first frame, the tick is rejected
(``missing_frames``, naming the missing messages). Nothing is ever filled in from an earlier
tick. Unknown ids, frames of the wrong length and classic/FD mismatches are ``bad_frame``.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Any, Literal, Optional, Union

import can
import numpy as np
from cantools.database.can import Database as CanDatabase

from cablesvc.sources.base import Rejection, TickInput
from cablesvc.sources.can.codec import FrameCodec, Signal, TickCodec
from cablesvc.sources.can.dbc import NOT_AVAILABLE, POSE_SIGNALS
from cablesvc.sources.can.layout import CanLayout, as_layout

__all__ = ["CLOCK_STEP_MARGIN_S", "EVENT_REASONS", "TickAssembler"]

#: A frame time this much [s] (beyond the deadline) earlier than the newest frame time seen
#: means the clock was stepped back (NTP, an operator): :class:`TickAssembler` re-bases.
CLOCK_STEP_MARGIN_S = 0.1
#: Reasons :class:`TickAssembler` returns that are events (counted in ``events``), not rejections.
EVENT_REASONS = frozenset({"clock_step"})


class _Partial:
    """A tick whose SYNC has not come yet: bus time of its first frame, how many data
    frames are in, and the frames' bytes by slot (then a place for the SYNC and the pad)."""

    __slots__ = ("first", "count", "frames")

    def __init__(self, first: float, frames: list[Any]):
        self.first = first
        self.count = 0
        self.frames = frames


@dataclass
class _Dead:
    since: float  # bus time at which the tick was rejected [s]
    late: int = 0


class _Slot:
    """Where one message goes in a tick, and where its tick_counter (SYNC: seq) sits."""

    __slots__ = ("index", "codec", "length", "is_fd", "is_sync", "fast", "b0", "b1", "order", "shift", "mask")

    def __init__(self, index: int, codec: FrameCodec, counter: Signal, is_sync: bool):
        self.index = index
        self.codec = codec
        self.length = codec.length
        self.is_fd = codec.is_fd
        self.is_sync = is_sync
        first, nbytes, shift = counter.span()
        self.b0, self.b1 = first, first + nbytes
        self.order: Literal["little", "big"] = "little" if counter.little_endian else "big"
        self.shift = shift
        self.mask = (1 << counter.length) - 1
        self.fast = counter.length == 8 and shift == 0

    def read(self, data: Union[bytes, bytearray]) -> int:
        if self.fast:
            return data[self.b0]
        return (int.from_bytes(data[self.b0:self.b1], self.order) >> self.shift) & self.mask


_PAD = b"\0"


class TickAssembler:
    """Frames in, complete ticks out (pure: all times come from the caller / the frames).

    :meth:`feed` takes one received :class:`can.Message` and returns what it completed or
    refused: :class:`~cablesvc.sources.base.TickInput` (not yet validated; ``stamp_ns`` =
    ``now_ns``, default ``time.monotonic_ns()``) and :class:`~cablesvc.sources.base.Rejection`
    items. Reasons: ``missing_frames`` (the message names the missing DBC messages),
    ``bad_frame`` (unknown id, wrong length, classic/FD mismatch, error/remote frame),
    ``late_frame`` (frames of a tick that was already rejected at its deadline),
    ``nonfinite`` (a tick in which some but not all forces, or some but not all pose values,
    are ``not_available``).

    Deadline: a tick whose SYNC has not arrived ``deadline_s`` [s] after its first frame is
    rejected. Time is *bus time*, the frames' ``timestamp`` [s] (python-can: receive time,
    ``time.time()`` scale), so a receive thread that falls behind and then reads a burst of
    queued frames does not reject ticks whose frames were all there in time. Each
    :meth:`feed` checks the deadlines against the newest frame time seen (only when the
    oldest pending tick may be due);
    :meth:`expire` checks them against ``bus_time`` (default ``time.time()``) when the bus
    is quiet. A frame without a timestamp (0) gets ``time.time()``.

    Clock steps: a frame time more than ``deadline_s`` + :data:`CLOCK_STEP_MARGIN_S` earlier
    than the newest frame time seen cannot be a queued or late frame (those come in time
    order): the clock was stepped back (NTP). The assembler re-bases its bus time on the new
    clock (pending ticks keep their age) and returns one ``clock_step`` item (a
    :class:`~cablesvc.sources.base.Rejection` whose reason is in :data:`EVENT_REASONS`: an
    event, nothing was refused), so ticks keep flowing instead of all expiring until the
    clock catches up.

    Cost: a data frame is a dict lookup, a counter read and a list store (its bytes are
    kept as they came); the SYNC decodes the whole tick with one numpy gather
    (:class:`FrameCodec` plans laid end to end).
    """

    def __init__(self, db: Union[CanLayout, CanDatabase, str, os.PathLike[str]], deadline_s: float = 0.005):
        self.layout = as_layout(db)
        if not (math.isfinite(deadline_s) and deadline_s > 0):
            raise ValueError(f"deadline_s must be > 0 s, got {deadline_s!r}")
        self.deadline = float(deadline_s)
        lay = self.layout
        self._tick: TickCodec = lay.tick
        self._cmask = (1 << lay.counter_bits) - 1
        self._pending: dict[int, _Partial] = {}
        self._dead: dict[int, _Dead] = {}
        self._bus_now = -math.inf
        self._earliest = math.inf  # <= the first-frame time of every pending or dead tick
        self._n_data = len(lay.data)
        self._std: dict[int, _Slot] = {}
        self._ext: dict[int, _Slot] = {}
        for i, c in enumerate(lay.data):
            (self._ext if c.is_extended else self._std)[c.frame_id] = _Slot(
                i, c, c.signals[c.index["tick_counter"]], False)
        sync = lay.sync
        (self._ext if sync.is_extended else self._std)[sync.frame_id] = _Slot(
            self._n_data, sync, sync.signals[sync.index["seq"]], True)
        self._blank: list[Any] = [None] * (self._n_data + 1) + [_PAD]

    @property
    def pending(self) -> int:
        """Number of ticks started (some frames in) and not yet closed or expired."""
        return len(self._pending)

    def next_deadline(self) -> Optional[float]:
        """Bus time [s] at which :meth:`expire` next has something to do (None: nothing
        pending). Never later than the true time; possibly earlier (then :meth:`expire`
        finds nothing and corrects it)."""
        if not self._pending and not self._dead:
            return None
        return self._earliest + self.deadline

    def _missing(self, p: Optional[_Partial]) -> list[str]:
        if p is None:
            return self.layout.data_names
        return [c.name for c, f in zip(self.layout.data, p.frames) if f is None]

    def feed(self, msg: can.Message, now_ns: Optional[int] = None) -> list[Union[TickInput, Rejection]]:
        """Take one frame; return the ticks it completed and the rejections it caused
        (including ticks whose deadline passed by this frame's time)."""
        ts = msg.timestamp or time.time()
        step: Optional[Rejection] = None
        if ts > self._bus_now:
            self._bus_now = ts
        elif ts < self._bus_now - self.deadline - CLOCK_STEP_MARGIN_S:
            step = self._rebase(ts)
        slot = (self._ext if msg.is_extended_id else self._std).get(msg.arbitration_id)
        data = msg.data
        if (slot is None or msg.is_error_frame or msg.is_remote_frame or len(data) != slot.length
                or msg.is_fd != slot.is_fd):
            out: list[Union[TickInput, Rejection]] = [self._bad_frame(msg, slot)]
        elif slot.is_sync:
            out = self._close(slot, data, now_ns)
        else:
            c = data[slot.b0] if slot.fast else slot.read(data)
            out = []
            if self._dead and c in self._dead:
                self._dead[c].late += 1
            else:
                p = self._pending.get(c)
                if p is None:
                    p = self._start(c, ts)
                elif p.frames[slot.index] is not None:
                    # a second frame of the same message with this counter: the earlier tick
                    # never got its SYNC. Reject it and start over with this frame.
                    out.append(Rejection(
                        "missing_frames",
                        f"tick with tick_counter {c}: no SYNC before the next {slot.codec.name} with the same "
                        f"counter; missing: {', '.join(self._missing(p) + [self.layout.sync.name])}",
                    ))
                    p = self._start(c, ts)
                p.frames[slot.index] = bytes(data)  # a copy: the caller may reuse the message
                p.count += 1
        if self._bus_now - self._earliest > self.deadline:
            out.extend(self.expire(bus_time=self._bus_now))
        if step is not None:
            out.insert(0, step)
        return out

    def _rebase(self, ts: float) -> Rejection:
        """The clock went back: move bus time to ``ts``, shifting pending and rejected ticks'
        times with it (they keep their age)."""
        shift = ts - self._bus_now
        for p in self._pending.values():
            p.first += shift
        for d in self._dead.values():
            d.since += shift
        self._earliest += shift
        self._bus_now = ts
        return Rejection("clock_step",
                         f"frame time went back {-shift:.3f} s (clock stepped back?): deadlines re-based on the "
                         f"new clock, {len(self._pending)} pending tick(s) kept")

    def _start(self, counter: int, ts: float) -> _Partial:
        p = self._pending[counter] = _Partial(ts, self._blank.copy())
        if ts < self._earliest:
            self._earliest = ts
        return p

    def _bad_frame(self, msg: can.Message, slot: Optional[_Slot]) -> Rejection:
        if msg.is_error_frame:
            return Rejection("bad_frame", f"error frame on the bus (id 0x{msg.arbitration_id:X})")
        if slot is None:
            width = 8 if msg.is_extended_id else 3
            return Rejection("bad_frame",
                             f"unknown CAN id 0x{msg.arbitration_id:0{width}X}"
                             f"{' (extended)' if msg.is_extended_id else ''}: not in {self.layout.path}")
        codec = slot.codec
        if msg.is_remote_frame:
            return Rejection("bad_frame", f"{codec.name} (0x{codec.frame_id:X}): remote frame, expected data")
        if bool(msg.is_fd) != codec.is_fd:
            want = "a CAN FD frame" if codec.is_fd else "a classic CAN frame"
            return Rejection("bad_frame",
                             f"{codec.name} (0x{codec.frame_id:X}): {len(msg.data)} data bytes in "
                             f"{'a CAN FD' if msg.is_fd else 'a classic'} frame, the DBC says {want} "
                             f"of {codec.length} bytes")
        return Rejection("bad_frame",
                         f"{codec.name} (0x{codec.frame_id:X}): {len(msg.data)} data bytes"
                         f"{' (CAN FD)' if msg.is_fd else ''}, the DBC says {codec.length}")

    def _close(self, slot: _Slot, data: Union[bytes, bytearray],
               now_ns: Optional[int]) -> list[Union[TickInput, Rejection]]:
        seq = slot.read(data)
        if not self._n_data:
            return [self._build([data, _PAD], seq, now_ns)]
        counter = seq & self._cmask
        p = self._pending.pop(counter, None)
        if p is None:
            return [self._orphan_sync(data, seq, counter)]
        if not self._pending and not self._dead:
            self._earliest = math.inf
        if p.count != self._n_data:
            return [Rejection("missing_frames",
                              f"tick seq {seq} (t {self._t_of(data)!r} s): missing {', '.join(self._missing(p))} "
                              f"at {self.layout.sync.name}")]
        frames = p.frames
        frames[-2] = data
        return [self._build(frames, seq, now_ns)]

    def _t_of(self, sync_data: Union[bytes, bytearray]) -> float:
        return self.layout.sync.decode(sync_data)["t"]

    def _orphan_sync(self, data: Union[bytes, bytearray], seq: int, counter: int) -> Rejection:
        name = self.layout.sync.name
        dead = self._dead.pop(counter, None)
        if not self._pending and not self._dead:
            self._earliest = math.inf
        if dead is not None:
            return Rejection("late_frame",
                             f"tick seq {seq}: {name} and {dead.late} other frame(s) arrived after the "
                             f"{self.deadline * 1e3:g} ms deadline; the tick was already rejected")
        return Rejection("missing_frames",
                         f"tick seq {seq} (t {self._t_of(data)!r} s): {name} arrived but no other frame of the tick; "
                         f"missing: {', '.join(self._missing(None))}")

    def _build(self, frames: list[Any], seq: int, now_ns: Optional[int]) -> Union[TickInput, Rejection]:
        tc = self._tick
        _x, v, na = tc.decode(b"".join(frames))
        force = position = orientation = None
        temperature = None
        if np.count_nonzero(na):
            return self._build_partial(v, na, seq, now_ns)
        if tc.k_force is not None:
            force = v[tc.k_force]
        if tc.k_pos is not None:
            position, orientation = v[tc.k_pos], v[tc.k_ori]
        if tc.k_temp is not None:
            temperature = float(v[tc.k_temp])
        return TickInput(seq=seq, t=float(v[tc.k_t]), motor_length=v[tc.k_ml], position=position,
                         orientation=orientation, force=force, temperature=temperature,
                         stamp_ns=time.monotonic_ns() if now_ns is None else now_ns)

    def _build_partial(self, v: np.ndarray, na: np.ndarray, seq: int,
                       now_ns: Optional[int]) -> Union[TickInput, Rejection]:
        """A tick with some values not_available: all forces or none, a whole pose or none."""
        tc = self._tick
        t = float(v[tc.k_t])
        v[na] = math.nan
        force = position = orientation = None
        temperature = None
        if tc.k_force is not None:
            fna = na[tc.k_force]
            if fna.any() and not fna.all():
                names = [f"force_{i} ({self.layout.where[f'force_{i}'][0].name})" for i in np.flatnonzero(fna)]
                return Rejection("nonfinite",
                                 f"tick seq {seq} (t {t!r} s): {', '.join(names)} {NOT_AVAILABLE} while other "
                                 f"cables have a force; a tick has all forces or none")
            if not fna.any():
                force = v[tc.k_force]
        if tc.k_pose is not None:
            pna = na[tc.k_pose]
            if pna.any() and not pna.all():
                names = [f"{POSE_SIGNALS[k]} ({self.layout.where[POSE_SIGNALS[k]][0].name})"
                         for k in np.flatnonzero(pna)]
                return Rejection("nonfinite",
                                 f"tick seq {seq} (t {t!r} s): {', '.join(names)} {NOT_AVAILABLE} while the rest "
                                 f"of the pose is given; a pose has all seven values or none")
            if not pna.any():
                position, orientation = v[tc.k_pos], v[tc.k_ori]
        if tc.k_temp is not None and not na[tc.k_temp]:
            temperature = float(v[tc.k_temp])
        return TickInput(seq=seq, t=t, motor_length=v[tc.k_ml], position=position, orientation=orientation,
                         force=force, temperature=temperature,
                         stamp_ns=time.monotonic_ns() if now_ns is None else now_ns)

    def expire(self, bus_time: Optional[float] = None) -> list[Rejection]:
        """Reject the ticks whose SYNC did not come within the deadline of their first frame,
        judged at ``bus_time`` [s] (default ``time.time()``: call it when the bus is quiet)."""
        now = time.time() if bus_time is None else float(bus_time)
        out: list[Rejection] = []
        earliest = math.inf
        if self._pending:
            for counter in [c for c, p in self._pending.items() if now - p.first > self.deadline]:
                p = self._pending.pop(counter)
                out.append(Rejection(
                    "missing_frames",
                    f"tick with tick_counter {counter}: no {self.layout.sync.name} within "
                    f"{self.deadline * 1e3:g} ms of its first frame; missing: "
                    f"{', '.join(self._missing(p) + [self.layout.sync.name])}",
                ))
                self._dead[counter] = _Dead(now)
            for p in self._pending.values():
                earliest = min(earliest, p.first)
        if self._dead:
            for counter in [c for c, d in self._dead.items() if now - d.since > self.deadline]:
                d = self._dead.pop(counter)
                if d.late:
                    out.append(Rejection(
                        "late_frame",
                        f"tick with tick_counter {counter}: {d.late} frame(s) arrived after its deadline "
                        f"and no {self.layout.sync.name}; the tick was already rejected",
                    ))
            for d in self._dead.values():
                earliest = min(earliest, d.since)
        self._earliest = earliest
        return out

