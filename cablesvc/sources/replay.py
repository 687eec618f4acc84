"""Replay input: the ticks of a recording (MCAP or CSV, recording format 1), paced.

``ReplaySource`` streams ``cablesvc.recording.iter_inputs`` (one MCAP chunk in memory at a
time) and releases tick k at ``start + (t_k - t_0) / speed`` on the monotonic clock:
``speed`` 1.0 is real time, 2.0 twice as fast, 0 as fast as the reader asks. ``stamp_ns``
is the release time. With ``loop`` the file is played again and again; on each pass
``t`` and ``seq`` are shifted so that they keep increasing (by the span of the file plus
one tick), the data itself repeats as recorded.

A step forward in ``t`` of more than ``max_gap_s`` (controller seconds) is never waited
for. When the tick after it is back before the jump, the far tick is a corrupted clock
value: it is rejected (``time_jump``, naming the tick) and the replay goes on. When the tick
after it follows on from it (or there is none), the recording really jumps: the event
``time_jump`` is reported and pacing starts again from that tick, released at once. After a
``resync`` (a controller restart in the recording) pacing also starts again from the
resynchronised tick. Every wait of :meth:`recv` ends by its ``timeout``.

A file that cannot be read, a message that is broken, or a file that was cut short
(``truncated``: the ticks before the cut are played) becomes a :class:`Problem`, never an
exception out of :meth:`recv`; a replay whose file ends in an error is finished after its
good ticks (or, with ``loop``, plays them again; a pass with no tick at all finishes it).
A damaged line of a CSV recording (cut short, garbled, ``1_000``) is rejected alone
(``bad_line``, naming line and column, counted in :attr:`ReplaySource.bad_lines`) and the
replay goes on with the next line.
"""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path
from typing import Any, ClassVar, Iterator, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from cablesvc.config.robot import Robot
from cablesvc.recording import RecordingError, RecordingTruncatedWarning, iter_inputs, read_metadata
from cablesvc.recording.csv_io import iter_csv_inputs
from cablesvc.sources.base import Source, TickInput, TickValidator

__all__ = ["ReplaySource", "ReplaySourceConfig"]


class ReplaySourceConfig(BaseModel):
    """``kind = "replay"``: play a recording file.

    ``path``: ``.mcap`` or ``.csv`` (recording format 1); ``speed``: time scale (1.0 real
    time, 2.0 twice as fast, 0 as fast as possible); ``loop``: start again at the end;
    ``max_gap_s``: the largest step forward in ``t`` [s] that is waited for (see the module
    docstring).
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["replay"] = "replay"
    path: Path
    speed: float = Field(default=1.0, ge=0, allow_inf_nan=False)
    loop: bool = False
    max_gap_s: float = Field(default=3600.0, gt=0, allow_inf_nan=False)


class ReplaySource(Source):
    """Ticks of a recording, paced by their ``t`` (see the module docstring). No thread:
    :meth:`recv` reads the next tick and waits until its release time."""

    kind: ClassVar[str] = "replay"

    def __init__(self, robot: Robot, config: ReplaySourceConfig):
        super().__init__(robot, config)
        self.config: ReplaySourceConfig = config
        self.path = Path(config.path)
        self._it: Optional[Iterator[Any]] = None
        self._pending: Optional[TickInput] = None
        self._pending_release_ns = 0
        self._lookahead: Optional[TickInput] = None  # read to judge a jump in t, not yet played
        self._origin_ns = 0
        self._t0: Optional[float] = None  # t released at _origin_ns (pacing base)
        self._pass = 0
        self._pass_ticks = 0
        self._t_shift = 0.0
        self._seq_shift = 0
        self._first_t: Optional[float] = None
        self._first_seq: Optional[int] = None
        self._last_t: Optional[float] = None
        self._last_seq: Optional[int] = None
        self._dt: Optional[float] = None
        #: Ticks read from the file so far (all passes), accepted or not.
        self.ticks_read = 0
        #: CSV lines rejected as unreadable (all passes): also ``counters.rejected["bad_line"]``.
        self.bad_lines = 0

    @property
    def label(self) -> str:
        return f"replay {self.path}"

    # ------------------------------------------------------------------ file
    def _start_pass(self) -> bool:
        """Open the file for a new pass; False (and a problem) when it cannot be read."""
        self._pass_ticks = 0
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", RecordingTruncatedWarning)
                if self.path.suffix.lower() == ".csv":   # a bad line costs one tick, not the rest
                    self._it = iter_csv_inputs(self.path, robot_cables=self.n_cables, on_error=self._bad_line)
                else:
                    self._it = iter_inputs(self.path, robot_cables=self.n_cables)
            self._warned(caught)
            return True
        except RecordingError as exc:
            self._report("recording_error", str(exc))
        except (OSError, ValueError) as exc:
            self._report("recording_error", f"{self.path}: cannot read: {exc}")
        self._it = None
        return False

    def _bad_line(self, exc: RecordingError) -> None:
        """A CSV line that is not a tick: rejected (``bad_line``, naming line and column) and
        counted; the replay goes on with the next line."""
        self.bad_lines += 1
        self._report("bad_line", str(exc))

    def _warned(self, caught: list[Any]) -> None:
        for w in caught:
            if issubclass(w.category, RecordingTruncatedWarning):
                self._report("truncated", f"{self.path}: {w.message}", kind="event")

    def open(self) -> None:
        """Open the file (errors become problems and finish the source)."""
        if self._opened:
            return
        self._opened = True
        try:
            meta = read_metadata(self.path)
            rec_robot = meta.get("robot", "")
            if rec_robot and rec_robot != self.robot.name:
                self._report("robot_mismatch", f"{self.path}: recorded on robot {rec_robot!r}, replayed for "
                                               f"{self.robot.name!r}", kind="event")
        except RecordingError as exc:
            self._report("recording_error", str(exc))
            self.finished = True
            return
        except OSError as exc:
            self._report("recording_error", f"{self.path}: cannot read: {exc}")
            self.finished = True
            return
        if not self._start_pass():
            self.finished = True
        self._origin_ns = time.monotonic_ns()

    def _next_raw(self) -> Optional[TickInput]:
        """Next tick of the file, passes and errors handled; None when finished."""
        while not self.finished:
            if self._it is None:
                self.finished = True
                return None
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", RecordingTruncatedWarning)
                    d = next(self._it)
                self._warned(caught)
            except StopIteration:
                self._warned(caught)
                if not self._end_of_pass():
                    return None
                continue
            except RecordingError as exc:
                self._warned(caught)
                self._report("recording_error", str(exc))
                if not self._end_of_pass():
                    return None
                continue
            except Exception as exc:  # noqa: BLE001 - a damaged file must not kill the daemon
                self._report("recording_error", f"{self.path}: {exc!r}")
                if not self._end_of_pass():
                    return None
                continue
            self.ticks_read += 1
            self._pass_ticks += 1
            t = float(d["t"])
            seq = int(d["seq"])
            if self._pass == 0:
                if self._first_t is None:
                    self._first_t, self._first_seq = t, seq
                elif self._last_t is not None and t > self._last_t and self._dt is None:
                    self._dt = t - self._last_t
                self._last_t, self._last_seq = t, seq

            def arr(v: Any) -> Optional[np.ndarray]:
                return None if v is None else np.array(v, dtype=np.float64)

            return TickInput(
                seq=seq + self._seq_shift, t=t + self._t_shift, motor_length=np.array(d["motor_length"], dtype=np.float64),
                position=arr(d.get("position")), orientation=arr(d.get("orientation")), force=arr(d.get("force")),
                temperature=d.get("temperature"), stamp_ns=0,
            )
        return None

    def _end_of_pass(self) -> bool:
        """The file ended (or broke); True when another pass starts."""
        self._it = None
        if not self.config.loop or self._pass_ticks == 0 or self._first_t is None:
            self.finished = True
            return False
        if self._pass == 0:
            assert self._last_t is not None and self._first_seq is not None and self._last_seq is not None
            self._span_t = (self._last_t - self._first_t) + (self._dt or 1e-3)
            self._span_seq = (self._last_seq - self._first_seq) + 1
        self._pass += 1
        self._t_shift = self._pass * self._span_t
        self._seq_shift = self._pass * self._span_seq
        if not self._start_pass():
            self.finished = True
            return False
        return True

    # ------------------------------------------------------------------ recv
    def _take(self) -> Optional[TickInput]:
        """The next tick to play: the one read ahead, else the next of the file."""
        if self._lookahead is not None:
            tick, self._lookahead = self._lookahead, None
            return tick
        return self._next_raw()

    @staticmethod
    def _finite_t(tick: Optional[TickInput]) -> Optional[float]:
        try:
            t = float(tick.t) if tick is not None else math.nan
        except (TypeError, ValueError):
            return None
        return t if math.isfinite(t) else None

    def _rebase(self, t: float, now_ns: int) -> None:
        """Pace the following ticks from ``t`` released at ``now_ns``."""
        self._t0 = t
        self._origin_ns = now_ns

    def _next_to_release(self) -> Optional[TickInput]:
        """The next tick to release with its release time set; a tick too far ahead in ``t``
        is rejected or starts a new pacing base (see the module docstring). None when the
        replay is finished."""
        max_gap = self.config.max_gap_s
        while True:
            tick = self._take()
            if tick is None:
                return None
            t = self._finite_t(tick)
            now = time.monotonic_ns()
            if self._t0 is None:
                if t is None:                     # no base yet: play it now (the checks refuse it)
                    self._pending_release_ns = 0
                    return tick
                self._rebase(t, now)
            ref = self._validator.last_t
            if t is not None and ref is not None and t - ref > max_gap:
                nxt = self._lookahead = self._next_raw()
                t_next = self._finite_t(nxt)
                follows = nxt is None or (t_next is not None and t < t_next <= t + max_gap)
                where = TickValidator._where(tick)
                if not follows:
                    self._report(
                        "time_jump",
                        f"{where}: t jumps {t - ref:.6g} s past the last accepted t {ref!r} s (more than "
                        f"max_gap_s {max_gap:g} s) and the next tick is not after it: a corrupted clock "
                        f"value, not waited for",
                    )
                    continue
                self._report(
                    "time_jump",
                    f"{where}: t jumps {t - ref:.6g} s past the last accepted t {ref!r} s (more than "
                    f"max_gap_s {max_gap:g} s); released now, pacing starts again from this tick",
                    kind="event",
                )
                self._rebase(t, now)
            speed = self.config.speed
            if speed == 0 or t is None or self._t0 is None:
                self._pending_release_ns = 0
            else:
                delay = (t - self._t0) / speed * 1e9
                if not math.isfinite(delay) or delay > 2.0**62:
                    delay = 2.0**62                # (tiny speed) later than any timeout: ~146 years
                self._pending_release_ns = self._origin_ns + max(0, int(delay))
            return tick

    def _sleep_until(self, target_ns: int) -> bool:
        """Sleep until ``target_ns`` (monotonic), in steps of at most 0.5 s; False when the
        source was closed meanwhile."""
        while True:
            if self._closed:
                return False
            left = target_ns - time.monotonic_ns()
            if left <= 0:
                return True
            time.sleep(min(left, 500_000_000) / 1e9)

    def recv(self, timeout: Optional[float] = None) -> Optional[TickInput]:
        """The next valid tick at its release time; None when ``timeout`` [s] passes first
        (the tick is kept for the next call) or when the replay is finished."""
        if not self._opened:
            self.open()
        deadline = None
        if timeout is not None:
            span = max(0.0, float(timeout)) * 1e9
            if span < 2.0**62:                     # longer (or NaN) waits as if None
                deadline = time.monotonic_ns() + int(span)
        while True:
            if self._closed:
                return None
            if self._pending is None:
                tick = self._next_to_release()
                if tick is None:
                    return None
                self._pending = tick
            release = self._pending_release_ns
            now = time.monotonic_ns()
            if release > now:
                if deadline is not None and deadline < release:
                    if deadline > now:
                        self._sleep_until(deadline)
                    return None
                if release - now > 200_000 and not self._sleep_until(release - 100_000):
                    return None
                while time.monotonic_ns() < release:
                    pass
            tick, self._pending = self._pending, None
            tick.stamp_ns = time.monotonic_ns()
            if self._admit(tick):
                if self._validator.resync_note is not None and self._finite_t(tick) is not None:
                    self._rebase(tick.t, tick.stamp_ns)   # a restarted controller clock: pace from here
                return tick
            if deadline is not None and time.monotonic_ns() >= deadline:
                return None

    def close(self) -> None:
        """Release the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        it, self._it = self._it, None
        if it is not None and hasattr(it, "close"):
            try:
                it.close()
            except Exception:  # noqa: BLE001
                pass
        self.finished = True
