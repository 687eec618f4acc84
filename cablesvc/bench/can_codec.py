"""``cablesvc bench can-codec``: CPU cost of the CAN frames of one tick, classic vs CAN FD.

For the classic layout (``robots/<robot>.dbc``, one frame per cable plus five platform
frames and SYNC) and the CAN FD layout (``robots/<robot>-fd.dbc``, two frames for up to
8 cables), per tick, with garbage collection off while timing:

* ``encode_us``: :func:`~cablesvc.sources.can.encode_tick` (values -> python-can
  messages; the compiled plan, no cantools call);
* ``assemble_us``: :meth:`~cablesvc.sources.can.TickAssembler.feed` of every frame
  of the tick (the last one completes it: one :class:`~cablesvc.sources.base.TickInput`);
* ``total_us``: the two together, per tick;
* ``cantools_*_us``: the baseline measured in the same run: cantools'
  ``Database.encode_message`` for every frame (signal dicts built from the tick, python-can
  messages made, as ``encode_tick`` makes them) and ``Database.decode_message`` for every
  frame plus gathering the values into a ``TickInput``;
  ``speedup``: cantools total / total at p50.

``receive`` > 0 also sends that many ticks over python-can's ``udp_multicast`` loopback
bus (:func:`~cablesvc.netutil.loopback_bus_config`) to a live
:class:`~cablesvc.sources.can.CanSource` in this process and reports the CPU time
of its receive thread per tick (python-can receive + assembling + validation + queueing:
``receive_cpu_us``), of python-can's ``Bus.recv`` alone for the same frames
(``python_can_recv_cpu_us``), and of python-can's ``Bus.send`` on the sending side
(``python_can_send_cpu_us``). Values are p50/p99 of per-tick times in microseconds
(receive: medians over chunks of ticks).
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import threading
import time
from typing import Any, Callable, Optional

import numpy as np

__all__ = ["add_parser", "run_codec_bench", "run_receive_bench"]

LAYOUTS = ("classic", "fd")


def _ticks(n: int, m: int, seed: int = 0) -> list:
    from cablesvc.sources.base import TickInput

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    ml = rng.uniform(0.5, 20.0, (n, m))
    force = rng.uniform(-50.0, 8000.0, (n, m))
    pos = rng.uniform(-5.0, 5.0, (n, 3))
    temp = rng.uniform(-40.0, 120.0, n)
    return [TickInput(seq=k, t=k * 1e-3, motor_length=ml[k], position=pos[k], orientation=q[k], force=force[k],
                      temperature=float(temp[k]), stamp_ns=0) for k in range(n)]


def _pct(ns: list[int]) -> dict[str, float]:
    a = np.asarray(ns, dtype=np.float64) / 1e3
    return {"p50": round(float(np.percentile(a, 50)), 2), "p99": round(float(np.percentile(a, 99)), 2)}


def _cantools_values(lay: Any, tick: Any) -> dict[str, dict[str, float]]:
    """Per message name, the signal dict cantools' encode_message wants for this tick."""
    vals: dict[str, float] = {"t": tick.t, "seq": tick.seq & ((1 << lay.seq_bits) - 1)}
    for i in range(lay.n_cables):
        vals[f"motor_length_{i}"] = float(tick.motor_length[i])
        vals[f"force_{i}"] = float(tick.force[i])
    for k, name in enumerate(("position_x", "position_y", "position_z")):
        vals[name] = float(tick.position[k])
    for k, name in enumerate(("orientation_qx", "orientation_qy", "orientation_qz", "orientation_qw")):
        vals[name] = float(tick.orientation[k])
    vals["temperature"] = float(tick.temperature)
    vals["tick_counter"] = tick.seq & ((1 << lay.counter_bits) - 1)
    return {c.name: {s.name: vals[s.name] for s in c.signals} for c in lay.frames}


def _bench_layout(lay: Any, ticks: list, baseline_n: int) -> dict[str, Any]:
    import can

    from cablesvc.sources.base import TickInput
    from cablesvc.sources.can import TickAssembler, encode_tick

    asm = TickAssembler(lay, deadline_s=1.0)
    enc: list[int] = []
    ass: list[int] = []
    tot: list[int] = []
    done = 0
    clock = time.perf_counter_ns
    for k, tick in enumerate(ticks):
        t0 = clock()
        msgs = encode_tick(lay, tick)
        t1 = clock()
        ts = 1000.0 + k * 1e-3
        for msg in msgs:
            msg.timestamp = ts
        t2 = clock()
        for msg in msgs:
            out = asm.feed(msg, 0)
        t3 = clock()
        enc.append(t1 - t0)
        ass.append(t3 - t2)
        tot.append(t1 - t0 + t3 - t2)
        done += len(out) == 1 and type(out[0]) is TickInput
    if done != len(ticks):
        raise RuntimeError(f"{lay.path}: {len(ticks) - done} of {len(ticks)} ticks did not assemble")
    # the cantools baseline: encode_message / decode_message for every frame of the tick
    db = lay.db
    frames = [(c.frame_id, c.name) for c in lay.frames]
    m = lay.n_cables
    ml_names = [f"motor_length_{i}" for i in range(m)]
    f_names = [f"force_{i}" for i in range(m)]
    pos_names = ("position_x", "position_y", "position_z")
    ori_names = ("orientation_qx", "orientation_qy", "orientation_qz", "orientation_qw")
    fd = lay.fd
    cenc: list[int] = []
    cdec: list[int] = []
    ctot: list[int] = []
    for tick in ticks[:baseline_n]:
        t0 = clock()
        per_msg = _cantools_values(lay, tick)
        msgs = [can.Message(arbitration_id=fid, is_extended_id=False, is_fd=fd, bitrate_switch=fd,
                            data=db.encode_message(fid, per_msg[name])) for fid, name in frames]
        t1 = clock()
        vals: dict[str, Any] = {}
        for (fid, _name), msg in zip(frames, msgs):
            vals.update(db.decode_message(fid, msg.data, decode_choices=False))
        TickInput(seq=int(vals["seq"]), t=float(vals["t"]), motor_length=np.array([vals[n] for n in ml_names]),
                  position=np.array([vals[n] for n in pos_names]), orientation=np.array([vals[n] for n in ori_names]),
                  force=np.array([vals[n] for n in f_names]), temperature=float(vals["temperature"]), stamp_ns=0)
        t2 = clock()
        cenc.append(t1 - t0)
        cdec.append(t2 - t1)
        ctot.append(t2 - t0)
    res = {"dbc": lay.path, "frames_per_tick": lay.frames_per_tick, "bytes_per_tick": lay.bytes_per_tick,
           "fd": lay.fd, "encode_us": _pct(enc), "assemble_us": _pct(ass), "total_us": _pct(tot),
           "cantools_encode_us": _pct(cenc), "cantools_decode_us": _pct(cdec), "cantools_total_us": _pct(ctot)}
    res["speedup"] = round(res["cantools_total_us"]["p50"] / max(res["total_us"]["p50"], 1e-9), 1)
    return res


def run_codec_bench(n: int = 20000, robot: str = "ipanema3", *, baseline_n: Optional[int] = None,
                    receive: int = 0, progress: Optional[Callable[[str], None]] = None) -> dict[str, Any]:
    """Time the codec for the classic and the CAN FD layout of ``robot``; ``n`` ticks each,
    the cantools baseline on ``baseline_n`` of them (default n // 4: it is much slower).
    ``receive`` > 0: also :func:`run_receive_bench` with that many ticks. Returns
    ``{"robot", "n", "baseline_n", "classic": {...}, "fd": {...}}``; the per-layout keys are
    in the module docstring."""
    from cablesvc.config import load_robot
    from cablesvc.sources.base import find_robot_companion
    from cablesvc.sources.can import dbc_suffix, load_can_layout

    say = progress or (lambda what: None)
    rob = load_robot(robot)
    baseline_n = max(1, n // 4) if baseline_n is None else int(baseline_n)
    ticks = _ticks(n, rob.n_cables)
    out: dict[str, Any] = {"robot": rob.name, "n": n, "baseline_n": baseline_n}
    for name in LAYOUTS:
        say(f"codec, {name}")
        lay = load_can_layout(find_robot_companion(rob, dbc_suffix(name == "fd")), rob.n_cables)
        gc.collect()
        enabled = gc.isenabled()
        gc.disable()
        try:
            out[name] = _bench_layout(lay, ticks, baseline_n)
        finally:
            if enabled:
                gc.enable()
    if receive:
        for name in LAYOUTS:
            say(f"udp_multicast receive, {name}")
            out[name].update(run_receive_bench(receive, robot=robot, fd=name == "fd"))
    return out


def _thread_cpu(th: threading.Thread) -> float:
    return time.clock_gettime(time.pthread_getcpuclockid(th.ident))


def run_receive_bench(ticks: int = 5000, *, robot: str = "ipanema3", fd: bool = True,
                      chunk: int = 100) -> dict[str, Any]:
    """CPU per tick of receiving over python-can's udp_multicast loopback bus (see the
    module docstring): ``receive_cpu_us`` (the :class:`CanSource` receive thread),
    ``python_can_recv_cpu_us`` (``Bus.recv`` alone), ``python_can_send_cpu_us``, and
    ``receive_accepted`` / ``receive_ticks``. Medians (and p99) over chunks of ``chunk``
    ticks sent back to back."""
    from cablesvc.config import load_robot
    from cablesvc.sources import open_source
    from cablesvc.netutil import free_udp_port, loopback_bus_config
    from cablesvc.sources.can import encode_tick, open_bus
    from cablesvc.sources.can.bus import grow_receive_buffer

    rob = load_robot(robot)
    cfg = loopback_bus_config(free_udp_port(), fd=fd)
    src = open_source(rob, {"kind": "can", **cfg, "deadline_s": 1.0})
    tick_list = _ticks(ticks, rob.n_cables, seed=1)
    msgs = [encode_tick(src.layout, t) for t in tick_list]
    tx = open_bus(cfg)
    raw_rx = None
    src_cpu: list[float] = []
    send_cpu: list[float] = []
    recv_cpu: list[float] = []
    try:
        with src:
            th = src._thread
            assert th is not None
            got = 0
            for a in range(0, ticks, chunk):
                part = msgs[a:a + chunk]
                c0 = _thread_cpu(th)
                s0 = time.thread_time()
                for frames in part:
                    for msg in frames:
                        tx.send(msg)
                send_cpu.append((time.thread_time() - s0) / len(part))
                end = time.monotonic() + 10.0
                while got < a + len(part) and time.monotonic() < end:
                    if src.recv(timeout=0.5) is not None:
                        got += 1
                src_cpu.append((_thread_cpu(th) - c0) / len(part))
            counters = src.counters.as_dict()
        # python-can's Bus.recv alone, the same frames
        raw_rx = open_bus(cfg)
        grow_receive_buffer(raw_rx)
        for a in range(0, ticks, chunk):
            part = msgs[a:a + chunk]
            n_frames = sum(len(f) for f in part)
            for frames in part:
                for msg in frames:
                    tx.send(msg)
            r0 = time.thread_time()
            k = 0
            while k < n_frames and raw_rx.recv(timeout=1.0) is not None:
                k += 1
            recv_cpu.append((time.thread_time() - r0) / len(part))
    finally:
        tx.shutdown()
        if raw_rx is not None:
            raw_rx.shutdown()

    def stat(v: list[float]) -> dict[str, float]:
        a = np.asarray(v) * 1e6
        return {"p50": round(float(np.median(a)), 1), "p99": round(float(np.percentile(a, 99)), 1)}

    return {"receive_ticks": ticks, "receive_accepted": counters["accepted"],
            "receive_rejected": counters["rejected"], "receive_cpu_us": stat(src_cpu),
            "python_can_recv_cpu_us": stat(recv_cpu), "python_can_send_cpu_us": stat(send_cpu)}


# --------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Register ``can-codec`` on the ``cablesvc bench`` subparsers."""
    p = sub.add_parser("can-codec", help="CPU cost of the CAN frames of one tick, classic vs CAN FD, vs cantools",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", default="ipanema3")
    p.add_argument("-n", "--ticks", type=int, default=20000, help="ticks per layout (default 20000)")
    p.add_argument("--baseline-ticks", type=int, default=None, help="ticks for the cantools baseline (default n/4)")
    p.add_argument("--receive", type=int, default=0, metavar="TICKS",
                   help="also receive this many ticks over the udp_multicast loopback bus (default 0: skip)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_can_codec)
    return p


def cmd_can_codec(args: Any) -> int:
    kw = dict(robot=args.robot, baseline_n=args.baseline_ticks, receive=args.receive)
    if args.json:
        print(json.dumps(run_codec_bench(args.ticks, **kw)))
        return 0
    res = run_codec_bench(args.ticks, progress=lambda what: print(f"... {what}", file=sys.stderr), **kw)
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:  # pragma: no cover - rich is a dependency of the CLI
        print(json.dumps(res, indent=2))
        return 0
    tb = Table(title=f"CAN codec per tick, {res['robot']}, {res['n']} ticks (cantools: {res['baseline_n']}), "
                     f"microseconds p50 / p99")
    for c in ("layout", "frames", "bytes", "encode", "assemble", "total", "cantools enc+dec", "speedup"):
        tb.add_column(c, justify="right")
    for name in LAYOUTS:
        r = res[name]

        def pp(d: dict[str, float]) -> str:
            return f"{d['p50']:.1f} / {d['p99']:.1f}"
        tb.add_row(name, str(r["frames_per_tick"]), str(r["bytes_per_tick"]), pp(r["encode_us"]),
                   pp(r["assemble_us"]), pp(r["total_us"]), pp(r["cantools_total_us"]), f"{r['speedup']:.1f}x")
    con = Console()
    con.print(tb)
    if args.receive:
        for name in LAYOUTS:
            r = res[name]
            con.print(f"{name}: udp_multicast receive thread {r['receive_cpu_us']['p50']:.0f} us CPU per tick "
                      f"(python-can Bus.recv alone {r['python_can_recv_cpu_us']['p50']:.0f}, send "
                      f"{r['python_can_send_cpu_us']['p50']:.0f}); {r['receive_accepted']} of {r['receive_ticks']} "
                      f"ticks accepted")
    return 0
