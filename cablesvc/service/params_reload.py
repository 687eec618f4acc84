"""New parameters without a restart: the daemon's side (:class:`ParamsReload`, a mixin of
:class:`~cablesvc.service.daemon.Daemon`). SIGHUP or a put / get on
``cablesvc/<robot>/params`` queue a request; the reload thread parses and checks the file,
builds and warms up the new kernel; the loop switches between two ticks
(:meth:`ParamsReload._apply_params`), carrying the hysteresis state over within a model
family (:func:`hand_over`). A refused file is logged, counted, kept for status and raised
as a ``params_refused`` alarm; the old parameters stay."""

from __future__ import annotations

import logging
import math
import os
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cablesvc.config.params import ModelParams
from cablesvc.jsonable import jsonable
from cablesvc.kernel import Predictor
from cablesvc.service.snapshot import params_fingerprint

log = logging.getLogger("cablesvc.daemon")

MAX_PARAMS_BYTES = 1_000_000   # a parameter file put over Zenoh (identified files are a few kB)


@dataclass
class _ParamsChange:
    """New parameters prepared by the reload thread, waiting for the loop to switch."""

    params: ModelParams
    predictor: Predictor
    fingerprint: str
    origin: str
    done: threading.Event = field(default_factory=threading.Event)
    result: dict[str, Any] | None = None


def hand_over(old: Predictor, new: Predictor) -> str:
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


class ParamsReload:
    """The :class:`~cablesvc.service.daemon.Daemon`'s parameter-reload methods (a mixin:
    they use the daemon's kernel, alarms, stats, locks, publisher and reload queue)."""

    def _init_reload(self, options) -> None:
        """The reload state of a new daemon (``options``: its DaemonOptions)."""
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
        state = hand_over(old, new)
        s = self.stats
        t = s.last_t if s.last_t is not None else 0.0
        changed = change.fingerprint != self.fingerprint
        old_desc = f"{self.params.model} {self.fingerprint}"
        # counted and described before the switch: status() reads without the loop's lock, and
        # a status that shows the new model must count it accepted and name its source (one in
        # CI did not: model "linear", accepted 0, when the count came after the alarms' events)
        self.reload_counts["accepted"] += 1
        self.fingerprint = change.fingerprint
        self.params_origin = change.origin
        self.params_since = {"wall_time": time.time(), "seq": s.last_seq, "t": s.last_t, "origin": change.origin}
        self.predictor = new
        self.params = change.params                  # last: status() names the model from it
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
        result = {"accepted": True, "applied": True, "origin": change.origin, "model": change.params.model,
                  "fingerprint": change.fingerprint, "previous": old_desc, "state": state,
                  "seq": s.last_seq, "t": s.last_t, "wall_time": time.time()}
        self.last_reload = result
        change.result = result
        change.done.set()                          # the reload thread logs it (no log I/O in the loop)
