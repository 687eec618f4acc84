"""The MCAP topics of a recording and their JSON schemas (``docs/recording-format.md``,
``docs/recording.md``): the one home of the input, forces and alarm schemas.

The input schema describes ``/cablesvc/input`` in format 1 (JSON inputs; format 2's binary
blocks have their protobuf schema in ``protobuf_block.py``). The forces and alarm schemas
are what the live service and ``--record`` register for ``/cablesvc/forces`` and
``/cablesvc/alarms``; the messages the daemon publishes on Zenoh
(:mod:`cablesvc.service.messages`) extend these two schemas with their live-only fields, so
every published payload is also a valid recorded one.

A writer embeds ``json.dumps`` of these dicts in the file: their text is part of the format.
"""

from __future__ import annotations

from typing import Any, Optional

__all__ = [
    "ALARM_JSON_SCHEMA",
    "ALARM_SCHEMA_NAME",
    "ALARMS_TOPIC",
    "FORCES_JSON_SCHEMA",
    "FORCES_SCHEMA_NAME",
    "FORCES_TOPIC",
    "INPUT_JSON_SCHEMA",
    "INPUT_SCHEMA_NAME",
    "INPUT_TOPIC",
    "JSON_SCHEMA_DIALECT",
    "MESSAGE_ENCODING",
    "OUTPUT_TOPICS",
    "SCHEMA_ENCODING",
    "json_schema",
    "vector",
]

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

INPUT_TOPIC = "/cablesvc/input"
INPUT_SCHEMA_NAME = "cablesvc.Input"

_NUMBER_OR_NULL = {"type": ["number", "null"]}


def vector(n: Optional[int], description: str) -> dict[str, Any]:
    """An array of numbers (null for a non-finite one): ``n`` of them, or at least one."""
    out: dict[str, Any] = {"type": "array", "items": _NUMBER_OR_NULL, "description": description}
    if n is None:
        out["minItems"] = 1
    else:
        out["minItems"] = n
        out["maxItems"] = n
    return out


def json_schema(title: str, description: str, properties: dict[str, Any],
                required: list[str]) -> dict[str, Any]:
    """A JSON Schema document of one object message (keys in the order the files hold)."""
    return {
        "$schema": JSON_SCHEMA_DIALECT,
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": required,
    }


INPUT_JSON_SCHEMA: dict[str, Any] = json_schema(
    INPUT_SCHEMA_NAME,
    "One control tick of a cable-driven parallel robot (cablesvc recording format 1). "
    "SI units; cable i is the i-th cable of the robot file; non-finite numbers are null.",
    {
        "seq": {"type": "integer", "description": "tick counter, +1 per tick"},
        "t": {"type": "number", "description": "controller clock, s; log_time = t in ns"},
        "pose": {
            "description": "platform pose, or null when the controller has none",
            "anyOf": [
                {
                    "type": "object",
                    "properties": {
                        "position": vector(3, "x, y, z in m"),
                        "orientation": vector(4, "unit quaternion [qx, qy, qz, qw]"),
                    },
                    "required": ["position", "orientation"],
                },
                {"type": "null"},
            ],
        },
        "motor_length": vector(None, "unstretched length paid out per cable, m"),
        "force": {
            "description": "measured cable forces, N, one per cable; null without sensors",
            "anyOf": [vector(None, "N per cable"), {"type": "null"}],
        },
        "temperature": {"type": ["number", "null"], "description": "deg C, or null"},
    },
    ["seq", "t", "pose", "motor_length", "force", "temperature"],
)

# Output topics cablesvc itself writes (docs/recording.md). Readers ignore topics they do
# not know; these schemas are what the live service and ``--record`` put in the file.
FORCES_TOPIC = "/cablesvc/forces"
FORCES_SCHEMA_NAME = "cablesvc.Forces"
FORCES_JSON_SCHEMA: dict[str, Any] = json_schema(
    FORCES_SCHEMA_NAME,
    "cable forces predicted by cablesvc for one input tick",
    {
        "seq": {"type": "integer", "description": "seq of the input tick predicted for"},
        "t": {"type": "number", "description": "t of that input tick, s"},
        "force": vector(None, "predicted force per cable, N"),
    },
    ["seq", "t", "force"],
)

ALARMS_TOPIC = "/cablesvc/alarms"
ALARM_SCHEMA_NAME = "cablesvc.Alarm"
ALARM_JSON_SCHEMA: dict[str, Any] = json_schema(
    ALARM_SCHEMA_NAME,
    "an alarm raised by cablesvc",
    {
        "seq": {"type": ["integer", "null"], "description": "input tick that raised it"},
        "t": {"type": "number", "description": "controller clock, s"},
        "severity": {"enum": ["info", "warning", "error"]},
        "code": {"type": "string", "description": "stable machine-readable alarm code"},
        "cable": {"type": ["integer", "null"], "description": "0-based cable, or null"},
        "message": {"type": "string", "description": "human-readable text"},
    },
    ["t", "severity", "code", "message"],
)

#: topic -> (schema name, JSON schema) for the output topics cablesvc documents.
OUTPUT_TOPICS: dict[str, tuple[str, dict[str, Any]]] = {
    FORCES_TOPIC: (FORCES_SCHEMA_NAME, FORCES_JSON_SCHEMA),
    ALARMS_TOPIC: (ALARM_SCHEMA_NAME, ALARM_JSON_SCHEMA),
}
