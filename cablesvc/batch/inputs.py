"""Which recordings a fleet job reads: paths, directories and globs.

:func:`expand_recordings` turns what the user typed (``cablesvc discover logs/`` or
``'logs/*/2026-11-2?.mcap'`` or several paths) into one sorted list of recording paths:

* a file is taken as it is (whatever its suffix: a wrong file is reported by the job that
  reads it, as a failed recording, so the others still run);
* a directory gives every ``*.mcap`` and ``*.csv`` file in it and its sub-directories;
* a pattern with ``*``, ``?`` or ``[`` is a glob (``**`` matches sub-directories); it
  gives the recordings among its matches (directories it matches are expanded as above).

A path that does not exist or a pattern that matches nothing is an error naming it
(:class:`FleetInputError`), before any work starts. The list is sorted and without
duplicates, so the same command gives the same rows in the same order.
"""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import Iterable

from cablesvc.errors import BatchError

__all__ = ["FleetInputError", "RECORDING_SUFFIXES", "expand_recordings", "is_pattern"]

#: suffixes a directory or a glob contributes (docs/recording-format.md)
RECORDING_SUFFIXES = (".mcap", ".csv")


class FleetInputError(BatchError, ValueError):
    """A path that does not exist or a glob / directory without recordings."""


def is_pattern(spec: str) -> bool:
    """True when ``spec`` is a glob (contains ``*``, ``?`` or ``[``) rather than a path."""
    return any(ch in spec for ch in "*?[")


def _in_dir(d: Path) -> list[str]:
    return [str(p) for p in sorted(d.rglob("*")) if p.is_file() and p.suffix.lower() in RECORDING_SUFFIXES]


def expand_recordings(specs: Iterable[str | os.PathLike]) -> list[str]:
    """The recordings named by ``specs`` (paths, directories, globs), sorted, no duplicates."""
    out: list[str] = []
    for raw in specs:
        spec = os.fspath(raw)
        p = Path(spec)
        if is_pattern(spec) and not p.exists():
            found: list[str] = []
            for m in sorted(glob.glob(spec, recursive=True)):
                mp = Path(m)
                if mp.is_dir():
                    found += _in_dir(mp)
                elif mp.is_file() and mp.suffix.lower() in RECORDING_SUFFIXES:
                    found.append(m)
            if not found:
                raise FleetInputError(f"{spec}: the pattern matches no recording (*.mcap, *.csv)")
            out += found
        elif p.is_dir():
            found = _in_dir(p)
            if not found:
                raise FleetInputError(f"{spec}: the directory holds no recording (*.mcap, *.csv)")
            out += found
        elif p.exists():
            out.append(spec)
        else:
            raise FleetInputError(f"{spec}: no such file or directory")
    seen: set[str] = set()
    unique = []
    for s in sorted(out, key=lambda s: os.path.normpath(os.path.abspath(s))):
        key = os.path.normpath(os.path.abspath(s))
        if key not in seen:
            seen.add(key)
            unique.append(s)
    return unique
