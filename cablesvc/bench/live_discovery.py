"""``cablesvc bench live-discovery``: discovered physics, run live by the daemon, removes the error it found.

For each of the seven library effects (pulley, creep, temperature, viscous, sag, dead
time, sensor offset/gain) one recording of the digital twin (``trajectory`` scenario of
ipanema3, 100 Hz, 0.1 N sensor noise): the effect sets in at ``onset`` s (after the
alarms' 60 s warm-up), ramping up over ``ramp`` s, as a cable that starts to creep, warm
up or slip would (:func:`with_onset`: one twin run, the effect faded in). Then, as a
user would:

1. the first half is replayed through a real :class:`~cablesvc.service.daemon.Daemon`
   (replay source at full speed, a real Zenoh peer on 127.0.0.1, the baseline parameters):
   ``rmse_live_before`` is the live residual RMS on the affected cables after the ramp,
   ``drift_alarm_before`` whether ``drift`` or ``spread`` was raised on an affected cable;
2. ``cablesvc discover --since T`` runs on the first half, T the time of the first alarm
   on an affected cable (the baseline over all of it, the analysis on the ticks since the
   alarm, what an alarmed user selects; the onset when no alarm came, ``discover_since``): ``rmse_discover_heldout`` is its held-out (test-block) RMS
   on the affected cables after the terms, ``named`` the terms it found;
3. the daemon takes the augmented parameter file without a restart (the reload of
   ``cablesvc run``: SIGHUP or a put on ``cablesvc/<robot>/params``) and the second half is
   replayed: ``rmse_live_after`` is the live residual RMS on the affected cables over
   the second half, ``drift_alarm_after`` whether ``drift`` or ``spread`` was raised on an
   affected cable after the reload.

The baseline is the twin's own truth model (the nominal amplitude model), so discovery runs
with ``exact_baseline=True``: this bench measures the live path of discovered terms, not
discovery against an imperfect baseline (``cablesvc bench discover`` does that).
``kernel_p50_ratio`` is the ``terms`` row of ``cablesvc bench kernel`` (every term on every
cable against the plain kernel timed in alternate blocks of the same run).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np

ROBOT = "ipanema3"
RATE = 100.0
NOISE = 0.1
#: effect specs (twin effect syntax), a few times the noise on their cables
EFFECTS = {
    "pulley": "pulley:0.004@1,4", "creep": "creep:1.5@2", "temperature": "temperature:-0.003@0,6",
    "viscous": "viscous:800@3", "sag": "sag:0.8@6", "deadtime": "deadtime:0.25@5",
    "offset_gain": "offset_gain:0.6@2,7",
}


def with_onset(eff, onset: float, ramp: float):
    """``eff`` acting from ``onset`` s on (twin time), faded in over ``ramp`` s: a copy of the
    effect whose step blends the value without it and with it. The effect's own state runs
    from the start (a dead time or a Bouc-Wen loop is the same physics, only switched in);
    an effect whose law is a clock since it began (``clocked``: creep) starts that clock at
    the onset, as a cable that starts to creep does, instead of stepping to the creep it
    would have accumulated since the recording's start."""
    import copy

    base_cls = type(eff)

    class _Shifted:                      # the tick as a clocked effect sees it
        __slots__ = ("_tick",)

        def __init__(self, tick):
            self._tick = tick

        def __getattr__(self, k):
            v = getattr(self._tick, k)
            return max(float(v) - onset, 0.0) if k == "t" else v

    class Onset(base_cls):
        def step(self, tick, value):
            before = value.copy()
            base_cls.step(self, _Shifted(tick) if base_cls.clocked else tick, value)
            w = min(max((float(tick.t) - onset) / ramp, 0.0), 1.0)
            value[...] = before + w * (value - before)

    Onset.__name__ = f"Onset{base_cls.__name__}"
    out = copy.copy(eff)
    out.__class__ = Onset
    return out


def make_onset_recording(spec: str, *, half: float, onset: float, ramp: float, seed: int):
    """The twin recording of 2 ``half`` s in which ``spec``'s effect sets in at ``onset`` s
    (faded in over ``ramp`` s, :func:`with_onset`); returns (recording, affected cables).
    One run of the twin: the motor lengths, the pose and the forces stay consistent."""
    from cablesvc.recording import Recording
    from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording

    eff = effect_from_spec(spec, 8)
    cables = sorted(int(c) for c in (eff.cables or range(8)))
    rec = simulate_recording(ROBOT, "trajectory", None,
                             truth=TruthConfig(effects=[with_onset(eff, onset, ramp)], noise_std=NOISE),
                             duration=2.0 * half, rate=RATE, seed=seed)
    meta = {k: v for k, v in rec.metadata.items() if k != "truth"}     # the answer key stays out
    return Recording(robot=rec.robot, metadata=meta, t=rec.t, seq=rec.seq, motor_length=rec.motor_length,
                     position=rec.position, orientation=rec.orientation, force=rec.force,
                     temperature=rec.temperature), cables


def _capturing_factory(port: int, forces: dict, alarms: list):
    from cablesvc.service.zenoh_io import Publisher, make_config

    class Capturing(Publisher):
        """The daemon's real Zenoh publisher, also keeping what it publishes for the bench."""

        def publish_forces(self, payload: dict) -> None:
            forces[int(payload["seq"])] = np.array(payload["force"], float)
            super().publish_forces(payload)

        def publish_alarm(self, event_payload: dict) -> None:
            alarms.append(dict(event_payload))
            super().publish_alarm(event_payload)

    def factory(robot: str, status):
        return Capturing(robot, make_config(listen=(f"tcp/127.0.0.1:{port}",), connect=()), status=status)
    return factory


def _raised(alarms: list[dict], cables: list[int], t0: float, t_from: float, t_to: float) -> bool:
    """Whether drift or spread was raised on one of ``cables`` between ``t_from`` and
    ``t_to`` s after the recording's start ``t0``."""
    for a in alarms:
        if a.get("code") not in ("drift", "spread") or a.get("action") != "raise":
            continue
        t = float(a.get("t", math.nan)) - t0
        if t_from <= t < t_to and a.get("cable") in cables:
            return True
    return False


def _first_raise(alarms: list[dict], cables: list[int], t0: float, t_from: float) -> Optional[float]:
    """Time [s after the start] of the first drift or spread raise on one of ``cables`` at
    or after ``t_from`` s, None without one."""
    ts = [float(a["since"] if a.get("since") is not None else a["t"]) - t0 for a in alarms
          if a.get("code") in ("drift", "spread") and a.get("action") == "raise" and a.get("cable") in cables
          and float(a.get("t", math.nan)) - t0 >= t_from]
    return min(ts) if ts else None


def run_effect(name: str, *, half: float = 180.0, onset: float = 75.0, ramp: float = 5.0, seed: int = 0,
               workdir: Optional[Path] = None) -> dict[str, Any]:
    """One effect's row (see the module docstring)."""
    from cablesvc.config import load_robot
    from cablesvc.discover import discover
    from cablesvc.discover.pipeline import baseline_params
    from cablesvc.recording import write_recording
    from cablesvc.service.daemon import Daemon, DaemonOptions
    from cablesvc.netutil import free_tcp_port

    t_start = time.perf_counter()
    rec, cables = make_onset_recording(EFFECTS[name], half=half, onset=onset, ramp=ramp, seed=seed)
    robot = load_robot(ROBOT)
    base = baseline_params(robot)
    n = rec.t.size
    n_half = n // 2
    t0 = float(rec.t[0])
    tmp = Path(workdir or tempfile.mkdtemp(prefix="cablesvc-live-discovery-"))
    path = tmp / f"{name}.mcap"
    write_recording(path, rec)
    forces: dict[int, np.ndarray] = {}
    alarms: list[dict] = []
    port = free_tcp_port()
    d = Daemon(DaemonOptions(robot=robot, params=base, source={"kind": "replay", "path": str(path), "speed": 0},
                             listen=(f"tcp/127.0.0.1:{port}",), connect=()),
               publisher_factory=_capturing_factory(port, forces, alarms))
    reload: dict[str, Any] = {}
    try:
        d.run(threading.Event(), max_ticks=n_half)
        # discovery on the first half, analysing the ticks since the first alarm on an
        # affected cable (``--since``: what a user who was alarmed selects; the onset itself
        # is the bench's secret); the baseline runs from the start, as the daemon's did
        since = _first_raise(alarms, list(cables), t0, onset)
        disc = discover(rec.slice(0, n_half), robot, base, exact_baseline=True,
                        since=onset if since is None else since)
        reload = d.reload_params(disc.augmented_params().to_toml(), origin="bench live-discovery", timeout=0.05)
        d.run(threading.Event())
    finally:
        d.close()
    seq_index = {int(q): k for k, q in enumerate(rec.seq)}
    missing = n - len(forces)
    pred = np.full_like(rec.force, np.nan)
    for q, f in forces.items():
        pred[seq_index[q]] = f
    res = rec.force - pred
    t_rel = rec.t - t0
    before = (t_rel >= onset + ramp) & (np.arange(n) < n_half)
    after = np.arange(n) >= n_half
    cs = list(cables)

    def rms(mask):
        e = res[mask][:, cs]
        e = e[np.isfinite(e)]
        return float(np.sqrt(np.mean(e ** 2))) if e.size else math.nan

    t_half = float(rec.t[n_half] - t0)
    heldout = float(np.sqrt(np.mean(disc.rmse_after[cs] ** 2)))
    return {"effect": name, "spec": EFFECTS[name], "cables": cs, "named": disc.named,
            "discover_since": onset if since is None else since,
            "rmse_live_before": rms(before), "rmse_live_after": rms(after), "rmse_discover_heldout": heldout,
            "rmse_discover_heldout_before": float(np.sqrt(np.mean(disc.rmse_before[cs] ** 2))),
            "drift_alarm_before": _raised(alarms, cs, t0, onset, t_half),
            "drift_alarm_after": _raised(alarms, cs, t0, t_half, math.inf),
            "alarms_before_onset": sum(1 for a in alarms if a.get("action") == "raise"
                                       and a.get("code") in ("drift", "spread") and float(a.get("t", 0)) - t0 < onset),
            "alarms_after": [{"code": a["code"], "cable": a.get("cable"), "t": round(float(a["t"]) - t0, 2)}
                             for a in alarms if a.get("action") == "raise" and a.get("code") in ("drift", "spread")
                             and float(a.get("t", 0)) - t0 >= t_half],
            "reload_accepted": bool(reload.get("accepted")),
            "ticks": n, "missing": missing, "seconds": time.perf_counter() - t_start}


def run_bench(effects: Optional[list[str]] = None, *, half: float = 180.0, onset: float = 75.0, seed: int = 0,
              kernel_ticks: int = 20_000, progress=None) -> dict[str, Any]:
    from cablesvc.bench.kernel import run_kernel_bench
    rows = []
    names = list(effects or EFFECTS)
    for i, name in enumerate(names):
        if progress:
            progress(i, len(names), name)
        rows.append(run_effect(name, half=half, onset=onset, seed=seed))
    kb = {r.input: r for r in run_kernel_bench(ROBOT, ticks=kernel_ticks, inputs=("terms",),
                                                machine_baseline=False)}
    ok = [r for r in rows if r["rmse_live_after"] <= 1.1 * r["rmse_discover_heldout"]
          and r["rmse_live_after"] < 0.5 * r["rmse_live_before"] and r["drift_alarm_before"]
          and not r["drift_alarm_after"]]
    return {"effects": rows, "kernel_p50_ratio": kb["terms"].kernel_p50_ratio,
            "kernel_p50_us": kb["terms"].plain_p50_us,
            "kernel_terms_p50_us": kb["terms"].p50_us,
            "effects_meeting_all": [r["effect"] for r in ok], "half_s": half, "onset_s": onset, "seed": seed}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("live-discovery", help="discovered terms run live: before/after the daemon reloads them",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--effect", action="append", choices=list(EFFECTS), help="only these effects (repeatable)")
    p.add_argument("--half", type=float, default=180.0, help="seconds per half of each recording (default 180)")
    p.add_argument("--onset", type=float, default=75.0, help="effect onset [s], after the 60 s warm-up (default 75)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=main)
    return p


def main(args) -> int:
    import logging
    logging.getLogger("cablesvc").setLevel(logging.WARNING)
    if args.onset < 60.0 or args.half <= args.onset + 30.0:
        print("cablesvc bench live-discovery: --onset must be >= 60 s (the alarms' warm-up) and --half at least "
              "30 s longer than --onset", file=__import__("sys").stderr)
        return 2
    res = run_bench(args.effect, half=args.half, onset=args.onset, seed=args.seed,
                    progress=None if args.json else (lambda i, n, e: print(f"[{i + 1}/{n}] {e} ...", flush=True)))
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"{'effect':<12} {'named':<24} {'live before':>11} {'heldout':>8} {'live after':>10} "
          f"{'alarm before':>12} {'alarm after':>11}")
    for r in res["effects"]:
        print(f"{r['effect']:<12} {','.join(r['named']) or '-':<24} {r['rmse_live_before']:>11.3f} "
              f"{r['rmse_discover_heldout']:>8.3f} {r['rmse_live_after']:>10.3f} {str(r['drift_alarm_before']):>12} "
              f"{str(r['drift_alarm_after']):>11}")
    print(f"kernel p50 with every term / without: {res['kernel_p50_ratio']:.2f}")
    print(f"effects meeting every acceptance line: {len(res['effects_meeting_all'])} of {len(res['effects'])}")
    return 0
