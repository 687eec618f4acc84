"""``cablesvc discover``: find the physics a cable model leaves out of a recording.

    cablesvc discover --robot ipanema3 [--params P | --calib calib.mcap] rec.mcap [--report DIR] [--json] [--out params.toml]
                      [--stream auto|on|off] [--analysis-rate HZ] [--max-groups K]
    cablesvc discover --boucwen [--data DIR] [--hold] [--json] [--report DIR]
    cablesvc discover logs/ 'more/*.mcap' [--scheduler tcp://host:8786 | --workers N] [--json] [--report DIR]

``--calib`` identifies the amplitude baseline from a calibration recording first (the same
call as ``cablesvc identify --model amplitude``). The first line printed is the verdict.
Prints where the residual is (cables, time, state), the terms chosen with their evidence,
with an identified baseline what the recording cannot show beside its recalibration (per
term not named, the least effect that could have been named), and the held-out RMSE per
cable before and after; ``--report`` writes JSON, PNG figures,
the augmented parameter file and an HTML page; ``--json`` prints the JSON instead of text.
Errors are raised as :class:`~cablesvc.errors.CablesvcError`: one line (cablesvc.cli.failures),
exit code 1. Several recordings, a directory or a glob run as a
fleet (:mod:`cablesvc.batch`, docs/cluster.md): one row per recording and a fleet summary.
"""

from __future__ import annotations

import argparse
import json

from cablesvc.errors import CablesvcError, ConfigError, DiscoveryError

__all__ = ["add_parser", "cmd_discover"]


def _as_discovery_error(e: Exception) -> CablesvcError:
    """A KeyError (an unknown term), OSError or ValueError out of the library as the
    discovery error it means (its message, a KeyError's without the quotes str() adds); a
    CablesvcError stays itself."""
    if isinstance(e, CablesvcError):
        return e
    return DiscoveryError(e.args[0] if isinstance(e, KeyError) and e.args else str(e))


def cmd_discover(args: argparse.Namespace) -> int:
    from cablesvc.config.robot import load_robot
    from cablesvc.discover import SelectOptions, ForwardSelector, discover, library
    from cablesvc.recording import RecordingError, read_recording

    if args.boucwen:
        return _cmd_boucwen(args)
    specs = [args.recording] if isinstance(args.recording, str) else list(args.recording or [])
    from cablesvc.batch.cli import fleet_requested
    if specs and fleet_requested(args, specs):
        return _cmd_fleet(args, specs)
    args.recording = specs[0] if len(specs) == 1 else None
    if not args.recording:
        raise ConfigError("a recording is needed (or --boucwen)")
    if not args.robot:                  # the robot the recording names (its metadata)
        from pathlib import Path

        from cablesvc.cli.paths import recording_robot
        from cablesvc.recording import read_metadata
        if not Path(args.recording).exists():
            raise ConfigError(f"{args.recording}: recording not found")
        try:
            named = read_metadata(args.recording).get("robot", "")
        except (RecordingError, OSError, ValueError) as e:
            raise DiscoveryError(f"cannot read the recording {args.recording}: {e}") from None
        args.robot = recording_robot(None, named, args.recording)

    if args.calib and args.params:
        raise ConfigError("give either --params or --calib (the baseline is identified from --calib)")
    try:
        robot = load_robot(args.robot)
        params = args.params
        if args.calib:
            from cablesvc.identify.cable import identify_cable
            try:
                calib = read_recording(args.calib)
            except RecordingError as e:                   # which of the two recordings
                raise DiscoveryError(f"--calib {args.calib}: {e}") from None
            params = identify_cable(calib, robot, "amplitude").params
            params.identification["recording"] = str(args.calib)
        terms = library(args.terms.split(",")) if args.terms else None
        sel = ForwardSelector(SelectOptions(min_gain=args.min_gain))
        from cablesvc.cli.stream_args import wants_streaming
        from cablesvc.discover.stream import discover_stream
        if args.stream == "on" and args.since:
            raise ConfigError("--since needs the whole recording in memory: use it with --stream off or auto")
        if not args.since and wants_streaming(args, args.recording, args.block):
            d = discover_stream(args.recording, robot, params, terms=terms, selector=sel, block=args.block,
                                exact_baseline=args.exact_baseline, rate=args.analysis_rate,
                                max_groups=args.max_groups)
        else:
            rec = read_recording(args.recording)
            d = discover(rec, robot, params, terms=terms, selector=sel, block=args.block,
                         exact_baseline=args.exact_baseline, since=args.since)
    except (KeyError, OSError, ValueError) as e:
        raise _as_discovery_error(e) from None
    files = {}
    if args.report:
        from cablesvc.discover.report import write_report
        files = write_report(d, args.report)
    if args.out:
        d.augmented_params().save(args.out)
        files["params"] = args.out
    if args.json:
        doc = d.to_json()
        doc["files"] = files
        print(json.dumps(doc, indent=1, default=float))
        return 0
    for line in d.summary():
        print(line)
    for k, v in files.items():
        print(f"wrote {k}: {v}")
    return 0


def _cmd_fleet(args, specs) -> int:
    """Many recordings (cablesvc.batch): one discovery per recording on Dask."""
    import os

    from cablesvc.batch.cli import cmd_fleet
    from cablesvc.config.params import load_params
    from cablesvc.config.robot import load_robot
    from cablesvc.discover import library

    for flag, given in (("--calib", args.calib), ("--out", args.out)):
        if given:
            raise ConfigError(f"{flag} is for one recording; with many, use --params (the same baseline for all) "
                        "or none (each robot's nominal baseline)")
    try:
        if args.robot:
            load_robot(args.robot)
        if args.params:
            load_params(args.params)
        terms = [t.strip() for t in args.terms.split(",") if t.strip()] if args.terms else None
        if terms:
            library(terms)
    except (KeyError, OSError, ValueError) as e:
        raise _as_discovery_error(e) from None
    opts = {"robot": os.path.abspath(args.robot) if args.robot and os.path.exists(args.robot) else args.robot,
            "params": os.path.abspath(args.params) if args.params else None, "terms": terms,
            "block": args.block, "min_gain": args.min_gain, "exact_baseline": bool(args.exact_baseline)}
    return cmd_fleet("discover", args, specs, opts)


def _cmd_boucwen(args) -> int:
    from pathlib import Path
    from cablesvc.discover.oscillator_case import boucwen_summary, run_boucwen_discovery
    try:
        res = run_boucwen_discovery(args.data, hold=args.hold)
    except (OSError, ValueError, KeyError) as e:
        raise _as_discovery_error(e) from None
    if args.report:
        d = Path(args.report)
        d.mkdir(parents=True, exist_ok=True)
        (d / "boucwen_discovery.json").write_text(json.dumps(res, indent=1, default=float))
        (d / "boucwen_discovery.txt").write_text("\n".join(boucwen_summary(res)) + "\n")
    if args.json:
        print(json.dumps(res, indent=1, default=float))
    else:
        print("\n".join(boucwen_summary(res)))
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("discover", help="find the physics a model leaves out of a recording",
                              description=__doc__.split("\n\n")[0] + " See docs/discovery.md.")
    p.add_argument("recording", nargs="*", help="recording with measured forces (.mcap or .csv); several paths, "
                   "a directory or a glob run as a fleet on Dask (docs/cluster.md)")
    p.add_argument("--robot", default=None, help="robot name or .toml file (default: the one the recording "
                   "names; a fleet: the one each recording names)")
    p.add_argument("--boucwen", action="store_true",
                   help="run discovery on the Bouc-Wen benchmark oscillator instead (linear start on train.h5)")
    p.add_argument("--data", default=None, help="--boucwen: benchmark data directory (default: "
                   "$CABLESVC_BOUCWEN_DATA or the data shipped with cablesvc)")
    p.add_argument("--hold", action="store_true", help="--boucwen: simulate with a zero-order-hold input")
    p.add_argument("--params", default=None, help="baseline parameter file (default: the robot's nominal model)")
    p.add_argument("--calib", default=None, metavar="CALIB",
                   help="calibration recording (platform at home, hold-sine, 002 Sec 4): identify the amplitude "
                        "baseline from it first (as cablesvc identify --model amplitude)")
    p.add_argument("--exact-baseline", action="store_true",
                   help="the baseline is the recording's exact model (a simulator's truth): no recalibration "
                        "nuisance, the whole term library competes")
    p.add_argument("--report", default=None, metavar="DIR", help="write JSON, figures, params.toml and index.html")
    p.add_argument("--out", default=None, help="write the augmented parameter file here")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--terms", default=None, help="comma-separated subset of the term library")
    p.add_argument("--block", type=float, default=2.5, help="split block length [s] (default 2.5)")
    p.add_argument("--since", type=float, default=None, metavar="SECONDS",
                   help="analyse only the ticks from SECONDS after the recording's start on (e.g. since an "
                        "alarm); the baseline still runs from the start, so its hysteresis state there is the "
                        "live kernel's, and the written file's creep clock starts there")
    from cablesvc.cli.stream_args import add_stream_arguments
    add_stream_arguments(p, max_groups=16, doc="docs/discovery.md",
                         what="stream the recording, decimated to --analysis-rate and sampled by whole split groups",
                         auto="when the recording is faster than 1.5 x the analysis rate or longer than "
                              "--max-groups groups",
                         groups="split groups (4 blocks each) kept (default 16)")
    p.add_argument("--min-gain", type=float, default=0.05,
                   help="least relative drop of the held-out MSE for a term to count (default 0.05)")
    from cablesvc.batch.cli import add_fleet_arguments
    add_fleet_arguments(p)
    p.set_defaults(func=cmd_discover)
    return p
