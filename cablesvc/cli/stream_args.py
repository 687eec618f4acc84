"""The streamed-path flags that ``cablesvc discover`` and ``cablesvc identify`` share:
``--stream auto|on|off``, ``--analysis-rate HZ`` and ``--max-groups K``
(:mod:`cablesvc.discover.stream`)."""

from __future__ import annotations

import argparse
from typing import Any, Optional


def add_stream_arguments(p: argparse.ArgumentParser, *, max_groups: int, what: str, auto: str, doc: str,
                         groups: str) -> None:
    """Add the three flags; ``what`` says what streaming does for this command, ``auto``
    when ``--stream auto`` streams, ``doc`` the page that explains it, ``groups`` what a
    group is and why the default ``max_groups``."""
    p.add_argument("--stream", choices=("auto", "on", "off"), default="auto",
                   help=f"{what} (bounded memory for long 1 kHz logs; {doc}). auto (default): {auto}")
    p.add_argument("--analysis-rate", type=float, default=100.0, metavar="HZ",
                   help="streamed path: the rate the recording is decimated to by block means (default 100)")
    p.add_argument("--max-groups", type=int, default=max_groups, metavar="K",
                   help=f"streamed path: the most {groups}, spread over the whole recording")


def wants_streaming(args: Any, path: Any, block: float, min_ticks: Optional[int] = None) -> bool:
    """Whether this command takes the streamed path: ``--stream on``, or ``auto`` and the
    recording is one it changes anything for (:func:`cablesvc.discover.stream.wants_stream`)."""
    if args.stream == "on":
        return True
    if args.stream == "off":
        return False
    from cablesvc.discover.stream import wants_stream
    return wants_stream(path, args.analysis_rate, block, args.max_groups, min_ticks=min_ticks)
