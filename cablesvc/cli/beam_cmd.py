"""``cablesvc beam simulate|identify|paper|bridge``: the hysteretic beam of paper 000.

* ``simulate``: stabilised loops of the flexural test (eqs 28-29) for a rope, length and
  amplitudes; writes ``loops.csv`` (and ``loops.png`` with ``--plot``) into ``--out``.
* ``identify``: PSO of 000 Sec 5 (p = 10, q = 75, Table 2 ranges, eq 25) then a
  least-squares polish, on a CSV loop (columns t, x, f in s, m, N, one stabilised
  period sampled at steps_per_cycle + 1 instants) or, with ``--synthetic``, on the
  beam's own loop plus noise; progress bar and a report.
* ``paper``: all loops of 000 Sec 6 and Figs 6-7 as PNG files.
* ``bridge``: fits the lumped Bouc-Wen cable model to the beam's loops and writes a
  parameter file for ``cablesvc run --params``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

# a bad argument or input file is a UsageError: one line, ``cablesvc beam <action>: ...``, exit code 2
# (printed by cablesvc.cli.failures.run_command; this module's docstring is the command's --help)
from cablesvc.cli.failures import UsageError
from cablesvc.cli.paths import dir_problem, file_problem

ROPES = {"7x19": "ROPE_7x19", "7x7": "ROPE_7x7"}


def _arg_type(convert, bound: str = "", ok=lambda v: True):
    """An argparse type: ``convert(text)``, finite and ``ok``; ``bound`` words the range in
    the error (argparse names the option)."""
    noun, must = ("an integer", "an integer") if convert is int else ("a number", "a finite number")

    def parse(text: str):
        try:
            v = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}{bound}, got {text!r}") from None
        if not (math.isfinite(v) and ok(v)):
            raise argparse.ArgumentTypeError(f"must be {must}{bound}, got {text!r}")
        return v
    return parse


_positive_float = _arg_type(float, " > 0", lambda v: v > 0)
_nonnegative_float = _arg_type(float, " >= 0", lambda v: v >= 0)
_positive_int = _arg_type(int, " >= 1", lambda v: v >= 1)
_finite_float = _arg_type(float)


def _rope(name: str):
    from cablesvc.beam import solver
    return getattr(solver, ROPES[name])


def _params(args: argparse.Namespace):
    from cablesvc.beam.solver import TABLE4, TABLE6, BeamParams
    base = TABLE4 if args.rope == "7x19" else TABLE6
    vals = base.as_array()
    for i, k in enumerate(("psi", "delta", "gamma", "beta", "n", "k3")):
        v = getattr(args, k, None)
        if v is not None:
            vals[i] = v
    return BeamParams.from_array(vals)


def _options(args: argparse.Namespace):
    from cablesvc.beam.solver import SolverOptions
    return SolverOptions(n_elements=args.elements, steps_per_cycle=args.steps, cycles=args.cycles)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rope", choices=sorted(ROPES), default="7x19", help="rope section (default 7x19, d = 10 mm)")
    p.add_argument("--length", type=_positive_float, default=None, help="length in mm (default 75 for 7x19, 100 for 7x7)")
    for k, u in (("psi", "-"), ("delta", "-"), ("gamma", "N^(1-n) m^(2-n)"), ("beta", "N^(1-n) m^(2-n)"),
                 ("n", "-"), ("k3", "N m^3")):
        p.add_argument(f"--{k}", type=_finite_float, default=None, help=f"{k} [{u}] (default: Table 4 / Table 6 of 000)")
    p.add_argument("--elements", type=_positive_int, default=24, help="two-node elements (default 24)")
    p.add_argument("--steps", type=_positive_int, default=240, help="load steps per period (default 240)")
    p.add_argument("--cycles", type=_positive_int, default=2, help="periods simulated, last one reported (default 2)")


def _size_problem(args: argparse.Namespace, lanes: int) -> str | None:
    """Why the run cannot fit in memory (``--steps`` x ``--cycles`` x ``--elements`` for
    ``lanes`` loops solved together; cablesvc.limits), or None: checked before the
    solver allocates anything."""
    from cablesvc.limits import beam_bytes, memory_problem

    return memory_problem(f"--steps {args.steps} x --cycles {args.cycles} x --elements {args.elements} "
                          f"for {lanes} loop(s)", beam_bytes(lanes, args.steps, args.cycles, args.elements))


def _length(args) -> float:
    return 1e-3 * (args.length if args.length is not None else (75.0 if args.rope == "7x19" else 100.0))


def cmd_simulate(args: argparse.Namespace) -> int:
    from cablesvc.beam.paper import hardening_ratio
    from cablesvc.beam.solver import stabilised_loop
    if args.out and (why := dir_problem(args.out)):
        raise UsageError(f"--out {args.out}: {why}")
    A = np.array([1e-3 * float(a) for a in args.amplitude])
    if why := _size_problem(args, A.size):
        raise UsageError(why)
    sec, length, par = _rope(args.rope), _length(args), _params(args)
    lp = stabilised_loop(sec, length, par, A, options=_options(args))
    rows = [{"amplitude_mm": 1e3 * a, "f_max_N": float(np.max(lp.f[i])), "f_min_N": float(np.min(lp.f[i])),
             "area_J": float(lp.area()[i]), "hardening_ratio": hardening_ratio(lp.x[i], lp.f[i]),
             "status": int(lp.status[i])} for i, a in enumerate(A)]
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        cols = ["t_s"] + [f"x_A{1e3 * a:g}mm_m,f_A{1e3 * a:g}mm_N" for a in A]
        data = np.column_stack([lp.t] + [np.column_stack([lp.x[i], lp.f[i]]) for i in range(A.size)])
        np.savetxt(out / "loops.csv", data, delimiter=",", header=",".join(cols), comments="")
        if args.plot:
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
            fig, ax = plt.subplots(figsize=(6, 4.5))
            for i in range(A.size):
                ax.plot(1e3 * lp.x[i], lp.f[i], label=f"A = {1e3 * A[i]:g} mm")
            ax.set_xlabel("x [mm]")
            ax.set_ylabel("f [N]")
            ax.legend()
            ax.grid(True, alpha=0.3)
            fig.tight_layout()
            fig.savefig(out / "loops.png", dpi=110)
            plt.close(fig)
    if args.json:
        print(json.dumps({"rope": args.rope, "length_m": length, "params": par.__dict__, "loops": rows}))
    else:
        print(f"{args.rope} rope, l = {1e3 * length:g} mm, psi={par.psi} delta={par.delta} gamma={par.gamma} "
              f"beta={par.beta} n={par.n} k3={par.k3}")
        for r in rows:
            print(f"  A = {r['amplitude_mm']:5.1f} mm: f in [{r['f_min_N']:.2f}, {r['f_max_N']:.2f}] N, loop area "
                  f"{r['area_J']:.4f} J, hardening ratio {r['hardening_ratio']:.3f}"
                  + ("" if r["status"] == 0 else f"  FAILED at step {r['status']}"))
        if args.out:
            print(f"wrote {Path(args.out) / 'loops.csv'}")
    return 0 if all(r["status"] == 0 for r in rows) else 1


def cmd_identify(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table
    from cablesvc.beam.identify import BeamTest, identify_beam, synthetic_test
    if why := _size_problem(args, args.particles):
        raise UsageError(why)
    sec, length = _rope(args.rope), _length(args)
    opt = _options(args)
    if args.synthetic:
        te = synthetic_test(sec, length, _params(args), 1e-3 * args.amplitude, noise=args.noise, seed=args.seed,
                            steps_per_cycle=args.steps)
    else:
        if not args.data:
            raise UsageError("give --data FILE.csv or --synthetic")
        try:
            d = np.loadtxt(args.data, delimiter=",", skiprows=1, ndmin=2)
        except (OSError, ValueError) as e:
            why = e.strerror if isinstance(e, OSError) and e.strerror else str(e).splitlines()[0]
            raise UsageError(f"--data {args.data}: cannot read the CSV: {why}") from None
        if d.ndim != 2 or d.shape[1] < 3:
            raise UsageError(f"--data {args.data}: need 3 columns t [s], x [m], f [N] after the header, "
                             f"got {d.shape[1] if d.ndim == 2 and d.size else 0}")
        if not np.all(np.isfinite(d[:, :3])):
            raise UsageError(f"--data {args.data}: t, x, f must be finite numbers")
        t, x, f = d[:, 0], d[:, 1], d[:, 2]
        if x.size != args.steps + 1:
            raise UsageError(f"--data {args.data}: has {x.size} samples; need --steps + 1 = "
                             f"{args.steps + 1} (one period)")
        if not t[-1] > t[0]:
            raise UsageError(f"--data {args.data}: time t must increase over the period "
                             f"(t[0] = {t[0]:g} s, t[-1] = {t[-1]:g} s)")
        if not np.max(np.abs(x)) > 0:
            raise UsageError(f"--data {args.data}: displacement x is zero everywhere")
        te = BeamTest(section=sec, length=length, amplitude=float(np.max(np.abs(x))), t=t, x=x, f=f,
                      omega=2 * np.pi / (t[-1] - t[0]))
    con = Console(stderr=args.json)
    with Progress(console=con, transient=True, disable=args.json) as prog:
        res = identify_beam(te, particles=args.particles, iterations=args.iterations, seed=args.seed, options=opt,
                            progress=prog, polish=not args.no_polish)
    report = {"method": res.method, "params": res.as_dict(), "mse_percent": res.mse_percent,
              "simulations": res.nsim, "seconds": res.seconds, "message": res.message}
    if "pso" in res:
        report["pso_only"] = {"params": res.pso.as_dict(), "mse_percent": res.pso.mse_percent,
                              "simulations": res.pso.nsim, "seconds": res.pso.seconds}
    if "rel_error" in res:
        report["rel_error"] = res.rel_error
    if res.get("rel_stderr") is not None:
        report["rel_stderr"] = res["rel_stderr"]      # noise-limited accuracy (polish Jacobian)
    if args.json:
        print(json.dumps(report, default=float))
        return 0
    tab = Table(title=f"beam identification ({res.method})")
    tab.add_column("parameter")
    tab.add_column("PSO only")
    tab.add_column("final")
    if "rel_error" in res:
        tab.add_column("truth")
        tab.add_column("error %")
    tr = te.truth.as_array() if te.truth is not None else None
    pso_x = res.pso.x if "pso" in res else res.x
    for i, k in enumerate(("psi", "delta", "gamma", "beta", "n")):
        row = [k, f"{pso_x[i]:.5g}", f"{res.x[i]:.5g}"]
        if "rel_error" in res:
            row += [f"{tr[i]:.5g}", f"{100 * res.rel_error[k]:+.2f}"]
        tab.add_row(*row)
    con.print(tab)
    con.print(f"eq 25 MSE: {res.mse_percent:.4f} % (Table 3 of 000: 0.40-0.50 %); {res.nsim} beam simulations "
              f"in {res.seconds:.1f} s")
    if res.get("rel_stderr") is not None:
        rs = res["rel_stderr"]
        con.print("standard errors from the polish's Jacobian (noise-limited accuracy): "
                  + ", ".join(f"{k} {100 * v:.2f} %" for k, v in rs.items()))
    return 0


def cmd_paper(args: argparse.Namespace) -> int:
    from cablesvc.beam.paper import reproduce
    if why := dir_problem(args.out):
        raise UsageError(f"--out {args.out}: {why}")
    from cablesvc.beam.paper import AMPLITUDES
    if why := _size_problem(args, len(AMPLITUDES)):
        raise UsageError(why)
    s = reproduce(args.out, options=_options(args))
    if args.json:
        print(json.dumps(s))
        return 0
    for name, rows in s["cases"].items():
        print(name)
        for r in rows:
            print(f"  A = {r['amplitude_mm']:4.0f} mm: f_max {r['f_max_N']:7.2f} N, secant {r['secant_N_per_mm']:6.2f} "
                  f"N/mm, area {r['area_J']:.4f} J, hardening ratio {r['hardening_ratio']:.3f}")
    for f in s.get("figures", []):
        print(f"wrote {f}")
    return 0


def cmd_bridge(args: argparse.Namespace) -> int:
    from cablesvc.beam.bridge import fit_lumped, write_params
    if args.write:
        why = file_problem(args.write)
        if why:
            raise UsageError(f"--write {args.write}: {why}")
    A = [1e-3 * float(a) for a in args.amplitude]
    if why := _size_problem(args, len(A)):
        raise UsageError(why)
    fit = fit_lumped(_rope(args.rope), _length(args), _params(args), A, options=_options(args))
    print(fit.report())
    if args.write:
        p = write_params(fit, args.write, robot=args.robot, n_ropes=args.ropes)
        print(f"wrote {p} (load it with: cablesvc run --params {p})")
    return 0


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``beam`` (simulate, identify, paper, bridge) on the top-level sub-parsers."""
    p = subparsers.add_parser("beam", help="hysteretic beam model of wire ropes (paper 000)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="beam", metavar="ACTION")

    s = sub.add_parser("simulate", help="stabilised force-displacement loops of the flexural test")
    _common(s)
    s.add_argument("--amplitude", type=_positive_float, nargs="+", default=[5, 10, 15, 20], help="amplitudes in mm")
    s.add_argument("--out", help="directory for loops.csv (and loops.png)")
    s.add_argument("--plot", action="store_true", help="also write loops.png")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_simulate)

    i = sub.add_parser("identify", help="PSO identification of psi, delta, gamma, beta, n (000 Sec 5)")
    _common(i)
    i.add_argument("--data", help="CSV with header and columns t [s], x [m], f [N]: one stabilised period")
    i.add_argument("--synthetic", action="store_true", help="identify from the beam's own loop plus noise")
    i.add_argument("--amplitude", type=_positive_float, default=10.0, help="synthetic test amplitude in mm (default 10)")
    i.add_argument("--noise", type=_nonnegative_float, default=0.01, help="synthetic noise std / RMS(f) (default 0.01)")
    i.add_argument("--particles", type=_positive_int, default=10)
    i.add_argument("--iterations", type=_positive_int, default=75)
    i.add_argument("--seed", type=int, default=0)
    i.add_argument("--no-polish", action="store_true", help="PSO only, as in the paper")
    i.add_argument("--json", action="store_true")
    i.set_defaults(func=cmd_identify)

    r = sub.add_parser("paper", help="reproduce the model curves and Figs 6-7 of 000")
    _common(r)
    r.add_argument("--out", default="beam-figures", help="directory for the PNG files")
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=cmd_paper)

    b = sub.add_parser("bridge", help="fit the lumped Bouc-Wen cable model to the beam; write a parameter file")
    _common(b)
    b.add_argument("--amplitude", type=_positive_float, nargs="+", default=[5, 10, 15, 20], help="amplitudes in mm")
    b.add_argument("--write", help="parameter file to write (TOML)")
    b.add_argument("--robot", default=None, help="robot name recorded in the file")
    b.add_argument("--ropes", type=_positive_float, default=1.0, help="ropes in parallel per cable (scales the force)")
    b.set_defaults(func=cmd_bridge)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])
    return p
