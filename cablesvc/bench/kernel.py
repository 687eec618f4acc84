"""``cablesvc bench kernel``: per-tick latency of the fixed-time kernel.

Runs N ticks of a robot with garbage collection frozen, for normal input (slow
sinusoidal elongation around the pretension, as in 002 Sec 4), adversarial input
(direction reversal every tick, cables going slack, very large amplitudes) and the normal
input without a pose (``no_pose``: the path of a bus that carries motor lengths only, where
the elasto-static forward kinematics finds the pose every tick), and
prints p50, p99, p99.9 and max per tick in microseconds, plus traced bytes allocated
per tick. The normal run is the baseline the adversarial runs are compared with, in
the same process and run. The ``terms`` runs put every library term and the baseline
recalibration on every cable (:func:`all_terms_params`) on the normal input, on the slack
input (sag near slack) and without a temperature channel; their ``kernel_p50_ratio`` is
their p50 over the p50 of the same kernel without terms on the same input, timed in blocks
of 500 ticks that alternate with the term run (``plain_p50_us``; issue 16). Alternating
matters here: on the shared development machine the plain kernel's p50 moved between 55
and 110 us from one run to the next a minute later, so a ratio against a separate run
moved by 2 x with it.

A second baseline, ``input = "machine"``, says what this machine's timer and scheduler
allow: a fixed workload of ``calls`` numpy additions on 8-element arrays (the kind of
work the kernel is made of, with no data dependence at all), sized at start so that its
median equals the kernel's, is timed in blocks of 500 alternating with the normal
kernel run (close in time, without disturbing the kernel's caches every tick). Its p99 is the p99 that any workload of the kernel's length gets here; the kernel
cannot be expected to beat it. ``cpu`` pins the process to one CPU and ``realtime`` asks
for SCHED_FIFO priority, the settings deploy/README.md recommends for production.
"""

from __future__ import annotations

import errno
import gc
import os
import time
import tracemalloc
from dataclasses import asdict, dataclass

import numpy as np

import cablesvc
from cablesvc.config import load_robot
from cablesvc.config.params import ModelParams, home_lengths, load_params, nominal_params
from cablesvc.kernel import Predictor
from cablesvc.models import ModelParameterError

INPUTS = ("normal", "reversal", "slack", "large", "no_pose", "terms", "terms_slack", "terms_no_temperature")
#: the runs with every library term (and the baseline recalibration) on every cable, on
#: the input named after the prefix (issue 16: ``kernel_p50_ratio`` = terms p50 / plain p50, alternating)
TERM_INPUTS = {"terms": "normal", "terms_slack": "slack", "terms_no_temperature": "normal"}
#: where the kernel's memory is allocated: tracemalloc sees every thread, and the progress
#: bar's refresh thread must not count as the kernel's
_KERNEL_FILES = tuple(tracemalloc.Filter(True, os.path.join(os.path.dirname(mod.__file__), "*"))
                      for mod in (cablesvc, np))
#: the machine baseline alternates with the kernel in blocks of this many ticks: close in
#: time (same machine conditions) without evicting the kernel's caches every tick
BLOCK = 500
#: ticks run before the traced allocation stretch (at most; fewer for short runs)
ALLOC_WARMUP = 200


class BenchArgumentError(ModelParameterError):
    """A bad argument of ``bench kernel`` (ticks, model): a one-line message naming the option.

    A ModelParameterError (a cablesvc.errors.ModelError and a ValueError), so the CLI prints
    it as one line; exit status 2, like argparse (cablesvc.cli.failures.exit_status)."""

    exit_status = 2


@dataclass
class KernelBenchResult:
    robot: str
    model: str
    input: str
    ticks: int
    p50_us: float
    p99_us: float
    p999_us: float
    max_us: float
    alloc_bytes_per_tick: float
    calls: int | None = None          # machine baseline only: numpy calls per "tick"
    scheduling: str = "default"
    kernel_p50_ratio: float | None = None   # terms runs: p50 / the plain kernel's p50, interleaved
    plain_p50_us: float | None = None       # terms runs: p50 of the plain kernel in the alternate blocks


def _fixed_work(n: int, a: np.ndarray = np.ones(8), b: np.ndarray = np.zeros(8)) -> None:
    add = np.add
    for _ in range(n):
        add(a, b, b)


def calibrate_calls(target_us: float, *, probes: int = 2000) -> int:
    """Number of 8-element numpy additions whose median time is ``target_us``."""
    clock = time.perf_counter_ns
    ts = np.empty(probes)
    for i in range(probes):
        a = clock()
        _fixed_work(20)
        ts[i] = clock() - a
    per_call = float(np.median(ts)) / 1e3 / 20
    return max(1, int(round(target_us / per_call)))


def set_scheduling(cpu: int | None, realtime: bool) -> str:
    """Pin to ``cpu`` and/or switch to SCHED_FIFO 50; returns a description. Raises
    OSError with the reason when the system refuses."""
    import os

    parts = []
    if cpu is not None:
        ncpu = os.cpu_count() or 1
        if not 0 <= int(cpu) < ncpu:
            raise OSError(errno.EINVAL, f"no CPU {cpu} on this machine (CPUs are 0..{ncpu - 1})")
        os.sched_setaffinity(0, {int(cpu)})
        parts.append(f"pinned to CPU {cpu}")
    if realtime:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
        parts.append("SCHED_FIFO 50")
    return ", ".join(parts) or "default"


def make_inputs(kind: str, L: np.ndarray, x_pre: np.ndarray, ticks: int, rate: float, seed: int = 0) -> np.ndarray:
    """Motor lengths (ticks, m) [m] for one input kind, platform held at the origin."""
    t = np.arange(ticks) / rate
    m = L.size
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, m)
    if kind in ("normal", "no_pose"):
        x = x_pre + 5e-4 * np.sin(2 * np.pi * 0.5 * t[:, None] + phase)
    elif kind == "reversal":          # direction of every cable flips every tick
        x = x_pre + 2e-4 * np.where(np.arange(ticks)[:, None] % 2 == 0, 1.0, -1.0) * np.ones(m)
    elif kind == "slack":             # cables run in and out of slack
        x = x_pre * (0.5 + 1.5 * np.sin(2 * np.pi * 2.0 * t[:, None] + phase))
    elif kind == "large":             # amplitudes 100x the identified range, random jumps
        x = x_pre + 0.05 * np.sin(2 * np.pi * 1.0 * t[:, None] + phase) + rng.normal(0, 1e-3, (ticks, m))
    else:
        raise ValueError(f"unknown input kind {kind!r}; one of {INPUTS}")
    return L[None, :] - x


def all_terms_params(params: ModelParams, m: int) -> ModelParams:
    """``params`` with every library term and the baseline recalibration on every cable, at
    values of the size discovery fits (dead time 50 ms, sag q = 10 N^3/m^3, ...): the
    heaviest term load a parameter file can ask of the kernel."""
    from cablesvc.models.terms import LIBRARY, Recalibration, term_class
    value = {"v_s": 1e-3, "tau": 0.05, "q": 10.0, "beta": 2000.0, "gamma": 500.0, "x_scale": 1e-3,
             "alpha_mean": 1.0, "T_mean": 20.0, "k": 1e5, "mu": 0.005, "c_v": 50.0}
    ident = dict(params.identification)
    ident["discovered_terms"] = list(LIBRARY)
    for name in [*LIBRARY, Recalibration.name]:
        t = term_class(name)
        ident[f"term_{name}"] = {k: [value.get(k, 0.01)] * m for k in t.params + t.hypers + t.ref_names}
    return ModelParams(model=params.model, params=dict(params.params), options=dict(params.options),
                       tables=dict(params.tables), robot=params.robot, identification=ident,
                       source=f"{params.source} + every term")


def run_kernel_bench(robot: str = "ipanema3", model: str = "amplitude", params_file: str | None = None,
                     ticks: int = 100_000, inputs=INPUTS, rate: float = 1000.0, progress=None,
                     machine_baseline: bool = True, cpu: int | None = None,
                     realtime: bool = False) -> list[KernelBenchResult]:
    """Run the benchmark; raises :class:`BenchArgumentError` for ticks < 1 or a model
    without nominal parameters, OSError when the scheduling asked for is refused."""
    if isinstance(ticks, bool) or not isinstance(ticks, (int, np.integer)) or ticks < 1:
        raise BenchArgumentError(f"--ticks must be a positive integer, got {ticks!r}")
    ticks = int(ticks)
    geom = load_robot(robot).geometry()
    pos = np.zeros(3)
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    L = home_lengths(geom)
    if params_file:
        params: ModelParams = load_params(params_file)
    else:
        try:
            params = nominal_params(geom, model)
        except ModelParameterError:
            raise
        except ValueError as e:
            raise BenchArgumentError(f"--model {model}: {e}") from None
    x_pre = 60.0 / (geom.ea / L)              # 60 N pretension
    sched = set_scheduling(cpu, realtime)
    results = []
    baseline: KernelBenchResult | None = None
    for kind in inputs:
        ml_all = make_inputs(TERM_INPUTS.get(kind, kind), L, x_pre, ticks, rate)
        pred = Predictor(geom, all_terms_params(params, geom.n_cables) if kind in TERM_INPUTS else params)
        p_in, q_in = (None, None) if kind == "no_pose" else (pos, quat)   # no_pose: the FK path
        # the temperature channel: present (20 deg C) except where the run is about its absence
        temp = None if kind == "terms_no_temperature" else 20.0
        # the term rows warm up longer: numpy fills small internal caches over the first
        # ~2000 ticks of the terms' calls (about 50 KB once, then nothing), which is not
        # memory kept per tick
        warm = max(min(1000, ticks // 10), 3000 if kind in TERM_INPUTS else 0)
        for k in range(warm):
            pred.tick(k / rate, ml_all[k % ticks], p_in, q_in, None, temp)
        # a term run is compared with the same kernel without terms on the same input, timed
        # in blocks that alternate with it: both see the same machine conditions (this shared
        # machine's speed drifts by 2 x between runs a minute apart)
        plain = Predictor(geom, params) if kind in TERM_INPUTS else None
        if plain is not None:
            for k in range(warm):
                plain.tick(k / rate, ml_all[k % ticks], p_in, q_in, None, temp)
        # allocation per tick, traced, over a separate stretch
        n_alloc = min(10_000, ticks)
        n_pre = min(ALLOC_WARMUP, ticks)      # sized to the run: short runs have fewer inputs
        tracemalloc.start()
        for k in range(n_pre):
            pred.tick((warm + k) / rate, ml_all[k], p_in, q_in, None, temp)
        # a full collection before each snapshot empties the interpreter's free lists (the
        # small floats and tuples it keeps for reuse): how full they happen to be depends on
        # everything the process did before (even which modules it imported), and made the
        # figure swing by ~100 B over the stretch; what is left counts what the kernel keeps
        gc.collect()
        before = tracemalloc.take_snapshot().filter_traces(_KERNEL_FILES)
        for k in range(n_alloc):
            pred.tick((warm + n_pre + k) / rate, ml_all[k % ticks], p_in, q_in, None, temp)
        gc.collect()
        after = tracemalloc.take_snapshot().filter_traces(_KERNEL_FILES)
        tracemalloc.stop()
        grown = sum(st.size_diff for st in after.compare_to(before, "filename"))
        alloc_per_tick = max(grown, 0) / n_alloc
        # timing
        durations = np.empty(ticks, dtype=np.int64)
        t0 = (warm + n_pre + n_alloc) / rate
        clock = time.perf_counter_ns
        paired = machine_baseline and baseline is None and kind == "normal"
        block = min(BLOCK, ticks)             # a run shorter than a block is one block
        calls = 0
        if paired:
            probe = np.empty(2000)
            for k in range(probe.size):
                a = clock()
                pred.tick(t0 + k / rate, ml_all[k % ticks], p_in, q_in, None, temp)
                probe[k] = clock() - a
            calls = calibrate_calls(float(np.median(probe)) / 1e3)
            base_d = np.empty(ticks - ticks % block, dtype=np.int64)
            t0 += probe.size / rate
        plain_d = np.empty(ticks - ticks % block, dtype=np.int64) if plain is not None else None
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            for k in range(ticks):
                ml = ml_all[k]
                a = clock()
                pred.tick(t0 + k / rate, ml, p_in, q_in, None, temp)
                durations[k] = clock() - a
                if paired and k % block == block - 1:   # a block of baseline "ticks" after each block
                    for j in range(k - block + 1, k + 1):
                        a = clock()
                        _fixed_work(calls)
                        base_d[j] = clock() - a
                if plain_d is not None and k % block == block - 1:   # the plain kernel, same ticks
                    for j in range(k - block + 1, k + 1):
                        a = clock()
                        plain.tick(t0 + j / rate, ml_all[j], p_in, q_in, None, temp)
                        plain_d[j] = clock() - a
                if progress is not None and k % 5000 == 0:
                    progress(kind, k, ticks)
        finally:
            gc.enable()
            gc.unfreeze()
        if paired:
            bu = base_d / 1e3
            baseline = KernelBenchResult(
                robot=robot, model="none", input="machine", ticks=ticks,
                p50_us=float(np.percentile(bu, 50)), p99_us=float(np.percentile(bu, 99)),
                p999_us=float(np.percentile(bu, 99.9)), max_us=float(bu.max()), alloc_bytes_per_tick=0.0,
                calls=calls, scheduling=sched)
        us = durations / 1e3
        p50 = float(np.percentile(us, 50))
        plain_p50 = float(np.percentile(plain_d / 1e3, 50)) if plain_d is not None else None
        results.append(KernelBenchResult(
            robot=robot, model=params.model, input=kind, ticks=ticks,
            p50_us=p50, p99_us=float(np.percentile(us, 99)),
            p999_us=float(np.percentile(us, 99.9)), max_us=float(us.max()),
            alloc_bytes_per_tick=float(alloc_per_tick), scheduling=sched,
            kernel_p50_ratio=(p50 / plain_p50 if plain_p50 else None),
            plain_p50_us=plain_p50))
    if baseline is not None:
        results.append(baseline)
    return results


def as_dicts(results: list[KernelBenchResult]) -> list[dict]:
    """The issue's keys for kernel runs (plus ``scheduling`` when not the default); the
    machine baseline adds ``calls`` and ``scheduling``."""
    out = []
    for r in results:
        d = asdict(r)
        if r.kernel_p50_ratio is None:
            del d["kernel_p50_ratio"]
        if r.plain_p50_us is None:
            del d["plain_p50_us"]
        if r.calls is None:
            del d["calls"]
            if r.scheduling == "default":
                del d["scheduling"]
        out.append(d)
    return out
