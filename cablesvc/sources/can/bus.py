"""Opening a python-can bus from a source's bus fields (:func:`open_bus`), and enlarging a
socket-based bus's kernel receive buffer (:func:`grow_receive_buffer`)."""

from __future__ import annotations

import os
import socket
from typing import Any, Mapping

import can

__all__ = ["grow_receive_buffer", "open_bus"]


def open_bus(bus_config: Mapping[str, Any]) -> can.BusABC:
    """Open a python-can bus from ``{"interface", "channel", "bitrate"?, "fd"?, "bus_kwargs"?}``
    (the fields of :class:`~cablesvc.sources.can.CanSourceConfig`; ``bitrate`` in bit/s;
    ``fd``: a CAN FD bus, python-can ``Bus(fd=True)``)."""
    kwargs = dict(bus_config.get("bus_kwargs") or {})
    if bus_config.get("bitrate") is not None:
        kwargs["bitrate"] = int(bus_config["bitrate"])
    if bus_config.get("fd"):
        kwargs["fd"] = True
    return can.Bus(interface=bus_config["interface"], channel=bus_config["channel"], **kwargs)


def grow_receive_buffer(bus: can.BusABC, size: int = 4 << 20) -> None:
    """Best effort: enlarge the kernel receive buffer of a socket-based bus (udp_multicast,
    socketcan) so that bursts of frames are not dropped while the receive thread is busy."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, AttributeError, OSError):
        return
    if not isinstance(fd, int) or fd < 0:
        return
    try:
        s = socket.socket(fileno=os.dup(fd))
    except OSError:
        return
    try:
        for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
            if opt is None:
                continue
            try:
                s.setsockopt(socket.SOL_SOCKET, opt, size)
                break
            except OSError:
                continue
    finally:
        s.close()
