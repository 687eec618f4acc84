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

from cablesvc.models import MODELS, AmplitudeDependent, CableModel, ModelParameterError
from cablesvc.models.amplitude import TABLE_COLUMNS

OPTION_KEYS = {"degree", "integrator", "substeps"}


class ParamFileError(ValueError):
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
        problems = []
        for k, v in self.params.items():
            a = np.asarray(v, dtype=float)
            if a.ndim > 1 or (a.ndim == 1 and a.size != n_cables):
                problems.append(f"params.{k}: expected a number or a list of {n_cables} values (one per cable), got shape {a.shape}")
        if problems:
            raise ParamFileError(self.source, problems)
        kwargs: dict[str, Any] = {k: np.asarray(v, dtype=float) for k, v in self.params.items()}
        kwargs.update(self.options)
        try:
            if cls is AmplitudeDependent:
                try:
                    tabs = {k: np.asarray(v, dtype=float) for k, v in self.tables.items()}
                except (TypeError, ValueError) as e:
                    raise ParamFileError(self.source, [f"tables: must hold numbers ({e})"]) from None
                if "amplitudes" not in tabs:
                    raise ParamFileError(self.source, ["tables.amplitudes: required for the amplitude model"])
                return cls((lanes, n_cables), **tabs, **kwargs)
            if self.tables:
                raise ParamFileError(self.source, [f"tables: only the amplitude model has tables, not {self.model!r}"])
            return cls((lanes, n_cables), **kwargs)
        except ModelParameterError as e:
            raise ParamFileError(self.source, [str(e)]) from None
        except TypeError as e:
            raise ParamFileError(self.source, [f"options: {e}"]) from None

    def amplitude_range(self) -> tuple[float, float] | None:
        """Elongation amplitudes [m] the parameters were identified on, if known."""
        r = self.identification.get("amplitude_range")
        if r is None and self.model == "amplitude" and "amplitudes" in self.tables:
            a = np.asarray(self.tables["amplitudes"], dtype=float)
            return float(a.min()), float(a.max())
        return None if r is None else (float(r[0]), float(r[1]))

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
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ParamFileError(path, ["file not found"]) from None
    except UnicodeDecodeError as e:
        raise ParamFileError(path, [f"not UTF-8 text (byte {e.start}): a TOML file is UTF-8"]) from None
    except OSError as e:
        raise ParamFileError(path, [f"cannot read: {e.strerror or e}"]) from None
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
    if raw.get("format") != 1:
        problems.append(f"format: must be 1, got {raw.get('format')!r}")
    model = raw.get("model")
    if not isinstance(model, str) or model not in MODELS:
        problems.append(f"model: must be one of {sorted(MODELS)}, got {model!r}")
    for k in raw.get("options", {}):
        if k not in OPTION_KEYS:
            problems.append(f"options.{k}: unknown option (known: {sorted(OPTION_KEYS)})")
    if isinstance(model, str) and model in MODELS:
        cls = MODELS[model]
        names = set(cls.param_names) if model != "polynomial" else None
        for k, v in raw.get("params", {}).items():
            if names is not None and k not in names:
                problems.append(f"params.{k}: not a parameter of the {model} model (parameters: {sorted(names)})")
            try:
                a = np.asarray(v, dtype=float)
                if not np.all(np.isfinite(a)):
                    problems.append(f"params.{k}: values must be finite")
            except (TypeError, ValueError):
                problems.append(f"params.{k}: must be a number or a list of numbers, got {v!r}")
        for k, v in raw.get("tables", {}).items():
            if k != "amplitudes" and k not in TABLE_COLUMNS:
                problems.append(f"tables.{k}: unknown table (known: amplitudes, {', '.join(TABLE_COLUMNS)})")
                continue
            try:
                a = np.asarray(v, dtype=float)
                if a.ndim not in (1, 2) or not np.all(np.isfinite(a)):
                    problems.append(f"tables.{k}: must be a list of finite numbers (one per level) or a list of "
                                    f"per-cable rows")
            except (TypeError, ValueError):
                problems.append(f"tables.{k}: must be a list of numbers, got {v!r}"[:200])
    if problems:
        raise ParamFileError(path, problems)
    return ModelParams(model=model, params=dict(raw.get("params", {})), options=dict(raw.get("options", {})),
                       tables=dict(raw.get("tables", {})), robot=raw.get("robot"),
                       identification=dict(raw.get("identification", {})), source=str(path))


def default_params(ea: np.ndarray, cable_length: np.ndarray, model: str = "amplitude") -> ModelParams:
    """Nominal parameters for a robot without identified ones, from its cables' E*A [N] and
    a typical free length [m] per cable.

    The amplitude model uses K1 = k = EA / L at every amplitude, a loss factor of 0.1
    (S_a = 0.1 pi k A^2) and alpha = 0.3: values of the order 002 reports for Dyneema at
    60 N pretension (amplitudes 0.1-1.5 mm). K1 is kept constant because with K0 = 0 and
    x_center = 0 the polynomial carries the whole tension, and an amplitude-dependent K1
    would make the predicted tension jump whenever the amplitude estimate changes. These
    are nominal, not identified: the service reports them as such.
    """
    k = np.asarray(ea, float) / np.asarray(cable_length, float)
    if model == "linear":
        return ModelParams(model="linear", params={"ea": np.asarray(ea, float).tolist()},
                           identification={"nominal": True})
    if model == "amplitude":
        amps = np.array([1e-4, 2.5e-4, 5e-4, 1e-3, 1.5e-3])
        soft = np.ones(5)
        K1 = np.outer(k, soft)
        Sa = 0.1 * np.pi * K1 * amps ** 2
        return ModelParams(model="amplitude", tables={
            "amplitudes": amps.tolist(), "K0": [0.0] * len(amps), "K1": K1.tolist(), "K2": [0.0] * len(amps),
            "K3": [0.0] * len(amps), "S_a": Sa.tolist(), "alpha": [0.3] * len(amps)},
            identification={"nominal": True, "amplitude_range": [1e-4, 1.5e-3]})
    raise ValueError(f"no nominal parameters for model {model!r}; identify them with `cablesvc identify`")
