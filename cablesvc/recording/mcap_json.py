"""The JSON encoding of MCAP messages (format 1 inputs, and the output topics): a tick or
payload to bytes for the writer, and the reader's strict parse of one input message.

Non-finite numbers are written as null; a part (pose, force) whose values are all
non-finite is a null part. The reader accepts exactly what ``INPUT_JSON_SCHEMA``
(``schemas.py``) describes and names the field at fault (:class:`BadField`).
"""

from __future__ import annotations

import json
import math
from typing import Any, Optional

import numpy as np

from ..jsonable import jsonable
from .format import INT64_MAX, INT64_MIN

_ENCODER = json.JSONEncoder(allow_nan=False, separators=(",", ":"))


# ===================================================================== writing
def float_list(x: Any, name: str, n: Optional[int] = None) -> list:
    """A 1-D sequence of numbers as a list of Python floats, non-finite values as None."""
    if isinstance(x, np.ndarray):
        if x.ndim != 1:
            raise ValueError(f"{name} must be 1-D, has shape {x.shape}")
        if x.dtype != np.float64:
            x = x.astype(np.float64)
        lst = x.tolist()
    else:
        lst = [float(v) for v in x]
    if n is not None and len(lst) != n:
        raise ValueError(f"{name} has {len(lst)} values, expected {n}")
    if not all(map(math.isfinite, lst)):
        lst = [v if math.isfinite(v) else None for v in lst]
    return lst


def encode_payload(payload: dict) -> bytes:
    """A JSON object (numpy arrays and scalars converted) as compact UTF-8 JSON."""
    try:
        return _ENCODER.encode(payload).encode()
    except (TypeError, ValueError):
        return _ENCODER.encode(jsonable(payload)).encode()


def _part_or_null(lst: list) -> Optional[list]:
    """``None`` (JSON null) for a part whose values are all non-finite (already None)."""
    return None if all(v is None for v in lst) else lst


def encode_input(seq: int, t: float, ml: list, force: Any, position: Any, orientation: Any,
                 temperature: Optional[float], n_cables: int) -> bytes:
    """One ``/cablesvc/input`` message of format 1; ``ml`` already through :func:`float_list`."""
    f = None if force is None else _part_or_null(float_list(force, "force", n_cables))
    if position is None and orientation is None:
        pose = None
    elif position is None or orientation is None:
        raise ValueError("position and orientation must be given together")
    else:
        pos = float_list(position, "position", 3)
        ori = float_list(orientation, "orientation", 4)
        # All non-finite: no pose (null), as write_mcap and the readers treat it.
        pose = None if _part_or_null(pos + ori) is None else {
            "position": pos, "orientation": ori
        }
    temp = None
    if temperature is not None:
        temp = float(temperature)
        if not math.isfinite(temp):
            temp = None
    return _ENCODER.encode(
        {
            "seq": seq,
            "t": t,
            "pose": pose,
            "motor_length": ml,
            "force": f,
            "temperature": temp,
        }
    ).encode()


# ===================================================================== reading
def json_type(v: Any) -> str:
    """The JSON type of a decoded value, in words (``"an array"``, ``"null"``, ...)."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "an object"
    return type(v).__name__


class BadField(Exception):
    """A field of one input message breaks the schema: ``name`` (``""`` for the whole
    message) and ``reason``; the reader turns it into a ``RecordingError`` naming the message."""

    def __init__(self, name: str, reason: str):
        super().__init__(name, reason)
        self.name = name
        self.reason = reason


def _numbers(v: Any, name: str, n: Optional[int], why: str = "") -> list:
    if type(v) is not list:
        raise BadField(name, f"expected an array of numbers, got {json_type(v)}")
    if n is not None and len(v) != n:
        raise BadField(name, f"has {len(v)} values, expected {n}{why}")
    for i, x in enumerate(v):
        tx = type(x)
        if tx is int:
            v[i] = _to_float(x, f"{name}[{i}]")
        elif tx is not float and x is not None:
            raise BadField(f"{name}[{i}]", f"expected a number or null, got {json_type(x)}")
    return v


def _to_float(x: int, name: str) -> float:
    """A JSON integer literal as a float; one beyond the float range is a bad field."""
    try:
        return float(x)
    except OverflowError:
        raise BadField(
            name, f"integer of {x.bit_length()} bits is too large for a 64-bit float "
            "(beyond +-1.8e308)"
        ) from None


def _absent(v: list) -> bool:
    return all(x is None or x != x for x in v)


_MISSING = object()


def parse_input(data: bytes, n_cables: Optional[int], robot_cables: Optional[int]) -> tuple:
    """One format-1 input message as ``(seq, t, position, orientation, motor_length, force,
    temperature)`` (lists of floats or None). ``n_cables``: the count every tick must have
    (None: this is the first tick, which fixes it); ``robot_cables`` only words the message.
    Raises :class:`BadField`."""
    try:
        obj = json.loads(data)
    except ValueError as e:
        raise BadField("", f"not valid JSON: {e}") from None
    except RecursionError:
        raise BadField("", "not valid JSON for format 1: nested too deeply") from None
    if type(obj) is not dict:
        raise BadField("", f"expected a JSON object, got {json_type(obj)}")
    seq = obj.get("seq", _MISSING)
    if seq is _MISSING:
        raise BadField("seq", "missing required field")
    if type(seq) is not int:
        raise BadField("seq", f"expected an integer, got {json_type(seq)} ({seq!r})")
    if not INT64_MIN <= seq <= INT64_MAX:
        raise BadField("seq", f"{seq} does not fit in 64 bits")
    t = obj.get("t", _MISSING)
    if t is _MISSING:
        raise BadField("t", "missing required field")
    if type(t) is int:
        t = _to_float(t, "t")
    elif type(t) is not float:
        raise BadField("t", f"expected a number, got {json_type(t)}")
    if not math.isfinite(t):
        raise BadField("t", f"must be finite, got {t!r}")
    ml = obj.get("motor_length", _MISSING)
    if ml is _MISSING:
        raise BadField("motor_length", "missing required field")
    if n_cables is None:
        ml = _numbers(ml, "motor_length", None)
        if not ml:
            raise BadField("motor_length", "is empty (a robot has at least 1 cable)")
        n_cables = len(ml)
    else:
        why = (
            f" (the robot has {n_cables} cables)"
            if robot_cables is not None
            else f" (message 0 had {n_cables})"
        )
        ml = _numbers(ml, "motor_length", n_cables, why)
    pose = obj.get("pose")
    position = orientation = None
    if pose is not None:
        if type(pose) is not dict:
            raise BadField("pose", f"expected an object or null, got {json_type(pose)}")
        for part in ("position", "orientation"):
            if part not in pose:
                raise BadField(
                    f"pose.{part}", "missing (pose needs position and orientation)"
                )
        position = _numbers(pose["position"], "pose.position", 3)
        orientation = _numbers(pose["orientation"], "pose.orientation", 4)
        if _absent(position) and _absent(orientation):
            position = orientation = None
    force = obj.get("force")
    if force is not None:
        force = _numbers(
            force, "force", n_cables, " (one per cable, like motor_length)"
        )
        if _absent(force):
            force = None
    temp = obj.get("temperature")
    if temp is not None:
        if type(temp) is not float and type(temp) is not int:
            raise BadField(
                "temperature", f"expected a number or null, got {json_type(temp)}"
            )
        temp = _to_float(temp, "temperature") if type(temp) is int else temp
        if temp != temp:
            temp = None
    return seq, t, position, orientation, ml, force, temp
