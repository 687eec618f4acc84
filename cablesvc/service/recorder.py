"""The daemon's recording writer: a thread fed by a bounded queue writes what the loop
hands it to MCAP (inputs, forces and alarms) or CSV (inputs only), by the file's suffix."""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from pathlib import Path

log = logging.getLogger("cablesvc.daemon")

REPLAY_RECORD_QUEUE = 2048          # ticks a replay's recorder may lag behind (the loop then waits)
RECORD_SUFFIXES = {".mcap": "MCAP (inputs, forces and alarms)", ".csv": "CSV (inputs only)"}


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
