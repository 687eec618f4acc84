"""``cablesvc bench soak``: the end-to-end set-up of ``bench e2e``, run long, as a time series.

The same three processes on loopback (:mod:`cablesvc.bench.e2e`): a simulated controller
process sends ticks on a CAN FD bus that stays on this host at ``--rate`` Hz for
``--minutes``, the daemon process (``cablesvc run --source can``) predicts and publishes,
and this process subscribes to ``cablesvc/<robot>/forces`` over Zenoh. On top of e2e it
records, per minute of the run:

* the daemon process's resident memory (``VmRSS`` of ``/proc/<pid>/status``), sampled every
  ``--rss-interval`` seconds (default 2 s);
* missed ticks: ticks the controller sent in that minute (``seq`` in
  ``[k * 60 * rate, (k + 1) * 60 * rate)``; the controller starts at seq 0 and sends seq/rate
  seconds after its start; the few ticks it sends past the end count in the last minute)
  minus the distinct ones received (``daemon_input.missed_ticks`` tells how many of those
  never reached the daemon's input);
* latency percentiles (input stamp in the daemon -> arrival at the subscriber) of the
  ticks of that minute.

``rss_growth_mb`` = RSS at the end minus RSS at the end of the warm-up: the first minute,
or the first 20 % of the run when the run is shorter than 5 minutes (``rss_warmup_s`` and
``rss_warmup_rule`` in the JSON say which). A daemon that leaks shows a growth that keeps
rising with the run length; a steady one stays within a few MB (allocator noise).
"""

from __future__ import annotations

import argparse
import array
import json
import math
import sys
import threading
import time
from typing import Any, Callable, Optional

from cablesvc.bench.e2e import (BENCH_DEADLINE_S, add_setup_options, latency_percentiles, run_three_processes,
                                 run_with_progress)

__all__ = ["add_parser", "cmd_soak", "read_rss_mb", "run_soak_bench"]


def read_rss_mb(pid: int) -> Optional[float]:
    """Resident set size of process ``pid`` [MiB] from ``/proc/<pid>/status`` (None when gone)."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0          # the kernel writes kB
    except (OSError, ValueError, IndexError):
        return None
    return None


class _MinuteCollector:
    """Zenoh callback: latencies [ns] and distinct seqs, bucketed by the tick's minute
    (``seq // ticks_per_minute``; the few ticks the controller sends past the last whole
    minute count in the last minute, ``n_minutes``)."""

    def __init__(self, ticks_per_minute: int, n_minutes: int):
        self.tpm = max(1, int(ticks_per_minute))
        self.last = max(1, int(n_minutes)) - 1
        self.lat: dict[int, array.array] = {}
        self.seqs: dict[int, set[int]] = {}
        self.count = 0

    def __call__(self, payload: dict, receive_ns: int) -> None:
        self.count += 1
        seq = int(payload["seq"])
        k = min(seq // self.tpm, self.last)
        lat = self.lat.get(k)
        if lat is None:
            lat = self.lat[k] = array.array("q")
            self.seqs[k] = set()
        self.seqs[k].add(seq)
        lat.append(receive_ns - int(payload["stamp_ns"]))


class _RssSampler(threading.Thread):
    """Samples the daemon's RSS every ``interval`` s: list of (seconds since ``t0``, MiB)."""

    def __init__(self, pid: int, interval: float):
        super().__init__(name="soak-rss", daemon=True)
        self.pid = pid
        self.interval = float(interval)
        self.samples: list[tuple[float, float]] = []
        self.t0 = time.monotonic()
        self._stop_ev = threading.Event()

    def restart_clock(self) -> None:
        self.t0 = time.monotonic()

    def sample(self) -> None:
        mb = read_rss_mb(self.pid)
        if mb is not None:
            self.samples.append((time.monotonic() - self.t0, mb))

    def run(self) -> None:
        while not self._stop_ev.wait(self.interval):
            self.sample()

    def stop(self) -> None:
        self._stop_ev.set()
        if self.is_alive():
            self.join(2.0)


def _rss_at(samples: list[tuple[float, float]], t: float) -> Optional[float]:
    """The first sample at or after ``t`` [s] (else the last one)."""
    after = [mb for s, mb in samples if s >= t]
    if after:
        return after[0]
    return samples[-1][1] if samples else None


def run_soak_bench(rate: float = 1000.0, minutes: float = 30.0, *, robot: str = "ipanema3", fd: bool = True,
                   encoding: str = "json", rss_interval: float = 2.0,
                   progress: Callable[[str, float], None] | None = None) -> dict[str, Any]:
    """Run the soak; returns the JSON keys of ``cablesvc bench soak``."""
    say = progress or (lambda what, frac: None)
    seconds = float(minutes) * 60.0
    tpm = int(round(rate * 60.0))
    n_minutes = max(1, math.ceil(float(minutes) - 1e-9))
    col = _MinuteCollector(tpm, n_minutes)
    sampler: Optional[_RssSampler] = None
    rss_start = None

    def subscribed(pid: int) -> None:
        nonlocal sampler, rss_start
        sampler = _RssSampler(pid, rss_interval)
        rss_start = read_rss_mb(pid)

    def ready() -> None:
        sampler.restart_clock()                       # RSS time axis: seconds since the controller is ready
        sampler.sample()
        sampler.start()

    def finished() -> None:
        sampler.sample()
        sampler.stop()

    try:
        run = run_three_processes(rate, seconds, col, robot=robot, fd=fd, encoding=encoding, say=say,
                                  on_subscribed=subscribed, on_ready=ready, on_finished=finished)
    finally:
        if sampler is not None:
            sampler.stop()
    fd = run["fd"]
    summary, status, shutdown_s = run["summary"], run["status"], run["shutdown_s"]
    sent = int(summary["ticks_sent"])
    samples = sampler.samples
    if seconds >= 300.0:
        warmup_s, rule = 60.0, "1 minute"
    else:
        warmup_s, rule = 0.2 * seconds, "20 % of the run (shorter than 5 minutes)"
    rss_warm = _rss_at(samples, warmup_s)
    rss_end = samples[-1][1] if samples else None
    per_minute = []
    all_lat = array.array("q")
    for k in range(n_minutes):
        lo = min(sent, k * tpm)
        hi = sent if k == n_minutes - 1 else min(sent, (k + 1) * tpm)
        lat = col.lat.get(k, array.array("q"))
        all_lat.extend(lat)
        got = len(col.seqs.get(k, ()))
        in_minute = [mb for s, mb in samples if s >= k * 60.0 and (s < (k + 1) * 60.0 or k == n_minutes - 1)]
        row = {"minute": k + 1, "ticks": hi - lo, "received": got, "missed": (hi - lo) - got,
               **latency_percentiles(lat),
               "rss_mb": round(in_minute[-1], 2) if in_minute else None,
               "rss_max_mb": round(max(in_minute), 2) if in_minute else None}
        per_minute.append(row)
    received = sum(len(s) for s in col.seqs.values())
    total = latency_percentiles(all_lat)
    # where the missing ticks are: runs of consecutive seqs never received (first 50 runs)
    got_all = set().union(*col.seqs.values()) if col.seqs else set()
    runs: list[list[int]] = []
    for q in range(sent):
        if q not in got_all:
            if runs and runs[-1][0] + runs[-1][1] == q:
                runs[-1][1] += 1
            elif len(runs) < 50:
                runs.append([q, 1])
    return {
        "minutes": float(minutes), "rate_hz": float(rate), "robot": robot, "transport": "can-fd" if fd else "can",
        "encoding": encoding, "deadline_s": BENCH_DEADLINE_S, "ticks": sent, "received": received, "missed": sent - received,
        "controller_overruns": summary.get("overruns"),
        "p50_us": total["p50_us"], "p99_us": total["p99_us"], "p999_us": total["p999_us"], "max_us": total["max_us"],
        "rss_start_mb": None if rss_start is None else round(rss_start, 2),
        "rss_warmup_mb": None if rss_warm is None else round(rss_warm, 2),
        "rss_end_mb": None if rss_end is None else round(rss_end, 2),
        "rss_growth_mb": None if rss_warm is None or rss_end is None else round(rss_end - rss_warm, 3),
        "rss_warmup_s": warmup_s, "rss_warmup_rule": rule, "rss_interval_s": float(rss_interval),
        "rss_samples": [[round(s, 2), round(mb, 2)] for s, mb in samples],
        "per_minute": per_minute,
        "missing_seq_runs": runs,
        "daemon_input": status.get("input"), "daemon_latency_us": status.get("latency_us"),
        # the daemon's side: puts made (forces block under congestion, so a put is lost only
        # if Zenoh closes a link blocked for 1 s), ticks not put because no subscriber
        # matched at that moment, puts that raised
        "daemon_published": status.get("published"), "daemon_skipped": status.get("skipped_no_subscriber"),
        "daemon_publish_errors": status.get("publish_errors"),
        "shutdown_s": round(shutdown_s, 3),
    }


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("soak", help="long end-to-end run: RSS, missed ticks and latency per minute",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_setup_options(p)
    p.add_argument("--minutes", type=float, default=30.0, help="length of the run in minutes (default 30)")
    p.add_argument("--rss-interval", type=float, default=2.0, help="seconds between RSS samples (default 2)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_soak)
    return p


def cmd_soak(args) -> int:
    if not (args.rate > 0 and args.minutes > 0 and args.rss_interval > 0):
        print("cablesvc bench soak: --rate, --minutes and --rss-interval must be > 0", file=sys.stderr)
        return 2
    kw = dict(robot=args.robot, fd=not args.classic, encoding=args.encoding, rss_interval=args.rss_interval)
    if args.json:
        print(json.dumps(run_soak_bench(args.rate, args.minutes, **kw)))
        return 0
    from rich.console import Console
    from rich.table import Table
    con = Console()
    res = run_with_progress(con, "soak", lambda progress: run_soak_bench(args.rate, args.minutes, progress=progress,
                                                                          **kw))
    tb = Table(title=f"soak, {res['robot']}, {res['transport']}, {res['encoding']}, {res['rate_hz']:g} Hz for "
                     f"{res['minutes']:g} min (input stamp -> subscriber; daemon RSS)")
    for c in ("minute", "ticks", "missed", "p50 us", "p99 us", "p99.9 us", "max us", "RSS MB"):
        tb.add_column(c, justify="right")

    def mb(v):
        return "-" if v is None else f"{v:.1f}"
    for r in res["per_minute"]:
        tb.add_row(str(r["minute"]), str(r["ticks"]), str(r["missed"]), f"{r['p50_us']:.0f}", f"{r['p99_us']:.0f}",
                   f"{r['p999_us']:.0f}", f"{r['max_us']:.0f}", mb(r["rss_mb"]))
    tb.add_row("all", str(res["ticks"]), str(res["missed"]), f"{res['p50_us']:.0f}", f"{res['p99_us']:.0f}",
               f"{res['p999_us']:.0f}", f"{res['max_us']:.0f}", mb(res["rss_end_mb"]))
    con.print(tb)
    growth = res["rss_growth_mb"]
    con.print(f"RSS growth {'-' if growth is None else f'{growth:+.2f}'} MB (end minus after the warm-up: "
              f"{res['rss_warmup_rule']}, {res['rss_warmup_s']:g} s); controller overruns "
              f"{res['controller_overruns']}; shutdown after SIGTERM {res['shutdown_s']:.2f} s")
    return 0


if __name__ == "__main__":
    _ap = argparse.ArgumentParser(prog="python -m cablesvc.bench.soak")
    _sub = _ap.add_subparsers(dest="bench", required=True)
    add_parser(_sub)
    _args = _ap.parse_args()
    sys.exit(_args.func(_args))
