"""``kind = "can"``: :class:`CanSource`, ticks from a python-can bus carrying the frames of
a DBC, and its configuration :class:`CanSourceConfig`."""

from __future__ import annotations

import errno
import threading
import time
from pathlib import Path
from typing import Any, ClassVar, Literal, Optional, Union

import can
from pydantic import BaseModel, ConfigDict, Field

from cablesvc.config.robot import Robot
from cablesvc.sources.base import Rejection, SourceConfigError, ThreadedSource, TickInput, find_robot_companion
from cablesvc.sources.can.assembler import EVENT_REASONS, TickAssembler
from cablesvc.sources.can.bus import grow_receive_buffer, open_bus
from cablesvc.sources.can.dbc import dbc_suffix
from cablesvc.sources.can.layout import load_can_layout

__all__ = ["CanSource", "CanSourceConfig"]


class CanSourceConfig(BaseModel):
    """``kind = "can"``: a python-can bus carrying the frames of a DBC.

    ``interface``/``channel``: as for ``can.Bus`` (``socketcan``/``can0`` beside a real
    controller; ``virtual`` for one process; ``udp_multicast`` for tests across processes);
    ``bitrate`` [bit/s] (None: leave the interface's setting); ``fd``: a CAN FD bus
    (python-can ``Bus(fd=True)``; needed for a DBC with CAN FD frames); ``dbc``: the DBC
    file (None: ``<robot>.dbc``, or ``<robot>-fd.dbc`` with ``fd``, found like robot files);
    ``deadline_s`` [s]: how long after its first frame a tick may wait for its SYNC;
    ``bus_kwargs``: more ``can.Bus`` keywords (e.g. ``can_filters`` on a shared bus,
    ``port``/``hop_limit`` for udp_multicast, ``data_bitrate`` for some FD interfaces).
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["can"] = "can"
    interface: str = "virtual"
    channel: Union[str, int] = "cablesvc"
    bitrate: Optional[int] = Field(default=None, gt=0)
    fd: bool = False
    dbc: Optional[Path] = None
    deadline_s: float = Field(default=0.005, gt=0, allow_inf_nan=False)
    bus_kwargs: dict[str, Any] = Field(default_factory=dict)


class CanSource(ThreadedSource):
    """Ticks from a CAN bus (the frames: :mod:`cablesvc.sources.can.dbc`).

    A receive thread reads the bus (``recv(timeout)``, then ``recv(0)`` until nothing is
    queued), feeds :class:`TickAssembler`, validates each tick as soon as its SYNC completes
    it and queues it for :meth:`recv`. ``config.fd``: the bus is opened with ``fd=True``
    and the default DBC is ``<robot>-fd.dbc``; a DBC with CAN FD frames needs it. A bus
    error is reported (``disconnected``) and the bus is reopened with backoff (0.05 s
    doubling to 2 s, reset once frames flow) until it works again (``reconnected``: one pair
    per outage) or the source is closed; the open happens outside the lock :meth:`close`
    takes, so a slow adapter does not hold up :meth:`close`. cablesvc only listens:
    it never transmits on the bus.
    """

    kind: ClassVar[str] = "can"

    def __init__(self, robot: Robot, config: CanSourceConfig):
        if config.dbc is not None:
            self._dbc_path: Path = config.dbc
        else:
            try:
                self._dbc_path = find_robot_companion(robot, dbc_suffix(config.fd))
            except SourceConfigError as exc:
                raise SourceConfigError(f"source.dbc: {exc}") from None
        self.layout = load_can_layout(self._dbc_path, robot.n_cables)
        if self.layout.fd and not config.fd:
            fd_names = [c.name for c in self.layout.frames if c.is_fd]
            raise SourceConfigError(
                f"source.fd: {self._dbc_path} describes CAN FD frames ({', '.join(fd_names)}); set fd = true "
                f"(a classic bus cannot carry them)"
            )
        super().__init__(robot, config)
        self.config: CanSourceConfig = config
        self.assembler = TickAssembler(self.layout, config.deadline_s)
        self._bus: Optional[can.BusABC] = None
        self._bus_lock = threading.Lock()
        self._down_since: Optional[float] = None  # monotonic time the current outage began
        self._reopen_attempts = 0
        self._opening = False  # the receive thread is inside _open_bus

    def _seq_bits(self) -> Optional[int]:
        return self.layout.seq_bits

    @property
    def label(self) -> str:
        return f"can {self.config.interface}:{self.config.channel}"

    def _bus_config(self) -> dict[str, Any]:
        return {"interface": self.config.interface, "channel": self.config.channel,
                "bitrate": self.config.bitrate, "fd": self.config.fd, "bus_kwargs": self.config.bus_kwargs}

    def _open_bus(self) -> can.BusABC:
        kwargs = dict(self.config.bus_kwargs)
        kwargs.setdefault("receive_own_messages", False)
        bus = open_bus({**self._bus_config(), "bus_kwargs": kwargs})
        grow_receive_buffer(bus)
        return bus

    def open(self) -> None:
        """Open the bus and start the receive thread.

        A configuration python-can cannot use at all (unknown interface, missing driver
        package, bad keyword) raises :class:`SourceConfigError`. A bus that exists in
        principle but is not there yet (``can0`` down or absent) is reported as
        ``disconnected`` and opened by the receive thread as soon as it works.
        """
        if self._opened:
            return
        try:
            self._bus = self._open_bus()
        except (can.CanInterfaceNotImplementedError, ImportError, TypeError, ValueError) as exc:
            raise SourceConfigError(
                f"source.interface: cannot use interface {self.config.interface!r} channel "
                f"{self.config.channel!r}: {exc}"
            ) from None
        except (can.CanError, OSError) as exc:
            if isinstance(exc, OSError) and exc.errno == errno.EAFNOSUPPORT:
                raise SourceConfigError(
                    f"source.interface: {self.config.interface!r} is not supported by this kernel: {exc}"
                ) from None
            self._bus = None
            self._down_since = time.monotonic()
            self._report("disconnected", f"cannot open the bus yet: {exc}; retrying with backoff up to 2 s",
                         kind="event")
        self._opened = True
        self._start_thread(self._run, f"cablesvc-can-{self.config.channel}")

    def _run(self) -> None:
        backoff = 0.05
        asm = self.assembler
        while not self._stop.is_set():
            bus = self._bus
            if bus is None:
                bus = self._reopen()
                if bus is None:
                    if self._stop.wait(backoff):
                        return
                    backoff = min(2.0, backoff * 2)
                    continue
            nxt = asm.next_deadline()
            timeout = 0.1 if nxt is None else max(0.0, min(0.1, nxt - time.time() + 1e-4))
            try:
                msg = bus.recv(timeout=timeout)
            except Exception as exc:  # noqa: BLE001 - python-can raises CanError and OSError
                self._bus_failed(bus, exc)
                if self._stop.wait(backoff):  # a bus that opens but fails at once must not spin
                    return
                backoff = min(2.0, backoff * 2)
                continue
            if self._down_since is not None:  # it opened and a receive worked: the outage is over
                self._bus_back()
            if msg is None:  # the bus is quiet: nothing is queued, so what is missing now is late
                self._handle(asm.expire())
                continue
            backoff = 0.05  # frames flow again
            # drain what is queued without waiting, handing each tick on as it completes
            while msg is not None:
                events = asm.feed(msg, time.monotonic_ns())
                if events:
                    self._handle(events)
                if self._stop.is_set():
                    return
                try:
                    msg = bus.recv(0.0)
                except Exception as exc:  # noqa: BLE001
                    self._bus_failed(bus, exc)
                    if self._stop.wait(backoff):
                        return
                    backoff = min(2.0, backoff * 2)
                    break

    def _reopen(self) -> Optional[can.BusABC]:
        """Open the bus (outside ``_bus_lock``: a slow open must not hold up :meth:`close`)
        and install it; None when it failed or the source is closing."""
        self._reopen_attempts += 1
        self._opening = True
        try:
            bus = self._open_bus()
        except Exception:  # noqa: BLE001 - any driver error: retry
            return None
        finally:
            self._opening = False
        with self._bus_lock:
            stopping = self._stop.is_set()
            if not stopping:
                self._bus = bus
        if stopping:  # close() came while it was opening: nobody else will shut it down
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001
                pass
            return None
        return bus

    def _bus_back(self) -> None:
        down = time.monotonic() - (self._down_since or time.monotonic())
        tries = self._reopen_attempts
        self._report("reconnected",
                     f"bus working again after {down:.2f} s ({tries} reopen attempt{'s' if tries != 1 else ''})",
                     kind="event")
        self._down_since = None
        self._reopen_attempts = 0

    def _handle(self, events: list[Union[TickInput, Rejection]]) -> None:
        for ev in events:
            if type(ev) is TickInput:
                self._deliver(ev)
            elif ev.reason in EVENT_REASONS:
                self._report(ev.reason, ev.message, kind="event")
            else:
                self._report(ev.reason, ev.message)

    def _bus_failed(self, bus: can.BusABC, exc: BaseException) -> None:
        """Drop a bus whose receive failed; report ``disconnected`` once per outage (a bus
        that reopens but fails again at once is the same outage)."""
        with self._bus_lock:
            if self._bus is bus:
                self._bus = None
        try:
            bus.shutdown()
        except Exception:  # noqa: BLE001
            pass
        if self._stop.is_set() or self._down_since is not None:
            return
        self._down_since = time.monotonic()
        self._reopen_attempts = 0
        self._report("disconnected", f"bus error: {exc!r}; reopening with backoff up to 2 s", kind="event")

    def close(self) -> None:
        """Stop the receive thread and shut the bus down (idempotent, < 1 s)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        # a thread inside a (possibly slow) bus open shuts that bus down itself when it returns
        self._join_thread(0.1 if self._opening else 0.9)
        with self._bus_lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001
                pass
