"""The exceptions of cablesvc: one root, one class per area.

Every error that cablesvc raises on purpose (a bad file, field, frame or option; a
recording it cannot read; a model whose parameters break its rules; a fit or a discovery
that cannot run; a daemon that cannot start) derives from :class:`CablesvcError`, through
the area it belongs to. The command line catches :class:`CablesvcError` and prints its
message as one line (``cablesvc <command>: <message>``); anything else is a bug and keeps
its traceback.

More specific classes live next to the code that raises them (``ParamFileError`` in
``config/params.py``, ``SourceConfigError`` in ``sources/base.py``, ...) and derive from
one of the area classes here; ``RecordingError``, ``IdentifyError``, ``DiscoveryError`` and
``SimulationError`` are raised as they are (``cablesvc.recording`` and the other packages
export them under the same names). Where a class was a ``ValueError`` or a
``RuntimeError`` before, it still is (it derives from both), so code that catches the
built-in keeps working.
"""

from __future__ import annotations

from typing import Any, Optional

__all__ = ["CablesvcError", "ConfigError", "RecordingError", "SourceError", "ModelError", "IdentifyError",
           "DiscoveryError", "SimulationError", "ServiceError", "BatchError"]


class CablesvcError(Exception):
    """Root of every error cablesvc raises on purpose; its message is meant for the user."""


class ConfigError(CablesvcError):
    """A robot file, parameter file, daemon or fleet configuration, or command-line option
    is wrong; the message names the file and the field."""


class RecordingError(CablesvcError):
    """A recording file (MCAP or CSV, format 1 or 2) cannot be read or written.

    ``path`` is the file, ``location`` where in it (``"message 17 on /cablesvc/input"``,
    ``"line 42, column f3"``, ``"metadata"``, ``"file"``), ``reason`` what is wrong; printed as
    ``path: location: reason``. Message indexes are 0-based in file order among the messages
    of that topic (= the row of the tick in the recording); CSV line numbers are 1-based
    physical lines. ``RecordingError(message)`` alone is a message with no location.
    """

    def __init__(self, path: Any, location: Optional[str] = None, reason: Optional[str] = None):
        # args as given: Dask and pickle rebuild the exception from them
        if reason is None and location is None:
            super().__init__(str(path))
        else:
            super().__init__(str(path), location or "file", reason)
        self.path = str(path)
        self.location = location or "file"
        self.reason = reason

    def __str__(self) -> str:
        return self.path if self.reason is None else f"{self.path}: {self.location}: {self.reason}"


class SourceError(CablesvcError):
    """An input source (CAN, Modbus, replay, simulated controller) cannot be opened or is
    configured wrongly."""


class ModelError(CablesvcError):
    """A cable model's or physics term's parameters break its rules (units, bounds, shape)."""


class IdentifyError(CablesvcError, ValueError):
    """Identification cannot run on the data or options given."""


class DiscoveryError(CablesvcError, ValueError):
    """Discovery cannot run on the recording or options given."""


class SimulationError(CablesvcError, ValueError):
    """The digital twin cannot simulate the scenario asked for."""


class ServiceError(CablesvcError):
    """The live daemon (one robot or a fleet) cannot start or go on."""


class BatchError(CablesvcError):
    """An offline job over many recordings (``cablesvc discover/identify`` on a fleet)
    cannot run: bad inputs, or a cluster that cannot take the work."""
