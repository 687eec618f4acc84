"""``cablesvc identify``: cable-model parameters from a recording.

    cablesvc identify --model amplitude --robot ipanema3 hold.mcap --out params.toml --report rep/

Shows a progress bar while it works, then a table of the parameters with standard errors;
``--out`` writes a parameter file that ``cablesvc run --params`` loads; ``--report`` writes a
Markdown report with PNG plots. Errors (unreadable recording, unknown model or method,
cable index out of range, robot/recording mismatch) are raised as
:class:`~cablesvc.errors.CablesvcError` (one clear line from cablesvc.cli.failures, exit code 1).
Several recordings, a directory or a glob run as a fleet (:mod:`cablesvc.batch`,
docs/cluster.md): one row per recording and a fleet summary of the cables that drift.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cablesvc.cli.paths import dir_problem, file_problem, recording_robot
from cablesvc.errors import CablesvcError, ConfigError, IdentifyError

__all__ = ["add_parser", "cmd_identify"]

DESCRIPTION = """\
Identify cable-model parameters from a recording (MCAP or CSV) with pose, motor lengths
and measured forces. Elongation x = l(pose) - motor_length from inverse kinematics, as in
the kernel. Methods: pso+lm = particle swarm (paper 000 Sec 5) then least squares (002
eqs 12-14); lm = least squares only; sqp = constrained multi-start SQP (001 Ch 5). The
amplitude model on a hold-sine recording is fitted per amplitude level (002 Sec 3)."""

EPILOG = """\
examples:
  cablesvc simulate --robot ipanema3 --scenario hold-sine --out hold.mcap
  cablesvc identify --model amplitude --robot ipanema3 hold.mcap --out params.toml --report report/
  cablesvc identify --model boucwen --cables 0,1 --method pso+lm hold.mcap --out bw.toml
  cablesvc run --params params.toml
  cablesvc identify --model amplitude nightly/ --workers 2 --report fleet/      (a fleet, docs/cluster.md)
"""


#: --stream auto reduces only recordings longer than this many ticks (20 s at 1 kHz, 200 s
#: at 100 Hz): shorter ones are fitted whole
STREAM_MIN_TICKS = 20_000
#: a platform held still (a 002 Sec 4 calibration) with up to this many 10 s groups is kept
#: whole for the amplitude model, which is fitted per amplitude level (002 Sec 3) and needs
#: every level of every cable; that fit costs seconds (2.7 s and 285 MB on the realistic
#: bench's 34 648-tick calibration, 5 s and 432 MB on four times that): an hour at 100 Hz.
#: Other recordings, and the swarm-fitted models, keep --max-groups groups, more where it
#: takes more for every cable to be excited in them
HELD_GROUPS_AMPLITUDE = 360


def _parse_cables(text: str | None) -> list[int] | None:
    if text is None or text.strip() == "":
        return None
    try:
        return [int(c) for c in text.split(",") if c.strip() != ""]
    except ValueError:
        raise ValueError(f"--cables: expected comma-separated cable indices like 0,1,2, got {text!r}") from None


def cmd_identify(args: argparse.Namespace) -> int:
    """Run ``cablesvc identify``; returns the exit code."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from cablesvc.config import load_robot
    from cablesvc.identify.cable import METHODS, MODEL_CHOICES, identify_cable
    from cablesvc.identify.report import format_value, write_report
    from cablesvc.recording import RecordingError, read_recording

    con = Console()
    if args.model not in MODEL_CHOICES:
        raise ConfigError(f"unknown model {args.model!r}; choose one of {', '.join(MODEL_CHOICES)}")
    if args.method not in METHODS:
        raise ConfigError(f"unknown method {args.method!r}; choose one of {', '.join(METHODS)}")
    try:
        cables = _parse_cables(args.cables)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    specs = [args.recording] if isinstance(args.recording, str) else list(args.recording)
    from cablesvc.batch.cli import fleet_requested
    if fleet_requested(args, specs) or args.json:
        return _cmd_fleet(args, specs, cables)
    if args.out and len(specs) != 1:
        raise ConfigError("--out is for one recording")
    args.recording = specs[0]
    rec_path = Path(args.recording)
    if not rec_path.exists():
        raise ConfigError(f"{rec_path}: recording not found")
    reduction = None
    try:
        from cablesvc.cli.stream_args import wants_streaming
        from cablesvc.discover.stream import reduced_recording
        from cablesvc.recording import read_metadata
        if args.max_groups < 1:
            raise ConfigError(f"--max-groups {args.max_groups}: must be >= 1")
        if wants_streaming(args, rec_path, 2.5, min_ticks=STREAM_MIN_TICKS):
            file_robot = read_metadata(rec_path).get("robot", "")
            robot = load_robot(recording_robot(args.robot, file_robot, rec_path))   # RobotFileError: one line as it is
            rec, reduction = reduced_recording(rec_path, robot, rate=args.analysis_rate,
                                               max_groups=args.max_groups, select="excitation",
                                               held_groups=HELD_GROUPS_AMPLITUDE if args.model == "amplitude"
                                               else None)
            rec.robot = file_robot
        else:
            rec = read_recording(rec_path)
    except RecordingError as e:                 # the message says which file and where
        raise IdentifyError(f"cannot read the recording: {e}") from None
    except (OSError, ValueError) as e:          # an unreadable file: name it
        raise IdentifyError(f"cannot read the recording {rec_path}: {e}") from None
    robot = load_robot(recording_robot(args.robot, rec.robot, rec_path))
    if args.robot and rec.robot and rec.robot != robot.name:
        con.print(f"[yellow]note:[/] the recording says robot {rec.robot!r}, using {robot.name!r} as asked")
    if args.out and Path(args.out).suffix.lower() != ".toml":
        raise ConfigError(f"--out {args.out}: the parameter file must end in .toml")
    # output paths are checked before the (long) fit, not after it
    if args.out and (why := file_problem(args.out)):
        raise ConfigError(f"--out {args.out}: cannot write the parameter file: {why}")
    if args.report and (why := dir_problem(args.report)):
        raise ConfigError(f"--report {args.report}: cannot write the report folder: {why}")
    try:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                      TimeElapsedColumn(), console=con, transient=True, disable=args.quiet) as prog:
            task = prog.add_task(f"identify {args.model}", total=1)

            def cb(done: float, total: float, text: str) -> None:
                prog.update(task, total=max(total, 1), completed=done, description=text)

            fit = identify_cable(rec, robot, args.model, cables=cables, shared=args.shared, method=args.method,
                                 seed=args.seed, progress=cb, iterations=args.iterations, particles=args.particles)
    except ValueError as e:
        if isinstance(e, CablesvcError):        # IdentifyError and friends: one line as they are
            raise
        raise IdentifyError(str(e)) from None   # a value the fit cannot take: one line

    if reduction is not None:
        from cablesvc.discover.pipeline import describe_reduction
        fit.notes.append(describe_reduction(reduction) + f"; fitted on those ticks (the model runs across the "
                         f"{reduction['gaps']} gaps between groups as if they were one record)")
        fit.params.identification["stream"] = {k: v for k, v in reduction.items() if k != "stream_seconds"}
    _print_table(con, fit, format_value)
    if args.out:
        fit.params.identification["recording"] = str(rec_path)
        fit.params.save(args.out)
        con.print(f"wrote {args.out} (cablesvc run --robot {robot.name} --params {args.out})")
    if args.report:
        path = write_report(fit, args.report, recording=str(rec_path), params_file=args.out)
        con.print(f"wrote {path}")
    return 0


def _cmd_fleet(args: argparse.Namespace, specs: list[str], cables: list[int] | None) -> int:
    """Many recordings (cablesvc.batch): one identification per recording on Dask."""
    import os

    from cablesvc.batch.cli import cmd_fleet
    from cablesvc.config import load_robot

    if args.out:
        raise ConfigError("--out is for one recording; with many, each row of --json / --report holds its parameter "
                          "file (params_toml)")
    if args.robot:
        load_robot(args.robot)
    opts = {"robot": os.path.abspath(args.robot) if args.robot and os.path.exists(args.robot) else args.robot,
            "model": args.model, "method": args.method, "cables": cables, "shared": bool(args.shared),
            "seed": args.seed, "particles": args.particles, "iterations": args.iterations}
    return cmd_fleet("identify", args, specs, opts)


def _print_table(con: Any, fit: Any, format_value: Any) -> None:
    from rich.table import Table
    if fit.amplitude is not None:
        from cablesvc.identify.amplitude_levels import PER_LEVEL, UNITS
        af = fit.amplitude
        tb = Table(title=f"amplitude model per level (002 eq 8), value +- standard error; "
                         f"{len(af.fits)} levels, {af.table_amplitudes.size}-point table")
        tb.add_column("cable", justify="right")
        tb.add_column("A [mm]", justify="right")
        for k in PER_LEVEL:
            tb.add_column(f"{k} [{UNITS[k]}]", justify="right")
        for j, c in enumerate(af.cables):
            lt = af.level_table(j)
            for i in range(len(af.fits)):
                tb.add_row(str(c), f"{lt['A'][i] * 1e3:.3g}", *[format_value(lt[k][i], lt[k + '_se'][i])
                                                                 for k in PER_LEVEL])
        con.print(tb)
    else:
        tb = Table(title=f"{fit.model} parameters, value +- standard error ({fit.method})")
        tb.add_column("cable", justify="right")
        for n, u in zip(fit.names, fit.units):
            tb.add_column(f"{n} [{u}]" if u else n, justify="right")
        tb.add_column("cond", justify="right")
        for j, r in enumerate(fit.results):
            lab = str(fit.cables[j]) if not fit.shared else "shared"
            tb.add_row(lab, *[format_value(v, s) for v, s in zip(r.x, r.stderr)], f"{r.get('cond', float('nan')):.3g}")
        con.print(tb)
        for j, r in enumerate(fit.results):
            for g in r.get("redundant") or []:
                con.print(f"[yellow]identifiability[/] ({'cable ' + str(fit.cables[j]) if not fit.shared else 'shared'}): "
                          f"{g.describe()}")
    con.print("force RMSE [N]: " + ", ".join(f"cable {c}: {v:.4g}" for c, v in zip(fit.cables, fit.rmse)))
    for n in fit.notes:
        con.print(f"[dim]{n}[/]")


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``identify`` on the top-level ``cablesvc`` sub-parsers."""
    p = subparsers.add_parser("identify", help="identify cable-model parameters from a recording",
                              description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recording", nargs="+", help="recording (.mcap or .csv) with pose, motor lengths and forces; "
                   "several paths, a directory or a glob run as a fleet on Dask (docs/cluster.md)")
    p.add_argument("--model", default="amplitude",
                   help="linear | polynomial | amplitude | boucwen | asymmetric (default amplitude)")
    p.add_argument("--robot", help="robot name or .toml path (default: the robot named in the recording)")
    p.add_argument("--cables", help="comma-separated 0-based cable indices (default all)")
    p.add_argument("--shared", action="store_true", help="one parameter set for all selected cables")
    p.add_argument("--method", default="pso+lm", help="pso+lm (default) | lm | sqp")
    p.add_argument("--out", help="write the parameter file (.toml) for cablesvc run --params")
    p.add_argument("--report", metavar="DIR", help="write report.md with PNG plots into DIR")
    p.add_argument("--seed", type=int, default=0, help="seed of the swarm / SQP starts (default 0)")
    p.add_argument("--particles", type=int, default=10, help="PSO particles p (000: 10)")
    p.add_argument("--iterations", type=int, default=75, help="PSO iterations q (000: 75)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    from cablesvc.cli.stream_args import add_stream_arguments
    add_stream_arguments(p, max_groups=3, doc="docs/identification.md",
                         what="read the recording in pieces, decimated to --analysis-rate and sampled by whole "
                              "10 s groups chosen so that every cable is excited in them",
                         auto="when the recording has more than 20 000 ticks and is faster than 1.5 x the "
                              "analysis rate or longer than --max-groups groups",
                         groups="10 s groups kept, more where it takes more for every cable to be excited "
                                "in them (default 3: the swarm and the least-squares refinement cost 1-4 "
                                "minutes on 6000 ticks); --model amplitude keeps a calibration (platform held "
                                "still) of up to 360 groups (an hour) whole, since it is fitted per amplitude level")
    p.add_argument("--json", action="store_true",
                   help="print the fleet JSON (one row per recording and the fleet summary; runs as a fleet)")
    from cablesvc.batch.cli import add_fleet_arguments
    add_fleet_arguments(p)
    p.set_defaults(func=cmd_identify)
    return p
