"""Snapshots of the daemon's hysteresis and alarm state: the file (written atomically,
read back), whose state it is (robot, parameters, input), and the daemon's side of it
(:class:`SnapshotState`: write one, read one at start, use it at the first tick only when
that tick is consistent with it). The daemon's module docstring says when they are written.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from cablesvc import __version__
from cablesvc.config.params import ModelParams

log = logging.getLogger("cablesvc.daemon")

SNAPSHOT_FORMAT = 2            # 2: the meta names the source and holds the last elongation
#: the first tick after a restart may move each cable's elongation by up to this many times
#: the largest one-tick move the snapshot's session saw: a snapshot taken while the motion was
#: still speeding up (2.5 s into a sine) saw a largest step just below the next tick's (both
#: 0.0016 mm to four decimals, and the restart fell back to rest); a jump of a few ticks of
#: motion nobody saw is still refused
RESTORE_STEP_FACTOR = 2.0


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


class SnapshotState:
    """The :class:`~cablesvc.service.daemon.Daemon`'s snapshot methods (a mixin: they use
    the daemon's kernel, alarms, stats, ``snapshot_path`` and the per-cable elongation
    record the loop keeps)."""

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
        every cable's elongation moved by at most what one tick could (:data:`RESTORE_STEP_FACTOR`
        times the largest one-tick move of the snapshot's session, at least the reversal dead
        band: the motion may still have been speeding up when the snapshot was taken) and, for a replay,
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
            tol = np.maximum(self._restore_tolerance(),
                             RESTORE_STEP_FACTOR * step if step.shape == x1.shape else 0.0)
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
