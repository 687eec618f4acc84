"""The live daemon: bus source -> fixed-time kernel -> alarms -> Zenoh (and MCAP, snapshots).

One loop in one thread does, per input tick::

    tick = source.recv()                    # CAN / Modbus / replay, validated by the source
    out = predictor.tick(...)               # IK, wrap angles, hysteretic forces (cablesvc.kernel)
    events = alarms.on_tick(...)            # drift (EWMA + CUSUM) and state alarms
    publisher.publish_forces(...)           # cablesvc/<robot>/forces
    publisher.publish_alarm(...)            # cablesvc/<robot>/alarms (raise / clear)

Everything slower or optional runs beside the loop, never in it: the recorder (MCAP or
CSV, by the --record suffix) is a writer thread fed by a bounded queue (for a live source
a full queue drops and counts, it never blocks the loop; a replay, which has no deadline,
waits for room instead, so that every accepted tick is recorded; at shutdown the queue is
written out, and any tick missing from the file makes the exit status non-zero), the
status queryable builds its answer from counters the loop updates, the terminal view
reads a copy made ten times a second, and snapshots of the hysteresis
state are written atomically (temporary file, fsync, rename) every few seconds and at
shutdown, and restored at start when they belong to the same robot and parameters.

Bad input never stops the loop: sources reject it (counted by reason, reported as
problems); an exception inside the kernel is counted as ``kernel_error``, the kernel is
reset, and the loop goes on.

New parameters without a restart (:meth:`Daemon.request_reload`, :meth:`Daemon.reload_params`):
SIGHUP re-reads the parameter file, a put on ``cablesvc/<robot>/params`` carries a file's
TOML text. A reload thread parses and checks it and builds the new kernel beside the
running one (and runs it once, so that its first live tick costs what any tick costs);
the loop swaps kernels between two ticks, under the lock a tick holds, so no tick is
missed or half done. The hysteresis state (reversal points, amplitude estimate, Bouc-Wen
z, ...) carries over when the model family is the same; a new family starts at rest at
the current elongation, pose and time kept. A file that does not parse, fails a check or
does not fit the robot (cable count, robot name) is refused with the reason: logged,
counted, in the status, raised as a ``params_refused`` alarm; the old parameters stay.

This module holds the options, the start checks and the loop; beside it,
:mod:`~cablesvc.service.snapshot` (snapshot files and restoring them),
:mod:`~cablesvc.service.recorder` (the recording writer thread) and
:mod:`~cablesvc.service.params_reload` (new parameters without a restart).
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from cablesvc import __version__
from cablesvc.config.params import ModelParams
from cablesvc.config.robot import Robot
from cablesvc.errors import ServiceError
from cablesvc.kernel import Predictor
from cablesvc.service.latency import value_at_percentiles
from cablesvc.service.messages import forces_payload
from cablesvc.service.params_reload import ParamsReload
from cablesvc.service.recorder import RECORD_SUFFIXES, REPLAY_RECORD_QUEUE, Recorder
from cablesvc.service.snapshot import SnapshotState, params_fingerprint, source_identity

log = logging.getLogger("cablesvc.daemon")


# ---- options ---------------------------------------------------------------------------

@dataclass
class DaemonOptions:
    """What ``cablesvc run`` configures. Paths may be None (feature off)."""

    robot: Robot
    params: ModelParams
    source: dict[str, Any]                       # a SourceConfig as a dict (kind=can|modbus|replay)
    zenoh_config_file: str | None = None         # router / TLS / access control; None = loopback peer
    listen: tuple[str, ...] | None = None        # None: the config file's, else tcp/127.0.0.1:7447
    connect: tuple[str, ...] | None = None       # None: the config file's, else none
    encoding: str = "json"                       # json | compact
    record: Path | None = None                   # MCAP of inputs and outputs
    snapshot: Path | None = None                 # hysteresis state file
    snapshot_interval_s: float = 5.0
    alarm_config: Any = None                     # cablesvc.alarms.AlarmConfig or None for defaults
    exit_when_finished: bool = True              # replay: stop at the end of the file
    record_queue: int = 100_000                  # ticks the recorder may lag behind
    record_overwrite: bool = False               # replace an existing record file (else refused)
    record_encoding: str = "protobuf"            # .mcap inputs: protobuf (binary blocks, format 2) | json
    wait_subscriber_s: float = 0.0               # before reading the source, wait this long for a subscriber
    direct: bool = True                          # process ticks on the source's receive thread (no hand-off)
    input_fault_clear_s: float = 5.0             # input_fault clears after this long without a rejection
    source_id: str | None = None                 # the input's identity in snapshots (None: source_identity)
    params_file: str | None = None               # what SIGHUP re-reads (None: params.source when it is a file)


class StartError(ServiceError, RuntimeError):
    """The daemon cannot start as configured (a --record target it must not write, a
    --replay file it cannot read); the message is one line naming the file."""


def check_record_target(record: Path, source: dict[str, Any], overwrite: bool) -> None:
    """Refuse a ``--record`` target before anything is opened (:class:`StartError`, one line):
    a suffix other than .mcap / .csv (the format follows the suffix), the input recording
    itself (also through a symlink, a hard link or another spelling of its path), an
    existing file without ``overwrite``, a directory, a missing parent directory."""
    record = Path(record)
    suffix = record.suffix.lower()
    if suffix not in RECORD_SUFFIXES:
        raise StartError(f"--record {record}: unknown recording format {suffix or '(no suffix)'!r}; "
                         "the suffix picks it: .mcap (inputs, forces and alarms) or .csv (inputs only)")
    replay = source.get("path") if source.get("kind") == "replay" else None
    if replay is not None:
        same = os.path.realpath(record) == os.path.realpath(replay)
        try:
            same = same or os.path.samefile(record, replay)
        except OSError:
            pass
        if same:
            raise StartError(f"--record {record}: this is the --replay input {replay}; recording onto it "
                             "would destroy it (record to another file)")
    if record.is_dir():
        raise StartError(f"--record {record}: is a directory, not a recording file")
    if os.path.lexists(record) and not overwrite:
        raise StartError(f"--record {record}: the file exists; it is kept (pass --overwrite to replace it)")
    parent = record.parent if str(record.parent) else Path(".")
    if not parent.is_dir():
        raise StartError(f"--record {record}: directory {parent} does not exist")



# ---- the daemon ------------------------------------------------------------------------

@dataclass
class LoopStats:
    """Counters the loop updates and the status queryable reads (plain Python numbers)."""

    started: float = field(default_factory=time.monotonic)
    ticks: int = 0
    published: int = 0                  # publish calls (the publisher counts what went out)
    kernel_errors: int = 0
    publish_errors: int = 0
    alarms_raised: int = 0
    last_seq: int | None = None
    last_t: float | None = None
    rate_window: deque = field(default_factory=lambda: deque(maxlen=2001))


class _Held:
    """Context manager releasing a lock the caller already acquired."""

    def __init__(self, lock):
        self.lock = lock

    def __enter__(self):
        return self.lock

    def __exit__(self, *exc):
        self.lock.release()


def _alarm_config(options: "DaemonOptions") -> Any:
    """The daemon's alarm configuration. A replay at speed 0 (as fast as it is read) has no
    tick period to watch: the wall-clock input watch (``input_stale`` / ``input_lost``) would
    time this machine, not the controller (a 0.36 s stall of a loaded machine raised
    ``input_stale`` in the middle of a speed-0 replay), so it is off there."""
    from cablesvc.alarms import AlarmConfig

    cfg = options.alarm_config or AlarmConfig()
    src = options.source if isinstance(options.source, dict) else {}
    try:
        as_fast = src.get("kind") == "replay" and float(src.get("speed", 1.0)) == 0.0
    except (TypeError, ValueError):
        as_fast = False                  # the source's own validation names the bad speed
    if as_fast and cfg.input.enabled:
        cfg = cfg.model_copy(update={"input": cfg.input.model_copy(update={"enabled": False})})
    return cfg


class Daemon(ParamsReload, SnapshotState):
    """Source, kernel, alarms, publisher: see the module docstring.

    ``publisher_factory(robot_name, status_fn) -> Publisher`` exists so that a test can
    pass a real publisher with its own config; by default a Zenoh publisher is opened from
    the options.
    """

    def __init__(self, options: DaemonOptions, *, source=None, publisher_factory: Callable | None = None):
        from cablesvc.alarms import AlarmManager
        from hdrh.histogram import HdrHistogram

        # The loop, the CAN receive thread and Zenoh's callbacks share the GIL. Python's default
        # switch interval (5 ms) lets one CPU-bound thread hold it for 5 ms: far beyond a
        # 1 ms tick. 0.2 ms bounds that wait at the cost of a few more switches.
        if sys.getswitchinterval() > 2e-4:
            sys.setswitchinterval(2e-4)
        self.opt = options
        self.robot = options.robot
        self.name = options.robot.name
        self.geom = options.robot.geometry()
        self.params = options.params
        self.fingerprint = params_fingerprint(options.params)
        self.predictor = Predictor(self.geom, options.params)
        self.alarms = AlarmManager(self.geom, options.params, _alarm_config(options))
        self.stats = LoopStats()
        self.hist = HdrHistogram(1, 60_000_000, 3)          # microseconds, input stamp -> published
        self.problems: deque = deque(maxlen=200)           # recent rejected inputs (for status)
        self.restored_from: str | None = None
        self._fault_alarm = None                   # the raised input_fault alarm, if any
        self._fault_last = 0.0
        self._fault_count = 0
        self._lock = threading.Lock()              # guards the view copy
        self._state_lock = threading.Lock()        # kernel + alarms: the tick vs snapshots / idle alarms
        self._view_copy: dict[str, Any] | None = None
        self._view_at = 0.0
        self._last_snapshot = time.monotonic()
        self.snapshot_path = options.snapshot
        self.snapshot_error: str | None = None
        self.source_id = options.source_id or source_identity(options.source)
        # a snapshot that passed the file checks waits for the first tick (see _resume)
        self._pending_restore: tuple[dict[str, Any], dict[str, np.ndarray], dict[str, Any]] | None = None
        # per cable: the last elongation and the largest move of one tick [m] (for the snapshot)
        m = self.geom.n_cables
        self._x_last = np.full(m, np.nan)
        self._step_max = np.zeros(m)
        self._dx = np.empty(m)
        self._dt_last: float | None = None           # the last tick's time step [s]
        self._init_reload(options)
        if options.record is not None:           # before anything is opened or restored
            check_record_target(Path(options.record), options.source, options.record_overwrite)
        self._restore()

        if source is None:
            from cablesvc.sources import open_source
            source = open_source(self.robot, options.source)
        self.source = source
        self.recorder: Recorder | None = None
        self._recorder_closed: Recorder | None = None  # the recorder after close (status, exit code)
        self.publisher = None
        self._closed_counts = (0, 0)              # (published, skipped) when the publisher closed
        try:
            if publisher_factory is None:
                from cablesvc.service.zenoh_io import Publisher, make_config
                given = {k: v for k, v in (("listen", options.listen), ("connect", options.connect)) if v is not None}
                cfg = make_config(options.zenoh_config_file, **given)
                self.publisher = Publisher(self.name, cfg, encoding=options.encoding, status=self.status)
            else:
                self.publisher = publisher_factory(self.name, self.status)
            if hasattr(self.publisher, "serve_params"):
                self.publisher.serve_params(self._on_params_put, self._on_params_query)
            self._reload_thread = threading.Thread(target=self._reload_worker, name=f"cablesvc-reload-{self.name}",
                                                   daemon=True)
            self._reload_thread.start()
            self.source.open()
            self._check_input_readable()
            # only now, with the input read, is anything opened for writing
            if options.record is not None:
                md = {"source": json.dumps(options.source, default=str), "model": options.params.model,
                      "params": options.params.to_toml(), "cablesvc_version": __version__}
                replay = options.source.get("kind") == "replay"
                # a replay waits for the writer (no tick dropped); a short queue keeps what is
                # left to write at shutdown, and so the time to stop, short
                size = min(options.record_queue, REPLAY_RECORD_QUEUE) if replay else options.record_queue
                try:
                    self.recorder = Recorder(Path(options.record), self.name, md, size, block=replay,
                                             overwrite=options.record_overwrite,
                                             encoding=options.record_encoding)
                except FileExistsError:
                    raise StartError(f"--record {options.record}: the file exists; it is kept "
                                     "(pass --overwrite to replace it)") from None
                except (OSError, ValueError) as e:
                    why = e.strerror if isinstance(e, OSError) and e.strerror else e
                    raise StartError(f"--record {options.record}: cannot write it: {why}") from None
        except BaseException:
            try:
                self.source.close()
            except Exception as e:  # noqa: BLE001
                log.error("closing the source failed: %s", e)
            self._close_outputs()
            raise

    def _check_input_readable(self) -> None:
        """A replay whose file cannot be read (empty, not a recording, bad header) is finished
        at open: a :class:`StartError` with the reader's one-line reason, before any output
        file is opened."""
        src = self.source
        if self.opt.source.get("kind") != "replay" or not getattr(src, "finished", False):
            return
        problems = src.problems()
        for p in problems:
            self.problems.append(p)
        why = next((p.message for p in problems if p.kind == "rejected"), None)
        raise StartError(f"cannot replay: {why or f'{src.label}: no tick to play'}")

    # -- status ---------------------------------------------------------------------------
    def tick_rate(self) -> float:
        w = list(self.stats.rate_window)
        if len(w) < 2 or w[-1] <= w[0]:
            return 0.0
        return (len(w) - 1) / ((w[-1] - w[0]) / 1e9)

    def status(self) -> dict[str, Any]:
        """Answer of the ``cablesvc/<robot>/status`` queryable (JSON-able)."""
        h = self.hist
        n = h.get_total_count()
        lat = {"count": n}
        if n:
            p50, p99, p999 = value_at_percentiles(h, (50, 99, 99.9))
            lat.update(p50_us=p50, p99_us=p99, p999_us=p999, max_us=h.get_max_value())
        s = self.stats
        # the loop (or the source's receive thread) changes these while a Zenoh thread runs
        # this: read each once, so that a None set in between cannot fail the query
        fault_alarm = self._fault_alarm
        params_alarm = self._params_alarm
        recorder = self.recorder or self._recorder_closed
        counters = self.source.counters.as_dict()
        if s.kernel_errors:
            # the source accepted these ticks but the kernel refused them: count them once,
            # as rejected, so that accepted + rejected = ticks received still holds
            counters.setdefault("rejected", {})["kernel_error"] = s.kernel_errors
            counters["accepted"] = counters.get("accepted", 0) - s.kernel_errors
        out = {
            "robot": self.name,
            "version": __version__,
            "uptime_s": round(time.monotonic() - s.started, 3),
            "ticks": s.ticks,
            "published": getattr(self.publisher, "forces_published", self._closed_counts[0]),
            "skipped_no_subscriber": getattr(self.publisher, "forces_skipped", self._closed_counts[1]),
            "publish_errors": s.publish_errors,      # ticks (or alarms) whose put raised: not published
            "tick_rate_hz": round(self.tick_rate(), 3),
            "latency_us": lat,
            "input": {"source": self.opt.source.get("kind"), **counters},
            "recent_problems": [{"wall_time": p.wall_time, "reason": p.reason, "message": p.message}
                                for p in list(self.problems)[-10:]],
            "model": self._model_status(),
            "params_reload": {"file": self.params_file, "key": f"cablesvc/{self.name}/params",
                              **self.reload_counts, "pending": self._pending_params is not None,
                              "last": self.last_reload},
            "alarms_active": [e.payload() for e in self.alarms.active()]
                             + ([fault_alarm.payload()] if fault_alarm is not None else [])
                             + ([params_alarm.payload()] if params_alarm is not None else []),
            "snapshot": {"path": str(self.snapshot_path) if self.snapshot_path else None,
                         "restored_from": self.restored_from, "error": self.snapshot_error},
            "last": {"seq": s.last_seq, "t": s.last_t},
        }
        if recorder is not None:
            out["recording"] = {"path": str(self.opt.record), "written": recorder.written,
                                "dropped": recorder.dropped, "missing": recorder.missing, "error": recorder.error}
        return out

    def view(self) -> dict[str, Any] | None:
        """Copy of the last output for the terminal view (refreshed ten times a second)."""
        with self._lock:
            return self._view_copy

    # -- the loop -------------------------------------------------------------------------
    def step(self, tick) -> None:
        """Process one validated input tick."""
        s = self.stats
        if self._pending_params is not None:        # new parameters: switch before this tick
            self._apply_params()
        self._last_tick = tick
        if self._pending_restore is not None:
            self._resume(tick)
        try:
            out = self.predictor.tick(tick.t, tick.motor_length, tick.position, tick.orientation,
                                      tick.force, tick.temperature)
        except Exception as e:  # noqa: BLE001 - counted, reset, go on
            s.kernel_errors += 1
            self.predictor.reset()
            self._problem("kernel_error", f"kernel failed on seq {tick.seq}: {e}")
            return
        if s.last_t is not None:
            self._dt_last = tick.t - s.last_t
        if self.snapshot_path is not None:       # the largest one-tick move (NaN at the first: fmax skips it)
            np.subtract(out.elongation, self._x_last, self._dx)
            np.absolute(self._dx, self._dx)
            np.fmax(self._step_max, self._dx, out=self._step_max)
            np.copyto(self._x_last, out.elongation)
        events = self.alarms.on_tick(tick.t, tick.seq, out)
        payload = forces_payload(self.name, tick.seq, out, tick.stamp_ns, self.geom.cable_names)
        # counted before it is published: a status query answered from another thread
        # between the two then never reports fewer ticks than the forces a subscriber
        # already holds (tests/test_fleet.py saw 299 ticks beside 300 forces under load)
        s.ticks += 1
        s.last_seq = tick.seq
        s.last_t = tick.t
        pub = self.publisher
        try:
            pub.publish_forces(payload)
            s.published += 1
        except Exception as e:  # noqa: BLE001
            s.publish_errors += 1
            self._problem("publish_error", f"publishing forces failed: {e}")
        alarm_payloads = [ev.payload() for ev in events] if events else ()
        for a in alarm_payloads:
            try:
                pub.publish_alarm(a)
            except Exception as e:  # noqa: BLE001
                s.publish_errors += 1
                self._problem("publish_error", f"publishing an alarm failed: {e}")
            if a.get("action") == "raise":
                s.alarms_raised += 1
        now = time.monotonic_ns()
        lat_us = (now - tick.stamp_ns) // 1000
        if lat_us >= 1:
            self.hist.record_value(min(lat_us, 60_000_000))
        s.rate_window.append(now)
        if self.recorder is not None:
            self.recorder.put((tick, payload, alarm_payloads))
        if now * 1e-9 - self._view_at > 0.1:
            self._view_at = now * 1e-9
            v = {"t": out.t, "seq": tick.seq, "force": out.force.copy(), "measured": out.measured.copy(),
                 "residual": out.residual.copy(), "elongation": out.elongation.copy(),
                 "wrap_angle": out.wrap_angle.copy(), "slack": out.slack.copy(),
                 "pose_from_fk": out.pose_from_fk}
            with self._lock:
                self._view_copy = v

    def _input_problems(self, problems) -> None:
        """Keep the source's problems for status and raise / clear the ``input_fault`` alarm."""
        from cablesvc.alarms import AlarmEvent

        now = time.monotonic()
        t = self.stats.last_t if self.stats.last_t is not None else 0.0
        for p in problems:
            self.problems.append(p)
            if getattr(p, "kind", "rejected") != "rejected":
                log.info("input event %s: %s", p.reason, p.message)
                continue
            log.warning("input rejected (%s): %s", p.reason, p.message)
            self._fault_last = now
            self._fault_count += 1
            if self._fault_alarm is None:
                self._fault_alarm = AlarmEvent(
                    action="raise", code="input_fault", cable=None, severity="warning", t=t, since=t,
                    seq=self.stats.last_seq, message=f"input rejected ({p.reason}): {p.message}")
                self._emit(self._fault_alarm)
        if self._fault_alarm is not None and now - self._fault_last > self.opt.input_fault_clear_s:
            raised = self._fault_alarm
            self._fault_alarm = None
            self._emit(AlarmEvent(
                action="clear", code="input_fault", cable=None, severity="info", t=t, since=raised.since,
                seq=self.stats.last_seq,
                message=f"no input rejected for {self.opt.input_fault_clear_s:g} s "
                        f"({self._fault_count} rejected while raised)"))
            self._fault_count = 0

    def _emit(self, ev) -> None:
        """Publish (and record) an alarm event raised or cleared outside a tick."""
        p = ev.payload()
        try:
            self.publisher.publish_alarm(p)
        except Exception as e:  # noqa: BLE001
            self.stats.publish_errors += 1
            log.error("publishing an alarm failed: %s", e)
        if p.get("action") == "raise":
            self.stats.alarms_raised += 1
        if self.recorder is not None:
            # log time: the event's controller time; before the first tick there is none
            t = ev.t if ev.t is not None and math.isfinite(ev.t) else (self.stats.last_t or 0.0)
            self.recorder.put((None, t, (p,)))

    def _problem(self, reason: str, message: str) -> None:
        from cablesvc.sources.base import Problem
        self.problems.append(Problem(time.time(), reason, message))
        log.warning("%s: %s", reason, message)

    def _idle(self) -> None:
        for ev in self.alarms.on_idle(time.monotonic()):
            self._emit(ev)

    def _step_locked(self, tick) -> None:
        with self._state_lock:
            self.step(tick)

    def run(self, stop: threading.Event, *, max_ticks: int | None = None) -> int:
        """Run until ``stop`` is set (or the replay ends, or ``max_ticks``). Returns 0.

        Sources with a receive thread (CAN, Modbus) hand each tick straight to
        :meth:`step` on that thread (``set_sink``: no queue, no hand-off); this thread then
        only does the periodic work (input watch, problems, snapshots) under the same lock.
        Other sources (replay) are read here.
        """
        src = self.source
        last_idle = 0.0
        if self.opt.wait_subscriber_s > 0 and hasattr(self.publisher, "subscribed"):
            end = time.monotonic() + self.opt.wait_subscriber_s
            while not stop.is_set() and time.monotonic() < end and not self.publisher.subscribed("forces"):
                stop.wait(0.02)
            if not self.publisher.subscribed("forces"):
                log.warning("no subscriber after %.1f s; starting anyway", self.opt.wait_subscriber_s)
        direct = self.opt.direct and hasattr(src, "set_sink")
        if direct:
            # ticks accepted since the source opened wait in its queue: step them first,
            # holding the lock the sink takes, so that direct ticks follow them in order
            with self._state_lock:
                for tick in src.set_sink(self._step_locked):
                    self.step(tick)
        try:
            while not stop.is_set():
                if direct:
                    tick = None
                    stop.wait(0.01)
                else:
                    tick = src.recv(timeout=0.05)
                    if tick is not None:
                        with self._state_lock:
                            self.step(tick)
                self._input_problems(src.problems())
                if self._pending_params is not None:      # no tick came: switch between ticks anyway
                    with self._state_lock:
                        if self._pending_params is not None:
                            self._apply_params()
                now = time.monotonic()
                if tick is None or now - last_idle > 0.01:
                    with self._state_lock:
                        self._idle()
                    last_idle = now
                if self.snapshot_path is not None and now - self._last_snapshot > self.opt.snapshot_interval_s:
                    with self._state_lock:
                        self.snapshot()
                if not direct and tick is None and src.finished and self.opt.exit_when_finished:
                    break
                if max_ticks is not None and self.stats.ticks >= max_ticks:
                    break
        finally:
            if direct:
                src.set_sink(None)
        return 0

    # -- shutdown -------------------------------------------------------------------------
    def _close_outputs(self) -> None:
        if self.recorder is not None:
            self.recorder.close()
            self._recorder_closed, self.recorder = self.recorder, None
        if self.publisher is not None:
            # status() after close reports what the publisher put and skipped, not the calls
            self._closed_counts = (getattr(self.publisher, "forces_published", self.stats.published),
                                   getattr(self.publisher, "forces_skipped", 0))
            try:
                self.publisher.close()
            except Exception as e:  # noqa: BLE001
                log.error("closing Zenoh failed: %s", e)
            self.publisher = None

    def _drain(self) -> None:
        """Step the ticks a threaded source queued (the caller holds the loop's lock); other
        sources queue none."""
        if not hasattr(self.source, "set_sink"):
            return
        for _ in range(10_000):
            tick = self.source.recv(timeout=0)
            if tick is None:
                break
            self.step(tick)

    def close(self) -> None:
        """Stop the source, process what it accepted before it stopped, write the final
        snapshot, close the recording and Zenoh (< 2 s).

        Between the end of :meth:`run` and the source's close, a receive thread can still
        accept a tick or two (it queues them once the direct sink is gone). Each is stepped
        and published here, so that every accepted tick has its output even at shutdown."""
        self._reload_q.put(None)                  # the reload thread ends (a pending change is dropped)
        # a loop stuck in one tick (it cannot be, with parameters in their limits) must not
        # hold the shutdown: then no final snapshot (the state would be half a tick)
        stuck = not self._state_lock.acquire(timeout=1.0)
        if not stuck:
            # ticks queued since the loop ended are stepped before the source closes: closing
            # a receive thread waits out its bus timeout (0.1 s for CAN), and they would wait
            with _Held(self._state_lock):
                self._drain()
        try:
            self.source.close()
        except Exception as e:  # noqa: BLE001
            log.error("closing the source failed: %s", e)
        if stuck or not self._state_lock.acquire(timeout=1.0):
            log.error("the loop did not finish its tick within 1 s; no final snapshot")
            self._close_outputs()
            return
        with _Held(self._state_lock):
            self._drain()                                 # what it accepted while closing
            self.snapshot()
            change, self._pending_params = self._pending_params, None
            if change is not None:                 # prepared, but the loop stopped before the switch
                change.result = {"accepted": True, "applied": False, "origin": change.origin,
                                 "fingerprint": change.fingerprint, "reason": "the daemon stopped before the switch"}
                change.done.set()
        self._close_outputs()

    def exit_problems(self) -> list[str]:
        """After :meth:`close`: one line for each thing that makes the exit status non-zero:
        accepted ticks missing from the recording, a recording that failed, a replay that
        played no tick."""
        out = []
        rec = self._recorder_closed or self.recorder
        if rec is not None:
            if rec.missing:
                out.append(f"recording {self.opt.record}: {rec.missing} of {rec.handed} ticks are missing "
                           f"({rec.dropped} dropped from a full queue, {rec.written} written)"
                           + (f"; {rec.error}" if rec.error else ""))
            elif rec.error:
                out.append(f"recording {self.opt.record}: {rec.error}")
        if self.opt.source.get("kind") == "replay" and self.stats.ticks == 0:
            out.append(f"replay {self.opt.source.get('path')}: no tick was played "
                       f"(input {json.dumps(self.source.counters.as_dict())})")
        return out
