"""Recording formats 1 and 2 (specified in ``docs/recording-format.md``): MCAP and CSV.

``read_recording`` / ``write_recording`` dispatch on the file suffix; ``iter_inputs``
streams ticks; ``McapRecordingWriter`` writes a live recording tick by tick (plus the
output topics in ``docs/recording.md``). ``RecordingError`` (a
:class:`cablesvc.errors.RecordingError`) names the file, the place and the reason.

Modules, each importing only those before it: ``schemas`` (the MCAP topics and their JSON
schemas), ``format`` (versions, :class:`Recording`, ticks, errors), ``protobuf_block`` (the
binary block encoding), ``mcap_json`` (the JSON encoding), ``mcap_layout`` (an MCAP file's
record structure, complete or cut short), ``mcap_writer``, ``mcap_reader``, ``csv_io``,
``files`` (dispatch on the suffix), ``chunks`` (a long recording in pieces).
"""

import importlib
from typing import Any

#: each public name and the module that defines it; a name is imported on first use
#: (module ``__getattr__``), so that ``cablesvc.recording.schemas`` (the topics and JSON
#: schemas the live service's messages use) does not pull in the MCAP and CSV readers and
#: writers: ``cablesvc listen`` starts without them
_HOMES = {
    "csv_io": ("POSE_COLUMNS", "csv_header", "iter_csv_inputs", "read_csv", "read_csv_metadata", "write_csv"),
    "files": ("iter_inputs", "read_metadata", "read_recording", "write_recording"),
    "format": ("BLOCK_FORMAT_VERSION", "ENCODINGS", "FORMAT_VERSION", "METADATA_NAME", "Recording", "RecordingError",
               "RecordingTruncatedWarning", "Tick", "Truncation"),
    "mcap_reader": ("iter_mcap_inputs", "read_mcap", "read_mcap_metadata"),
    "mcap_writer": ("DEFAULT_BLOCK_TICKS", "DEFAULT_CHUNK_SIZE", "DEFAULT_ENCODING", "McapRecordingWriter",
                    "write_mcap"),
    "schemas": ("ALARM_JSON_SCHEMA", "ALARM_SCHEMA_NAME", "ALARMS_TOPIC", "FORCES_JSON_SCHEMA", "FORCES_SCHEMA_NAME",
                "FORCES_TOPIC", "INPUT_JSON_SCHEMA", "INPUT_SCHEMA_NAME", "INPUT_TOPIC", "MESSAGE_ENCODING",
                "OUTPUT_TOPICS", "SCHEMA_ENCODING"),
}
_HOME = {name: module for module, names in _HOMES.items() for name in names}


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first use (then an attribute here)."""
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


#: the public names: those of the table above
__all__ = sorted(_HOME)
