"""The one input interface of the live daemon: :class:`Source`, its tick and its checks.

Every transport (CAN, Modbus TCP, recording replay) is a :class:`Source` subclass chosen by
configuration (``cablesvc.sources.open_source``). A source hands the daemon validated
:class:`TickInput` objects, one per controller tick, through :meth:`Source.recv`.

Bad input never raises out of a source and is never repaired by guessing: every rejected
tick or frame becomes a :class:`Problem` (short stable ``reason`` code plus a message that
names the file / field / frame at fault), is counted in :class:`SourceCounters` by reason,
and the source keeps running. :class:`TickValidator` holds the checks that every source
shares (shapes, finite values, ranges, unit quaternion, time and sequence order).

Units are SI throughout: m, N, s, deg C; quaternions ``[qx, qy, qz, qw]``.
"""

from __future__ import annotations

import collections
import math
import os
import queue
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Optional

import numpy as np

from cablesvc.config.robot import Robot, RobotGeometry, robot_search_path
from cablesvc.errors import SourceError

__all__ = [
    "DEFAULT_MAX_MOTOR_LENGTH",
    "PROBLEM_BUFFER",
    "Problem",
    "Rejection",
    "Source",
    "SourceConfigError",
    "SourceCounters",
    "ThreadedSource",
    "TickInput",
    "TickValidator",
    "find_robot_companion",
]

#: Default upper bound of an accepted motor length [m] (:class:`TickValidator`).
DEFAULT_MAX_MOTOR_LENGTH = 100.0
#: How many undrained problems a source keeps; older ones are dropped (and counted).
PROBLEM_BUFFER = 1000


class SourceConfigError(SourceError, ValueError):
    """A source configuration (or a file it names: DBC, register map) that cannot be used.

    The message names the field (``can.dbc``, ``modbus.register_map``, ``replay.path``, or
    the file and entry) and says why.
    """


@dataclass(slots=True)
class TickInput:
    """One controller tick as a source delivers it (SI units).

    ``seq``: controller tick counter (after :class:`TickValidator`, unwrapped: it keeps
    counting past the width of the field on the bus); ``t``: controller clock [s];
    ``motor_length`` (m,) float64 C-contiguous [m]; ``position`` (3,) [m] or None;
    ``orientation`` (4,) unit quaternion ``[qx, qy, qz, qw]`` or None; ``force`` (m,)
    measured cable forces [N] or None; ``temperature`` [deg C] or None; ``stamp_ns``:
    ``time.monotonic_ns()`` when the tick became complete at the source (the origin of the
    daemon's latency measurements).
    """

    seq: int
    t: float
    motor_length: np.ndarray
    position: Optional[np.ndarray]
    orientation: Optional[np.ndarray]
    force: Optional[np.ndarray]
    temperature: Optional[float]
    stamp_ns: int


@dataclass
class Problem:
    """One rejected input (or one input-side event) for the daemon to log or publish.

    ``wall_time``: ``time.time()`` when it was found [s since the epoch]; ``reason``: a short
    stable code (``nonfinite``, ``out_of_range``, ``bad_shape``, ``bad_quaternion``,
    ``time_backwards``, ``duplicate_seq``, ``seq_backwards``, ``missing_frames``,
    ``bad_frame``, ``late_frame``, ``modbus_error``, ``torn_read``, ``recording_error``,
    ``time_jump``, ``queue_overflow``, ``bad_line`` (a damaged line of a CSV replay); events: ``disconnected``, ``reconnected``, ``resync``,
    ``truncated``, ``robot_mismatch``, ``time_jump``); ``message``: what and where, in words; ``kind``:
    ``"rejected"`` (an input was refused) or ``"event"`` (something happened to the link).
    """

    wall_time: float
    reason: str
    message: str
    kind: str = "rejected"


@dataclass(slots=True)
class Rejection:
    """Why one tick or frame was refused: ``reason`` code and ``message`` (see :class:`Problem`)."""

    reason: str
    message: str


@dataclass
class SourceCounters:
    """What a source has seen since it was created.

    ``accepted``: ticks delivered (a tick that passed the checks but was then dropped from a
    full queue is moved from ``accepted`` to ``rejected["queue_overflow"]``, so that
    ``accepted`` + ``rejected`` counts every tick once); ``rejected``: refused ticks/frames
    by reason;
    ``events``: non-rejections by reason (``disconnected``, ``reconnected``, ``resync``, ...);
    ``unchanged``: polls that saw the same tick again (Modbus polling faster than the
    controller; normal, not an error); ``missed_ticks``: gaps in ``seq`` between accepted
    ticks (ticks the source never delivered, whatever the cause; a tick dropped from a full
    queue is counted as ``queue_overflow`` instead); ``problems_dropped``:
    problems lost because nobody drained :meth:`Source.problems` in time.
    """

    accepted: int = 0
    rejected: collections.Counter = field(default_factory=collections.Counter)
    events: collections.Counter = field(default_factory=collections.Counter)
    unchanged: int = 0
    missed_ticks: int = 0
    problems_dropped: int = 0

    def as_dict(self) -> dict:
        """Plain-dict snapshot: ``{"accepted": n, "rejected": {reason: n}, ...}``."""
        return {
            "accepted": int(self.accepted),
            "rejected": dict(self.rejected),
            "events": dict(self.events),
            "unchanged": int(self.unchanged),
            "missed_ticks": int(self.missed_ticks),
            "problems_dropped": int(self.problems_dropped),
        }


def _fmt(v: float) -> str:
    """A number for a message (repr of the float; 'nan'/'inf' spelled as Python does)."""
    return repr(float(v))


class _Where:
    """``tick seq N (t T s)`` of a tick, made when formatted."""

    __slots__ = ("tick",)

    def __init__(self, tick: TickInput):
        self.tick = tick

    def __str__(self) -> str:
        tick = self.tick
        try:
            return f"tick seq {int(tick.seq)} (t {_fmt(tick.t)} s)"
        except (TypeError, ValueError):
            return f"tick seq {tick.seq!r} (t {tick.t!r})"

    __format__ = lambda self, spec: format(str(self), spec)  # noqa: E731


class TickValidator:
    """The checks every source applies to a tick before delivering it.

    Rejects (reason code in brackets): wrong shapes or types [``bad_shape``]; non-finite
    ``t``, motor lengths, pose, forces or temperature [``nonfinite``]; a motor length
    <= 0 m or > ``max_motor_length`` [m] [``out_of_range``]; a force whose magnitude is above
    ``force_factor`` times the cable's ``force_max`` of the robot file [``out_of_range``]; an
    orientation whose norm differs from 1 by more than ``quaternion_tolerance``
    [``bad_quaternion``] (within the tolerance it is renormalised); the same ``seq`` as the
    last accepted tick [``duplicate_seq``]; a smaller ``seq`` [``seq_backwards``]; ``t`` not
    above the last accepted ``t`` [``time_backwards``].

    ``seq_bits``: width of the controller's counter on the bus (None: unbounded). With it,
    ``seq`` is taken modulo 2**seq_bits: a step forward of less than half the range is a
    new tick (the wrap-around is followed), and the accepted tick's ``seq`` is unwrapped
    into a count that keeps increasing. ``resync_after``: after that many consecutive order
    rejections (a controller restart: its clock and counter start again) the next tick is
    accepted as the start of a new timeline and :attr:`resync_note` says so. An exact repeat
    of the last accepted tick (same ``seq``, same ``t``: a frozen controller) is always
    ``duplicate_seq`` and never counts towards a resync.

    :meth:`check` counts into :attr:`counters` (shared with the owning source).
    """

    def __init__(
        self,
        robot: Robot | RobotGeometry,
        *,
        max_motor_length: float = DEFAULT_MAX_MOTOR_LENGTH,
        force_factor: float = 10.0,
        quaternion_tolerance: float = 1e-3,
        seq_bits: Optional[int] = None,
        resync_after: int = 100,
        counters: Optional[SourceCounters] = None,
    ):
        geom = robot.geometry() if isinstance(robot, Robot) else robot
        if not (math.isfinite(max_motor_length) and max_motor_length > 0):
            raise ValueError(f"max_motor_length must be a finite number > 0 m, got {max_motor_length!r}")
        if seq_bits is not None and not (1 <= int(seq_bits) <= 64):
            raise ValueError(f"seq_bits must be in 1..64, got {seq_bits!r}")
        self.n_cables = int(geom.n_cables)
        self.cable_names = tuple(geom.cable_names)
        self.max_motor_length = float(max_motor_length)
        self.force_limit = np.asarray(geom.force_max, dtype=np.float64) * float(force_factor)
        self.force_factor = float(force_factor)
        self.quaternion_tolerance = float(quaternion_tolerance)
        self.seq_bits = None if seq_bits is None else int(seq_bits)
        self._modulus = None if seq_bits is None else 1 << int(seq_bits)
        self.resync_after = int(resync_after)
        self.counters = counters if counters is not None else SourceCounters()
        #: Set by :meth:`check` when the tick it accepted restarted the timeline (else None).
        self.resync_note: Optional[str] = None
        self.reset()

    def reset(self) -> None:
        """Forget the last accepted tick (the next tick is accepted whatever its seq/t)."""
        self.last_seq: Optional[int] = None  # unwrapped
        self.last_raw_seq: Optional[int] = None
        self.last_t: Optional[float] = None
        self._order_rejections = 0

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _where(tick: TickInput) -> "_Where":
        """Where a tick is, for messages: formatted only when a message is made (the
        accepted-tick path runs at 1 kHz and never needs it)."""
        return _Where(tick)

    def _vector(self, tick: TickInput, name: str, value: Any, n: int, unit: str):
        """Return (array, None) or (None, Rejection) for a (n,) float vector field."""
        try:
            arr = np.ascontiguousarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            return None, Rejection("bad_shape", f"{self._where(tick)}: {name} is not numeric: {exc}")
        if arr.shape != (n,):
            return None, Rejection(
                "bad_shape", f"{self._where(tick)}: {name} has shape {arr.shape}, expected ({n},) [{unit}]"
            )
        if math.isfinite(arr.sum()):          # one reduction on the normal path
            return arr, None
        bad = ~np.isfinite(arr)                # a NaN/inf, or finite values whose sum overflowed
        if bad.any():
            i = int(np.argmax(bad))
            more = f" (and {int(bad.sum()) - 1} more)" if bad.sum() > 1 else ""
            return None, Rejection(
                "nonfinite", f"{self._where(tick)}: {name}[{i}] is {_fmt(arr[i])}{more}; values must be finite"
            )
        return arr, None

    # ------------------------------------------------------------------ check
    def check(self, tick: TickInput) -> Optional[Rejection]:
        """Validate ``tick``; None when accepted, else the :class:`Rejection`.

        On acceptance the tick is normalised in place: arrays become float64 C-contiguous
        copies, the orientation is renormalised, ``seq`` is unwrapped (``seq_bits``), and
        the tick becomes the reference for the order checks. A rejected tick changes
        nothing but the counters.
        """
        self.resync_note = None
        rej, resync = self._check(tick)
        if rej is None:
            self.counters.accepted += 1
            if resync is not None:
                self.resync_note = resync
                self.counters.events["resync"] += 1
        else:
            self.counters.rejected[rej.reason] += 1
        return rej

    def _check(self, tick: TickInput) -> tuple[Optional[Rejection], Optional[str]]:
        where = self._where(tick)
        # ---- scalars
        seq = tick.seq
        if isinstance(seq, (bool, np.bool_)) or not isinstance(seq, (int, np.integer)):
            return Rejection("bad_shape", f"{where}: seq must be an integer, got {type(seq).__name__}"), None
        seq = int(seq)
        if self._modulus is not None and not 0 <= seq < self._modulus:
            return Rejection(
                "out_of_range", f"{where}: seq {seq} does not fit the {self.seq_bits}-bit counter"
            ), None
        try:
            t = float(tick.t)
        except (TypeError, ValueError):
            return Rejection("bad_shape", f"{where}: t must be a number of seconds, got {tick.t!r}"), None
        if not math.isfinite(t):
            return Rejection("nonfinite", f"{where}: t is {_fmt(t)}; the controller clock must be finite"), None
        temperature = tick.temperature
        if temperature is not None:
            try:
                temperature = float(temperature)
            except (TypeError, ValueError):
                return Rejection("bad_shape", f"{where}: temperature must be a number (deg C), got {temperature!r}"), None
            if not math.isfinite(temperature):
                return Rejection("nonfinite", f"{where}: temperature is {_fmt(temperature)} deg C; must be finite"), None

        # ---- vectors
        m = self.n_cables
        ml, rej = self._vector(tick, "motor_length", tick.motor_length, m, "m")
        if rej:
            return rej, None
        assert ml is not None
        if ml.min() <= 0.0 or ml.max() > self.max_motor_length:
            low = ml <= 0.0
            high = ml > self.max_motor_length
            i = int(np.argmax(low | high))
            why = "<= 0 m" if low[i] else f"> max_motor_length {self.max_motor_length:g} m"
            return Rejection(
                "out_of_range",
                f"{where}: motor_length[{i}] ({self.cable_names[i]}) = {_fmt(ml[i])} m is {why}",
            ), None
        force = None
        if tick.force is not None:
            force, rej = self._vector(tick, "force", tick.force, m, "N")
            if rej:
                return rej, None
            assert force is not None
            if (np.abs(force) - self.force_limit).max() > 0.0:
                i = int(np.argmax(np.abs(force) > self.force_limit))
                return Rejection(
                    "out_of_range",
                    f"{where}: force[{i}] ({self.cable_names[i]}) = {_fmt(force[i])} N exceeds "
                    f"{self.force_factor:g} x force_max = {self.force_limit[i]:g} N",
                ), None
        if (tick.position is None) != (tick.orientation is None):
            missing = "orientation" if tick.orientation is None else "position"
            return Rejection("bad_shape", f"{where}: pose has no {missing}; a pose needs both or neither"), None
        position = orientation = None
        if tick.position is not None:
            position, rej = self._vector(tick, "position", tick.position, 3, "m")
            if rej:
                return rej, None
            orientation, rej = self._vector(tick, "orientation", tick.orientation, 4, "[qx, qy, qz, qw]")
            if rej:
                return rej, None
            assert orientation is not None
            norm = float(np.sqrt(orientation @ orientation))
            if abs(norm - 1.0) > self.quaternion_tolerance:
                return Rejection(
                    "bad_quaternion",
                    f"{where}: orientation {orientation.tolist()} has norm {norm:.9g}; a unit quaternion "
                    f"must have norm 1 within {self.quaternion_tolerance:g}",
                ), None
            orientation = orientation / norm

        # ---- order
        resync = None
        unwrapped = seq
        if self.last_seq is not None:
            assert self.last_t is not None and self.last_raw_seq is not None
            if self._modulus is not None:
                step = (seq - self.last_raw_seq) % self._modulus
                if step >= self._modulus // 2:
                    step -= self._modulus
            else:
                step = seq - self.last_seq
            order: Optional[Rejection] = None
            if step == 0:
                if t == self.last_t:
                    # the very same tick again (a frozen controller, a repeated frame): never a
                    # sign of a restart, so it neither counts towards nor triggers a resync
                    return Rejection(
                        "duplicate_seq", f"{where}: seq {seq} and t repeat the last accepted tick exactly"
                    ), None
                order = Rejection("duplicate_seq", f"{where}: seq {seq} repeats the last accepted tick")
            elif step < 0:
                order = Rejection(
                    "seq_backwards", f"{where}: seq {seq} is {-step} behind the last accepted seq {self.last_raw_seq}"
                )
            elif t <= self.last_t:
                order = Rejection(
                    "time_backwards",
                    f"{where}: t {_fmt(t)} s is not after the last accepted t {_fmt(self.last_t)} s",
                )
            if order is not None:
                self._order_rejections += 1
                if self._order_rejections <= self.resync_after:
                    return order, None
                resync = (
                    f"{where}: {self._order_rejections - 1} ticks in a row were out of order after seq "
                    f"{self.last_raw_seq} (t {_fmt(self.last_t)} s); taking this tick as the start of a "
                    f"new timeline (controller restarted?)"
                )
                unwrapped = self.last_seq + 1
            else:
                unwrapped = self.last_seq + step
                if step > 1:
                    self.counters.missed_ticks += step - 1
        self._order_rejections = 0

        # ---- accept
        tick.seq = unwrapped
        tick.t = t
        tick.motor_length = ml
        tick.force = force
        tick.position = position
        tick.orientation = orientation
        tick.temperature = temperature
        self.last_seq = unwrapped
        self.last_raw_seq = seq
        self.last_t = t
        return None, resync


# --------------------------------------------------------------------------------------
# Source
# --------------------------------------------------------------------------------------


class Source(ABC):
    """One input of the live daemon (python-can style: one interface, many transports).

    Life cycle: ``open()``, then ``recv()`` until ``finished`` (finite sources only), then
    ``close()`` (idempotent, returns within 1 s). Also a context manager. ``recv(timeout)``
    returns the next valid :class:`TickInput` or None on timeout [s] / when finished.
    :meth:`problems` drains what was rejected since the last call.

    Subclasses set ``kind`` and take ``(robot, config)`` with their pydantic config.
    """

    kind: ClassVar[str] = ""

    def __init__(self, robot: Robot, config: Any):
        self.robot = robot
        self.config = config
        self.geometry = robot.geometry()
        self.n_cables = self.geometry.n_cables
        self.counters = SourceCounters()
        self.finished = False
        self._problems: collections.deque[Problem] = collections.deque()
        self._problem_lock = threading.Lock()
        self._opened = False
        self._closed = False
        self._validator = self._make_validator()

    # ------------------------------------------------------------------ interface
    @abstractmethod
    def open(self) -> None:
        """Connect / open files and start any receive thread."""

    @abstractmethod
    def recv(self, timeout: Optional[float] = None) -> Optional[TickInput]:
        """Next valid tick, or None when ``timeout`` [s] passes or the source is finished."""

    @abstractmethod
    def close(self) -> None:
        """Stop threads and release the transport; idempotent, returns within 1 s."""

    @property
    def label(self) -> str:
        """Short human description of where the ticks come from (used in messages)."""
        return self.kind

    def problems(self) -> list[Problem]:
        """Drain the problems reported since the last call (oldest first).

        At most :data:`PROBLEM_BUFFER` are kept between calls; older ones are dropped and
        counted in ``counters.problems_dropped``.
        """
        with self._problem_lock:
            out = list(self._problems)
            self._problems.clear()
        return out

    def __enter__(self) -> "Source":
        self.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ helpers
    def _make_validator(self) -> TickValidator:
        return TickValidator(self.robot, counters=self.counters, seq_bits=self._seq_bits())

    def _seq_bits(self) -> Optional[int]:
        """Width of the controller's tick counter on this transport (None: unbounded)."""
        return None

    def _report(self, reason: str, message: str, *, kind: str = "rejected") -> None:
        """Record a problem; ``kind`` "rejected" or "event" says which counter it goes to,
        "none" counts nothing (already counted, e.g. by the validator)."""
        with self._problem_lock:
            if kind == "rejected":
                self.counters.rejected[reason] += 1
            elif kind == "event":
                self.counters.events[reason] += 1
            if len(self._problems) >= PROBLEM_BUFFER:
                self._problems.popleft()
                self.counters.problems_dropped += 1
            self._problems.append(Problem(time.time(), reason, f"{self.label}: {message}",
                                          "event" if kind == "event" else "rejected"))

    def _admit(self, tick: TickInput) -> bool:
        """Validate ``tick``; report and return False when it is rejected."""
        rej = self._validator.check(tick)
        if rej is not None:
            self._report(rej.reason, rej.message, kind="none")
            return False
        if self._validator.resync_note is not None:
            self._report("resync", self._validator.resync_note, kind="none")
        return True


class ThreadedSource(Source):
    """A :class:`Source` whose ticks arrive on a background thread and wait in a bounded
    queue until :meth:`recv` takes them (``queue_size`` ticks; when it is full the oldest
    tick is dropped and counted as ``queue_overflow`` instead of ``accepted``)."""

    queue_size: ClassVar[int] = 4096

    def __init__(self, robot: Robot, config: Any):
        super().__init__(robot, config)
        self._queue: queue.Queue[TickInput] = queue.Queue(maxsize=self.queue_size)
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._sink: Optional[Any] = None
        self._sink_lock = threading.Lock()

    def set_sink(self, sink: Optional[Any]) -> list[TickInput]:
        """Hand every valid tick to ``sink(tick)`` on the receive thread itself instead of
        queueing it for :meth:`recv` (None: back to the queue).

        This saves one thread hand-off per tick (a lock, a wake-up and a GIL transfer: tens
        of microseconds, milliseconds on a loaded machine), which is what the live daemon
        wants. The sink must be quick and must not raise; an exception it raises is
        reported as ``sink_error`` and the tick counts as delivered.

        Returns the ticks that were waiting in the queue, taken out atomically with the
        switch: no tick is queued after them once a sink is set, so a caller that processes
        them before letting the sink run (e.g. holding the lock the sink takes) sees every
        accepted tick exactly once and in order.
        """
        with self._sink_lock:
            pending = []
            while True:
                try:
                    pending.append(self._queue.get_nowait())
                except queue.Empty:
                    break
            if sink is None:                      # back to queueing: keep the order
                for tick in pending:
                    self._queue.put_nowait(tick)
                pending = []
            self._sink = sink
        return pending

    def _deliver(self, tick: TickInput) -> None:
        """Validate and queue a tick, or hand it to the sink (receive thread)."""
        if not self._admit(tick):
            return
        with self._sink_lock:                     # a tick is queued or sunk, never lost in a switch
            sink = self._sink
            if sink is None:
                self._enqueue(tick)
                return
        try:
            sink(tick)
        except Exception as exc:  # noqa: BLE001 - the receive thread must survive
            self._report("sink_error", f"tick seq {tick.seq}: the consumer failed: {exc!r}")

    def _enqueue(self, tick: TickInput) -> None:
        while True:
            try:
                self._queue.put_nowait(tick)
                return
            except queue.Full:
                try:
                    old = self._queue.get_nowait()
                except queue.Empty:
                    continue
                # the dropped tick was counted as accepted when it passed the checks: it is
                # not delivered after all, so it moves to rejected (queue_overflow); both
                # counts change on this (the receive) thread
                self.counters.accepted -= 1
                self._report(
                    "queue_overflow",
                    f"tick seq {old.seq} dropped: {self.queue_size} ticks waiting, the reader is not keeping up",
                )

    def recv(self, timeout: Optional[float] = None) -> Optional[TickInput]:
        """Next valid tick from the receive thread, or None after ``timeout`` [s]
        (None: wait until one arrives or the source is closed)."""
        if timeout is None:
            while not self._closed:
                try:
                    return self._queue.get(timeout=0.1)
                except queue.Empty:
                    continue
            return None
        try:
            return self._queue.get(timeout=max(0.0, timeout)) if timeout > 0 else self._queue.get_nowait()
        except queue.Empty:
            return None

    def _start_thread(self, target: Any, name: str) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=target, name=name, daemon=True)
        self._thread.start()

    def _join_thread(self, timeout: float = 0.9) -> None:
        self._stop.set()
        th = self._thread
        if th is not None and th is not threading.current_thread():
            th.join(timeout)
        self._thread = None


def find_robot_companion(robot: Robot, suffix: str) -> Path:
    """Find ``<robot name><suffix>`` (e.g. ``ipanema3.dbc``) the way robot files are found:
    next to the robot file it was loaded from, then in each folder of
    :func:`cablesvc.config.robot_search_path`. Raises :class:`SourceConfigError` listing the
    folders searched when there is none."""
    name = f"{robot.name}{suffix}"
    dirs: list[Path] = []
    if robot.source is not None:
        dirs.append(Path(robot.source).resolve().parent)
    dirs.extend(robot_search_path())
    seen: list[Path] = []
    for d in dirs:
        if d in seen:
            continue
        seen.append(d)
        cand = d / name
        if cand.is_file():
            return cand
    raise SourceConfigError(
        f"no {name} for robot {robot.name!r}: looked in {', '.join(os.fspath(d) for d in seen)}; "
        f"give the file explicitly"
    )
