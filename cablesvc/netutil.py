"""Loopback addresses and free ports, for the simulated controllers, the benches and the tests.

Nothing here is part of the sources' API: a real deployment names its own bus, Modbus
server and Zenoh endpoints. What cablesvc starts on its own (the embedded simulated
controller of ``cablesvc run``, ``cablesvc bench ...``, the test suite) stays on this host:

* :func:`free_tcp_port`: a TCP port free right now on 127.0.0.1 (a Modbus server, a Zenoh
  listener);
* :func:`free_udp_port`: a UDP port free right now (one CAN bus of its own);
* :func:`loopback_bus_config`: a python-can bus that crosses processes but never leaves the
  host (``udp_multicast`` on an IPv6 interface-local group, ff11::/16, or IPv4 with TTL 0);
  ``fd=True`` carries CAN FD frames. It is what vcan would be, without a kernel module.

A port found free can be taken by another process before it is used; the callers bind it
at once.
"""

from __future__ import annotations

import errno
import socket
import struct
from typing import Any, Optional

__all__ = [
    "LOOPBACK_GROUP_IPV4",
    "LOOPBACK_GROUP_IPV6",
    "LOOPBACK_HOST",
    "LOOPBACK_PORT",
    "free_tcp_port",
    "free_udp_port",
    "loopback_bus_config",
]

#: The IPv4 loopback address every listener cablesvc starts for itself binds to.
LOOPBACK_HOST = "127.0.0.1"
#: IPv6 interface-local multicast group (scope 1: never sent on a wire) for cross-process buses.
LOOPBACK_GROUP_IPV6 = "ff11::c0:ab1e"
#: IPv4 fallback group, used with TTL 0 (the kernel loops it back and sends no data out).
LOOPBACK_GROUP_IPV4 = "239.255.42.99"
#: Default UDP port of :func:`loopback_bus_config`.
LOOPBACK_PORT = 43117


def _ipv6_multicast_works(group: str) -> bool:
    try:
        s = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    except OSError:
        return False
    try:
        s.bind(("", 0))
        s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP,
                     socket.inet_pton(socket.AF_INET6, group) + struct.pack("@I", 0))
        return True
    except OSError:
        return False
    finally:
        s.close()


def free_tcp_port(host: str = LOOPBACK_HOST) -> int:
    """A TCP port on ``host`` that is free right now (for tests and demos)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def free_udp_port() -> int:
    """A UDP port that is free right now on this host (for tests that need their own bus)."""
    for family, addr in ((socket.AF_INET6, "::"), (socket.AF_INET, "")):
        try:
            with socket.socket(family, socket.SOCK_DGRAM) as s:
                s.bind((addr, 0))
                return int(s.getsockname()[1])
        except OSError as exc:
            if exc.errno not in (errno.EAFNOSUPPORT, errno.EADDRNOTAVAIL):
                raise
    raise OSError("no UDP port available")


def loopback_bus_config(port: Optional[int] = None, fd: bool = False) -> dict[str, Any]:
    """A CAN bus that crosses processes but never leaves this host.

    python-can's ``udp_multicast`` interface on the IPv6 interface-local multicast group
    :data:`LOOPBACK_GROUP_IPV6` (scope ff11::/16: the kernel delivers it to sockets on this
    host and never transmits it on a link) with hop limit 0. Where IPv6 multicast is not
    available, the IPv4 group :data:`LOOPBACK_GROUP_IPV4` with TTL 0 (the kernel loops the
    datagram back to local members and sends none out). ``port`` [UDP]: default
    :data:`LOOPBACK_PORT`; give each independent bus its own (see :func:`free_udp_port`).
    ``fd``: carry CAN FD frames (python-can's udp_multicast ``fd`` argument; with
    ``fd=False`` that interface refuses to send FD frames and silently drops received ones).
    Needs the ``msgpack`` package (python-can's ``multicast`` extra).

    Returns ``{"interface", "channel", "bitrate": None, "fd", "bus_kwargs"}``: the fields of
    :class:`~cablesvc.sources.can.CanSourceConfig` and the ``bus_config`` of the simulated CAN
    controller.
    """
    group = LOOPBACK_GROUP_IPV6 if _ipv6_multicast_works(LOOPBACK_GROUP_IPV6) else LOOPBACK_GROUP_IPV4
    return {
        "interface": "udp_multicast",
        "channel": group,
        "bitrate": None,
        "fd": bool(fd),
        "bus_kwargs": {"port": int(LOOPBACK_PORT if port is None else port), "hop_limit": 0, "fd": bool(fd)},
    }
