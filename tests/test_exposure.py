"""Issue 7, security: nothing listens on a non-loopback interface unless configured.

The daemon's sockets are read from Linux's /proc (the process's socket inodes, looked up
in /proc/net/tcp, tcp6, udp, udp6), not from the daemon's own word. The default embedded
demo (the README's main command) must have only loopback sockets; a daemon told to listen
on 0.0.0.0 must show that listener, which proves the check can see one.
"""

from __future__ import annotations

import ipaddress
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cablesvc.netutil import free_tcp_port

pytestmark = pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc")

_TCP_STATES = {"0A": "LISTEN", "01": "ESTABLISHED"}


def _addr(hexaddr: str) -> ipaddress._BaseAddress:
    """/proc/net address (host byte order per 32-bit word) -> ip address."""
    raw = bytes.fromhex(hexaddr)
    words = [raw[i:i + 4][::-1] for i in range(0, len(raw), 4)]
    ip = ipaddress.ip_address(b"".join(words))
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def process_sockets(pid: int) -> list[tuple[str, str, int, str]]:
    """(protocol, local address, port, state) of every inet socket the process holds."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        try:
            lines = Path(f"/proc/{pid}/net/{proto}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if f[9] in inodes:
                host, port = f[1].split(":")
                out.append((proto, str(_addr(host)), int(port, 16), _TCP_STATES.get(f[3], f[3])))
    return out


def exposed(sockets) -> list[tuple[str, str, int, str]]:
    """Sockets bound to anything but a loopback address (0.0.0.0 and :: included)."""
    return [s for s in sockets if not ipaddress.ip_address(s[1]).is_loopback]


def _run_and_inspect(args: list[str], want_port: int, tmp_path: Path):
    env = dict(os.environ, CABLESVC_STATE_DIR=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-m", "cablesvc", "run", "--no-view", "--no-snapshot", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 60
        socks = []
        while time.monotonic() < deadline and proc.poll() is None:
            socks = process_sockets(proc.pid)
            if any(s[2] == want_port and s[3] == "LISTEN" for s in socks):
                time.sleep(1.0)                      # let the rest of start-up open what it opens
                return process_sockets(proc.pid)
            time.sleep(0.1)
        raise AssertionError(f"daemon never listened on {want_port}; sockets {socks}; "
                             f"stderr: {proc.stderr.read()[-2000:] if proc.poll() is not None else ''}")
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)


def test_the_default_daemon_has_loopback_sockets_only(tmp_path):
    socks = _run_and_inspect([], 7447, tmp_path)        # the README's main command, as it is
    assert any(s[3] == "LISTEN" for s in socks)
    assert exposed(socks) == [], socks


def test_a_configured_wildcard_listener_is_seen(tmp_path):
    port = free_tcp_port()
    socks = _run_and_inspect(["--listen", f"tcp/0.0.0.0:{port}"], port, tmp_path)
    assert ("tcp", "0.0.0.0", port, "LISTEN") in exposed(socks)


def test_no_private_keys_or_certificates_in_the_repository():
    """deploy/ names where TLS material lives (/etc/cablesvc/tls); none is shipped."""
    root = Path(__file__).resolve().parents[1]
    found = []
    files = []
    for d, dirs, names in os.walk(root):
        # hidden folders (.git, .venv), build output: pruned, not walked and then skipped
        dirs[:] = [x for x in dirs if not (x.startswith(".") or x in ("build", "dist") or x.endswith(".egg-info"))]
        files += [Path(d) / n for n in names if not n.startswith(".")]
    for p in files:
        rel = p.relative_to(root)
        if not p.is_file():
            continue
        if p.suffix in (".pem", ".key", ".p12", ".pfx", ".crt"):
            found.append(str(rel))
            continue
        if p.stat().st_size > 2_000_000:
            continue
        try:
            text = p.read_text(errors="ignore")
        except OSError:
            continue
        if "PRIVATE KEY-----" in text and p.name != "test_exposure.py":
            found.append(str(rel))
    assert found == []
