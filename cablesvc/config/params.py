"""Cable-model parameter files (TOML): what identification writes and the kernel loads.

Format (SI units)::

    format = 1
    model = "amplitude"        # linear | polynomial | amplitude | boucwen | asymmetric
    robot = "ipanema3"         # robot the parameters belong to (checked against --robot)
    [options]                  # build options, not identified: degree, integrator, substeps
    [params]                   # each value: a number (every cable) or a list, one per cable
    x_center = 0.0
    [tables]                   # amplitude model only: one row per amplitude level
    amplitudes = [1e-4, 5e-4, 1e-3]      # m
    K1 = [2.1e4, 1.9e4, 1.8e4]           # per level (all cables) or a list of per-cable rows
    [identification]           # provenance, free form: data set, date, rmse, std errors,
    amplitude_range = [1e-4, 1.5e-3]     # elongation amplitudes the fit has seen (m)
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cablesvc.errors import ConfigError
from cablesvc.models import MODELS, CableModel, ModelParameterError
from cablesvc.models.base import is_int as _is_int

#: every option a parameter file's [options] may hold, over all models (each model says which
#: are its own: ``MODELS[name].file_options()``)
OPTION_KEYS = {k for cls in MODELS.values() for k in cls.file_options()}
#: every table a parameter file's [tables] may hold, over all models, in the models' order
TABLE_KEYS = tuple(dict.fromkeys(k for cls in MODELS.values() for k in cls.table_names))


def _no_tables(model: str) -> str:
    having = " or ".join(name for name, cls in MODELS.items() if cls.table_names)
    return f"tables: only the {having} model has tables, not {model!r}"


def _content_problems(model: str, params: dict, options: dict, tables: dict) -> list[str]:
    """Value checks of [params], [options] and [tables] for a known model: one message per
    problem, naming the field (shared by load_params and ModelParams.build). The checks are
    the model class's (``option_problems``, ``param_problems``, ``table_problems``)."""
    cls = MODELS[model]
    problems = cls.option_problems(options, OPTION_KEYS)
    problems += cls.param_problems(params)
    if cls.table_names:
        problems += cls.table_problems(tables)
    elif tables:
        problems.append(_no_tables(model))
    return problems


def _amplitude_range_problems(r: Any) -> list[str]:
    """identification.amplitude_range: two finite numbers lo, hi [m] with 0 <= lo <= hi, hi > 0.

    lo = hi and lo = 0 are allowed: identification writes them for a single amplitude level
    or a single fitted cable, and for a cable that did not move."""
    ok = isinstance(r, (list, tuple)) and len(r) == 2 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in r)
    if ok:
        lo, hi = float(r[0]), float(r[1])
        ok = bool(np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi and hi > 0)
    if ok:
        return []
    return [f"identification.amplitude_range: must be two finite amplitudes [lo, hi] in m with 0 <= lo <= hi and hi > 0, "
            f"got {r!r}"[:200]]


class ParamFileError(ConfigError, ValueError):
    """A parameter file is invalid; the message names the file and the field."""

    def __init__(self, path: str | Path, problems: list[str]):
        self.path = str(path)
        self.problems = problems
        super().__init__(f"{path}: invalid parameter file:\n" + "\n".join(f"  - {p}" for p in problems))


@dataclass
class ModelParams:
    """A cable model's configuration: which model, its options, parameters and tables."""

    model: str
    params: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    tables: dict[str, Any] = field(default_factory=dict)
    robot: str | None = None
    identification: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"

    def build(self, n_cables: int, lanes: int = 1) -> CableModel:
        """Instantiate the model for ``(lanes, n_cables)``; raises ParamFileError naming the field."""
        if self.model not in MODELS:
            raise ParamFileError(self.source, [f"model: unknown model {self.model!r}; known: {sorted(MODELS)}"])
        cls = MODELS[self.model]
        problems = _content_problems(self.model, self.params, self.options, self.tables)
        if problems:
            raise ParamFileError(self.source, problems)
        for k, v in self.params.items():
            a = np.asarray(v, dtype=float)
            if a.ndim > 1 or (a.ndim == 1 and a.size != n_cables):
                problems.append(f"params.{k}: expected a number or a list of {n_cables} values (one per cable), got shape {a.shape}")
        if problems:
            raise ParamFileError(self.source, problems)
        try:
            tabs = {k: np.asarray(v, dtype=float) for k, v in self.tables.items()}
        except (TypeError, ValueError) as e:      # not expected after the checks above
            raise ParamFileError(self.source, [f"tables: must hold numbers ({e})"]) from None
        params = {k: np.asarray(v, dtype=float) for k, v in self.params.items()}
        try:
            return cls.from_file((lanes, n_cables), params, dict(self.options), tabs)
        except ModelParameterError as e:
            raise ParamFileError(self.source, [str(e)]) from None
        except TypeError as e:
            raise ParamFileError(self.source, [f"options: {e}"]) from None
        except ValueError as e:      # not expected after the checks above; never a traceback
            raise ParamFileError(self.source, [f"{self.model} model: {e}"]) from None

    def amplitude_range(self) -> tuple[float, float] | None:
        """Elongation amplitudes [m] the parameters were identified on, if known."""
        r = self.identification.get("amplitude_range")
        if r is None:
            return MODELS[self.model].table_range(self.tables) if self.model in MODELS else None
        if _amplitude_range_problems(r):
            raise ParamFileError(self.source, _amplitude_range_problems(r))
        return float(r[0]), float(r[1])

    def to_toml(self) -> str:
        """Serialise to the TOML format of this module."""
        lines = ["format = 1", f'model = "{self.model}"']
        if self.robot:
            lines.append(f'robot = "{self.robot}"')
        for section, d in (("options", self.options), ("params", self.params), ("tables", self.tables),
                           ("identification", self.identification)):
            if d:
                lines.append(f"\n[{section}]")
                for k, v in d.items():
                    lines.append(f"{k} = {_toml_value(v)}")
        return "\n".join(lines) + "\n"

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml())


def _toml_value(v: Any) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def load_params(path: str | Path) -> ModelParams:
    """Read and check a parameter file. Raises ParamFileError listing every problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ParamFileError(path, ["file not found"]) from None
    except UnicodeDecodeError as e:
        raise ParamFileError(path, [f"not UTF-8 text (byte {e.start}): a TOML file is UTF-8"]) from None
    except OSError as e:
        raise ParamFileError(path, [f"cannot read: {e.strerror or e}"]) from None
    return parse_params(text, str(path))


def parse_params(text: str | bytes, source: str = "<text>") -> ModelParams:
    """Check the TOML text of a parameter file (e.g. a Zenoh put of one); ``source`` names it
    in the messages and becomes :attr:`ModelParams.source`. Raises ParamFileError listing
    every problem, as :func:`load_params` does for a file."""
    path = source
    if isinstance(text, (bytes, bytearray, memoryview)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as e:
            raise ParamFileError(path, [f"not UTF-8 text (byte {e.start}): a TOML file is UTF-8"]) from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ParamFileError(path, [f"TOML syntax: {e}"]) from None
    problems = []
    for section in ("options", "params", "tables", "identification"):
        if section in raw and not isinstance(raw[section], dict):
            problems.append(f"{section}: must be a table ([{section}]), got {type(raw[section]).__name__}")
    if problems:
        raise ParamFileError(path, problems)
    known = {"format", "model", "robot", "options", "params", "tables", "identification"}
    for k in raw:
        if k not in known:
            problems.append(f"{k}: unknown key (known: {sorted(known)})")
    fmt = raw.get("format")
    if not (_is_int(fmt) and fmt == 1):
        problems.append(f"format: must be the integer 1, got {fmt!r}")
    model = raw.get("model")
    if not isinstance(model, str) or model not in MODELS:
        problems.append(f"model: must be one of {sorted(MODELS)}, got {model!r}")
    for k in raw.get("options", {}):
        if k not in OPTION_KEYS:
            problems.append(f"options.{k}: unknown option (known: {sorted(OPTION_KEYS)})")
    if isinstance(model, str) and model in MODELS:
        cls = MODELS[model]
        names = cls.file_param_names()
        for k in raw.get("params", {}):
            if names is not None and k not in names:
                problems.append(f"params.{k}: not a parameter of the {model} model (parameters: {sorted(names)})")
        for k in raw.get("tables", {}):
            if k not in TABLE_KEYS:
                problems.append(f"tables.{k}: unknown table (known: {', '.join(TABLE_KEYS)})")
        if raw.get("tables") and not cls.table_names:
            problems.append(_no_tables(model))
        known_tables = {k: v for k, v in raw.get("tables", {}).items() if k in cls.table_names}
        problems += _content_problems(model, raw.get("params", {}), raw.get("options", {}), known_tables)
    if "amplitude_range" in raw.get("identification", {}):
        problems += _amplitude_range_problems(raw["identification"]["amplitude_range"])
    if problems:
        raise ParamFileError(path, problems)
    return ModelParams(model=model, params=dict(raw.get("params", {})), options=dict(raw.get("options", {})),
                       tables=dict(raw.get("tables", {})), robot=raw.get("robot"),
                       identification=dict(raw.get("identification", {})), source=str(path))


def default_params(ea: np.ndarray, cable_length: np.ndarray, model: str = "amplitude") -> ModelParams:
    """Nominal parameters for a robot without identified ones, from its cables' E*A [N] and
    a typical free length [m] per cable: the model class's :meth:`~CableModel.nominal` (the
    amplitude model: K1 = EA / L at every amplitude with a loss factor of 0.1; the linear
    model: E*A). These are nominal, not identified: the service reports them as such.
    Raises ValueError for a model without nominal parameters."""
    cls = MODELS.get(model)
    if cls is None or not cls.has_nominal:
        raise ValueError(f"no nominal parameters for model {model!r}; identify them with `cablesvc identify`")
    sections = cls.nominal(ea, cable_length)
    return ModelParams(model=cls.name, params=sections.get("params", {}), tables=sections.get("tables", {}),
                       identification=sections.get("identification", {}))


def home_lengths(geom: Any) -> np.ndarray:
    """The free length [m] of every cable at the home pose (platform at the origin, not
    rotated): the typical length the nominal parameters and the nominal stiffness EA / L use.
    ``geom`` is a :class:`~cablesvc.config.robot.RobotGeometry`; returns (m,)."""
    from cablesvc.kinematics import inverse_kinematics

    return inverse_kinematics(geom, np.zeros((1, 3)), np.array([[0.0, 0.0, 0.0, 1.0]])).length[0]


def nominal_params(geom: Any, model: str = "amplitude") -> ModelParams:
    """Nominal parameters at the home pose: :func:`default_params` for the robot's E*A and its
    cable lengths at the home pose (:func:`home_lengths`). The default model of the daemon,
    discovery and the twin when no parameter file is given."""
    return default_params(geom.ea, home_lengths(geom), model)
