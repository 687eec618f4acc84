"""The one command line of cablesvc: ``cablesvc <command> ...``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EPILOG = """\
examples:
  cablesvc run                                  live daemon, embedded default: simulated IPAnema 3 on virtual CAN,
                                                Zenoh peer on 127.0.0.1:7447, live view of forces and alarms
  cablesvc listen                               print what a running daemon publishes
  cablesvc simulate --robot ipanema3 --scenario hold-sine --out rec.mcap
  cablesvc simulate --robot ipanema3 --scenario trajectory --effect pulley --out traj.mcap
  cablesvc robots check robots/ipanema3.toml    validate a robot file, one line per problem
  cablesvc bench kernel --json                  per-tick latency of the fixed-time kernel
"""


def _console():
    from rich.console import Console
    return Console(stderr=False)


# ---- simulate --------------------------------------------------------------------------

def cmd_simulate(args) -> int:
    """``cablesvc simulate``; a bad flag is a UsageError (exit 2), a file that cannot be
    written a SimulationError (exit 1): one line each (cablesvc.cli.failures)."""
    from cablesvc.cli.failures import UsageError
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params
    from cablesvc.errors import SimulationError
    from cablesvc.simulate import SCENARIOS, TruthConfig, effect_from_spec, list_effects, simulate_recording

    if args.list:
        con = _console()
        con.print("[bold]scenarios[/]")
        for name, fn in SCENARIOS.items():
            con.print(f"  {name:16s} {(fn.__doc__ or '').strip().splitlines()[0]}")
        con.print("[bold]effects[/] (--effect NAME\\[:MAGNITUDE]\\[@CABLES])")
        for line in list_effects():
            con.print(f"  {line}")
        return 0
    if not args.out:
        raise UsageError("--out is required (a .mcap or .csv path)")
    out = Path(args.out)
    parent = out.parent if str(out.parent) else Path(".")
    if out.is_dir():
        raise UsageError(f"--out {args.out} is a directory; give a .mcap or .csv file path")
    if not parent.is_dir():
        raise UsageError(f"--out {args.out}: directory {parent} does not exist")
    robot = load_robot(args.robot)
    if why := _twin_size_problem(args, robot.n_cables):
        raise UsageError(why)
    effects = [effect_from_spec(s, robot.n_cables) for s in args.effect]
    base = load_params(args.truth_params) if args.truth_params else None
    truth = TruthConfig(base=base, effects=effects, noise_std=args.noise, seed=args.seed)
    kwargs = {}
    for kv in args.set:
        k, _, v = kv.partition("=")
        try:
            kwargs[k] = json.loads(v)
        except json.JSONDecodeError:
            kwargs[k] = v
    try:
        rec = simulate_recording(robot, args.scenario, out, truth=truth, duration=args.duration,
                                 rate=args.rate, seed=args.seed, encoding=args.encoding, **kwargs)
    except OSError as e:                    # a read-only directory, a full disk, ...: one line naming the file
        raise SimulationError(f"cannot write {e.filename or args.out}: {e.strerror or e}") from None
    print(f"wrote {args.out}: {rec.n_ticks} ticks, {rec.n_cables} cables, "
          f"{rec.t[-1] - rec.t[0]:.1f} s, effects: {', '.join(e.describe() for e in effects) or 'none'}")
    return 0


def _twin_size_problem(args, n_cables: int) -> str | None:
    """``--rate`` / ``--duration`` that are not finite and > 0, or whose run would not fit
    in memory (cablesvc.limits): checked before the twin allocates anything."""
    import math

    from cablesvc.limits import TWIN_DEFAULT_DURATION_MAX_S, memory_problem, twin_bytes

    for flag, v in (("--rate", args.rate), ("--duration", args.duration)):
        if v is not None and not (math.isfinite(v) and v > 0):
            return f"{flag}: expected a finite number > 0, got {v!r}"
    duration = TWIN_DEFAULT_DURATION_MAX_S if args.duration is None else args.duration
    what = (f"--rate {args.rate:g} Hz x " + (f"--duration {args.duration:g} s" if args.duration is not None else
                                             f"the scenario's duration (up to {duration:g} s)")
            + f" = {args.rate * duration:.3g} ticks of {n_cables} cables")
    return memory_problem(what, twin_bytes(args.rate * duration, n_cables))


# ---- robots ----------------------------------------------------------------------------

def cmd_robots(args) -> int:
    from cablesvc.config import RobotFileError, load_robot, robot_search_path
    from cablesvc.config.robot import robot_files

    if args.action == "list":
        seen = set()
        for d in robot_search_path():
            for p in robot_files(d):
                if p.stem in seen:
                    continue
                seen.add(p.stem)
                try:
                    r = load_robot(p)
                    print(f"{p.stem:12s} {r.n_cables} cables  {p}")
                except RobotFileError as e:
                    print(f"{p.stem:12s} INVALID ({len(e.problems)} problems)  {p}")
        return 0
    bad = 0
    for f in args.files:
        try:
            r = load_robot(f)
            print(f"{f}: ok ({r.n_cables} cables)")
        except RobotFileError as e:
            print(str(e), file=sys.stderr)
            bad += 1
    return 1 if bad else 0


# ---- bench -----------------------------------------------------------------------------

def cmd_bench_kernel(args) -> int:
    from cablesvc.bench.kernel import INPUTS, as_dicts, run_kernel_bench
    from cablesvc.cli.failures import UsageError

    inputs = args.input or list(INPUTS)
    kw = {"machine_baseline": not args.no_baseline, "cpu": args.cpu, "realtime": args.realtime}

    def bench(**more):
        # a bad --ticks / --model is a BenchArgumentError (exit 2, like argparse; printed by main)
        try:
            return run_kernel_bench(args.robot, args.model, args.params, args.ticks, inputs, **kw, **more)
        except OSError as e:
            raise UsageError(f"cannot set the scheduling asked for (--cpu/--realtime): {e}") from None

    if args.json:
        res = bench()
        for d in as_dicts(res):
            print(json.dumps(d))
        return 0
    from rich.progress import Progress
    from rich.table import Table
    con = _console()
    with Progress(console=con, transient=True) as prog:
        task = prog.add_task("kernel", total=args.ticks * len(inputs))
        done = {}

        def cb(kind, k, n):
            done[kind] = k
            prog.update(task, completed=sum(done.values()), description=f"{kind}")
        res = bench(progress=cb)
    tb = Table(title=f"kernel latency per tick, {res[0].robot}, model {res[0].model}, {args.ticks} ticks, "
                     f"gc frozen, scheduling {res[0].scheduling}")
    for c in ("input", "p50 us", "p99 us", "p99.9 us", "max us", "alloc B/tick", "p99 / normal p99"):
        tb.add_column(c, justify="right")
    base = next((r.p99_us for r in res if r.input == "normal"), None)
    for r in res:
        label = r.input if r.calls is None else f"machine ({r.calls} numpy calls)"
        tb.add_row(label, f"{r.p50_us:.1f}", f"{r.p99_us:.1f}", f"{r.p999_us:.1f}", f"{r.max_us:.1f}",
                   f"{r.alloc_bytes_per_tick:.2f}", f"{r.p99_us / base:.2f}" if base else "-")
    con.print(tb)
    return 0


# ---- parser ----------------------------------------------------------------------------

def wants_bench(argv: list[str] | None) -> bool:
    """Whether this command line is ``cablesvc bench ...``: its first word that is not an
    option (the top level has only -h and --version, neither takes a value)."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    return bool(words) and words[0] == "bench"


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The whole command line. The benchmarks' own parsers (whose modules import numpy, the
    robot model and the simulator: about 0.3 s) are built only for ``cablesvc bench ...``
    (``argv``, default sys.argv[1:]): every other command starts without them, and the
    top-level ``--help`` lists ``bench`` the same either way."""
    p = argparse.ArgumentParser(
        prog="cablesvc", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG,
        description="Real-time cable-force prediction with hysteresis for cable-driven parallel robots.")
    from cablesvc import __version__
    p.add_argument("--version", action="version", version=f"cablesvc {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    from cablesvc.cli import run_cmd
    run_cmd.add_parser(sub)

    s = sub.add_parser("simulate", help="write a recording from the digital twin",
                       description="Digital twin: drives the robot and records pose, motor lengths, measured "
                                   "forces (truth model + sensor noise) and temperature in the recording format.")
    s.add_argument("--robot", default="ipanema3", help="robot name or .toml path")
    s.add_argument("--scenario", default="hold-sine", help="scenario name; --list shows them")
    s.add_argument("--out", help="output .mcap or .csv")
    s.add_argument("--encoding", choices=["protobuf", "json"], default="protobuf",
                   help=".mcap input encoding: protobuf (binary blocks, format 2, default) or json (format 1)")
    s.add_argument("--duration", type=float, default=None, help="seconds (default: the scenario's)")
    s.add_argument("--rate", type=float, default=1000.0, help="tick rate in Hz")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--noise", type=float, default=0.1, help="force sensor noise std in N (default 0.1)")
    s.add_argument("--effect", action="append", default=[], metavar="NAME[:MAG][@CABLES]",
                   help="switch on extra truth physics, e.g. pulley:0.02@1,4 (repeatable)")
    s.add_argument("--truth-params", help="parameter file of the truth base model")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="scenario option, e.g. --set amplitudes=[1e-4,5e-4]")
    s.add_argument("--list", action="store_true", help="list scenarios and effects")
    s.set_defaults(func=cmd_simulate)

    from cablesvc.cli import beam_cmd, discover_cmd, identify_cmd, listen_cmd
    for command in (listen_cmd, identify_cmd, discover_cmd, beam_cmd):
        command.add_parser(sub)

    rb = sub.add_parser("robots", help="list or check robot definition files")
    rb.add_argument("action", choices=["list", "check"])
    rb.add_argument("files", nargs="*", help="files to check")
    rb.set_defaults(func=cmd_robots)

    b = sub.add_parser("bench", help="benchmarks (latency, accuracy, load)")
    b.set_defaults(func=lambda a: (b.print_help(), 2)[1])
    if wants_bench(argv):
        _add_benches(b)
    return p


def _add_benches(b: argparse.ArgumentParser) -> None:
    """The ``cablesvc bench`` subcommands."""
    bsub = b.add_subparsers(dest="bench", metavar="BENCH")
    bk = bsub.add_parser("kernel", help="per-tick latency of the fixed-time kernel",
                         description="100 000 ticks with gc frozen; p50/p99/p99.9/max per tick for normal and "
                                     "adversarial input (reversal every tick, slack, very large amplitudes), "
                                     "and for the normal input without a pose (no_pose: the elasto-static "
                                     "forward kinematics runs every tick).")
    bk.add_argument("--robot", default="ipanema3")
    bk.add_argument("--model", default="amplitude", help="model with nominal parameters (amplitude, linear)")
    bk.add_argument("--params", help="parameter file instead of nominal parameters")
    bk.add_argument("--ticks", type=int, default=100_000)
    bk.add_argument("--input", action="append", choices=["normal", "reversal", "slack", "large", "no_pose", "terms",
                                                         "terms_slack", "terms_no_temperature"],
                    help="only these inputs (repeatable; default all)")
    bk.add_argument("--json", action="store_true", help="one JSON object per run")
    bk.add_argument("--no-baseline", action="store_true",
                    help="skip the machine baseline (a fixed numpy workload as long as the kernel, timed "
                         "in blocks alternating with the normal run: the p99 this machine gives such work)")
    bk.add_argument("--cpu", type=int, help="pin the benchmark to this CPU (as a production deployment would)")
    bk.add_argument("--realtime", action="store_true", help="run at SCHED_FIFO priority 50 (needs CAP_SYS_NICE)")
    bk.set_defaults(func=cmd_bench_kernel)
    from cablesvc.bench import (alarms, beam, boucwen, cable_experiment, can_codec, discover, discover_scale, e2e,
                                live_discovery, record, soak)
    from cablesvc.bench import fleet as fleet_bench
    from cablesvc.bench import read as read_bench
    for bench in (e2e, soak, alarms, beam, discover, boucwen, cable_experiment, can_codec, record, fleet_bench,
                  read_bench, live_discovery, discover_scale):
        bench.add_parser(bsub)


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:            # Ctrl-C before a command installed its own handling
        print("cablesvc: interrupted", file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from cablesvc.cli.failures import run_command
    return run_command(args)


if __name__ == "__main__":
    raise SystemExit(main())
