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
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import queue
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
from cablesvc.jsonable import jsonable
from cablesvc.config.robot import Robot
from cablesvc.kernel import Predictor
from cablesvc.service.messages import forces_payload

log = logging.getLogger("cablesvc.daemon")

SNAPSHOT_FORMAT = 2            # 2: the meta names the source and holds the last elongation
MAX_PARAMS_BYTES = 1_000_000   # a parameter file put over Zenoh (identified files are a few kB)


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


def default_snapshot_path(robot: str) -> Path:
    """``$CABLESVC_STATE_DIR`` or ``$XDG_STATE_HOME/cablesvc`` or ``~/.local/state/cablesvc``."""
    base = os.environ.get("CABLESVC_STATE_DIR")
    if not base:
        base = os.path.join(os.environ.get("XDG_STATE_HOME", os.path.expanduser("~/.local/state")), "cablesvc")
    return Path(base) / f"{robot}.state.npz"


def params_fingerprint(params: ModelParams) -> str:
    """Short hash of the parameter file's content: a snapshot only restores onto the same model."""
    return hashlib.sha256(params.to_toml().encode()).hexdigest()[:16]


def source_identity(source: dict[str, Any]) -> str:
    """The input a hysteresis state belongs to, as written into its snapshot: a CAN bus by
    interface and channel, a Modbus server by host, port and unit, a replay by the
    recording's absolute path. A snapshot is restored only onto the same identity: a replay
    (or a simulator) never takes over, nor overwrites, the live robot's state."""
    kind = source.get("kind")
    if kind == "can":
        return f"can:{source.get('interface')}:{source.get('channel')}"
    if kind == "modbus":
        return f"modbus:{source.get('host')}:{source.get('port')}:{source.get('unit')}"
    if kind == "replay" and source.get("path"):
        return f"replay:{os.path.realpath(source['path'])}"
    return f"{kind}:{json.dumps(source, sort_keys=True, default=str)}"


# ---- snapshots -------------------------------------------------------------------------

def _flatten_state(prefix: str, d: Any, out: dict[str, np.ndarray]) -> None:
    if isinstance(d, dict):
        for k, v in d.items():
            _flatten_state(f"{prefix}{k}/", v, out)
    else:
        out[prefix[:-1]] = np.asarray(d)


def _unflatten_state(prefix: str, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    root: dict[str, Any] = {}
    for key, v in arrays.items():
        if not key.startswith(prefix):
            continue
        parts = key[len(prefix):].split("/")
        node = root
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = v[()] if v.ndim == 0 else v
    return root


def write_snapshot(path: Path, meta: dict[str, Any], predictor_state: dict[str, np.ndarray],
                   alarm_state: dict[str, Any]) -> None:
    """Atomic snapshot: write a temporary file next to ``path``, fsync it, rename over ``path``.

    A crash at any moment leaves either the previous snapshot or the new one, never a torn file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {"meta": np.array(json.dumps(meta))}
    _flatten_state("kernel/", predictor_state, arrays)
    _flatten_state("alarms/", alarm_state, arrays)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        np.savez(f, **arrays)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    try:                                  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def read_snapshot(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray], dict[str, Any]]:
    """(meta, predictor state, alarm state) of a snapshot file; raises ValueError when unreadable."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(str(arrays["meta"][()]))
    except Exception as e:                 # noqa: BLE001 - any damage means "not restorable"
        raise ValueError(f"{path}: not a readable cablesvc snapshot ({e})") from e
    kernel = {k[len("kernel/"):]: v for k, v in arrays.items() if k.startswith("kernel/")}
    return meta, kernel, _unflatten_state("alarms/", arrays)


# ---- recorder --------------------------------------------------------------------------

class StartError(RuntimeError):
    """The daemon cannot start as configured (a --record target it must not write, a
    --replay file it cannot read); the message is one line naming the file."""


REPLAY_RECORD_QUEUE = 2048          # ticks a replay's recorder may lag behind (the loop then waits)
RECORD_SUFFIXES = {".mcap": "MCAP (inputs, forces and alarms)", ".csv": "CSV (inputs only)"}


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


class Recorder:
    """Recording writer thread: the loop hands it (input, forces payload, alarm payloads)
    tuples, and (None, t, alarm payloads) for alarms raised or cleared outside a tick (input
    stale, lost or faulty). ``.mcap`` records all three; ``.csv`` the inputs only.

    The queue is bounded. With ``block=False`` (live sources) a full queue drops the tick
    and counts it (``dropped``): the loop never waits for the disk. With ``block=True``
    (replays, which have no real-time deadline) the loop waits for room instead, so that no
    tick is dropped whatever the replay speed.

    :meth:`close` waits for the thread to write everything queued: as long as it makes
    progress, whatever the length of the queue; only a writer that stalls (no item written
    for ``stall_s``) is given up on. ``missing`` = ticks handed over - ticks written
    (dropped, lost to a write error, or still queued when the writer stalled).

    The writer is flushed every ``flush_s`` (1 s) while ticks come, and when the queue has
    been idle that long: a kill -9 of the daemon loses at most about ``flush_s`` of ticks,
    at any rate (the binary encoding holds up to 1000 ticks in memory otherwise).
    """

    def __init__(self, path: Path, robot: str, metadata: dict[str, str], maxsize: int, *,
                 block: bool = False, overwrite: bool = True, stall_s: float = 10.0,
                 encoding: str = "protobuf", flush_s: float = 1.0):
        from cablesvc.recording import ALARMS_TOPIC, FORCES_TOPIC, McapRecordingWriter
        from cablesvc.recording.csv_io import CsvRecordingWriter

        self._forces_topic = FORCES_TOPIC
        self._alarms_topic = ALARMS_TOPIC
        path = Path(path)
        if path.suffix.lower() == ".csv":
            md = dict(metadata)
            if "params" in md:                      # CSV metadata are one line each
                md["params_json"] = json.dumps(md.pop("params"))
            self.writer = CsvRecordingWriter(path, robot, metadata=md, overwrite=overwrite)
        else:
            self.writer = McapRecordingWriter(path, robot, metadata=metadata, overwrite=overwrite,
                                              encoding=encoding)
        self._topics = getattr(self.writer, "has_topics", True)
        self.q: queue.Queue = queue.Queue(maxsize=maxsize)
        self.block = block
        self.stall_s = stall_s
        self.flush_s = flush_s          # flush the writer this often while ticks come (kill -9 loses <= this)
        self._dirty = False
        self._flushed_at = time.monotonic()
        self.handed = 0                 # ticks the loop handed over (queued or dropped)
        self.dropped = 0                # ticks dropped from a full queue (block=False) or after close
        self.written = 0
        self.error: str | None = None
        self._done = 0                  # items taken off the queue (progress, for close)
        self._closing = False
        self._abandoned = False
        self._thread = threading.Thread(target=self._run, name="cablesvc-recorder", daemon=True)
        self._thread.start()

    @property
    def missing(self) -> int:
        """Ticks handed over that are not in the file (yet)."""
        return self.handed - self.written

    def put(self, item) -> None:
        if item[0] is not None:
            self.handed += 1
        if self._closing:
            if item[0] is not None:
                self.dropped += 1
            return
        try:
            self.q.put_nowait(item)
            return
        except queue.Full:
            pass
        last, last_at = self._done, time.monotonic()
        while self.block and self._thread.is_alive() and not self._closing:
            try:
                self.q.put(item, timeout=0.1)
                return
            except queue.Full:
                pass
            if self._done != last:
                last, last_at = self._done, time.monotonic()
            elif time.monotonic() - last_at > self.stall_s:
                # a hung disk must not hang the loop (nor the shutdown, which needs the loop's lock)
                self.block = False
                log.error("the recording writer wrote nothing for %g s: ticks are dropped from now on "
                          "(counted as missing)", self.stall_s)
        if item[0] is not None:
            self.dropped += 1

    def _flush(self) -> None:
        """Hand what was written to the OS (the binary writer's block in progress and the
        chunk in progress): a kill -9 then loses at most ``flush_s`` of ticks, whatever the
        tick rate and the size of a chunk."""
        self._dirty = False
        self._flushed_at = time.monotonic()
        if self.error:
            return
        try:
            self.writer.flush()
        except Exception as e:  # noqa: BLE001 - a full disk must not stop the daemon
            self.error = f"recording stopped: {e}"
            log.error(self.error)

    def _run(self) -> None:
        while True:
            try:
                item = self.q.get(timeout=self.flush_s)
            except queue.Empty:                    # idle: flush what the last ticks left
                if self._dirty:
                    self._flush()
                continue
            if self._dirty and time.monotonic() - self._flushed_at >= self.flush_s:
                self._flush()
            self._done += 1
            self._dirty = True
            if item is None:
                if self._abandoned:               # close() gave up on us: close the file ourselves
                    try:
                        self.writer.close()
                    except Exception:  # noqa: BLE001
                        pass
                return
            if self.error:
                continue
            tick, forces, alarms = item
            try:
                if tick is None:                   # alarms outside a tick: forces is their time
                    if self._topics:
                        for a in alarms:
                            self.writer.write(self._alarms_topic, forces, a)
                    continue
                self.writer.write_input(tick.seq, tick.t, tick.motor_length, tick.force, tick.position,
                                        tick.orientation, tick.temperature)
                if self._topics:
                    self.writer.write(self._forces_topic, tick.t, forces)
                    for a in alarms:
                        self.writer.write(self._alarms_topic, tick.t, a)
                self.written += 1
            except Exception as e:  # noqa: BLE001 - a full disk must not stop the daemon
                self.error = f"recording stopped: {e}"
                log.error(self.error)

    def close(self) -> int:
        """Write out the queue, close the file; return :attr:`missing` (0: every tick handed
        over is in the file). Waits while the writer makes progress (bounded by the queue);
        a writer stalled for ``stall_s`` is left behind and its file is not closed."""
        self._closing = True
        sentinel = False
        last, last_at = -1, time.monotonic()
        while self._thread.is_alive():
            if not sentinel:
                try:
                    self.q.put(None, timeout=0.1)
                    sentinel = True
                except queue.Full:
                    pass
            else:
                self._thread.join(0.1)
            if self._done != last:
                last, last_at = self._done, time.monotonic()
            elif time.monotonic() - last_at > self.stall_s:
                self.error = (f"the recording writer stalled: nothing written for {self.stall_s:g} s with "
                              f"{self.q.qsize()} items still queued; gave up waiting")
                log.error("%s", self.error)
                self._abandoned = True
                if not self._thread.is_alive():       # it finished just now: close it here after all
                    self._abandoned = False
                    break
                return self.missing
        try:
            self.writer.close()
        except Exception as e:  # noqa: BLE001
            self.error = f"closing the recording failed: {e}"
            log.error("%s", self.error)
        return self.missing


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


@dataclass
class _ParamsChange:
    """New parameters prepared by the reload thread, waiting for the loop to switch."""

    params: ModelParams
    predictor: Predictor
    fingerprint: str
    origin: str
    done: threading.Event = field(default_factory=threading.Event)
    result: dict[str, Any] | None = None


def _hand_over(old: Predictor, new: Predictor) -> str:
    """Carry the kernel state of ``old`` into ``new`` (same robot); returns what happened.

    Same model family (model name): the whole state (the model's memory: reversal points,
    amplitude estimate, Bouc-Wen z, ...; the pose the FK warm-starts from; the last tick's
    time) carries over, so that reloading the same parameters changes nothing. Another
    family: its memory means nothing to the new model, which starts at rest at the last
    tick's elongation (as at a start, but with the pose and time kept: the next tick's dt
    is the real one)."""
    d = old.state_dict()
    if not d:
        return "none yet (no tick processed): the new model starts at the first tick"
    why = ""
    if type(old.model) is type(new.model):        # the same model class: its memory fits
        try:
            new.load_state_dict(d)
            return "kept (same model family)"
        except (KeyError, ValueError) as e:
            why = f" (the {new.params.model} state did not fit: {e})"
    x = np.array(old.out.elongation, dtype=float).reshape(1, -1)
    fresh = new.model.create_state(x)
    d2 = {f"model.{k}": v for k, v in fresh.as_dict().items()}
    d2.update({k: v for k, v in d.items() if not k.startswith("model.")})
    new.load_state_dict(d2)
    return (f"reset: the model family changed from {old.params.model} to {new.params.model}{why}; the new model "
            "starts at rest at the current elongation (pose and time kept)")


class Daemon:
    """Source, kernel, alarms, publisher: see the module docstring.

    ``publisher_factory(robot_name, status_fn) -> Publisher`` exists so that a test can
    pass a real publisher with its own config; by default a Zenoh publisher is opened from
    the options.
    """

    def __init__(self, options: DaemonOptions, *, source=None, publisher_factory: Callable | None = None):
        from cablesvc.alarms import AlarmConfig, AlarmManager
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
        self.alarms = AlarmManager(self.geom, options.params, options.alarm_config or AlarmConfig())
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
        # parameter reload (see the module docstring): a change prepared by the reload
        # thread waits in _pending_params until the loop takes it between two ticks
        pf = options.params_file
        if pf is None and options.params.source and os.path.isfile(options.params.source):
            pf = options.params.source
        self.params_file: str | None = os.path.abspath(pf) if pf else None
        self.params_origin = f"file {self.params_file}" if self.params_file else "nominal (no parameter file)"
        self.params_since: dict[str, Any] = {"wall_time": time.time(), "seq": None, "t": None, "origin": "start"}
        self.reload_counts = {"accepted": 0, "refused": 0}
        self.last_reload: dict[str, Any] | None = None
        self._pending_params: _ParamsChange | None = None
        self._params_alarm = None                  # the raised params_refused alarm, if any
        self._last_tick = None                     # the last input tick (warms up a new kernel)
        self._reload_q: queue.SimpleQueue = queue.SimpleQueue()     # put() is safe in a signal handler
        self._reload_thread: threading.Thread | None = None
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

    # -- state restore / snapshot ---------------------------------------------------------
    def _snapshot_meta(self) -> dict[str, Any]:
        """``source``: whose state it is; ``elongation`` the last tick's [m] and
        ``step_max`` the largest move of one tick seen [m], per cable: what the first tick of
        the next start is checked against (:meth:`_resume`)."""
        return {"format": SNAPSHOT_FORMAT, "robot": self.name, "model": self.params.model,
                "params": self.fingerprint, "source": self.source_id, "seq": self.stats.last_seq,
                "t": self.stats.last_t, "elongation": [None if v != v else float(v) for v in self._x_last],
                "step_max": [float(v) for v in self._step_max], "dt_last": self._dt_last,
                "wall_time": time.time(), "cablesvc_version": __version__}

    def _restore_tolerance(self) -> np.ndarray:
        """Per cable, the smallest elongation jump [m] the first tick may always show against
        the snapshot: the model's reversal dead band (the motion the model itself treats as
        noise). :meth:`_resume` allows more: the largest one-tick move seen before it."""
        from cablesvc.models.reversal import REVERSAL_DEADBAND

        db = np.broadcast_to(np.asarray(self.params.params.get("reversal_deadband", REVERSAL_DEADBAND), float),
                             (self.geom.n_cables,))
        return db

    def _resume(self, tick) -> None:
        """First tick after a restorable snapshot was read: use it only if it is consistent
        with this tick's input, else start from rest (logged, ``snapshot.error`` says why).

        The tick is run once from rest to get its elongation. The snapshot is consistent when
        every cable's elongation moved by at most what one tick could (the largest one-tick
        move of the snapshot's session, at least the reversal dead band) and, for a replay,
        when the recording continues after the snapshot's time (a replay from its start is
        not the state at its end). Then the state is loaded with its time re-anchored: this
        tick comes one tick (the snapshot session's last time step) after the snapshot,
        whatever the clock did meanwhile, so the downtime or a restarted clock is not a time
        step (f640b8f took dt = 0 after a clock restart and predicted the damping force of
        |dx| / 1e-12 s: 0 N and 5000-6600 N); a direct continuation is exact. The restored
        alarms' times move into this session's time base by the same shift
        (AlarmManager.rebase_time)."""
        meta, kernel, alarms = self._pending_restore
        self._pending_restore = None
        p = self.snapshot_path
        try:
            out = self.predictor.tick(tick.t, tick.motor_length, tick.position, tick.orientation,
                                      tick.force, tick.temperature)
            x1 = out.elongation.copy()
            pos, quat = out.position.copy(), out.orientation.copy()
        except Exception:  # noqa: BLE001 - the tick itself is counted by step()
            self.predictor.reset()
            return
        self.predictor.reset()
        t_snap = meta.get("t")
        x_snap = np.array([np.nan if v is None else v for v in (meta.get("elongation") or [])], dtype=float)
        why = None
        if x_snap.shape != x1.shape or not np.all(np.isfinite(x_snap)) or not isinstance(t_snap, (int, float)):
            why = "it holds no elongation to compare with"
        else:
            step = np.asarray(meta.get("step_max") or np.zeros_like(x1), dtype=float)
            tol = np.maximum(self._restore_tolerance(), step if step.shape == x1.shape else 0.0)
            jump = np.abs(x1 - x_snap)
            bad = np.flatnonzero(~(jump <= tol))
            if bad.size:
                i = int(bad[np.argmax(jump[bad] / tol[bad])])
                why = (f"cable {i} ({self.geom.cable_names[i]}) is at elongation {x1[i] * 1e3:.4f} mm, "
                       f"{jump[i] * 1e3:.4f} mm from the snapshot's {x_snap[i] * 1e3:.4f} mm, more than one tick "
                       f"can move ({tol[i] * 1e3:.4f} mm): the cables moved since")
            elif self.source_id.startswith("replay:") and tick.t < t_snap:
                why = (f"the replay starts at t = {tick.t:.3f} s, before the snapshot's t = {t_snap:.3f} s: "
                       "the state at its end is not the state at its start")
        if why:
            log.warning("not restoring %s: %s; starting from rest", p, why)
            self.snapshot_error = f"not restored: {why}"
            return
        try:
            dt = meta.get("dt_last")
            dt = float(dt) if isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0 else 0.0
            k = dict(kernel)
            k["t_prev"] = np.array([tick.t - dt])
            if not np.all(np.isfinite(np.asarray(k.get("pose.position", np.nan), dtype=float))):
                k["pose.position"] = pos.reshape(1, 3)
                k["pose.orientation"] = quat.reshape(1, 4)
            self.predictor.load_state_dict(k)
            if alarms:
                self.alarms.load_state_dict(alarms)
                self.alarms.rebase_time(tick.t - dt - float(t_snap))
        except Exception as e:  # noqa: BLE001 - a bad snapshot must never stop the loop
            self.predictor.reset()
            self.snapshot_error = f"not restored: {e}"
            log.warning("not restoring %s: %s; starting from rest", p, e)
            return
        self.restored_from = str(p)
        clock = "" if tick.t >= t_snap else " (the controller clock restarted)"
        log.info("restored hysteresis state from %s (seq %s, t %s; first tick t %s%s)", p, meta.get("seq"),
                 t_snap, tick.t, clock)

    def _restore(self) -> None:
        p = self.snapshot_path
        if p is None or not p.exists():
            return
        try:
            meta, kernel, alarms = read_snapshot(p)
            why = None
            if meta.get("format") != SNAPSHOT_FORMAT:
                why = f"snapshot format {meta.get('format')} (expected {SNAPSHOT_FORMAT})"
            elif meta.get("robot") != self.name:
                why = f"it belongs to robot {meta.get('robot')!r}"
            elif meta.get("params") != self.fingerprint:
                why = "it was made with other model parameters"
            elif meta.get("source") != self.source_id and str(meta.get("source")).startswith("sim:"):
                why = "it was written by another start of the embedded simulator, which starts from rest"
            elif meta.get("source") != self.source_id:
                # another input's state (the live robot's, seen from a replay): neither used nor
                # replaced; this run writes no snapshot
                why = f"it belongs to source {meta.get('source')!r}, not {self.source_id!r}"
                log.warning("not restoring %s: %s; starting from rest, and leaving that file alone "
                            "(this run writes no snapshot)", p, why)
                self.snapshot_error = f"not restored and not overwritten: {why}"
                self.snapshot_path = None
                return
            if why:
                log.warning("not restoring %s: %s; starting from rest", p, why)
                self.snapshot_error = f"not restored: {why}"
                return
            if kernel:
                self._pending_restore = (meta, kernel, alarms)     # checked against the first tick
                log.info("read hysteresis state from %s (seq %s, t %s); it is used if the first tick is "
                         "consistent with it", p, meta.get("seq"), meta.get("t"))
        except Exception as e:  # noqa: BLE001 - a bad snapshot must never stop the start
            self.predictor.reset()
            self.snapshot_error = f"not restored: {e}"
            log.warning("not restoring %s: %s; starting from rest", p, e)

    def snapshot(self) -> None:
        """Write the hysteresis and alarm state atomically (no-op without a snapshot path, and
        before the first tick while a read snapshot waits for it: the file already holds it)."""
        if self.snapshot_path is None or self._pending_restore is not None:
            return
        try:
            write_snapshot(self.snapshot_path, self._snapshot_meta(), self.predictor.state_dict(),
                           self.alarms.state_dict())
            if self.snapshot_error and self.snapshot_error.startswith("snapshot failed"):
                self.snapshot_error = None        # (why a snapshot was not restored stays)
        except Exception as e:  # noqa: BLE001 - a full disk must not stop the daemon
            self.snapshot_error = f"snapshot failed: {e}"
            log.error("%s", self.snapshot_error)
        self._last_snapshot = time.monotonic()

    # -- parameter reload -----------------------------------------------------------------
    def _model_status(self) -> dict[str, Any]:
        """The active model for status: name, where its parameters came from, fingerprint,
        parameters, the discovered terms its file lists, since when it is active."""
        p = self.params
        terms = p.identification.get("discovered_terms") if isinstance(p.identification, dict) else None
        return {"name": p.model, "params_file": p.source, "source": self.params_origin,
                "fingerprint": self.fingerprint, "params": jsonable(p.params), "options": jsonable(p.options),
                "terms": list(terms) if isinstance(terms, (list, tuple)) else [],
                "active_since": dict(self.params_since), "identification": jsonable(p.identification)}

    def request_reload(self, text: str | bytes | None = None, *, origin: str = "SIGHUP", reply=None) -> None:
        """Ask for new parameters without waiting: ``text`` the TOML text of a parameter
        file, or None to re-read :attr:`params_file`. Safe in a signal handler (a put on a
        SimpleQueue); the reload thread does the work (:meth:`reload_params`). ``reply``:
        called with the outcome (a dict) when it is known."""
        self._reload_q.put((text, origin, reply))

    def _reload_worker(self) -> None:
        while True:
            item = self._reload_q.get()
            if item is None:
                return
            text, origin, reply = item
            try:
                result = self.reload_params(text, origin=origin)
            except Exception as e:  # noqa: BLE001 - the thread must survive anything
                log.exception("parameter reload failed: %s", e)
                result = {"accepted": False, "origin": origin, "reason": f"internal error: {e}"}
            if reply is not None:
                try:
                    reply(result)
                except Exception as e:  # noqa: BLE001
                    log.error("replying to a parameter reload failed: %s", e)

    def _on_params_put(self, data: bytes, origin: str) -> None:
        """A put on cablesvc/<robot>/params (a Zenoh thread): queue it, return at once."""
        self.request_reload(bytes(data), origin=origin)

    def _on_params_query(self, query, data: bytes | None) -> None:
        """A get on cablesvc/<robot>/params (a Zenoh thread). With a payload: a reload whose
        outcome is the reply; without: the active parameters (TOML) and their fingerprint."""
        pub = self.publisher
        if data is None or not bytes(data).strip():
            pub.reply_params(query, {"robot": self.name, "model": self._model_status(),
                                     "toml": self.params.to_toml()})
            return
        self.request_reload(bytes(data), origin=f"zenoh get on cablesvc/{self.name}/params",
                            reply=lambda result: pub.reply_params(query, result) if pub is not None else None)

    def reload_params(self, text: str | bytes | None = None, *, origin: str = "api",
                      timeout: float = 5.0) -> dict[str, Any]:
        """Load new parameters: parse and check ``text`` (a parameter file's TOML) or the
        parameter file (None), build and warm up the new kernel here (not in the loop), hand
        it to the loop and wait up to ``timeout`` s until the loop has switched at a tick
        boundary. Returns the outcome: ``accepted``, ``reason`` (refused), ``fingerprint``,
        ``model``, ``state`` (what happened to the hysteresis state), ``applied`` and the
        ``seq`` / ``t`` of the last tick before the switch. Never raises for a bad file."""
        from cablesvc.config.params import ParamFileError, load_params, parse_params

        try:
            if text is not None and len(text) > MAX_PARAMS_BYTES:
                raise ParamFileError(f"<{origin}>", [f"{len(text)} bytes: a parameter file is at most "
                                                     f"{MAX_PARAMS_BYTES} bytes"])
            if text is None:
                if self.params_file is None:
                    raise ParamFileError("(no parameter file)", [
                        "the daemon started with nominal parameters and has no file to re-read; put a parameter "
                        f"file on cablesvc/{self.name}/params or restart with --params"])
                params = load_params(self.params_file)
                src = f"file {self.params_file} ({origin})"
            else:
                params = parse_params(text, f"<{origin}>")
                src = origin
            if params.robot and params.robot != self.name:
                raise ParamFileError(params.source, [f"robot: the parameters were identified for robot "
                                                     f"{params.robot!r}, not {self.name!r}"])
            new = Predictor(self.geom, params)       # builds the model: checks the cable count, options, ...
            params.amplitude_range()                 # the alarms need it valid
            last = self._last_tick
            if last is not None:                     # one tick now: compiles and allocates off the loop
                try:
                    new.tick(last.t, last.motor_length, last.position, last.orientation, last.force,
                             last.temperature)
                except Exception as e:  # noqa: BLE001 - only a warm-up: the loop counts what fails live
                    log.warning("the new kernel's warm-up tick failed (%s); switching anyway", e)
                new.reset()
        except ParamFileError as e:
            where = "" if str(e.path).startswith("<") else f"{e.path}: "
            return self._refuse(origin, where + "; ".join(e.problems))
        except Exception as e:  # noqa: BLE001 - whatever the file holds, the daemon goes on
            return self._refuse(origin, f"{type(e).__name__}: {e}")
        change = _ParamsChange(params=params, predictor=new, fingerprint=params_fingerprint(params), origin=src)
        with self._state_lock:
            prev = self._pending_params
            if prev is not None:                     # a newer request replaces one not yet taken
                prev.result = {"accepted": False, "origin": prev.origin, "applied": False,
                               "reason": "superseded by a newer reload before the loop took it"}
                prev.done.set()
            self._pending_params = change
        if not change.done.wait(timeout):
            log.warning("new parameters (%s, %s %s) wait for the loop: it has not switched within %g s", src,
                        params.model, change.fingerprint, timeout)
            return {"accepted": True, "applied": False, "origin": src, "fingerprint": change.fingerprint,
                    "model": params.model, "reason": f"the loop has not taken it within {timeout:g} s; it switches "
                                                     "between the next two ticks"}
        r = change.result
        if r.get("applied"):
            log.info("new parameters active from the tick after seq %s (t %s): %s %s from %s (was %s); hysteresis "
                     "state: %s", r["seq"], r["t"], r["model"], r["fingerprint"], r["origin"], r["previous"], r["state"])
        return r

    def _refuse(self, origin: str, reason: str) -> dict[str, Any]:
        """A reload that is refused: logged, counted, kept for status, raised as the
        ``params_refused`` alarm (once; its message follows the latest refusal)."""
        from cablesvc.alarms import ALARM_CODES, AlarmEvent

        log.error("new parameters (%s) refused, the old ones stay active (%s): %s", origin, self.fingerprint, reason)
        result = {"accepted": False, "applied": False, "origin": origin, "reason": reason,
                  "active_fingerprint": self.fingerprint, "wall_time": time.time()}
        with self._state_lock:
            self.reload_counts["refused"] += 1
            self.last_reload = result
            from cablesvc.sources.base import Problem
            self.problems.append(Problem(time.time(), "params_refused", f"{origin}: {reason}"[:2000]))
            t = self.stats.last_t if self.stats.last_t is not None else 0.0
            ev = AlarmEvent(action="raise", code="params_refused", cable=None,
                            severity=ALARM_CODES["params_refused"][0], t=t,
                            since=self._params_alarm.since if self._params_alarm is not None else t,
                            seq=self.stats.last_seq,
                            message=f"new parameters ({origin}) refused, {self.params.model} {self.fingerprint} "
                                    f"stays active: {reason}"[:2000])
            self._params_alarm = ev
            self._emit(ev)
        return result

    def _apply_params(self) -> None:
        """Switch to the pending parameters (the loop, between two ticks, under the state lock)."""
        from cablesvc.alarms import AlarmEvent

        change, self._pending_params = self._pending_params, None
        old, new = self.predictor, change.predictor
        state = _hand_over(old, new)
        s = self.stats
        t = s.last_t if s.last_t is not None else 0.0
        changed = change.fingerprint != self.fingerprint
        old_desc = f"{self.params.model} {self.fingerprint}"
        self.predictor = new
        self.params = change.params
        self.fingerprint = change.fingerprint
        self.params_origin = change.origin
        self.params_since = {"wall_time": time.time(), "seq": s.last_seq, "t": s.last_t, "origin": change.origin}
        events = self.alarms.set_params(change.params, t, s.last_seq)
        if changed:        # another model: the residual's baseline is another one too
            events += self.alarms.reset_drift()
        if self._params_alarm is not None:
            raised, self._params_alarm = self._params_alarm, None
            events.append(AlarmEvent("clear", "params_refused", None, "info", t, raised.since, s.last_seq,
                                     f"new parameters ({change.origin}) accepted"))
        for ev in events:
            self._emit(ev)
        if self._pending_restore is not None and changed:
            self._pending_restore = None             # that state belongs to the old parameters
            self.snapshot_error = "not restored: the parameters changed before the first tick"
        if self.snapshot_path is not None:
            self._last_snapshot = -math.inf          # the next loop pass writes one for the new parameters
        self.reload_counts["accepted"] += 1
        result = {"accepted": True, "applied": True, "origin": change.origin, "model": change.params.model,
                  "fingerprint": change.fingerprint, "previous": old_desc, "state": state,
                  "seq": s.last_seq, "t": s.last_t, "wall_time": time.time()}
        self.last_reload = result
        change.result = result
        change.done.set()                          # the reload thread logs it (no log I/O in the loop)

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
            lat.update(p50_us=h.get_value_at_percentile(50), p99_us=h.get_value_at_percentile(99),
                       p999_us=h.get_value_at_percentile(99.9), max_us=h.get_max_value())
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
        s.ticks += 1
        s.last_seq = tick.seq
        s.last_t = tick.t
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

    def close(self) -> None:
        """Stop the source, process what it accepted before it stopped, write the final
        snapshot, close the recording and Zenoh (< 2 s).

        Between the end of :meth:`run` and the source's close, a receive thread can still
        accept a tick or two (it queues them once the direct sink is gone). Each is stepped
        and published here, so that every accepted tick has its output even at shutdown."""
        self._reload_q.put(None)                  # the reload thread ends (a pending change is dropped)
        try:
            self.source.close()
        except Exception as e:  # noqa: BLE001
            log.error("closing the source failed: %s", e)
        # a loop stuck in one tick (it cannot be, with parameters in their limits) must not
        # hold the shutdown: then no final snapshot (the state would be half a tick)
        if not self._state_lock.acquire(timeout=1.0):
            log.error("the loop did not finish its tick within 1 s; no final snapshot")
            self._close_outputs()
            return
        with _Held(self._state_lock):
            if hasattr(self.source, "set_sink"):          # queued ticks exist only for threaded sources
                for _ in range(10_000):
                    tick = self.source.recv(timeout=0)
                    if tick is None:
                        break
                    self.step(tick)
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
