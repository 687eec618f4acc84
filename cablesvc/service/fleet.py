"""Several robots in one daemon process, each on its own source, over one Zenoh session.

A cell with two or three cable robots would otherwise run one ``cablesvc run`` per robot,
each with its own Zenoh session (its own listen port, its own router connection, its own
TLS handshake). :class:`Fleet` runs one :class:`~cablesvc.service.daemon.Daemon` per robot
in one process instead:

* one Zenoh session, opened once from the shared settings (``zenoh_config_file``,
  ``listen``, ``connect``); every robot's :class:`~cablesvc.service.zenoh_io.Publisher`
  declares its own keys on it (``cablesvc/<robot>/forces|alarms|status``) and its own
  liveliness token, so a client sees exactly what N single-robot daemons would publish;
* one loop thread per robot (``Daemon.run``), so a slow or faulty input of one robot never
  delays or stops another: bad ticks are rejected inside that robot's daemon, and even an
  unexpected exception out of a loop only ends that robot's thread (it is logged and shown
  in that robot's status under ``fleet.error``);
* :meth:`Fleet.close` stops every loop, closes every daemon in parallel (each writes its
  snapshot, closes its source and recording, withdraws its Zenoh declarations) and then
  the session, within ``timeout`` (2 s).

Robot names must be unique: they are the Zenoh key chunk and the default snapshot file.
Start-up is all or nothing: when one robot cannot start (its source does not open, its
recording is missing, ...) the robots already opened are closed again, the session too,
and :class:`FleetStartError` names the robot that failed.

The TOML form (``cablesvc run --config fleet.toml``, ``[[robots]]`` tables) is
checked by :class:`cablesvc.config.daemon.FleetConfig` and planned by
:func:`cablesvc.service.plan.plan_fleet`; ``deploy/fleet.example.toml`` is an example.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Sequence

from cablesvc.errors import ConfigError, ServiceError
from cablesvc.service.daemon import Daemon, DaemonOptions

log = logging.getLogger("cablesvc.fleet")

__all__ = ["Fleet", "FleetError", "FleetStartError", "duplicate_names"]


class FleetError(ConfigError, ValueError):
    """A fleet that cannot be built as given (e.g. two robots with the same name)."""


class FleetStartError(ServiceError, RuntimeError):
    """One robot of the fleet could not start; the others were closed again.

    ``index`` is the robot's position in the list given to :class:`Fleet` (the
    ``robots[index]`` entry of a fleet config), ``robot`` its name, ``cause`` the exception.
    """

    def __init__(self, index: int, robot: str, cause: BaseException):
        self.index = index
        self.robot = robot
        self.cause = cause
        super().__init__(f"robots[{index}] ({robot}): cannot start: {cause}")


def duplicate_names(names: Sequence[str]) -> list[tuple[int, int, str]]:
    """``(first index, repeated index, name)`` for every name that appears again."""
    first: dict[str, int] = {}
    out = []
    for i, n in enumerate(names):
        if n in first:
            out.append((first[n], i, n))
        else:
            first.setdefault(n, i)
    return out


class Fleet:
    """One daemon per robot in this process, sharing one Zenoh session (module docstring).

    ``robots``: one :class:`DaemonOptions` per robot; their own Zenoh fields
    (``zenoh_config_file``, ``listen``, ``connect``) are ignored, the session is opened from
    the arguments here (the same meaning as in ``DaemonOptions``: ``None`` = the config
    file's, else the loopback default). Each robot keeps its own ``encoding``.
    ``session``: an already open Zenoh session to use instead (the caller keeps it and
    closes it; :meth:`close` then leaves it open).
    ``sources``: optional already built sources, one per robot (``None`` entries: built
    from the options), as ``Daemon(source=...)``.
    """

    def __init__(self, robots: Sequence[DaemonOptions], *, zenoh_config_file: str | None = None,
                 listen: Sequence[str] | None = None, connect: Sequence[str] | None = None,
                 session=None, sources: Sequence[Any] | None = None):
        from cablesvc.service.zenoh_io import keys

        robots = list(robots)
        if not robots:
            raise FleetError("a fleet needs at least one robot")
        names = [o.robot.name for o in robots]
        for first, again, name in duplicate_names(names):
            raise FleetError(f"robots[{again}]: robot name {name!r} is already used by robots[{first}]; "
                             "names must be unique (each robot publishes under cablesvc/<name>/)")
        for i, n in enumerate(names):
            try:
                keys(n)
            except ValueError as e:
                raise FleetError(f"robots[{i}]: {e}") from None
        if sources is not None and len(sources) != len(robots):
            raise FleetError(f"{len(sources)} sources for {len(robots)} robots")
        self.names: list[str] = names
        self.daemons: dict[str, Daemon] = {}
        self._threads: dict[str, threading.Thread] = {}
        self._errors: dict[str, str] = {}
        self._stop = threading.Event()
        self._closed = False
        self._close_lock = threading.Lock()
        self.owns_session = session is None
        if session is None:
            import zenoh

            from cablesvc.service.zenoh_io import make_config
            given = {k: tuple(v) for k, v in (("listen", listen), ("connect", connect)) if v is not None}
            session = zenoh.open(make_config(zenoh_config_file, **given))
        self.session = session
        try:
            for i, opt in enumerate(robots):
                src = None if sources is None else sources[i]
                try:
                    self.daemons[opt.robot.name] = Daemon(opt, source=src,
                                                          publisher_factory=self._publisher_factory(opt))
                except Exception as e:  # noqa: BLE001 - named and re-raised below
                    raise FleetStartError(i, opt.robot.name, e) from e
        except BaseException:
            self._close_all(time.monotonic() + 2.0)
            raise

    def _publisher_factory(self, opt: DaemonOptions) -> Callable:
        """``publisher_factory`` for ``Daemon``: a Publisher on the shared session whose status
        answer is the daemon's status plus this fleet's view of that robot's loop."""
        from cablesvc.service.zenoh_io import Publisher

        def make(name: str, status_fn: Callable[[], dict]):
            return Publisher(name, encoding=opt.encoding, session=self.session,
                             status=lambda: self._with_worker(name, status_fn()))
        return make

    def _with_worker(self, name: str, st: dict[str, Any]) -> dict[str, Any]:
        th = self._threads.get(name)
        st["fleet"] = {"robots": list(self.names), "running": th is not None and th.is_alive(),
                       "error": self._errors.get(name)}
        return st

    # -- running ------------------------------------------------------------------------------
    @property
    def stop_event(self) -> threading.Event:
        """The event :meth:`start` hands every loop (set by :meth:`close`, or by a signal handler)."""
        return self._stop

    def start(self, stop: threading.Event | None = None, *, max_ticks: int | None = None) -> None:
        """Start one loop thread per robot; they run until ``stop`` (default: :attr:`stop_event`)
        is set, or each one's replay ends, or ``max_ticks``. Returns at once."""
        if self._threads:
            raise RuntimeError("fleet already started")
        if stop is not None:
            self._stop = stop
        for name, d in self.daemons.items():
            th = threading.Thread(target=self._work, args=(name, d, self._stop, max_ticks),
                                  name=f"cablesvc-loop-{name}", daemon=True)
            self._threads[name] = th
        for th in self._threads.values():
            th.start()

    def _work(self, name: str, daemon: Daemon, stop: threading.Event, max_ticks: int | None) -> None:
        """One robot's loop. An exception ends this robot's loop only: logged, kept for status."""
        try:
            daemon.run(stop, max_ticks=max_ticks)
        except BaseException as e:  # noqa: BLE001 - the other robots go on
            self._errors[name] = f"{type(e).__name__}: {e}"
            log.exception("robot %s: the loop stopped: %s", name, e)

    def running(self) -> list[str]:
        """Names of the robots whose loop runs now."""
        return [n for n, th in self._threads.items() if th.is_alive()]

    def run(self, stop: threading.Event | None = None, *, max_ticks: int | None = None) -> int:
        """:meth:`start`, then wait until ``stop`` is set or every loop has ended. Does not
        close (call :meth:`close`). Returns 0."""
        self.start(stop, max_ticks=max_ticks)
        while not self._stop.is_set() and self.running():
            self._stop.wait(0.05)
        return 0

    def status(self) -> dict[str, dict[str, Any]]:
        """Each robot's status (as its ``cablesvc/<robot>/status`` queryable answers), by name."""
        return {n: self._with_worker(n, d.status()) for n, d in self.daemons.items()}

    # -- shutdown -------------------------------------------------------------------------------
    def close(self, timeout: float = 2.0) -> None:
        """Stop every loop, close every daemon (snapshot, source, recording, Zenoh
        declarations; in parallel), then the session. Idempotent; returns within ``timeout``
        s even if a daemon hangs in its close (that one is then logged and left behind)."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        deadline = time.monotonic() + timeout
        self._stop.set()
        for th in self._threads.values():      # the loops wake every 10-50 ms
            th.join(max(0.0, min(deadline - time.monotonic(), 0.5 * timeout)))
        self._close_all(deadline)

    def _close_all(self, deadline: float) -> None:
        closers = []
        for name, d in self.daemons.items():
            th = threading.Thread(target=self._close_one, args=(name, d), name=f"cablesvc-close-{name}", daemon=True)
            th.start()
            closers.append((name, th))
        for name, th in closers:
            # keep a little time for the session itself
            th.join(max(0.0, deadline - time.monotonic() - 0.1))
            if th.is_alive():
                log.error("robot %s: closing did not finish in time; going on", name)
        if self.owns_session and self.session is not None:
            try:
                self.session.close()
            except Exception as e:  # noqa: BLE001
                log.error("closing the Zenoh session failed: %s", e)

    @staticmethod
    def _close_one(name: str, d: Daemon) -> None:
        try:
            d.close()
        except Exception as e:  # noqa: BLE001 - the others still close
            log.error("robot %s: closing failed: %s", name, e)

    def __enter__(self) -> "Fleet":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
