"""``cablesvc bench beam``: speed and accuracy of the hysteretic beam of paper 000.

1. ``loop_seconds``: wall time of ONE stabilised loop (7x19 rope, l = 75 mm, A = 10 mm,
   Table 4 parameters, default discretisation), median of ``--repeat`` runs after a
   warm-up (numba compilation excluded).
2. The identification of 000 Sec 6 on synthetic data, on the paper's test protocol: the
   loops of the beam with Table 4 parameters at A = 5, 10, 15, 20 mm (``--amplitudes``)
   computed on a fine discretisation, sampled ``--samples-per-cycle`` times per loop
   (default 2400: a 240 Hz load cell at the paper's 0.1 Hz), each plus Gaussian noise of
   ``--noise`` x RMS(f);
   eq 25 = mean of the per-loop eq-25 values. PSO as in the paper (p = 10, q = 75,
   w = 0.8, c1 = 2.8, c2 = 1.3, Table 2 ranges) in the ``--coords`` search coordinates of
   the Table 2 box (default ``valley``, see ``cablesvc.beam.identify.BoxMap``):
   (75 + 1) x 10 particles x 4 loops = 3040 beam simulations, 40 lanes per call
   (``pso_seconds``), then a least-squares polish (``polish_seconds``).
   ``psi_error``/``delta_error``/``mse_percent`` are those of the final (polished)
   estimate (``errors_are`` says so); the PSO-only ones are under ``pso_only``.

Diagnostics, computed after the identification (which never sees the truth):
``truth_mse_percent`` (eq 25 at the truth on the same data) and ``optimisation_ok`` (final
MSE at or below it: the optimiser found the least-squares minimum); ``psi_stderr``,
``delta_stderr``, ``rel_stderr``, ``psi_delta_correlation`` (polish Jacobian at the
estimate), ``product_error``/``product_stderr`` (psi delta = EJ_e / EJ) and
``within_2_stderr``. At 1 % noise and 2400 samples per loop the standard errors of psi
and delta are 0.83-0.89 %; with 241 samples (the model's own load steps) they were
2.3-3.1 % and the 2 % target failed for some noise realisations (docs/beam.md).

Targets (issue 5): PSO <= 180 s on 2 cores; |psi_error|, |delta_error| <= 2 %; MSE at or
below Table 3 of 000 (0.40-0.50 %). Exit code 1 when one is missed by the final estimate;
``passed`` and ``pso_only.passed`` in the JSON say which.
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
PROTOCOL_MM = (0.005, 0.010, 0.015, 0.020)        # m: the paper's amplitudes 5, 10, 15, 20 mm
DEFAULT_COORDS = "valley"
#: force samples per loop in the synthetic data: a load cell read at 240 Hz over the
#: paper's 10 s cycle (0.1 Hz); the model runs 240 load steps per cycle and is read at the
#: samples by cubic interpolation in time (beam.identify.cubic_resampling)
SAMPLES_PER_CYCLE = 2400
NAMES = ("psi", "delta", "gamma", "beta", "n")


def run_bench(*, amplitudes: Any = PROTOCOL_MM, noise: float = 0.01, seed: int = 0, repeat: int = 5,
              particles: int = 10, iterations: int = 75, coords: str = DEFAULT_COORDS, polish: bool = True,
              samples_per_cycle: int = SAMPLES_PER_CYCLE, progress: Any = None) -> dict:
    """``amplitudes`` in m (a float or a sequence); all loops are one test set, eq 25 is
    the mean of the per-loop eq-25 values. ``samples_per_cycle``: force samples per loop
    in the data (a multiple of the model's 240 load steps per cycle)."""
    from cablesvc.beam.identify import LoopObjective, identify_beam, protocol_tests
    from cablesvc.beam.solver import ROPE_7x19, TABLE4, stabilised_loop

    amps = [float(a) for a in np.atleast_1d(amplitudes)]
    length = 0.075
    stabilised_loop(ROPE_7x19, length, TABLE4, 0.010)              # warm-up / compile
    ts = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        stabilised_loop(ROPE_7x19, length, TABLE4, 0.010)
        ts.append(time.perf_counter() - t0)
    tests = protocol_tests(ROPE_7x19, length, TABLE4, amps, noise=noise, seed=seed, steps_per_cycle=samples_per_cycle)
    res = identify_beam(tests, particles=particles, iterations=iterations, seed=seed, progress=progress,
                        coords=coords, polish=polish)
    p = res["pso"] if polish else res
    # diagnostics, computed AFTER the identification (which never sees the truth): eq 25 at
    # the truth on the same noisy data and objective. An estimate at or below it means the
    # optimiser did its job and the remaining error is the data's (noise), not the search's.
    of_truth = float(LoopObjective(tests)(TABLE4.as_array()[None, :5])[0])
    floor = float(np.mean([100.0 * np.mean((te.f - te.info["f_clean"]) ** 2) / np.var(te.f) for te in tests]))
    pso_only = {"psi_error": float(p["rel_error"]["psi"]), "delta_error": float(p["rel_error"]["delta"]),
                "mse_percent": float(p["mse_percent"]),
                "estimate": {k: float(v) for k, v in zip(NAMES, p.x)},
                "rel_error": {k: float(v) for k, v in p["rel_error"].items()}}
    return {
        "loop_seconds": float(np.median(ts)),
        "loop_seconds_all": [float(v) for v in ts],
        "pso_seconds": float(p["seconds"]),
        "pso_simulations": int(p["nsim"]),
        "polish_seconds": float(res.get("polish_seconds", 0.0)),
        "polish_simulations": int(res.get("polish_nsim", 0)),
        "errors_are": "after the least-squares polish; PSO-only errors under pso_only" if polish
                      else "PSO only (no polish)",
        "psi_error": float(res["rel_error"]["psi"]),
        "delta_error": float(res["rel_error"]["delta"]),
        "mse_percent": float(res["mse_percent"]),
        "pso_only": pso_only,
        "objective": "eq 25 of 000, mean over the loops of the test set",
        "coords": coords,
        "noise_floor_percent": floor,
        "truth_mse_percent": 100.0 * of_truth,
        "optimisation_ok": bool(res["mse_percent"] <= 100.0 * of_truth),
        "product_error": float(res.x[0] * res.x[1] / (TABLE4.psi * TABLE4.delta) - 1.0),
        **_statistics(res),
        "estimate": {k: float(v) for k, v in zip(NAMES, res.x)},
        "rel_error": {k: float(v) for k, v in res["rel_error"].items()},
        "truth": {k: float(v) for k, v in zip(NAMES, TABLE4.as_array())},
        "amplitudes_m": amps, "noise": noise, "seed": seed, "samples_per_cycle": int(samples_per_cycle),
        "targets": {"pso_seconds": TARGET_PSO_SECONDS, "param_error": TARGET_PARAM_ERROR,
                    "mse_percent": TARGET_MSE_PERCENT},
    }


def _statistics(res: Any) -> dict:
    """Relative standard errors of psi, delta and psi delta from the polish's Jacobian
    (cov = s^2 (J^T J)^-1 at the estimate), their correlation, and whether the errors are
    within 2 standard errors. Empty without a polish."""
    cov = res.get("covariance")
    if cov is None or "rel_stderr" not in res:
        return {}
    x = np.asarray(res.get("polish_x", res.x), float)
    cov = np.asarray(cov, float)
    rs = res["rel_stderr"]
    corr = float(np.asarray(res["correlation"])[0, 1])
    # var(ln psi + ln delta) = var(ln psi) + var(ln delta) + 2 cov(ln psi, ln delta)
    prod = float(np.sqrt(max(cov[0, 0] / x[0] ** 2 + cov[1, 1] / x[1] ** 2 + 2 * cov[0, 1] / (x[0] * x[1]), 0.0)))
    e = res["rel_error"]
    return {"psi_stderr": float(rs["psi"]), "delta_stderr": float(rs["delta"]), "psi_delta_correlation": corr,
            "product_stderr": prod, "rel_stderr": {k: float(v) for k, v in rs.items()},
            "within_2_stderr": bool(abs(e["psi"]) <= 2 * rs["psi"] and abs(e["delta"]) <= 2 * rs["delta"])}


def passed(r: dict, pso_only: bool = False) -> bool:
    """All targets met; with ``pso_only`` the errors of the PSO alone are checked."""
    e = r["pso_only"] if pso_only else r
    return (r["pso_seconds"] <= TARGET_PSO_SECONDS and abs(e["psi_error"]) <= TARGET_PARAM_ERROR
            and abs(e["delta_error"]) <= TARGET_PARAM_ERROR and e["mse_percent"] <= TARGET_MSE_PERCENT)


def _amps(text: str) -> list[float]:
    return [1e-3 * float(v) for v in text.split(",") if v.strip()]


def cmd_bench_beam(args: argparse.Namespace) -> int:
    kw = dict(amplitudes=_amps(args.amplitudes), noise=args.noise, seed=args.seed, repeat=args.repeat,
              coords=args.coords, samples_per_cycle=args.samples_per_cycle)
    if args.json:
        r = run_bench(**kw)
        r["passed"] = passed(r)
        r["pso_only"]["passed"] = passed(r, pso_only=True)
        print(json.dumps(r))
        return 0 if r["passed"] else 1
    from rich.console import Console
    from rich.progress import Progress
    con = Console()
    with Progress(console=con, transient=True) as prog:
        r = run_bench(progress=prog, **kw)
    ok = passed(r)
    amps = ", ".join(f"{1e3 * a:g}" for a in r["amplitudes_m"])
    con.print(f"one stabilised loop (7x19, l = 75 mm, A = 10 mm): "
              f"{r['loop_seconds']:.3f} s (median of {len(r['loop_seconds_all'])})")
    con.print(f"test set: loops at A = {amps} mm, {r['samples_per_cycle']} samples per loop, noise "
              f"{100 * r['noise']:g} % RMS; eq 25 = mean over loops; "
              f"PSO coordinates: {r['coords']}")
    con.print(f"PSO p = 10, q = 75 ({r['pso_simulations']} beam simulations): {r['pso_seconds']:.1f} s "
              f"(target <= {TARGET_PSO_SECONDS:g} s)")
    con.print(f"  PSO only : psi error {100 * r['pso_only']['psi_error']:+.2f} %, delta error "
              f"{100 * r['pso_only']['delta_error']:+.2f} %, MSE {r['pso_only']['mse_percent']:.4f} % "
              f"({'PASS' if passed(r, True) else 'FAIL'})")
    con.print(f"least-squares polish ({r['polish_simulations']} simulations): {r['polish_seconds']:.1f} s")
    con.print(f"  final    : psi error {100 * r['psi_error']:+.2f} %, delta error {100 * r['delta_error']:+.2f} %, "
              f"MSE {r['mse_percent']:.4f} % (noise floor {r['noise_floor_percent']:.4f} %, Table 3: 0.40-0.50 %)")
    if "psi_stderr" in r:
        con.print(f"  noise-limited accuracy (Jacobian at the estimate): psi +/- {100 * r['psi_stderr']:.2f} %, "
                  f"delta +/- {100 * r['delta_stderr']:.2f} % (correlation {r['psi_delta_correlation']:+.3f}); "
                  f"psi delta error {100 * r['product_error']:+.2f} % +/- {100 * r['product_stderr']:.2f} %")
    con.print(f"  eq 25 at the truth on the same data: {r['truth_mse_percent']:.4f} % "
              + ("(estimate at or below it: optimisation OK)" if r["optimisation_ok"]
                 else "(estimate ABOVE it: optimisation short)"))
    con.print("PASS" if ok else "FAIL")
    return 0 if ok else 1


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``beam`` on the ``cablesvc bench`` sub-parsers."""
    p = subparsers.add_parser("beam", help="hysteretic beam of 000: loop time, PSO identification (p = 10, q = 75)",
                              description=__doc__.split("\n\n")[1] if __doc__ else None)
    p.add_argument("--amplitudes", default=",".join(f"{1e3 * a:g}" for a in PROTOCOL_MM),
                   help="test amplitudes in mm, comma separated (default 5,10,15,20: the paper's protocol)")
    p.add_argument("--noise", type=float, default=0.01, help="noise std as a fraction of RMS(f) (default 0.01)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--samples-per-cycle", type=int, default=SAMPLES_PER_CYCLE,
                   help=f"force samples per loop in the synthetic data, a multiple of 240 (default "
                        f"{SAMPLES_PER_CYCLE}: a 240 Hz load cell over the paper's 10 s cycle)")
    p.add_argument("--repeat", type=int, default=5, help="loop timings (median reported)")
    p.add_argument("--coords", choices=("linear", "valley"), default=DEFAULT_COORDS,
                   help=f"PSO search coordinates on the Table 2 box (default {DEFAULT_COORDS})")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_bench_beam)
    return p
