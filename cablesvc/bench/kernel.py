"""``cablesvc bench kernel``: per-tick latency of the fixed-time kernel.

Runs N ticks of a robot with garbage collection frozen, for normal input (slow
sinusoidal elongation around the pretension, as in 002 Sec 4) and adversarial input
(direction reversal every tick, cables going slack, very large amplitudes), and
prints p50, p99, p99.9 and max per tick in microseconds, plus traced bytes allocated
per tick. The normal run is the baseline the adversarial runs are compared with, in
the same process and run.
"""

from __future__ import annotations

import gc
import time
import tracemalloc
from dataclasses import asdict, dataclass

import numpy as np

from cablesvc.config import load_robot
from cablesvc.config.params import ModelParams, default_params, load_params
from cablesvc.kernel import Predictor
from cablesvc.kinematics import inverse_kinematics

INPUTS = ("normal", "reversal", "slack", "large")


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


def make_inputs(kind: str, L: np.ndarray, x_pre: np.ndarray, ticks: int, rate: float, seed: int = 0) -> np.ndarray:
    """Motor lengths (ticks, m) [m] for one input kind, platform held at the origin."""
    t = np.arange(ticks) / rate
    m = L.size
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, m)
    if kind == "normal":
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


def run_kernel_bench(robot: str = "ipanema3", model: str = "amplitude", params_file: str | None = None,
                     ticks: int = 100_000, inputs=INPUTS, rate: float = 1000.0, progress=None) -> list[KernelBenchResult]:
    geom = load_robot(robot).geometry()
    pos = np.zeros(3)
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    L = inverse_kinematics(geom, pos[None], quat[None]).length[0]
    params: ModelParams = load_params(params_file) if params_file else default_params(geom.ea, L, model)
    x_pre = 60.0 / (geom.ea / L)              # 60 N pretension
    results = []
    for kind in inputs:
        ml_all = make_inputs(kind, L, x_pre, ticks, rate)
        pred = Predictor(geom, params)
        warm = min(1000, ticks // 10)
        for k in range(warm):
            pred.tick(k / rate, ml_all[k], pos, quat)
        # allocation per tick, traced, over a separate stretch
        n_alloc = min(10_000, ticks)
        tracemalloc.start()
        for k in range(200):
            pred.tick((warm + k) / rate, ml_all[k], pos, quat)
        base, _ = tracemalloc.get_traced_memory()
        for k in range(n_alloc):
            pred.tick((warm + 200 + k) / rate, ml_all[k % ticks], pos, quat)
        cur, _ = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        alloc_per_tick = max(cur - base, 0) / n_alloc
        # timing
        durations = np.empty(ticks, dtype=np.int64)
        t0 = (warm + 200 + n_alloc) / rate
        clock = time.perf_counter_ns
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            for k in range(ticks):
                ml = ml_all[k]
                a = clock()
                pred.tick(t0 + k / rate, ml, pos, quat)
                durations[k] = clock() - a
                if progress is not None and k % 5000 == 0:
                    progress(kind, k, ticks)
        finally:
            gc.enable()
            gc.unfreeze()
        us = durations / 1e3
        results.append(KernelBenchResult(
            robot=robot, model=params.model, input=kind, ticks=ticks,
            p50_us=float(np.percentile(us, 50)), p99_us=float(np.percentile(us, 99)),
            p999_us=float(np.percentile(us, 99.9)), max_us=float(us.max()),
            alloc_bytes_per_tick=float(alloc_per_tick)))
    return results


def as_dicts(results: list[KernelBenchResult]) -> list[dict]:
    return [asdict(r) for r in results]
