"""``cablesvc bench beam``: speed and accuracy of the hysteretic beam of paper 000.

1. ``loop_seconds``: wall time of ONE stabilised loop (7x19 rope, l = 75 mm, A = 10 mm,
   Table 4 parameters, default discretisation), median of ``--repeat`` runs after a
   warm-up (numba compilation excluded).
2. The identification of 000 Sec 6 on synthetic data: the loop of the beam with Table 4
   parameters at A = 10 mm computed on a fine discretisation, plus Gaussian noise of
   ``--noise`` x RMS(f); PSO exactly as in the paper (p = 10, q = 75, w = 0.8, c1 = 2.8,
   c2 = 1.3, Table 2 ranges, eq 25 objective) = 750 beam simulations batched 10 lanes per
   call (``pso_seconds``), then a least-squares polish (``polish_seconds``).
   ``psi_error``/``delta_error`` are relative errors of the final estimate (PSO-only ones
   under ``pso_only``), ``mse_percent`` eq 25 x 100 of the final estimate.

Targets (issue 5): PSO <= 180 s on 2 cores; |psi_error|, |delta_error| <= 2 %; MSE at or
below Table 3 of 000 (0.40-0.50 %). Exit code 1 when one is missed.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

TARGET_PSO_SECONDS = 180.0
TARGET_PARAM_ERROR = 0.02
TARGET_MSE_PERCENT = 0.40


def run_bench(*, amplitude: float = 0.010, noise: float = 0.01, seed: int = 0, repeat: int = 5,
              particles: int = 10, iterations: int = 75, progress: Any = None) -> dict:
    from cablesvc.beam.identify import identify_beam, synthetic_test
    from cablesvc.beam.solver import ROPE_7x19, TABLE4, stabilised_loop

    length = 0.075
    stabilised_loop(ROPE_7x19, length, TABLE4, amplitude)          # warm-up / compile
    ts = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        stabilised_loop(ROPE_7x19, length, TABLE4, amplitude)
        ts.append(time.perf_counter() - t0)
    test = synthetic_test(ROPE_7x19, length, TABLE4, amplitude, noise=noise, seed=seed)
    res = identify_beam(test, particles=particles, iterations=iterations, seed=seed, progress=progress)
    p = res["pso"]
    return {
        "loop_seconds": float(np.median(ts)),
        "loop_seconds_all": [float(v) for v in ts],
        "pso_seconds": float(p["seconds"]),
        "pso_simulations": int(p["nsim"]),
        "polish_seconds": float(res["polish_seconds"]),
        "polish_simulations": int(res["polish_nsim"]),
        "psi_error": float(res["rel_error"]["psi"]),
        "delta_error": float(res["rel_error"]["delta"]),
        "mse_percent": float(res["mse_percent"]),
        "pso_only": {"psi_error": float(p["rel_error"]["psi"]), "delta_error": float(p["rel_error"]["delta"]),
                     "mse_percent": float(p["mse_percent"])},
        "noise_floor_percent": float(100.0 * np.mean((test.f - test.info["f_clean"]) ** 2) / np.var(test.f)),
        "estimate": {k: float(v) for k, v in zip(("psi", "delta", "gamma", "beta", "n"), res.x)},
        "truth": {k: float(v) for k, v in zip(("psi", "delta", "gamma", "beta", "n"), TABLE4.as_array())},
        "amplitude_m": amplitude, "noise": noise, "seed": seed,
        "targets": {"pso_seconds": TARGET_PSO_SECONDS, "param_error": TARGET_PARAM_ERROR,
                    "mse_percent": TARGET_MSE_PERCENT},
    }


def passed(r: dict) -> bool:
    return (r["pso_seconds"] <= TARGET_PSO_SECONDS and abs(r["psi_error"]) <= TARGET_PARAM_ERROR
            and abs(r["delta_error"]) <= TARGET_PARAM_ERROR and r["mse_percent"] <= TARGET_MSE_PERCENT)


def cmd_bench_beam(args: argparse.Namespace) -> int:
    if args.json:
        r = run_bench(amplitude=args.amplitude, noise=args.noise, seed=args.seed, repeat=args.repeat)
        print(json.dumps(r))
        return 0 if passed(r) else 1
    from rich.console import Console
    from rich.progress import Progress
    con = Console()
    with Progress(console=con, transient=True) as prog:
        r = run_bench(amplitude=args.amplitude, noise=args.noise, seed=args.seed, repeat=args.repeat, progress=prog)
    ok = passed(r)
    con.print(f"one stabilised loop (7x19, l = 75 mm, A = {1e3 * r['amplitude_m']:g} mm): "
              f"{r['loop_seconds']:.3f} s (median of {len(r['loop_seconds_all'])})")
    con.print(f"PSO p = 10, q = 75 ({r['pso_simulations']} beam simulations): {r['pso_seconds']:.1f} s "
              f"(target <= {TARGET_PSO_SECONDS:g} s)")
    con.print(f"  PSO only : psi error {100 * r['pso_only']['psi_error']:+.2f} %, delta error "
              f"{100 * r['pso_only']['delta_error']:+.2f} %, MSE {r['pso_only']['mse_percent']:.4f} %")
    con.print(f"least-squares polish ({r['polish_simulations']} simulations): {r['polish_seconds']:.1f} s")
    con.print(f"  final    : psi error {100 * r['psi_error']:+.2f} %, delta error {100 * r['delta_error']:+.2f} %, "
              f"MSE {r['mse_percent']:.4f} % (noise floor {r['noise_floor_percent']:.4f} %, Table 3: 0.40-0.50 %)")
    con.print("PASS" if ok else "FAIL")
    return 0 if ok else 1


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``beam`` on the ``cablesvc bench`` sub-parsers."""
    p = subparsers.add_parser("beam", help="hysteretic beam of 000: loop time, PSO identification (750 simulations)",
                              description=__doc__.split("\n\n")[1] if __doc__ else None)
    p.add_argument("--amplitude", type=float, default=0.010, help="test amplitude in m (default 0.010)")
    p.add_argument("--noise", type=float, default=0.01, help="noise std as a fraction of RMS(f) (default 0.01)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat", type=int, default=5, help="loop timings (median reported)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_bench_beam)
    return p
