"""``cablesvc bench alarms``: detection delay and false alarms of the drift detector.

Synthetic residuals (measured - predicted) at ``rate_hz`` (default 1 kHz) for ``n_cables``
cables: a per-cable bias uniform in +-0.5 N (what a good model leaves, learned as the
baseline during the warm-up) plus Gaussian sensor noise of ``noise_n`` (default 0.1 N).
Three runs per seed, each through :meth:`DriftDetector.update_batch` (bit-identical to
the per-tick path the daemon uses):

- **noise only** for ``hours`` (default one hour, 3.6 M ticks): every raise is a false alarm;
- **step**: after the warm-up and one more minute, a step of ``step_n`` (0.4 N, the
  offset of paper 002 Fig 6), positive on even cables, negative on odd ones; delay =
  time from the step to the raise on that cable;
- **ramp**: from the same moment, an offset growing at ``ramp_n_per_h`` (0.4 N per hour),
  same signs; delay = time from the start of the ramp to the raise.

It reports per scenario the median and maximum delay over all cables and seeds, the
estimated offset at the raise (``offset_n`` of the event; for the ramp also the true
offset at that moment) and the false alarms.
"""

from __future__ import annotations

import json
import time
from typing import Any, Callable

import numpy as np

from cablesvc.alarms.drift import DriftConfig, DriftDetector

CHUNK_S = 60.0          # seconds of data generated at once


def _run(det: DriftDetector, rng: np.random.Generator, bias: np.ndarray, rate: float, noise: float,
         duration_s: float, offset_fn: Callable[[np.ndarray], np.ndarray] | None, change_t: float,
         stop_when_all: bool, model_error: tuple[float, float] = (0.0, 1.0),
         ) -> tuple[dict[int, tuple[float, float]], int, int]:
    """Feed ``duration_s`` of residuals; returns ({cable: (raise t, offset_n)} of the first raise
    at or after ``change_t``, raises before ``change_t``, samples processed).
    ``model_error`` (std [N], correlation time [s]): a zero-mean Ornstein-Uhlenbeck component
    added to the residual, standing for model error that varies slowly with the motion."""
    from scipy.signal import lfilter

    m = bias.size
    me_std, me_tau = model_error
    a = float(np.exp(-1.0 / (rate * me_tau)))
    me_b = [me_std * float(np.sqrt(1.0 - a * a))]
    zi = (rng.standard_normal(m) * me_std * a)[None, :] if me_std > 0 else None
    n_total = int(round(duration_s * rate))
    chunk = int(CHUNK_S * rate)
    first: dict[int, tuple[float, float]] = {}
    early = 0
    k0 = 0
    while k0 < n_total:
        n = min(chunk, n_total - k0)
        t = (k0 + np.arange(n)) / rate
        R = rng.standard_normal((n, m))
        R *= noise
        R += bias
        if zi is not None:
            ou, zi = lfilter(me_b, [1.0, -a], rng.standard_normal((n, m)), axis=0, zi=zi)
            R += ou
        if offset_fn is not None:
            R += offset_fn(t)
        for ev in det.update_batch(t, R, seq=k0):
            if ev.action != "raise":
                continue
            if ev.t < change_t:
                early += 1
            elif ev.cable not in first:
                first[ev.cable] = (ev.t, float(ev.offset_n))
        k0 += n
        if stop_when_all and len(first) == m:
            break
    return first, early, k0 * m


def _summary(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"median": None, "max": None, "min": None}
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "max": float(a.max()), "min": float(a.min())}


def run_alarm_bench(seed: int = 0, hours: float = 1.0, *, n_seeds: int = 5, n_cables: int = 8,
                    rate_hz: float = 1000.0, noise_n: float = 0.1, step_n: float = 0.4,
                    ramp_n_per_h: float = 0.4, model_error_n: float = 0.0, model_error_tau_s: float = 5.0,
                    config: DriftConfig | None = None,
                    progress: Callable[[str, int, int], None] | None = None) -> dict[str, Any]:
    """Run the three scenarios for seeds ``seed .. seed + n_seeds - 1``; see the module
    docstring. Units: s, N, Hz. Returns a JSON-able dict with ``per_seed`` rows and the
    ``step``, ``ramp`` and ``noise`` summaries. ``model_error_n`` > 0 adds a slowly varying
    zero-mean residual (std [N], correlation time ``model_error_tau_s`` [s]) to every run:
    a robustness check beyond white sensor noise."""
    cfg = config if config is not None else DriftConfig()
    pre_s = cfg.warmup_s + 60.0
    step_max_s = 600.0
    ramp_max_s = 3.0 * 3600.0 * (0.4 / max(ramp_n_per_h, 1e-9))     # a generous cap
    signs = np.where(np.arange(n_cables) % 2 == 0, 1.0, -1.0)
    rows = []
    step_delays, step_offsets, ramp_delays, ramp_offsets, ramp_true = [], [], [], [], []
    false_noise = false_pre = 0
    samples = 0
    me = (model_error_n, model_error_tau_s)
    wall0 = time.perf_counter()
    for j in range(n_seeds):
        s = seed + j
        rng = np.random.default_rng(s)
        bias = rng.uniform(-0.5, 0.5, n_cables)
        # noise only
        if progress:
            progress("noise", j, n_seeds)
        det = DriftDetector(n_cables, cfg)
        first, early, ns = _run(det, rng, bias, rate_hz, noise_n, hours * 3600.0, None, float("inf"), False, me)
        n_false = early
        samples += ns
        # step
        if progress:
            progress("step", j, n_seeds)
        det = DriftDetector(n_cables, cfg)
        fs, early_s, ns = _run(det, rng, bias, rate_hz, noise_n, pre_s + step_max_s,
                               lambda t: np.where(t[:, None] >= pre_s, step_n * signs, 0.0), pre_s, True, me)
        samples += ns
        sd = [fs[i][0] - pre_s for i in sorted(fs)]
        so = [fs[i][1] * signs[i] for i in sorted(fs)]
        # ramp
        if progress:
            progress("ramp", j, n_seeds)
        det = DriftDetector(n_cables, cfg)
        rate_s = ramp_n_per_h / 3600.0
        fr, early_r, ns = _run(det, rng, bias, rate_hz, noise_n, pre_s + ramp_max_s,
                               lambda t: np.maximum(t[:, None] - pre_s, 0.0) * rate_s * signs, pre_s, True, me)
        samples += ns
        rd = [fr[i][0] - pre_s for i in sorted(fr)]
        ro = [fr[i][1] * signs[i] for i in sorted(fr)]
        rt = [(fr[i][0] - pre_s) * rate_s for i in sorted(fr)]
        false_noise += n_false
        false_pre += early_s + early_r
        step_delays += sd
        step_offsets += so
        ramp_delays += rd
        ramp_offsets += ro
        ramp_true += rt
        rows.append({
            "seed": s, "false_alarms_noise": n_false, "false_alarms_before_change": early_s + early_r,
            "step_detected": len(fs), "step_delay_s": _summary(sd), "step_offset_n": _summary(so),
            "ramp_detected": len(fr), "ramp_delay_s": _summary(rd), "ramp_offset_n": _summary(ro),
        })
    wall = time.perf_counter() - wall0
    n_total = n_cables * n_seeds
    return {
        "config": cfg.model_dump(),
        "setup": {"seeds": list(range(seed, seed + n_seeds)), "cables": n_cables, "rate_hz": rate_hz,
                  "noise_n": noise_n, "hours_noise_only": hours, "step_n": step_n, "ramp_n_per_h": ramp_n_per_h,
                  "change_at_s": pre_s, "bias": "uniform +-0.5 N per cable",
                  "model_error_n": model_error_n, "model_error_tau_s": model_error_tau_s},
        "noise": {"ticks_per_seed": int(round(hours * 3600.0 * rate_hz)), "false_alarms": false_noise,
                  "false_alarms_before_change": false_pre},
        "step": {"detected": len(step_delays), "of": n_total, "delay_s": _summary(step_delays),
                 "offset_n": _summary(step_offsets)},
        "ramp": {"detected": len(ramp_delays), "of": n_total, "delay_s": _summary(ramp_delays),
                 "offset_n": _summary(ramp_offsets), "true_offset_at_raise_n": _summary(ramp_true)},
        "per_seed": rows,
        "samples": samples,
        "wall_s": wall,
        "samples_per_s": samples / wall if wall > 0 else None,
    }


# ---- command line --------------------------------------------------------------------------

def cmd_bench_alarms(args) -> int:
    """Handler of ``cablesvc bench alarms``."""
    kw = dict(n_seeds=args.seeds, n_cables=args.cables, rate_hz=args.rate, noise_n=args.noise,
              step_n=args.step, ramp_n_per_h=args.ramp, model_error_n=args.model_error,
              model_error_tau_s=args.model_error_tau)
    if args.json:
        print(json.dumps(run_alarm_bench(args.seed, args.hours, **kw)))
        return 0
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    con = Console()
    with Progress(console=con, transient=True) as prog:
        task = prog.add_task("alarms", total=3 * args.seeds)

        def cb(kind, j, n):
            prog.update(task, completed=3 * j + ("noise", "step", "ramp").index(kind),
                        description=f"seed {args.seed + j}: {kind}")
        res = run_alarm_bench(args.seed, args.hours, progress=cb, **kw)
    su = res["setup"]
    tb = Table(title=(f"drift detector: {su['cables']} cables x {len(su['seeds'])} seeds, {su['rate_hz']:g} Hz, "
                      f"noise {su['noise_n']:g} N"))
    for c in ("scenario", "raised", "delay s (med)", "delay s (max)", "offset N (med)", "false alarms"):
        tb.add_column(c, justify="right")

    def f(v, fmt="{:.1f}"):
        return "-" if v is None else fmt.format(v)
    st, rp, no = res["step"], res["ramp"], res["noise"]
    tb.add_row(f"step {su['step_n']:g} N", f"{st['detected']}/{st['of']}", f(st["delay_s"]["median"]),
               f(st["delay_s"]["max"]), f(st["offset_n"]["median"], "{:.3f}"), "-")
    tb.add_row(f"ramp {su['ramp_n_per_h']:g} N/h", f"{rp['detected']}/{rp['of']}", f(rp["delay_s"]["median"]),
               f(rp["delay_s"]["max"]), f"{f(rp['offset_n']['median'], '{:.3f}')} "
               f"(true {f(rp['true_offset_at_raise_n']['median'], '{:.3f}')})", "-")
    tb.add_row(f"noise {su['hours_noise_only']:g} h", "-", "-", "-", "-",
               f"{no['false_alarms'] + no['false_alarms_before_change']}")
    con.print(tb)
    con.print(f"{res['samples'] / 1e6:.1f} M samples in {res['wall_s']:.1f} s "
              f"({res['samples_per_s'] / 1e6:.1f} M samples/s, data generation included)")
    return 0


def add_parser(subparsers) -> Any:
    """Register ``alarms`` on the ``cablesvc bench`` subparsers; returns the parser."""
    p = subparsers.add_parser(
        "alarms", help="drift detector: step / ramp detection delay, false alarms in an hour of noise",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--seeds", type=int, default=5, help="number of seeds (default 5)")
    p.add_argument("--hours", type=float, default=1.0, help="hours of noise-only data per seed (default 1)")
    p.add_argument("--cables", type=int, default=8, help="cables (default 8)")
    p.add_argument("--rate", type=float, default=1000.0, help="tick rate in Hz (default 1000)")
    p.add_argument("--noise", type=float, default=0.1, help="sensor noise std in N (default 0.1)")
    p.add_argument("--step", type=float, default=0.4, help="step offset in N (default 0.4)")
    p.add_argument("--ramp", type=float, default=0.4, help="ramp rate in N per hour (default 0.4)")
    p.add_argument("--model-error", type=float, default=0.0,
                   help="std in N of a slowly varying zero-mean model error added to the residual (default 0)")
    p.add_argument("--model-error-tau", type=float, default=5.0,
                   help="correlation time in s of that model error (default 5)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench_alarms)
    return p
