"""Checks of the paths a command is given, made before it spends minutes computing: each
output check returns why the path cannot be used, in words, or None; :func:`recording_robot`
names the robot of an input recording or says why there is none."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["dir_problem", "file_problem", "recording_robot"]


def file_problem(path: str | os.PathLike[str]) -> str | None:
    """Why ``path`` cannot be written as a file (its folder must exist), or None."""
    p = Path(path)
    if p.is_dir():
        return "is a directory"
    parent = p.parent
    if not parent.is_dir():
        return f"folder {parent} does not exist"
    if not os.access(parent, os.W_OK):
        return f"folder {parent} is not writable"
    if p.exists() and not os.access(p, os.W_OK):
        return "is not writable"
    return None


def dir_problem(path: str | os.PathLike[str]) -> str | None:
    """Why ``path`` cannot be used as an output folder (created with its parents), or None."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        return "exists and is not a directory"
    anc = p
    while not anc.exists() and anc.parent != anc:
        anc = anc.parent
    if not anc.is_dir():
        return f"{anc} is not a directory"
    if not os.access(anc, os.W_OK):
        return f"{anc} is not writable"
    return None


def recording_robot(given: str | None, named: str | None, path: str | os.PathLike[str]) -> str:
    """The robot to use for the recording at ``path``: ``given`` (--robot), else the one its
    metadata ``named``; neither is a :class:`~cablesvc.errors.ConfigError` naming the file
    and the robots available (rather than a lookup of '')."""
    name = given or named
    if not name:
        from cablesvc.config.robot import available_robots
        from cablesvc.errors import ConfigError
        raise ConfigError(f"{path}: the recording names no robot (no 'robot' metadata): give --robot NAME or a "
                          f".toml path (available: {', '.join(available_robots())})")
    return name
