"""How the command line reports a failure: every error cablesvc raises on purpose is a
:class:`~cablesvc.errors.CablesvcError`; :func:`run_command` (the one place, used by
``cablesvc.cli.main``) catches it and prints one line, ``cablesvc <command>: <message>``,
with the exit status of :func:`exit_status` (2 for a bad command-line value, as argparse
does; 1 otherwise). Anything else is a bug and keeps its traceback."""

from __future__ import annotations

import sys

from cablesvc.errors import CablesvcError, ConfigError, ServiceError

__all__ = ["UsageError", "exit_status", "run_command", "zenoh_failure"]

#: commands whose sub-command (an attribute of the same name) belongs in the line:
#: ``cablesvc bench kernel: ...``, ``cablesvc beam identify: ...``
WITH_ACTION = ("bench", "beam")


class UsageError(ConfigError, ValueError):
    """A command-line value that no config can fix (``--count 0``, ``--rate -1``): exit status 2."""

    exit_status = 2


def exit_status(e: CablesvcError) -> int:
    """The exit status for ``e``: its class's ``exit_status`` (2 for a usage error), else 1."""
    return int(getattr(e, "exit_status", 1))


def zenoh_failure(what: str, where: str, e: BaseException) -> ServiceError:
    """A Zenoh error (``zenoh.ZError``) as one line: ``cannot open the Zenoh session
    (<where>): <zenoh's message without its source location>``; ``what`` is ``open the
    Zenoh session`` or ``use the Zenoh configuration``."""
    return ServiceError(f"cannot {what} ({where}): {str(e).split(' at /')[0]}")


def run_command(args) -> int:
    """Run the parsed command ``args.func(args)``; a :class:`CablesvcError` becomes one line
    on stderr, ``cablesvc <command>: <message>`` (``bench kernel`` for a benchmark, ``beam
    identify`` for a beam action), and its exit status."""
    try:
        return int(args.func(args) or 0)
    except CablesvcError as e:
        action = getattr(args, args.command, None) if args.command in WITH_ACTION else None
        command = " ".join(c for c in (args.command, action) if c)
        print(f"cablesvc {command}: {e}", file=sys.stderr)
        return exit_status(e)
