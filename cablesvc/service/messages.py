"""Payloads the live daemon publishes, their JSON Schemas and their encodings.

Three payloads (key expressions in :mod:`cablesvc.service.zenoh_io`, full description with
examples in ``docs/messages.md``):

- **forces** (:data:`FORCES_SCHEMA`), one per processed tick: predicted force, elongation,
  wrap angle and slack flag per cable, measured force and residual when the bus has
  them, the wrench residual, the pose used. Built on the MCAP ``/cablesvc/forces``
  schema of :mod:`cablesvc.recording.schemas` (seq, t, force), so a superset of it.
- **alarm** (:data:`ALARM_SCHEMA`), one per raise or clear: ``AlarmEvent.payload()``. Built
  on the MCAP ``/cablesvc/alarms`` schema (t, severity, code, message, seq, cable).
- **status** (:data:`STATUS_SCHEMA`), the answer to a query on the status key.

Numbers are SI (N, m, rad, s, ns). Non-finite numbers never appear: an absent value is
null (a cable without a force sensor has a null measured force; a tick without any
measured force has ``measured`` and ``residual`` null).

Encodings (:func:`encode` / :func:`decode`):

- ``"json"`` -> ``application/json``: UTF-8 JSON. Python's float repr is the shortest
  string that reads back to the same double, so floats round-trip exactly.
- ``"compact"`` -> ``application/x-cablesvc-forces-v1`` (forces only): a fixed binary
  layout of little-endian float64 arrays, laid out in ``docs/messages.md`` and in
  :func:`encode_compact`. Null numbers are NaN there. Also exact.
"""

from __future__ import annotations

import json
import math
import struct
from typing import Any, Sequence

import numpy as np
import orjson

from cablesvc.alarms import ACTIONS, ALARM_CODES, SEVERITIES
from cablesvc.recording.schemas import ALARM_JSON_SCHEMA, FORCES_JSON_SCHEMA, JSON_SCHEMA_DIALECT, json_schema

__all__ = [
    "ALARM_SCHEMA",
    "COMPACT_ENCODING",
    "ENCODINGS",
    "FORCES_SCHEMA",
    "JSON_ENCODING",
    "STATUS_SCHEMA",
    "check_schema",
    "decode",
    "decode_compact",
    "encode",
    "encode_compact",
    "forces_payload",
]

JSON_ENCODING = "application/json"
COMPACT_ENCODING = "application/x-cablesvc-forces-v1"
#: short name -> encoding string
ENCODINGS = {"json": JSON_ENCODING, "compact": COMPACT_ENCODING}

_NUM = {"type": ["number", "null"]}


def _vec(description: str, n: int | None = None, nullable: bool = False) -> dict[str, Any]:
    v: dict[str, Any] = {"type": "array", "items": _NUM, "description": description}
    if n is not None:
        v["minItems"] = v["maxItems"] = n
    if nullable:
        return {"description": description, "anyOf": [v, {"type": "null"}]}
    return v


def _extend(recorded: dict[str, Any], description: str, live: dict[str, Any], required: list[str]) -> dict[str, Any]:
    """The published schema of a message: its recorded schema (``cablesvc.recording.schemas``:
    the fields a recording keeps, as they are there) with the fields only the live daemon
    sends added, or constrained more tightly where ``live`` names a recorded field again."""
    return json_schema(recorded["title"], description, {**recorded["properties"], **live}, required)


FORCES_SCHEMA: dict[str, Any] = _extend(
    FORCES_JSON_SCHEMA,
    "Cable forces predicted by cablesvc for one input tick (published on cablesvc/<robot>/forces). "
    "SI units; arrays have one value per cable in robot-file order; non-finite numbers are null.",
    {
        "robot": {"type": "string", "description": "robot name (robot file)"},
        "stamp_ns": {"type": "integer",
                     "description": "daemon host CLOCK_MONOTONIC when the input tick was received, ns"},
        "cables": {"type": "array", "items": {"type": "string"}, "description": "cable names"},
        "elongation": _vec("elongation x = l(pose) - motor_length per cable, m"),
        "wrap_angle": _vec("pulley wrap angle per cable, rad"),
        "slack": {"type": "array", "items": {"type": "boolean"},
                  "description": "predicted tension below the slack threshold (force_min)"},
        "measured": _vec("measured force per cable, N (null for a cable without sensor); "
                         "null when the tick has no measured force", nullable=True),
        "residual": _vec("measured - predicted per cable, N; null when the tick has no measured force",
                         nullable=True),
        "wrench_residual": _vec("A^T f + w: fx, fy, fz [N], mx, my, mz [N m]", 6),
        "position": _vec("platform position used, m (world frame)", 3),
        "orientation": _vec("platform orientation used, unit quaternion [qx, qy, qz, qw]", 4),
        "amplitude": _vec("elongation amplitude estimate per cable, m (amplitude model); null otherwise",
                          nullable=True),
        "temperature": {"type": ["number", "null"], "description": "deg C, null when the bus has none"},
        "pose_from_fk": {"type": "boolean",
                         "description": "true when the pose came from the elasto-static forward kinematics"},
        "fk_residual": {"type": ["number", "null"], "description": "|A^T f + w| after the FK, N; 0 with a measured pose"},
    },
    ["robot", "seq", "t", "stamp_ns", "force", "elongation", "wrap_angle", "slack", "measured",
     "residual", "wrench_residual", "pose_from_fk"],
)

ALARM_SCHEMA: dict[str, Any] = _extend(
    ALARM_JSON_SCHEMA,
    "An alarm raised or cleared by cablesvc (published on cablesvc/<robot>/alarms). A superset of "
    "the MCAP /cablesvc/alarms schema.",
    {
        "action": {"enum": list(ACTIONS), "description": "raise: the condition holds; clear: it is over"},
        "code": {"enum": list(ALARM_CODES), "description": "stable machine-readable alarm code"},
        "severity": {"enum": list(SEVERITIES)},
        "since": {"type": ["number", "null"],
                  "description": "controller time the condition started, s (for a clear: of the alarm it clears)"},
        "offset_n": {"type": ["number", "null"], "description": "drift: estimated offset from the baseline, N"},
        "suggested_action": {"type": ["string", "null"], "description": "drift, spread: what to do"},
        "value": {"type": ["number", "null"],
                  "description": "the quantity at the event (N; m for amplitude_range; s for input alarms)"},
        "limit": {"type": ["number", "null"], "description": "the threshold it was compared with, same unit"},
        "robot": {"type": "string", "description": "robot name (optional)"},
    },
    ["action", "code", "cable", "severity", "t", "since", "seq", "message"],
)

STATUS_SCHEMA: dict[str, Any] = {
    "$schema": JSON_SCHEMA_DIALECT,
    "title": "cablesvc.Status",
    "description": ("Answer of the daemon to a query on cablesvc/<robot>/status. Only robot is guaranteed; the "
                    "daemon fills in the other documented fields, and may add more. Non-finite numbers are null."),
    "type": "object",
    "properties": {
        "robot": {"type": "string"},
        "version": {"type": "string", "description": "cablesvc version"},
        "uptime_s": {"type": ["number", "null"], "description": "s since the daemon started"},
        "ticks": {"type": ["integer", "null"], "description": "input ticks processed"},
        "published": {"type": ["integer", "null"], "description": "forces messages published"},
        "tick_rate_hz": {"type": ["number", "null"], "description": "recent input tick rate, Hz"},
        "latency_us": {"type": "object", "description": "input receive -> published, us: count, p50_us, p99_us, "
                                                        "p999_us, max_us"},
        "input": {"type": "object", "description": "bus source and its counters"},
        "recent_problems": {"type": "array", "items": {"type": "object"}},
        "model": {"type": "object", "description": "active cable model: name, params_file, source, fingerprint, "
                                                   "params, options, terms (discovered_terms), active_since, ..."},
        "params_reload": {"type": "object", "description": "parameter reloads (SIGHUP, cablesvc/<robot>/params): "
                                                           "file, key, accepted, refused, pending, last outcome"},
        "alarms_active": {"type": "array", "items": ALARM_SCHEMA, "description": "raise events of active alarms"},
        "snapshot": {"type": "object"},
        "last": {"type": "object", "description": "seq and t of the last tick"},
        "recording": {"type": "object"},
    },
    "required": ["robot"],
}


# ---- schema check ------------------------------------------------------------------------------

_JSON_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}


def check_schema(instance: Any, schema: dict[str, Any], path: str = "$") -> list[str]:
    """Problems of ``instance`` against ``schema`` (empty list: valid). Implements the part of
    JSON Schema 2020-12 the schemas of this module use: type, enum, properties, required,
    items, minItems, maxItems, anyOf. For tests and debugging, not a general validator."""
    probs: list[str] = []
    if "anyOf" in schema:
        if all(check_schema(instance, sub, path) for sub in schema["anyOf"]):
            probs.append(f"{path}: matches none of the allowed forms")
        return probs
    t = schema.get("type")
    if t is not None:
        types = [t] if isinstance(t, str) else list(t)
        if not any(_JSON_TYPES[k](instance) for k in types):
            return [f"{path}: expected {' or '.join(types)}, got {instance!r:.60}"]
    if "enum" in schema and instance not in schema["enum"]:
        probs.append(f"{path}: {instance!r} not one of {schema['enum']}")
    if isinstance(instance, dict):
        for k in schema.get("required", ()):
            if k not in instance:
                probs.append(f"{path}: missing required {k!r}")
        for k, sub in schema.get("properties", {}).items():
            if k in instance:
                probs += check_schema(instance[k], sub, f"{path}.{k}")
    if isinstance(instance, list):
        if "minItems" in schema and len(instance) < schema["minItems"]:
            probs.append(f"{path}: fewer than {schema['minItems']} items")
        if "maxItems" in schema and len(instance) > schema["maxItems"]:
            probs.append(f"{path}: more than {schema['maxItems']} items")
        if "items" in schema:
            for j, v in enumerate(instance):
                probs += check_schema(v, schema["items"], f"{path}[{j}]")
    return probs


# ---- forces payload ----------------------------------------------------------------------------

def _floats(a) -> list:
    """list of Python floats; non-finite values -> None."""
    lst = a.tolist() if isinstance(a, np.ndarray) else [float(v) for v in a]
    isf = math.isfinite
    for v in lst:
        if not isf(v):
            return [v if isf(v) else None for v in lst]
    return lst


def _floats_or_none(a) -> list | None:
    """Like :func:`_floats`, but None when no value is finite (the part is absent)."""
    lst = a.tolist() if isinstance(a, np.ndarray) else [float(v) for v in a]
    isf = math.isfinite
    n_fin = 0
    for v in lst:
        if isf(v):
            n_fin += 1
    if n_fin == len(lst):
        return lst
    if n_fin == 0:
        return None
    return [v if isf(v) else None for v in lst]


def _scalar(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def forces_payload(robot: str, seq: int, out, stamp_ns: int, cable_names: Sequence[str]) -> dict[str, Any]:
    """The forces message of one tick, matching :data:`FORCES_SCHEMA`.

    ``out`` a :class:`~cablesvc.kernel.TickOutput` (its arrays are copied into lists),
    ``stamp_ns`` the daemon's ``time.monotonic_ns()`` when the input tick was received,
    ``cable_names`` the robot's cable names."""
    return {
        "robot": robot,
        "seq": int(seq),
        "t": float(out.t),
        "stamp_ns": int(stamp_ns),
        "cables": list(cable_names),
        "force": _floats(out.force),
        "elongation": _floats(out.elongation),
        "wrap_angle": _floats(out.wrap_angle),
        "slack": out.slack.tolist() if isinstance(out.slack, np.ndarray) else [bool(v) for v in out.slack],
        "measured": _floats_or_none(out.measured),
        "residual": _floats_or_none(out.residual),
        "wrench_residual": _floats(out.wrench_residual),
        "position": _floats(out.position),
        "orientation": _floats(out.orientation),
        "amplitude": _floats_or_none(out.amplitude),
        "temperature": _scalar(out.temperature),
        "pose_from_fk": bool(out.pose_from_fk),
        "fk_residual": _scalar(out.fk_residual),
    }


# ---- encodings ---------------------------------------------------------------------------------

_ORJSON_OPTS = orjson.OPT_SERIALIZE_NUMPY


def _dumps_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def encode(payload: dict[str, Any], encoding: str) -> tuple[bytes, str]:
    """(bytes, encoding string) of a payload. ``encoding``: "json" (any payload) or
    "compact" (forces payloads only); the full encoding strings are accepted too.
    JSON output has no NaN/Infinity: :func:`forces_payload` and ``AlarmEvent.payload``
    already use null, anything else non-finite raises ValueError."""
    enc = _normalise(encoding)
    if enc == JSON_ENCODING:
        # orjson: shortest round-trip float text like json's repr, ~20x faster (1 kHz budget)
        try:
            return orjson.dumps(payload, default=_dumps_default, option=_ORJSON_OPTS), JSON_ENCODING
        except TypeError:          # e.g. an int beyond 64 bits: the standard library handles it
            return (json.dumps(payload, separators=(",", ":"), allow_nan=False, default=_dumps_default).encode(),
                    JSON_ENCODING)
    return encode_compact(payload), COMPACT_ENCODING


def decode(data: bytes | bytearray | memoryview, encoding: str) -> dict[str, Any]:
    """Inverse of :func:`encode`. ``encoding`` as published (a Zenoh encoding string, with
    or without a ``;schema`` suffix) or a short name. Raises ValueError on bad data."""
    enc = _normalise(encoding)
    if enc == JSON_ENCODING:
        try:
            out = orjson.loads(bytes(data))          # ~5x json.loads: a subscriber keeps up at 1 kHz
        except orjson.JSONDecodeError as e:
            raise ValueError(f"not valid JSON: {e}") from None
        if not isinstance(out, dict):
            raise ValueError("JSON payload is not an object")
        return out
    return decode_compact(data)


def _normalise(encoding: str) -> str:
    e = str(encoding).split(";", 1)[0].strip()
    e = ENCODINGS.get(e, e)
    if e not in (JSON_ENCODING, COMPACT_ENCODING):
        raise ValueError(f"unknown encoding {encoding!r}; known: json ({JSON_ENCODING}), compact ({COMPACT_ENCODING})")
    return e


# compact layout, version 1 (docs/messages.md):
#   header  <4s B B H q q d  = magic b"CSF1", version 1, flags, m, seq, stamp_ns, t     (32 bytes)
#           flags: 1 pose_from_fk, 2 measured, 4 residual, 8 amplitude, 16 cable names, 32 position/orientation
#   fixed   15 x <f8        = fk_residual, temperature, wrench_residual[6], position[3], orientation[4]
#   cables  m x <f8 each    = force, elongation, wrap_angle, then measured, residual, amplitude if flagged
#   slack   m x u8          = 0 / 1
#   names   u8 len + UTF-8  = robot, then each cable name
_MAGIC = b"CSF1"
_VERSION = 1
_HEADER = struct.Struct("<4sBBHqqd")
_F_POSE_FK, _F_MEASURED, _F_RESIDUAL, _F_AMPLITUDE, _F_CABLES, _F_POSE = 1, 2, 4, 8, 16, 32
_N_FIXED = 15


_STRUCTS: dict[int, struct.Struct] = {}


def _f64_struct(n: int) -> struct.Struct:
    st = _STRUCTS.get(n)
    if st is None:
        st = _STRUCTS[n] = struct.Struct(f"<{n}d")
    return st


def _name(s: str) -> bytes:
    b = s.encode()
    if len(b) > 255:
        raise ValueError(f"compact encoding: name longer than 255 bytes: {s[:40]!r}...")
    return bytes((len(b),)) + b


_NAN = math.nan
_NAMES: dict[tuple, bytes] = {}          # (robot, *cables) -> encoded names block
_NONE3 = (None, None, None)
_NONE4 = (None, None, None, None)


def encode_compact(p: dict[str, Any]) -> bytes:
    """Forces payload -> compact binary (layout above and in ``docs/messages.md``)."""
    try:
        force = p["force"]
        m = len(force)
        flags = _F_POSE_FK if p["pose_from_fk"] else 0
        pos = p.get("position")
        quat = p.get("orientation")
        if "position" in p or "orientation" in p:
            flags |= _F_POSE
        wres = p["wrench_residual"]
        if len(wres) != 6 or len(pos or _NONE3) != 3 or len(quat or _NONE4) != 4:
            raise ValueError("compact encoding: wrench_residual needs 6 values, position 3, orientation 4")
        vals = [p.get("fk_residual"), p.get("temperature"), *wres, *(pos or _NONE3), *(quat or _NONE4)]
        for key in ("force", "elongation", "wrap_angle"):
            v = p[key]
            if len(v) != m:
                raise ValueError(f"compact encoding: {key} must have {m} values, got {len(v)}")
            vals += v
        for key, flag in (("measured", _F_MEASURED), ("residual", _F_RESIDUAL), ("amplitude", _F_AMPLITUDE)):
            v = p.get(key)
            if v is not None:
                if len(v) != m:
                    raise ValueError(f"compact encoding: {key} must have {m} values, got {len(v)}")
                flags |= flag
                vals += v
        st = _f64_struct(len(vals))
        try:
            floats = st.pack(*vals)
        except struct.error:                      # None (null) -> NaN
            floats = st.pack(*[_NAN if v is None else v for v in vals])
        cables = p.get("cables")
        if cables is not None:
            flags |= _F_CABLES
            if len(cables) != m:
                raise ValueError(f"compact encoding: {len(cables)} cable names for {m} cables")
            ck = (p["robot"], *cables)
        else:
            ck = (p["robot"],)
        names = _NAMES.get(ck)
        if names is None:
            names = b"".join([_name(c) for c in ck])
            if len(_NAMES) < 64:
                _NAMES[ck] = names
        slack = bytes([1 if v else 0 for v in p["slack"]])
        if len(slack) != m:
            raise ValueError(f"compact encoding: slack must have {m} values")
        head = _HEADER.pack(_MAGIC, _VERSION, flags, m, int(p["seq"]), int(p["stamp_ns"]), float(p["t"]))
    except KeyError as e:
        raise ValueError(f"compact encoding is for forces payloads; missing {e}") from None
    except (struct.error, OverflowError, TypeError) as e:
        raise ValueError(f"compact encoding: {e}") from None
    return b"".join((head, floats, slack, names))


def _list(a: Sequence[float]) -> list:
    lst = list(a)
    for v in lst:
        if v != v:
            return [None if v != v else v for v in lst]
    return lst


def _opt(v: float) -> float | None:
    return None if v != v else v


def decode_compact(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """Compact binary -> forces payload (the dict :func:`forces_payload` made)."""
    buf = bytes(data)
    if len(buf) < _HEADER.size or buf[:4] != _MAGIC:
        raise ValueError("not a cablesvc compact forces message (bad magic)")
    magic, version, flags, m, seq, stamp_ns, t = _HEADER.unpack_from(buf, 0)
    if version != _VERSION:
        raise ValueError(f"compact forces message version {version}, this reader knows {_VERSION}")
    n_opt = sum(1 for f in (_F_MEASURED, _F_RESIDUAL, _F_AMPLITUDE) if flags & f)
    n_f = _N_FIXED + (3 + n_opt) * m
    off = _HEADER.size
    end = off + 8 * n_f
    if len(buf) < end + m + 1:
        raise ValueError("compact forces message truncated")
    f = _f64_struct(n_f).unpack_from(buf, off)
    slack = [b != 0 for b in buf[end:end + m]]
    pos = end + m
    names = []
    for _ in range(1 + (m if flags & _F_CABLES else 0)):
        if pos >= len(buf):
            raise ValueError("compact forces message truncated (names)")
        n = buf[pos]
        try:
            names.append(buf[pos + 1:pos + 1 + n].decode())
        except UnicodeDecodeError:
            raise ValueError("compact forces message: name is not UTF-8") from None
        pos += 1 + n
    if pos != len(buf):
        raise ValueError("compact forces message has trailing bytes")
    k = _N_FIXED
    per = {}
    for key in ("force", "elongation", "wrap_angle"):
        per[key] = _list(f[k:k + m])
        k += m
    for key, flag in (("measured", _F_MEASURED), ("residual", _F_RESIDUAL), ("amplitude", _F_AMPLITUDE)):
        if flags & flag:
            per[key] = _list(f[k:k + m])
            k += m
        else:
            per[key] = None
    fixed = f[:_N_FIXED]
    out = {
        "robot": names[0],
        "seq": seq,
        "t": t,
        "stamp_ns": stamp_ns,
    }
    if flags & _F_CABLES:
        out["cables"] = names[1:]
    out.update({
        "force": per["force"],
        "elongation": per["elongation"],
        "wrap_angle": per["wrap_angle"],
        "slack": slack,
        "measured": per["measured"],
        "residual": per["residual"],
        "wrench_residual": _list(f[2:8]),
    })
    if flags & _F_POSE:
        out["position"] = _list(f[8:11])
        out["orientation"] = _list(f[11:15])
    out["amplitude"] = per["amplitude"]
    out["temperature"] = _opt(fixed[1])
    out["pose_from_fk"] = bool(flags & _F_POSE_FK)
    out["fk_residual"] = _opt(fixed[0])
    return out
