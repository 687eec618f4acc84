"""``cablesvc bench alarms``: detection delay and false alarms of the drift and spread detectors.

Synthetic residuals (measured - predicted) at ``rate_hz`` (default 1 kHz) for ``n_cables``
cables: a per-cable bias uniform in +-0.5 N (what a good model leaves, learned as the
baseline during the warm-up) plus Gaussian sensor noise of ``noise_n`` (default 0.1 N),
white, or with ``--noise-filter-hz F`` through a first-order low-pass filter of cut-off F
(a load-cell amplifier's; its std stays ``noise_n``). Six runs per seed, each through the
detectors' ``update_batch`` (bit-identical to the per-tick path the daemon uses):

- **noise only** for ``hours`` (default one hour, 3.6 M ticks), through drift and spread:
  every raise is a false alarm;
- **step**: after the warm-up and one more minute, a step of ``step_n`` (0.4 N, the
  offset of paper 002 Fig 6), positive on even cables, negative on odd ones; delay =
  time from the step to the raise on that cable;
- **ramp**: from the same moment, an offset growing at ``ramp_n_per_h`` (0.4 N per hour),
  same signs; delay = time from the start of the ramp to the raise.

- **zero-mean effects** for the spread detector, setting in at the same moment on every
  cable, each of peak ``effect_n`` (0.3 N, 3 x the noise) over a motion of period
  ``period_s`` (4 s; cable i phase-shifted by 2 pi i / m): a pulley friction
  ``effect_n`` sign(v), a viscous force c v, and a dead time d of a 20 N force swing,
  f(t) - f(t - d) (d about 9.5 ms with the defaults); delay = time from the onset to the
  spread raise. Drift runs on the same data (it should not see them).

With ``--replay MINUTES`` (:func:`run_replay_bench`) also **effect-free replays**: the
digital twin's ``trajectory`` scenario of ipanema3 (nominal amplitude truth, sensor noise
``noise_n``) through the live kernel with the truth's own parameters, as the daemon
computes it, the residual of every tick into drift and spread: every raise is a false
alarm; it also reports the largest spread / noise-floor ratio after the warm-up.

It reports per scenario the median and maximum delay over all cables and seeds, the
estimated offset at the raise (``offset_n`` of the event; for the ramp also the true
offset at that moment), the false alarms, and the spread raises the 0.4 N step causes.
"""

from __future__ import annotations

import gc
import json
import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from cablesvc.simulate.noise import ar1, lowpass_phi

if TYPE_CHECKING:      # the detectors load numba: imported where the bench runs, so that
    # building the CLI (every ``cablesvc`` command) does not pay for them
    from cablesvc.alarms.drift import DriftConfig
    from cablesvc.alarms.spread import SpreadConfig

CHUNK_S = 60.0          # seconds of data generated at once
SWING_N = 20.0          # force swing of the dead-time scenario [N]
EFFECTS = ("friction", "viscous", "dead_time")


def _run(dets, rng: np.random.Generator, bias: np.ndarray, rate: float, noise: float,
         duration_s: float, offset_fn: Callable[[np.ndarray], np.ndarray] | None, change_t: float,
         stop_when_all: bool, model_error: tuple[float, float] = (0.0, 1.0),
         noise_filter_hz: float | None = None,
         ) -> tuple[list[dict[int, tuple[float, float]]], list[int], int]:
    """Feed ``duration_s`` of residuals to every detector of ``dets`` (the same data); returns,
    per detector, {cable: (raise t, value)} of the first raise at or after ``change_t``
    (value: ``offset_n`` for drift, the spread for spread) and the raises before
    ``change_t``, and the samples processed. ``stop_when_all``: stop once the first detector
    has raised on every cable. ``model_error`` (std [N], correlation time [s]): a zero-mean
    Ornstein-Uhlenbeck component added to the residual, standing for model error that
    varies slowly with the motion. ``noise_filter_hz``: the sensor noise (std ``noise``)
    has passed a first-order low-pass filter of that cut-off [Hz] (None: white)."""
    m = bias.size
    me_std, me_tau = model_error
    a = float(np.exp(-1.0 / (rate * me_tau)))
    ou_prev = rng.standard_normal(m) if me_std > 0 else None
    phi = lowpass_phi(noise_filter_hz, 1.0 / rate) if noise_filter_hz else None
    noise_prev = rng.standard_normal(m) if phi is not None else None
    n_total = int(round(duration_s * rate))
    chunk = int(CHUNK_S * rate)
    firsts: list[dict[int, tuple[float, float]]] = [{} for _ in dets]
    earlies = [0] * len(dets)
    k0 = 0
    while k0 < n_total:
        n = min(chunk, n_total - k0)
        t = (k0 + np.arange(n)) / rate
        R = rng.standard_normal((n, m))
        if phi is not None:
            R = ar1(R, phi, noise_prev)
            noise_prev = R[-1].copy()
        R *= noise
        R += bias
        if ou_prev is not None:
            ou = ar1(rng.standard_normal((n, m)), a, ou_prev)
            ou_prev = ou[-1].copy()
            R += me_std * ou
        if offset_fn is not None:
            R += offset_fn(t)
        for j, det in enumerate(dets):
            first = firsts[j]
            for ev in det.update_batch(t, R, seq=k0):
                if ev.action != "raise":
                    continue
                if ev.t < change_t:
                    earlies[j] += 1
                elif ev.cable not in first:
                    first[ev.cable] = (ev.t, float(ev.offset_n if ev.offset_n is not None else ev.value))
        k0 += n
        if stop_when_all and len(firsts[0]) == m:
            break
    return firsts, earlies, k0 * m


def zero_mean_effect(kind: str, n_cables: int, size_n: float, period_s: float, onset_s: float,
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """offset_fn (t (n,) -> (n, m) [N]) of a zero-mean effect of peak ``size_n`` from ``onset_s``
    over a motion of period ``period_s`` (cable i phase-shifted by 2 pi i / m): ``friction``
    size sign(v), ``viscous`` c v, ``dead_time`` f(t) - f(t - d) of a force swing
    f = SWING_N sin(w t + phase), with d = :func:`dead_time_s`."""
    w = 2.0 * np.pi / period_s
    phase = 2.0 * np.pi * np.arange(n_cables) / n_cables
    d = dead_time_s(size_n, period_s)

    def fn(t: np.ndarray) -> np.ndarray:
        x = w * t[:, None] + phase
        if kind == "friction":
            e = size_n * np.sign(np.cos(x))           # v = d/dt sin(x)
        elif kind == "viscous":
            e = size_n * np.cos(x)
        elif kind == "dead_time":
            e = SWING_N * (np.sin(x) - np.sin(x - w * d))
        else:
            raise ValueError(f"unknown effect {kind!r} (one of {', '.join(EFFECTS)})")
        return np.where(t[:, None] >= onset_s, e, 0.0)
    return fn


def dead_time_s(size_n: float, period_s: float) -> float:
    """Dead time [s] whose residual on a SWING_N sine of period ``period_s`` peaks at size_n:
    2 SWING_N sin(w d / 2) = size_n."""
    return 2.0 / (2.0 * np.pi / period_s) * float(np.arcsin(min(1.0, size_n / (2.0 * SWING_N))))


def _summary(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"median": None, "max": None, "min": None}
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "max": float(a.max()), "min": float(a.min())}


def run_alarm_bench(seed: int = 0, hours: float = 1.0, *, n_seeds: int = 5, n_cables: int = 8,
                    rate_hz: float = 1000.0, noise_n: float = 0.1, step_n: float = 0.4,
                    ramp_n_per_h: float = 0.4, model_error_n: float = 0.0, model_error_tau_s: float = 5.0,
                    effect_n: float = 0.3, period_s: float = 4.0, noise_filter_hz: float | None = None,
                    config: DriftConfig | None = None, spread_config: SpreadConfig | None = None,
                    progress: Callable[[str, int, int], None] | None = None) -> dict[str, Any]:
    """Run the scenarios for seeds ``seed .. seed + n_seeds - 1``; see the module
    docstring. Units: s, N, Hz. Returns a JSON-able dict with ``per_seed`` rows and the
    ``step``, ``ramp`` and ``noise`` summaries of drift and the ``spread`` summary.
    ``model_error_n`` > 0 adds a slowly varying zero-mean residual (std [N], correlation
    time ``model_error_tau_s`` [s]) to every run: a robustness check beyond white sensor noise;
    ``noise_filter_hz`` passes the sensor noise through a first-order low-pass filter of that
    cut-off [Hz] (a load-cell amplifier's; its std stays ``noise_n``)."""
    from cablesvc.alarms.drift import DriftConfig, DriftDetector
    from cablesvc.alarms.spread import SpreadConfig, SpreadDetector

    cfg = config if config is not None else DriftConfig()
    scfg = spread_config if spread_config is not None else SpreadConfig()
    pre_s = max(cfg.warmup_s, scfg.warmup_s) + 60.0
    step_max_s = 600.0
    effect_max_s = 120.0
    ramp_max_s = 3.0 * 3600.0 * (0.4 / max(ramp_n_per_h, 1e-9))     # a generous cap
    signs = np.where(np.arange(n_cables) % 2 == 0, 1.0, -1.0)
    rows = []
    step_delays, step_offsets, ramp_delays, ramp_offsets, ramp_true = [], [], [], [], []
    false_noise = false_pre = spread_false = spread_on_step = 0
    eff: dict[str, dict[str, list]] = {k: {"delay": [], "spread": [], "drift": [], "early": []} for k in EFFECTS}
    samples = 0
    nk = dict(model_error=(model_error_n, model_error_tau_s), noise_filter_hz=noise_filter_hz)
    wall0 = time.perf_counter()
    for j in range(n_seeds):
        s = seed + j
        rng = np.random.default_rng(s)
        bias = rng.uniform(-0.5, 0.5, n_cables)
        # noise only: drift and spread on the same data
        if progress:
            progress("noise", j, n_seeds)
        (_, _), (early, early_sp), ns = _run([DriftDetector(n_cables, cfg), SpreadDetector(n_cables, scfg)], rng,
                                             bias, rate_hz, noise_n, hours * 3600.0, None, float("inf"), False, **nk)
        n_false = early
        samples += ns
        # step (spread runs beside drift: how often a step of the mean also raises spread)
        if progress:
            progress("step", j, n_seeds)
        (fs, fs_sp), (early_s, _), ns = _run(
            [DriftDetector(n_cables, cfg), SpreadDetector(n_cables, scfg)], rng, bias, rate_hz, noise_n,
            pre_s + step_max_s, lambda t: np.where(t[:, None] >= pre_s, step_n * signs, 0.0), pre_s, True, **nk)
        samples += ns
        sd = [fs[i][0] - pre_s for i in sorted(fs)]
        so = [fs[i][1] * signs[i] for i in sorted(fs)]
        # ramp
        if progress:
            progress("ramp", j, n_seeds)
        rate_s = ramp_n_per_h / 3600.0
        (fr,), (early_r,), ns = _run([DriftDetector(n_cables, cfg)], rng, bias, rate_hz, noise_n, pre_s + ramp_max_s,
                                     lambda t: np.maximum(t[:, None] - pre_s, 0.0) * rate_s * signs, pre_s, True, **nk)
        samples += ns
        rd = [fr[i][0] - pre_s for i in sorted(fr)]
        ro = [fr[i][1] * signs[i] for i in sorted(fr)]
        rt = [(fr[i][0] - pre_s) * rate_s for i in sorted(fr)]
        # zero-mean effects: spread first (it should raise), drift on the same data
        row_eff = {}
        for kind in EFFECTS:
            if progress:
                progress(kind, j, n_seeds)
            (fe, fe_dr), (early_e, early_ed), ns = _run(
                [SpreadDetector(n_cables, scfg), DriftDetector(n_cables, cfg)], rng, bias, rate_hz, noise_n,
                pre_s + effect_max_s, zero_mean_effect(kind, n_cables, effect_n, period_s, pre_s), pre_s, True, **nk)
            samples += ns
            ed = [fe[i][0] - pre_s for i in sorted(fe)]
            e = eff[kind]
            e["delay"] += ed
            e["spread"] += [fe[i][1] for i in sorted(fe)]
            e["drift"].append(len(fe_dr))
            e["early"].append(early_e + early_ed)
            row_eff[kind] = {"detected": len(fe), "delay_s": _summary(ed), "drift_raised": len(fe_dr)}
        false_noise += n_false
        false_pre += early_s + early_r
        spread_false += early_sp
        spread_on_step += len(fs_sp)
        step_delays += sd
        step_offsets += so
        ramp_delays += rd
        ramp_offsets += ro
        ramp_true += rt
        rows.append({
            "seed": s, "false_alarms_noise": n_false, "false_alarms_before_change": early_s + early_r,
            "step_detected": len(fs), "step_delay_s": _summary(sd), "step_offset_n": _summary(so),
            "ramp_detected": len(fr), "ramp_delay_s": _summary(rd), "ramp_offset_n": _summary(ro),
            "spread_false_alarms_noise": early_sp, "spread_raised_on_step": len(fs_sp), "spread_effects": row_eff,
        })
    wall = time.perf_counter() - wall0
    n_total = n_cables * n_seeds
    cable_hours = n_total * hours
    return {
        "config": cfg.model_dump(),
        "spread_config": scfg.model_dump(),
        "setup": {"seeds": list(range(seed, seed + n_seeds)), "cables": n_cables, "rate_hz": rate_hz,
                  "noise_n": noise_n, "hours_noise_only": hours, "step_n": step_n, "ramp_n_per_h": ramp_n_per_h,
                  "change_at_s": pre_s, "bias": "uniform +-0.5 N per cable",
                  "model_error_n": model_error_n, "model_error_tau_s": model_error_tau_s,
                  "noise_filter_hz": noise_filter_hz,
                  "effect_n": effect_n, "period_s": period_s, "dead_time_s": dead_time_s(effect_n, period_s),
                  "dead_time_swing_n": SWING_N, "effect_window_s": effect_max_s},
        "noise": {"ticks_per_seed": int(round(hours * 3600.0 * rate_hz)), "false_alarms": false_noise,
                  "false_alarms_before_change": false_pre},
        "step": {"detected": len(step_delays), "of": n_total, "delay_s": _summary(step_delays),
                 "offset_n": _summary(step_offsets)},
        "ramp": {"detected": len(ramp_delays), "of": n_total, "delay_s": _summary(ramp_delays),
                 "offset_n": _summary(ramp_offsets), "true_offset_at_raise_n": _summary(ramp_true)},
        "spread": {
            "noise": {"cable_hours": cable_hours, "false_alarms": spread_false,
                      "false_alarms_per_cable_hour": spread_false / cable_hours if cable_hours > 0 else None},
            "raised_on_step": {"raised": spread_on_step, "of": n_total},
            "effects": {k: {"detected": len(e["delay"]), "of": n_total, "detection_rate": len(e["delay"]) / n_total,
                            "delay_s": _summary(e["delay"]), "spread_at_raise_n": _summary(e["spread"]),
                            "drift_raised": int(sum(e["drift"])), "raises_before_onset": int(sum(e["early"]))}
                        for k, e in eff.items()},
        },
        "per_seed": rows,
        "samples": samples,
        "wall_s": wall,
        "samples_per_s": samples / wall if wall > 0 else None,
    }


def run_replay_bench(minutes: float = 30.0, *, robot: str = "ipanema3", rate_hz: float = 1000.0, seed: int = 0,
                     noise_n: float = 0.1, chunk_s: float = 30.0, config: DriftConfig | None = None,
                     spread_config: SpreadConfig | None = None,
                     progress: Callable[[str, int, int], None] | None = None) -> dict[str, Any]:
    """Effect-free replays (see the module docstring) of ``minutes`` at ``rate_hz``, simulated
    in chunks of ``chunk_s`` seconds (seeds ``seed``, ``seed + 1``, ...; each chunk through a
    fresh kernel, like its fresh truth model), the detectors running on across the chunks
    with the time continued. Short chunks keep the simulator's memory small (about 1 GB for
    30 s at 1 kHz). Returns a JSON-able dict."""
    from cablesvc.alarms.drift import DriftConfig, DriftDetector
    from cablesvc.alarms.spread import SpreadConfig, SpreadDetector

    from cablesvc.kernel import Predictor
    from cablesvc.simulate.truth import TruthConfig
    from cablesvc.simulate.twin import simulate_twin

    cfg = config if config is not None else DriftConfig()
    scfg = spread_config if spread_config is not None else SpreadConfig()
    total_s = minutes * 60.0
    n_chunks = max(1, int(np.ceil(total_s / chunk_s - 1e-9)))
    drift = spread = None
    events: list = []
    ratio_max = 0.0
    ticks = 0
    sim_s = kernel_s = 0.0
    for c in range(n_chunks):
        if progress:
            progress("replay", c, n_chunks)
        dur = min(chunk_s, total_s - c * chunk_s)
        w0 = time.perf_counter()
        run = simulate_twin(robot, "trajectory", truth=TruthConfig(noise_std=noise_n), duration=dur, rate=rate_hz,
                            seed=seed + c)
        w1 = time.perf_counter()
        rec, geom = run.recording, run.truth.geom
        m = geom.n_cables
        if drift is None:
            drift, spread = DriftDetector(m, cfg, geom.cable_names), SpreadDetector(m, scfg, geom.cable_names)
        pred = Predictor(geom, run.truth.params)
        n = rec.t.size
        R = np.empty((n, m))
        for k in range(n):
            R[k] = pred.tick(rec.t[k], rec.motor_length[k], rec.position[k], rec.orientation[k], rec.force[k]).residual
        sim_s += w1 - w0
        kernel_s += time.perf_counter() - w1
        t = rec.t + c * chunk_s
        per_s = int(round(rate_hz))                    # one-second blocks: read the ratio after each
        for k0 in range(0, n, per_s):
            events += drift.update_batch(t[k0:k0 + per_s], R[k0:k0 + per_s], seq=ticks + k0)
            events += spread.update_batch(t[k0:k0 + per_s], R[k0:k0 + per_s], seq=ticks + k0)
            if spread.ready.all():
                ratio_max = max(ratio_max, float(np.max(spread.ratio)))
        ticks += n
        del run, rec, pred, R
        gc.collect()            # the twin's run holds reference cycles: free its arrays before the next chunk
    m = drift.n_cables
    raised = [e for e in events if e.action == "raise"]
    return {
        "setup": {"robot": robot, "scenario": "trajectory", "minutes": minutes, "rate_hz": rate_hz, "cables": m,
                  "noise_n": noise_n, "chunk_s": chunk_s, "seeds": list(range(seed, seed + n_chunks)),
                  "kernel_params": "the truth's own (nominal amplitude)"},
        "ticks": ticks,
        "cable_hours": m * total_s / 3600.0,
        "false_alarms": {code: sum(e.code == code for e in raised) for code in ("drift", "spread")},
        "spread_ratio_max": ratio_max,
        "spread_raise_ratio": scfg.raise_ratio,
        "events": [e.payload() for e in raised[:20]],
        "simulate_s": sim_s,
        "kernel_s": kernel_s,
    }


# ---- command line --------------------------------------------------------------------------

def cmd_bench_alarms(args) -> int:
    """Handler of ``cablesvc bench alarms``."""
    kw = dict(n_seeds=args.seeds, n_cables=args.cables, rate_hz=args.rate, noise_n=args.noise,
              step_n=args.step, ramp_n_per_h=args.ramp, model_error_n=args.model_error,
              model_error_tau_s=args.model_error_tau, effect_n=args.effect, period_s=args.period,
              noise_filter_hz=args.noise_filter_hz)
    if args.json:
        res = run_alarm_bench(args.seed, args.hours, **kw)
        if args.replay > 0:
            res["replay"] = run_replay_bench(args.replay, rate_hz=args.rate, seed=args.seed, noise_n=args.noise)
        print(json.dumps(res))
        return 0
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    con = Console()
    with Progress(console=con, transient=True) as prog:
        kinds = ("noise", "step", "ramp") + EFFECTS
        task = prog.add_task("alarms", total=len(kinds) * args.seeds)

        def cb(kind, j, n):
            prog.update(task, completed=len(kinds) * j + kinds.index(kind),
                        description=f"seed {args.seed + j}: {kind}")
        res = run_alarm_bench(args.seed, args.hours, progress=cb, **kw)
    su = res["setup"]
    tb = Table(title=(f"drift detector: {su['cables']} cables x {len(su['seeds'])} seeds, {su['rate_hz']:g} Hz, "
                      f"noise {su['noise_n']:g} N"
                      + (f" through a {su['noise_filter_hz']:g} Hz filter" if su['noise_filter_hz'] else "")))
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
    sp = res["spread"]
    tb = Table(title=(f"spread detector: zero-mean effects of peak {su['effect_n']:g} N over a {su['period_s']:g} s "
                      f"motion (dead time {su['dead_time_s'] * 1e3:.1f} ms of a {su['dead_time_swing_n']:g} N swing)"))
    for c in ("scenario", "raised", "delay s (med)", "delay s (max)", "spread N (med)", "drift raised",
              "false alarms"):
        tb.add_column(c, justify="right")
    for kind, e in sp["effects"].items():
        tb.add_row(kind.replace("_", " "), f"{e['detected']}/{e['of']}", f(e["delay_s"]["median"], "{:.2f}"),
                   f(e["delay_s"]["max"], "{:.2f}"), f(e["spread_at_raise_n"]["median"], "{:.3f}"),
                   f"{e['drift_raised']}/{e['of']}", f"{e['raises_before_onset']}")
    tb.add_row(f"step {su['step_n']:g} N (drift's)", f"{sp['raised_on_step']['raised']}/{sp['raised_on_step']['of']}",
               "-", "-", "-", "-", "-")
    no = sp["noise"]
    tb.add_row(f"noise {su['hours_noise_only']:g} h", "-", "-", "-", "-", "-",
               f"{no['false_alarms']} in {no['cable_hours']:g} cable-hours")
    con.print(tb)
    if args.replay > 0:
        with Progress(console=con, transient=True) as prog:
            task = prog.add_task("replay", total=1)

            def cb2(kind, j, n):
                prog.update(task, total=n, completed=j, description=f"effect-free replay: chunk {j + 1}/{n}")
            rp = run_replay_bench(args.replay, rate_hz=args.rate, seed=args.seed, noise_n=args.noise, progress=cb2)
        su2 = rp["setup"]
        con.print(f"effect-free replay ({su2['robot']} {su2['scenario']}, {su2['minutes']:g} min at "
                  f"{su2['rate_hz']:g} Hz, {rp['ticks']} ticks, {rp['cable_hours']:g} cable-hours, live kernel): "
                  f"false alarms drift {rp['false_alarms']['drift']}, spread {rp['false_alarms']['spread']}; "
                  f"largest spread / noise floor {rp['spread_ratio_max']:.3f} (raise at {rp['spread_raise_ratio']:g})")
    con.print(f"{res['samples'] / 1e6:.1f} M samples in {res['wall_s']:.1f} s "
              f"({res['samples_per_s'] / 1e6:.1f} M samples/s, data generation included)")
    return 0


def add_parser(subparsers) -> Any:
    """Register ``alarms`` on the ``cablesvc bench`` subparsers; returns the parser."""
    p = subparsers.add_parser(
        "alarms", help="drift and spread detectors: detection delay, false alarms in hours of noise",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None)
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--seeds", type=int, default=5, help="number of seeds (default 5)")
    p.add_argument("--hours", type=float, default=1.0, help="hours of noise-only data per seed (default 1)")
    p.add_argument("--cables", type=int, default=8, help="cables (default 8)")
    p.add_argument("--rate", type=float, default=1000.0, help="tick rate in Hz (default 1000)")
    p.add_argument("--noise", type=float, default=0.1, help="sensor noise std in N (default 0.1)")
    p.add_argument("--step", type=float, default=0.4, help="step offset in N (default 0.4)")
    p.add_argument("--noise-filter-hz", type=float, default=None, metavar="F",
                   help="pass the sensor noise through a first-order low-pass filter of cut-off F Hz, as a "
                        "load-cell amplifier does (its std stays --noise; default: white)")
    p.add_argument("--ramp", type=float, default=0.4, help="ramp rate in N per hour (default 0.4)")
    p.add_argument("--model-error", type=float, default=0.0,
                   help="std in N of a slowly varying zero-mean model error added to the residual (default 0)")
    p.add_argument("--model-error-tau", type=float, default=5.0,
                   help="correlation time in s of that model error (default 5)")
    p.add_argument("--effect", type=float, default=0.3,
                   help="peak of the zero-mean effects of the spread rows in N (default 0.3)")
    p.add_argument("--period", type=float, default=4.0, help="period of the motion in s (default 4)")
    p.add_argument("--replay", type=float, default=0.0, metavar="MINUTES",
                   help="also replay MINUTES of an effect-free simulated recording through the live kernel and "
                        "count the false alarms (default 0: off; 30 min at 1 kHz take several minutes)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench_alarms)
    return p
