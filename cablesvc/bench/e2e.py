"""``cablesvc bench e2e``: end-to-end latency of the live daemon, three processes on loopback.

* a simulated controller process (:mod:`cablesvc.sources.simulated`) sends the ticks of a
  twin recording on a CAN bus that crosses processes but stays on this host (python-can
  ``udp_multicast`` on an interface-local IPv6 group, see ``docs/sources.md``) at
  ``--rate`` Hz, evenly spaced;
* the daemon process (``cablesvc run --source can``) assembles, predicts and publishes;
* this process subscribes to ``cablesvc/<robot>/forces`` over Zenoh and timestamps every
  message on arrival.

Latency = arrival at the subscriber minus the input stamp (``stamp_ns`` in the message:
``time.monotonic_ns()`` in the daemon when the tick's last frame had been received and
the tick was complete; CLOCK_MONOTONIC is one clock for all processes of a host).
Missed ticks = ticks the controller sent minus distinct ticks received.

Two baselines, measured in the same run, say how much of that latency is this machine's
and not the daemon's:

* ``baseline``: Zenoh alone. A publisher process sends messages of the same size at the
  same rate, stamped just before ``put``, to the same subscriber; no bus, no controller.
* ``pipeline_baseline``: the same three processes, with the daemon replaced by a
  pass-through (:func:`_passthrough_daemon`): the same CAN source (frames assembled,
  decoded and validated, stamped the same way) and the same publisher, but instead of
  the kernel, the alarms and the payload, one fixed message of the daemon's size per
  tick. What it measures is the floor of this set-up on this machine: a daemon with a
  kernel that took no time at all would see this latency.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

from hdrh.histogram import HdrHistogram

from cablesvc.service.latency import value_at_percentiles

#: the daemon's CAN tick deadline in the benchmarks [s] (see run_three_processes)
BENCH_DEADLINE_S = 0.25


def latency_percentiles(lat_ns: list[int]) -> dict[str, float]:
    """p50, p99, p99.9 and max of latencies given in ns, in us (an HDR histogram from 1 us to
    60 s, 3 significant digits); NaN for no latencies."""
    h = HdrHistogram(1, 60_000_000, 3)
    for v in lat_ns:
        h.record_value(max(1, min(v // 1000, 60_000_000)))
    if not lat_ns:
        return {"p50_us": float("nan"), "p99_us": float("nan"), "p999_us": float("nan"), "max_us": float("nan")}
    p50, p99, p999 = value_at_percentiles(h, (50, 99, 99.9))
    return {"p50_us": float(p50), "p99_us": float(p99), "p999_us": float(p999), "max_us": float(max(lat_ns) / 1000)}


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(str(v))


def write_daemon_config(path: Path, robot: str, listen: str, source: dict[str, Any],
                        encoding: str = "json") -> None:
    """A daemon TOML config (the format of ``cablesvc run --config``)."""
    lines = [f"robot = {_toml_value(robot)}", f"listen = [{_toml_value(listen)}]",
             f"encoding = {_toml_value(encoding)}", "", "[source]"]
    nested = {}
    for k, v in source.items():
        if v is None:
            continue
        if isinstance(v, dict):
            nested[k] = v
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for k, d in nested.items():
        lines += ["", f"[source.{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in d.items() if vv is not None]
    path.write_text("\n".join(lines) + "\n")


class _Collector:
    def __init__(self):
        self.lat: list[int] = []
        self.seqs: set[int] = set()
        self.count = 0

    def __call__(self, payload: dict, receive_ns: int) -> None:
        self.count += 1
        self.seqs.add(payload["seq"])
        self.lat.append(receive_ns - payload["stamp_ns"])


def _wait_alive(listener, robot: str, timeout: float, proc: subprocess.Popen) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
            raise RuntimeError(f"the daemon exited with {proc.returncode} before publishing:\n{err[-3000:]}")
        if robot in listener.alive(timeout=0.5):
            return
        time.sleep(0.1)
    raise RuntimeError(f"no liveliness token of robot {robot!r} after {timeout:.0f} s")


def _stop(proc: subprocess.Popen, timeout: float = 5.0) -> float:
    """SIGTERM and wait; returns the seconds the process took to exit."""
    t0 = time.monotonic()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return time.monotonic() - t0


def run_baseline(rate: float, seconds: float, n_cables: int = 8) -> dict[str, Any]:
    """Zenoh alone: a publisher process at ``rate`` Hz, same payload shape, same subscriber."""
    from cablesvc.service.zenoh_io import Listener, make_config
    from cablesvc.netutil import free_tcp_port

    port = free_tcp_port()
    col = _Collector()
    proc = subprocess.Popen([sys.executable, "-m", "cablesvc.bench.e2e", "--baseline-publisher", str(port),
                             str(rate), str(seconds), str(n_cables)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    lst = None
    try:
        lst = Listener("baseline", make_config(listen=(), connect=(f"tcp/127.0.0.1:{port}",)), on_forces=col)
        _wait_alive(lst, "baseline", 20.0, proc)
        out, err = proc.communicate(timeout=seconds + 30)
        time.sleep(0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
        if lst is not None:
            lst.close()
    sent = json.loads(out.decode().strip().splitlines()[-1])["sent"]
    return {"ticks": sent, "received": len(col.seqs), "missed": sent - len(col.seqs),
            **latency_percentiles(col.lat)}


def _baseline_publisher(port: int, rate: float, seconds: float, n_cables: int) -> None:
    from cablesvc.service.zenoh_io import Publisher, make_config

    pub = Publisher("baseline", make_config(listen=(f"tcp/127.0.0.1:{port}",)), status=lambda: {})
    time.sleep(1.5)                                  # let the subscriber find us (it waits on liveliness)
    m = n_cables
    base = {"robot": "baseline", "seq": 0, "t": 0.0, "stamp_ns": 0, "force": [100.0 + i for i in range(m)],
            "elongation": [1e-4] * m, "wrap_angle": [0.1] * m, "slack": [False] * m, "measured": [100.0] * m,
            "residual": [0.01] * m, "wrench_residual": [0.0] * 6, "pose_from_fk": False}
    period = 1e9 / rate
    n = int(rate * seconds)
    t0 = time.monotonic_ns()
    for k in range(n):
        due = t0 + int(k * period)
        while True:
            now = time.monotonic_ns()
            if now >= due:
                break
            if due - now > 300_000:
                time.sleep((due - now - 200_000) / 1e9)
        base["seq"] = k
        base["t"] = k / rate
        base["stamp_ns"] = time.monotonic_ns()
        pub.publish_forces(base)
    time.sleep(0.5)
    pub.close()
    print(json.dumps({"sent": n}), flush=True)


def _passthrough_daemon(config_path: str) -> None:
    """The ``pipeline_baseline`` daemon (see the module docstring): the source and the
    publisher of ``cablesvc run --config config_path``, nothing in between. Stops on SIGTERM."""
    import tomllib

    from cablesvc.config import load_robot
    from cablesvc.service.zenoh_io import Publisher, make_config
    from cablesvc.sources import open_source

    with open(config_path, "rb") as f:
        cfg = tomllib.load(f)
    robot = load_robot(cfg["robot"])
    m = robot.geometry().n_cables
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    source = open_source(robot, cfg["source"])
    published = [0]

    def status() -> dict[str, Any]:
        return {"robot": robot.name, "published": published[0],
                "input": {"source": cfg["source"]["kind"], **source.counters.as_dict()}}

    pub = Publisher(robot.name, make_config(listen=cfg["listen"]), encoding=cfg.get("encoding", "json"),
                    status=status)
    # a forces message (forces_payload) with fixed numbers of full precision (17 digits, as
    # the daemon's are), so that it encodes to the daemon's size
    third = [(k + 1) / 3.0 for k in range(m)]
    msg = {"robot": robot.name, "seq": 0, "t": 0.0, "stamp_ns": 0, "cables": list(robot.geometry().cable_names),
           "force": [60.0 + v for v in third], "elongation": [v * 1e-4 for v in third], "wrap_angle": third,
           "slack": [False] * m, "measured": [60.0 + v / 7 for v in third], "residual": [v / 7 for v in third],
           "wrench_residual": [(k + 1) / 3.0 for k in range(6)], "position": [0.0, 0.0, 0.0], "orientation": [0.0, 0.0, 0.0, 1.0],
           "amplitude": [v * 1e-3 for v in third], "temperature": None, "pose_from_fk": False, "fk_residual": 0.0}

    def sink(tick) -> None:
        msg["seq"] = tick.seq
        msg["t"] = tick.t
        msg["stamp_ns"] = tick.stamp_ns
        pub.publish_forces(msg)
        published[0] += 1

    try:
        source.open()
        for tick in source.set_sink(sink):          # ticks accepted before the sink was set
            sink(tick)
        while not stop.wait(0.05):
            source.problems()
    finally:
        source.set_sink(None)
        source.close()
        pub.close()


def run_three_processes(rate: float, seconds: float, collector: Callable[[dict, int], None], *,
                        robot: str = "ipanema3", fd: bool = True, encoding: str = "json",
                        passthrough: bool = False,
                        say: Callable[[str, float], None] | None = None,
                        on_subscribed: Callable[[int], None] | None = None,
                        on_ready: Callable[[], None] | None = None,
                        on_finished: Callable[[], None] | None = None) -> dict[str, Any]:
    """The set-up shared by ``bench e2e`` and ``bench soak`` (see the module docstring).

    Starts the daemon process on a loopback CAN bus, subscribes ``collector(payload,
    receive_ns)`` to its forces, runs the controller process for ``seconds`` at ``rate`` Hz,
    and stops everything. Hooks: ``on_subscribed(daemon_pid)`` once the subscription is in
    place, ``on_ready()`` when the controller starts ticking, ``on_finished()`` after the
    last messages arrived. ``passthrough``: run :func:`_passthrough_daemon` instead of
    ``cablesvc run`` (the pipeline baseline). Returns ``fd`` (False when the bus has no CAN
    FD), the controller's ``summary``, the daemon's ``status`` and ``shutdown_s`` (SIGTERM
    to exit).
    """
    from cablesvc.service.zenoh_io import Listener, make_config
    from cablesvc.netutil import free_udp_port, loopback_bus_config
    from cablesvc.netutil import free_tcp_port

    say = say or (lambda what, frac: None)
    try:
        bus = loopback_bus_config(free_udp_port(), fd=fd)
    except TypeError:                                   # a python-can bus without FD support
        bus = loopback_bus_config(free_udp_port())
        fd = False
    zport = free_tcp_port()
    with tempfile.TemporaryDirectory(prefix="cablesvc-e2e-") as tmp:
        cfg = Path(tmp) / "daemon.toml"
        # The tick deadline catches frames that never come. The simulated controller is a
        # Python process on a shared VM, not a real-time controller: the VM stalls it for up
        # to ~90 ms at times, between two frames of one tick. A deadline shorter than that
        # rejects ticks whose frames were only late in being sent, which measures the
        # sender, not the daemon. 0.25 s is above every stall seen here and still rejects a
        # tick missing a frame within a quarter of a second.
        source = {"kind": "can", "interface": bus["interface"], "channel": bus["channel"], "fd": fd if fd else None,
                  "deadline_s": BENCH_DEADLINE_S, "bus_kwargs": bus.get("bus_kwargs") or {}}
        write_daemon_config(cfg, robot, f"tcp/127.0.0.1:{zport}", source, encoding)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        say("starting the daemon", 0.0)
        if passthrough:
            argv = [sys.executable, "-m", "cablesvc.bench.e2e", "--passthrough-daemon", str(cfg)]
        else:
            argv = [sys.executable, "-m", "cablesvc", "run", "--config", str(cfg), "--no-view",
                    "--no-snapshot", "--log-level", "WARNING"]
        daemon = subprocess.Popen(argv,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        lst = None
        ctl = None
        try:
            lst = Listener(robot, make_config(listen=(), connect=(f"tcp/127.0.0.1:{zport}",)), on_forces=collector)
            _wait_alive(lst, robot, 60.0, daemon)
            time.sleep(1.0)                               # let the daemon learn of our subscription
            if on_subscribed:
                on_subscribed(daemon.pid)
            say("starting the controller", 0.0)
            ctl = subprocess.Popen([sys.executable, "-m", "cablesvc.sources.simulated", "--transport", "can",
                                    "--robot", robot, "--rate", str(rate), "--seconds", str(seconds),
                                    "--duration", "20", "--bus-config", json.dumps(bus)],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
            lines: list[str] = []

            def read_ctl():
                for line in ctl.stdout:
                    lines.append(line.decode())
            reader = threading.Thread(target=read_ctl, daemon=True)
            reader.start()
            while ctl.poll() is None and not any('"ready"' in x for x in lines):
                time.sleep(0.05)
            if on_ready:
                on_ready()
            t0 = time.monotonic()
            while ctl.poll() is None:
                time.sleep(0.25)
                say("running", min(1.0, (time.monotonic() - t0) / max(seconds, 1e-9)))
                if daemon.poll() is not None:
                    raise RuntimeError("the daemon died during the run: "
                                       + daemon.stderr.read().decode(errors="replace")[-3000:])
            reader.join(2.0)
            time.sleep(1.0)                               # let the last messages arrive
            if on_finished:
                on_finished()
            summary = next((json.loads(x) for x in reversed(lines) if '"done"' in x), None)
            if summary is None:
                raise RuntimeError("the controller ended without a summary: "
                                   + ctl.stderr.read().decode(errors="replace")[-3000:])
            status = lst.status(timeout=3.0) or {}
        finally:
            shutdown_s = _stop(daemon)
            if ctl is not None and ctl.poll() is None:
                _stop(ctl)
            if lst is not None:
                lst.close()
    return {"fd": fd, "summary": summary, "status": status, "shutdown_s": shutdown_s}


def run_pipeline_baseline(rate: float, seconds: float, *, robot: str = "ipanema3", fd: bool = True,
                          encoding: str = "json", say: Callable[[str, float], None] | None = None) -> dict[str, Any]:
    """The three processes with the pass-through daemon (see the module docstring)."""
    col = _Collector()
    run = run_three_processes(rate, seconds, col, robot=robot, fd=fd, encoding=encoding, say=say, passthrough=True)
    sent = int(run["summary"]["ticks_sent"])
    return {"ticks": sent, "received": len(col.seqs), "missed": sent - len(col.seqs),
            **latency_percentiles(col.lat), "daemon_input": run["status"].get("input")}


def run_e2e_bench(rate: float = 1000.0, seconds: float = 60.0, *, robot: str = "ipanema3", fd: bool = True,
                  encoding: str = "json", baseline_seconds: float | None = 10.0,
                  pipeline_seconds: float | None = 20.0,
                  progress: Callable[[str, float], None] | None = None) -> dict[str, Any]:
    """Run the three-process benchmark; returns the JSON keys of ``cablesvc bench e2e``.
    ``baseline_seconds`` / ``pipeline_seconds``: length of the two baselines (0 or None:
    skip)."""
    say = progress or (lambda what, frac: None)
    baseline = pipeline = None
    if baseline_seconds:
        say("baseline: Zenoh alone", 0.0)
        baseline = run_baseline(rate, baseline_seconds)
    if pipeline_seconds:
        pipeline = run_pipeline_baseline(rate, pipeline_seconds, robot=robot, fd=fd, encoding=encoding,
                                         say=lambda what, frac: say(f"pipeline baseline: {what}", frac))
    col = _Collector()
    run = run_three_processes(rate, seconds, col, robot=robot, fd=fd, encoding=encoding, say=say)
    status = run["status"]
    result: dict[str, Any] = {"rate_hz": rate, "seconds": seconds, "robot": robot,
                              "transport": "can-fd" if run["fd"] else "can", "encoding": encoding,
                              "deadline_s": BENCH_DEADLINE_S}
    if baseline is not None:
        result["baseline"] = baseline
    if pipeline is not None:
        result["pipeline_baseline"] = pipeline
    sent = int(run["summary"]["ticks_sent"])
    result.update(ticks=sent, received=len(col.seqs), missed=sent - len(col.seqs),
                  controller_overruns=run["summary"].get("overruns"), **latency_percentiles(col.lat),
                  daemon_input=status.get("input"), daemon_latency_us=status.get("latency_us"),
                  daemon_published=status.get("published"), daemon_skipped=status.get("skipped_no_subscriber"),
                  shutdown_s=round(run["shutdown_s"], 3))
    return result


def run_with_progress(console, label: str, run: Callable[[Callable[[str, float], None]], Any]) -> Any:
    """``run(progress)`` under a transient rich progress bar; ``progress(what, fraction)``
    updates it. Shared by ``bench e2e`` and ``bench soak``."""
    from rich.progress import Progress

    with Progress(console=console, transient=True) as prog:
        task = prog.add_task(label, total=1.0)
        return run(lambda what, frac: prog.update(task, description=what, completed=frac))


def add_setup_options(p: argparse.ArgumentParser) -> None:
    """Options of the three-process set-up shared by ``bench e2e`` and ``bench soak``."""
    p.add_argument("--rate", type=float, default=1000.0, help="controller tick rate in Hz (default 1000)")
    p.add_argument("--robot", default="ipanema3")
    p.add_argument("--classic", action="store_true", help="classic CAN frames instead of CAN FD")
    p.add_argument("--encoding", choices=["json", "compact"], default="json")


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("e2e", help="end-to-end latency: controller process -> daemon -> Zenoh subscriber",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_setup_options(p)
    p.add_argument("--seconds", type=float, default=60.0, help="length of the measured run (default 60)")
    p.add_argument("--baseline-seconds", type=float, default=10.0, help="Zenoh-only baseline length (0: skip)")
    p.add_argument("--pipeline-seconds", type=float, default=20.0,
                   help="pipeline baseline length: the same processes with a pass-through daemon (0: skip)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_e2e)
    return p


def cmd_e2e(args) -> int:
    kw = dict(robot=args.robot, fd=not args.classic, encoding=args.encoding, baseline_seconds=args.baseline_seconds,
              pipeline_seconds=args.pipeline_seconds)
    if args.json:
        print(json.dumps(run_e2e_bench(args.rate, args.seconds, **kw)))
        return 0
    from rich.console import Console
    from rich.table import Table
    con = Console()
    res = run_with_progress(con, "e2e", lambda progress: run_e2e_bench(args.rate, args.seconds, progress=progress, **kw))
    tb = Table(title=f"end-to-end latency, {res['robot']}, {res['transport']}, {res['encoding']}, "
                     f"{res['rate_hz']:g} Hz for {res['seconds']:g} s (input stamp -> subscriber)")
    for c in ("run", "ticks", "missed", "p50 us", "p99 us", "p99.9 us", "max us"):
        tb.add_column(c, justify="right")
    rows = [("daemon", res)]
    if "pipeline_baseline" in res:
        rows.append(("baseline: bus + Zenoh, pass-through daemon", res["pipeline_baseline"]))
    if "baseline" in res:
        rows.append(("baseline: Zenoh only", res["baseline"]))
    for name, r in rows:
        tb.add_row(name, str(r["ticks"]), str(r["missed"]), f"{r['p50_us']:.0f}", f"{r['p99_us']:.0f}",
                   f"{r['p999_us']:.0f}", f"{r['max_us']:.0f}")
    con.print(tb)
    con.print(f"controller overruns {res['controller_overruns']}, daemon input {json.dumps(res['daemon_input'])}, "
              f"shutdown after SIGTERM {res['shutdown_s']:.2f} s")
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 6 and sys.argv[1] == "--baseline-publisher":
        _baseline_publisher(int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5]))
    elif len(sys.argv) == 3 and sys.argv[1] == "--passthrough-daemon":
        _passthrough_daemon(sys.argv[2])
