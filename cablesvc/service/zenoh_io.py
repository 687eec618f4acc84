"""Zenoh side of the live service: the daemon's :class:`Publisher` and the client's :class:`Listener`.

Key expressions, per robot (``keys(robot)``):

=========================== ============================================================
``cablesvc/<robot>/forces``  one forces message per processed tick (put, express,
                             block under congestion: a tick is never dropped)
``cablesvc/<robot>/alarms``  one message per alarm raise or clear (put, express,
                             block under congestion: an alarm is never dropped)
``cablesvc/<robot>/status``  queryable: a get returns the daemon's status as JSON
``cablesvc/<robot>/alive``   liveliness token, present while the daemon runs
``cablesvc/<robot>/params``  subscriber: a put of a parameter file's TOML text makes the
                             daemon switch to it (at a tick boundary; a bad file is
                             refused and the old parameters stay); queryable: a get with
                             such a payload does the same and replies with the outcome
                             (JSON), a get without payload replies with the active
                             parameters (:meth:`Publisher.serve_params`)
=========================== ============================================================

Payloads and encodings are in :mod:`cablesvc.service.messages` and ``docs/messages.md``.

Network configuration (:func:`make_config`): by default a peer that listens on
``tcp/127.0.0.1:7447`` only, with multicast scouting off, so nothing leaves the host
unless configured. Deployments with a router, TLS and access control load a JSON5 file
(``deploy/zenoh-router.json5``, ``deploy/zenoh-peer.json5``).

Written against eclipse-zenoh 1.x (the Python API of 1.0 and later: ``zenoh.open``,
``declare_publisher(express=...)``, ``liveliness().declare_token``).
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from typing import Any, Callable, Iterable, NamedTuple

import zenoh

from cablesvc.jsonable import jsonable
from cablesvc.service.messages import ENCODINGS, JSON_ENCODING, decode, encode

__all__ = ["DEFAULT_LISTEN", "Keys", "Listener", "Publisher", "Received", "keys", "make_config"]

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
PREFIX = "cablesvc"
_UNSET: Any = object()
_MODES = ("peer", "client", "router")


#: how long a link may stay blocked (transmit queue full under BLOCK congestion control)
#: before Zenoh closes it [us]: the longest a stuck subscriber can hold up the daemon
BLOCK_CLOSE_US = 1_000_000


def make_config(config_file: str | None = None, *, mode: str = _UNSET, listen: Iterable[str] | str = _UNSET,
                connect: Iterable[str] | str = _UNSET, multicast_scouting: bool = _UNSET) -> zenoh.Config:
    """A Zenoh configuration for the daemon or a client.

    Without ``config_file``: ``mode`` (default "peer"), listening only on ``listen``
    (default ``(DEFAULT_LISTEN,)``; ``()`` listens nowhere), connecting to ``connect``
    (default none), multicast scouting off (``multicast_scouting``).
    With ``config_file`` (JSON5, e.g. ``deploy/zenoh-router.json5``): the file as is, and
    only the arguments given explicitly here override it.
    """
    if config_file is not None:
        cfg = zenoh.Config.from_file(str(config_file))
    else:
        cfg = zenoh.Config()
        mode = "peer" if mode is _UNSET else mode
        listen = (DEFAULT_LISTEN,) if listen is _UNSET else listen
        connect = () if connect is _UNSET else connect
        multicast_scouting = False if multicast_scouting is _UNSET else multicast_scouting
    if mode is not _UNSET:
        if mode not in _MODES:
            raise ValueError(f"mode must be one of {_MODES}, got {mode!r}")
        cfg.insert_json5("mode", json.dumps(mode))
    if listen is not _UNSET:
        cfg.insert_json5("listen/endpoints", json.dumps(_endpoints(listen)))
    if connect is not _UNSET:
        cfg.insert_json5("connect/endpoints", json.dumps(_endpoints(connect)))
    if multicast_scouting is not _UNSET:
        cfg.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
    if config_file is None:
        # Forces go out at data-high priority. Zenoh's default transmit queue for that
        # priority is 2 batches: a subscriber descheduled for a few milliseconds at 1 kHz
        # overflows it. 16 (the maximum) rides out short stalls without blocking.
        cfg.insert_json5("transport/link/tx/queue/size/data_high", "16")
        # Forces are put with BLOCK congestion control: "every accepted tick is published
        # once" has to hold at the subscriber too. Under DROP, Zenoh silently dropped what a
        # full queue could not take: 30-minute soaks at 1 kHz lost 103, 51 and 97 of 1.8 M
        # messages after VM stalls (drop waits 1-5 ms), with 0 lost at the daemon's input.
        # The price: a subscriber that stops reading holds up the daemon's puts until Zenoh
        # closes its link, after this long blocked (Zenoh's default: 5 s).
        cfg.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close",
                         str(BLOCK_CLOSE_US))
    return cfg


def _endpoints(v: Iterable[str] | str) -> list[str]:
    eps = [v] if isinstance(v, str) else list(v)
    for e in eps:
        if not isinstance(e, str) or "/" not in e:
            raise ValueError(f"a Zenoh endpoint looks like tcp/127.0.0.1:7447, got {e!r}")
    return eps


class Keys(NamedTuple):
    """Key expressions of one robot (or of all robots: ``*`` in place of the name)."""

    forces: str
    alarms: str
    status: str
    alive: str
    params: str


def keys(robot: str | None) -> Keys:
    """Key expressions of ``robot``; None gives the wildcard ones matching every robot."""
    if robot is None:
        r = "*"
    else:
        r = str(robot)
        if not r or any(c in r for c in "/*$?#") or r != r.strip():
            raise ValueError(f"robot name {robot!r} cannot be a Zenoh key chunk (no '/', '*', '$', '?', '#')")
    base = f"{PREFIX}/{r}"
    return Keys(f"{base}/forces", f"{base}/alarms", f"{base}/status", f"{base}/alive", f"{base}/params")


def _robot_of(key: str) -> str:
    parts = str(key).split("/")
    return parts[1] if len(parts) >= 3 else str(key)


class Publisher:
    """The daemon's outputs on Zenoh for one robot.

    Opens a session with ``config``, or uses ``session``, an already open Zenoh session
    shared with other publishers (one daemon process serving several robots,
    :mod:`cablesvc.service.fleet`): a shared session belongs to whoever opened it, and
    :meth:`close` then withdraws only this robot's declarations and leaves the session
    open. Either way it declares the forces publisher (express, data-high
    priority, block under congestion) and the alarms publisher (express, interactive-high
    priority, block under congestion), a queryable on the status key answering
    ``json(status())``, and a liveliness token on the alive key. ``encoding`` "json" or
    "compact" is the encoding of the forces messages (alarms and status are always JSON).
    ``skip_unmatched``: do not encode forces while no subscriber matches (saves the
    encoding time when no client listens).
    """

    def __init__(self, robot: str, config: zenoh.Config | None = None, *, encoding: str = "json",
                 status: Callable[[], dict] | None = None, skip_unmatched: bool = True,
                 session: zenoh.Session | None = None):
        if (config is None) == (session is None):
            raise ValueError("Publisher needs exactly one of config (open a session) or session (share one)")
        if encoding not in ENCODINGS and encoding not in ENCODINGS.values():
            raise ValueError(f"encoding must be one of {sorted(ENCODINGS)}, got {encoding!r}")
        self.robot = robot
        self.keys = k = keys(robot)
        self.encoding = encoding
        self._enc_str = ENCODINGS.get(encoding, encoding)
        self._status = status if status is not None else (lambda: {"robot": robot})
        self._lock = threading.Lock()
        self._closed = False
        self.skip_unmatched = bool(skip_unmatched)
        self.forces_published = 0
        self.forces_skipped = 0
        self.alarms_published = 0
        self.status_queries = 0
        #: whether :meth:`close` closes the session (it opened it) or leaves it to its owner
        self.owns_session = session is None
        self.session = zenoh.open(config) if session is None else session
        try:
            self._forces = self.session.declare_publisher(
                k.forces, encoding=zenoh.Encoding(self._enc_str), express=True,
                congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh.Priority.DATA_HIGH)
            self._alarms = self.session.declare_publisher(
                k.alarms, encoding=zenoh.Encoding(JSON_ENCODING), express=True,
                congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh.Priority.INTERACTIVE_HIGH)
            self._queryable = self.session.declare_queryable(k.status, self._on_query)
            self._token = self.session.liveliness().declare_token(k.alive)
            # the forces path asks "is anyone listening?" every tick: while the matching
            # notifications say yes it does not query Zenoh (~2 us); while they say no it asks
            # Zenoh itself before skipping (the notification of a new subscriber may lag)
            self._forces_matched = bool(self.subscribed("forces"))
            self._matching = self._forces.declare_matching_listener(self._on_matching)
            self._forces_matched = bool(self.subscribed("forces"))   # a change before the listener
        except BaseException:
            if self.owns_session:
                self.session.close()
            else:                          # a shared session stays open: withdraw what was declared
                self._undeclare()
            raise

    def _on_query(self, query) -> None:
        """Status queryable callback (a Zenoh thread)."""
        self.status_queries += 1
        try:
            body = json.dumps(jsonable(self._status()), separators=(",", ":"), allow_nan=False)
        except Exception as e:  # noqa: BLE001 - the querier gets the reason
            try:
                query.reply_err(f"status failed: {e}")
            except Exception:  # noqa: BLE001
                pass
            return
        try:
            query.reply(self.keys.status, body, encoding=zenoh.Encoding(JSON_ENCODING))
        except Exception:  # noqa: BLE001 - session closing under us
            pass

    def serve_params(self, on_put: Callable[[bytes, str], None],
                     on_query: Callable[[Any, bytes | None], None]) -> None:
        """Take new parameters on the params key (``cablesvc/<robot>/params``): a put calls
        ``on_put(payload bytes, origin)`` and a get calls ``on_query(query, payload bytes or
        None)`` on the Zenoh thread that received it. Both must return at once (the daemon
        queues the work for its reload thread, which replies to the query later with
        :meth:`reply_params`). Who may put or get there is the access control's business
        (``deploy/zenoh-router.json5``: only the ``cablesvc-operator`` certificate)."""
        k = self.keys.params

        def put_cb(sample) -> None:
            if sample.kind != zenoh.SampleKind.PUT:
                return                                  # a delete carries no parameters
            try:
                on_put(sample.payload.to_bytes(), f"zenoh put on {k}")
            except Exception:  # noqa: BLE001 - a callback must never raise into Zenoh
                pass

        def query_cb(query) -> None:
            try:
                payload = query.payload
                on_query(query, None if payload is None else payload.to_bytes())
            except Exception as e:  # noqa: BLE001
                try:
                    query.reply_err(f"params failed: {e}")
                except Exception:  # noqa: BLE001
                    pass

        self._params_sub = self.session.declare_subscriber(k, put_cb)
        self._params_q = self.session.declare_queryable(k, query_cb)

    def reply_params(self, query, answer: dict) -> None:
        """Reply (JSON) to a get on the params key; never raises (the querier may be gone)."""
        try:
            body = json.dumps(jsonable(answer), separators=(",", ":"), allow_nan=False)
            query.reply(self.keys.params, body, encoding=zenoh.Encoding(JSON_ENCODING))
        except Exception:  # noqa: BLE001
            pass
        finally:
            try:
                query.drop()
            except Exception:  # noqa: BLE001 - older bindings finalise the query when it is freed
                pass

    def _on_matching(self, status) -> None:
        self._forces_matched = bool(getattr(status, "matching", status))

    def subscribed(self, what: str = "forces") -> bool:
        """Whether Zenoh knows of a subscriber matching the forces (or ``"alarms"``) key now.

        Asking about the forces also brings the flag :meth:`publish_forces` reads up to date:
        the matching notification runs on a Zenoh thread and can come tens of milliseconds
        after the status reads true (a loaded machine), and ticks published in between were
        skipped, so a daemon that waited for its subscriber (``--wait-subscriber``) could still
        lose its first ticks."""
        pub = self._forces if what == "forces" else self._alarms
        try:
            ms = pub.matching_status
        except Exception:  # noqa: BLE001 - closed
            return False
        matched = bool(getattr(ms, "matching", ms))
        if what == "forces":
            self._forces_matched = matched
        return matched

    def publish_forces(self, payload: dict) -> None:
        """Put one forces payload (:func:`~cablesvc.service.messages.forces_payload`). A no-op
        after :meth:`close`. With ``skip_unmatched`` (default) the payload is not even
        encoded while no subscriber matches (counted in ``forces_skipped``)."""
        if self._closed:
            return
        if self.skip_unmatched and not self._forces_matched and not self.subscribed("forces"):
            # skipped only if Zenoh says so now, not on the notification alone (it may lag)
            self.forces_skipped += 1
            return
        data, _ = encode(payload, self._enc_str)
        self._forces.put(data)
        self.forces_published += 1

    def publish_forces_bytes(self, data: bytes) -> None:
        """Put an already encoded forces message (in this publisher's encoding)."""
        if self._closed:
            return
        self._forces.put(data)
        self.forces_published += 1

    def publish_alarm(self, event_payload: dict) -> None:
        """Put one alarm payload (``AlarmEvent.payload()``), JSON. A no-op after :meth:`close`."""
        if self._closed:
            return
        p = event_payload if "robot" in event_payload else {**event_payload, "robot": self.robot}
        data, _ = encode(p, "json")
        self._alarms.put(data)
        self.alarms_published += 1

    def _undeclare(self) -> None:
        for obj in (getattr(self, "_params_sub", None), getattr(self, "_params_q", None),
                    getattr(self, "_matching", None), getattr(self, "_token", None), getattr(self, "_queryable", None),
                    getattr(self, "_alarms", None), getattr(self, "_forces", None)):
            if obj is not None:
                try:
                    obj.undeclare()
                except Exception:  # noqa: BLE001 - already gone (or the session closed under us)
                    pass

    def close(self) -> None:
        """Withdraw the liveliness token, undeclare everything and close the session when
        this publisher opened it (a shared ``session`` is left to its owner). Idempotent;
        returns in milliseconds."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._undeclare()
        if not self.owns_session:
            return
        try:
            self.session.close()
        except Exception:  # noqa: BLE001
            pass

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> "Publisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Received(NamedTuple):
    """A message taken from a :class:`Listener` queue: the decoded payload and
    ``receive_ns``, the listener host's ``time.monotonic_ns()`` when it arrived, the key
    expression and the encoding string it was published with."""

    payload: dict
    receive_ns: int
    key: str
    encoding: str


class _Queue:
    """Bounded queue that drops the oldest item when full (counted in ``dropped``)."""

    def __init__(self, size: int):
        self._d: deque = deque(maxlen=size)
        self._cv = threading.Condition()
        self.dropped = 0
        self.closed = False

    def put(self, item) -> None:
        with self._cv:
            if len(self._d) == self._d.maxlen:
                self.dropped += 1
            self._d.append(item)
            self._cv.notify()

    def get(self, timeout: float | None) -> Any:
        with self._cv:
            if not self._d and not self.closed:
                self._cv.wait_for(lambda: self._d or self.closed, timeout)
            return self._d.popleft() if self._d else None

    def close(self) -> None:
        with self._cv:
            self.closed = True
            self._cv.notify_all()

    def __len__(self) -> int:
        return len(self._d)


class Listener:
    """Client side: subscribes to the forces and alarms of one robot (``robot`` None: all).

    With ``on_forces`` / ``on_alarm`` each decoded message is handed to the callback as
    ``(payload, receive_ns)`` (``receive_ns`` = ``time.monotonic_ns()`` when the sample
    reached the callback, taken before decoding); callbacks run on a Zenoh thread and should
    be quick. Without a callback, messages go to a bounded queue (``queue_size``; the oldest
    is dropped when full, counted in ``dropped``) read with :meth:`forces` / :meth:`alarms`.
    Messages that cannot be decoded are counted in ``decode_errors`` and skipped.
    """

    def __init__(self, robot: str | None, config: zenoh.Config, *, on_forces: Callable | None = None,
                 on_alarm: Callable | None = None, queue_size: int = 10_000):
        self.robot = robot
        self.keys = k = keys(robot)
        self.decode_errors = 0
        self.last_error: str | None = None
        self._on_forces = on_forces
        self._on_alarm = on_alarm
        self._qf = _Queue(queue_size)
        self._qa = _Queue(queue_size)
        self._lock = threading.Lock()
        self._closed = False
        self.session = zenoh.open(config)
        try:
            self._sub_f = self.session.declare_subscriber(k.forces, self._forces_cb)
            self._sub_a = self.session.declare_subscriber(k.alarms, self._alarm_cb)
        except BaseException:
            self.session.close()
            raise

    def _decode(self, sample) -> dict | None:
        try:
            return decode(sample.payload.to_bytes(), str(sample.encoding))
        except Exception as e:  # noqa: BLE001 - a bad message must not stop the listener
            self.decode_errors += 1
            self.last_error = f"{sample.key_expr}: {e}"
            return None

    def _forces_cb(self, sample) -> None:
        self._deliver(sample, self._on_forces, self._qf)

    def _alarm_cb(self, sample) -> None:
        self._deliver(sample, self._on_alarm, self._qa)

    def _deliver(self, sample, handler, q) -> None:
        """A received message, decoded, to ``handler`` (payload, receive time [ns]) when the
        listener has one, else onto the queue ``q``; an undecodable one is counted and dropped."""
        now = time.monotonic_ns()
        p = self._decode(sample)
        if p is None:
            return
        if handler is not None:
            handler(p, now)
        else:
            q.put(Received(p, now, str(sample.key_expr), str(sample.encoding)))

    def forces(self, timeout: float | None = None) -> Received | None:
        """Next forces message from the queue, waiting up to ``timeout`` s (None: forever, until
        :meth:`close`); None when nothing came."""
        return self._qf.get(timeout)

    def alarms(self, timeout: float | None = None) -> Received | None:
        """Next alarm message from the queue (see :meth:`forces`)."""
        return self._qa.get(timeout)

    @property
    def dropped(self) -> int:
        """Messages dropped because a queue was full."""
        return self._qf.dropped + self._qa.dropped

    def statuses(self, timeout: float = 2.0) -> list[dict]:
        """Status of every daemon answering on the status key (all robots when robot is None)."""
        out = []
        for reply in self.session.get(self.keys.status, timeout=timeout):
            s = reply.ok
            if s is None:
                continue
            try:
                out.append(decode(s.payload.to_bytes(), str(s.encoding)))
            except ValueError:
                self.decode_errors += 1
        return out

    def status(self, timeout: float = 2.0) -> dict | None:
        """The daemon's status (a Zenoh get on the status key), or None when no daemon answered
        within ``timeout`` s. With robot None: the first answer."""
        st = self.statuses(timeout)
        return st[0] if st else None

    def alive(self, timeout: float = 1.0) -> list[str]:
        """Robots whose daemon holds its liveliness token now (sorted)."""
        robots = set()
        for reply in self.session.liveliness().get(self.keys.alive, timeout=timeout):
            s = reply.ok
            if s is not None:
                robots.add(_robot_of(str(s.key_expr)))
        return sorted(robots)

    def close(self) -> None:
        """Undeclare the subscribers and close the session; wakes queue readers. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for obj in (getattr(self, "_sub_f", None), getattr(self, "_sub_a", None)):
            if obj is not None:
                try:
                    obj.undeclare()
                except Exception:  # noqa: BLE001
                    pass
        try:
            self.session.close()
        except Exception:  # noqa: BLE001
            pass
        self._qf.close()
        self._qa.close()

    def __enter__(self) -> "Listener":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
