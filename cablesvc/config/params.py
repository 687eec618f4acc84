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
from cablesvc.models.boucwen import INTEGRATORS, max_live_substeps

OPTION_KEYS = {"degree", "integrator", "substeps"}
#: parameters that must be strictly positive, per model (the kernel divides by them)
POSITIVE_PARAMS = {"amplitude": ("amplitude_init", "omega_init")}
#: each model's elastic stiffness [N/m] (linear: E*A [N]): > 0 for every cable, with the
#: model's default where the file omits it. A cable's tension grows with its elongation
#: (eq 3 of 002; a1 of eqs 4-7 of 002; k_e of eq 1 of 000; k1 of 001 eq 4.3): zero or a
#: negative stiffness makes the predicted tension fall, or stay put, as the cable stretches.
STIFFNESS_PARAMS = {"linear": ("ea",), "polynomial": ("a1",), "boucwen": ("k_e",), "asymmetric": ("k1",)}
#: hysteretic stiffnesses [N/m]: >= 0 (0: no hysteresis, what identification writes for a
#: cable it did not fit)
NONNEGATIVE_PARAMS = {"boucwen": ("k_d",), "asymmetric": ("alpha",)}
#: amplitude-model tables that are stiffnesses: > 0 at every amplitude level and cable
POSITIVE_TABLES = {"K1": "linear stiffness K1(A) of eq 8 of 002 [N/m]"}
#: tables the amplitude model requires
REQUIRED_TABLES = ("amplitudes", "K0", "K1")


def _has_bool(v: Any) -> bool:
    """Whether v is, or holds, a boolean (TOML true/false): booleans are not numbers here."""
    if isinstance(v, (bool, np.bool_)):
        return True
    if isinstance(v, np.ndarray):
        return v.dtype == bool
    if isinstance(v, (list, tuple)):
        return any(_has_bool(x) for x in v)
    return False


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _content_problems(model: str, params: dict, options: dict, tables: dict) -> list[str]:
    """Value checks of [params], [options] and [tables] for a known model: one message per
    problem, naming the field (shared by load_params and ModelParams.build)."""
    problems = []
    allowed = set(MODELS[model].extra_options()) | ({"degree"} if model == "polynomial" else set())
    for k, v in options.items():
        if k not in OPTION_KEYS:
            continue      # reported by load_params; build passes it on to the model
        if k not in allowed:
            problems.append(f"options.{k}: not an option of the {model} model"
                            + (f" (options: {sorted(allowed)})" if allowed else " (it has none)"))
        elif k == "degree" and not (_is_int(v) and v >= 1 and v % 2 == 1):
            problems.append(f"options.degree: must be an odd integer >= 1, got {v!r}")
        elif k == "substeps" and not (_is_int(v) and v >= 1):
            problems.append(f"options.substeps: must be an integer >= 1, got {v!r}")
        elif k == "substeps":
            integ = options.get("integrator", "semi-implicit")
            most = max_live_substeps(integ if integ in INTEGRATORS else "semi-implicit")
            if v > most:
                problems.append(f"options.substeps: {v} sub-steps per tick cannot fit the live tick; the {integ} "
                                f"integrator allows at most {most} (half of a 1 kHz tick, derivation in "
                                f"cablesvc/models/boucwen.py)")
        elif k == "integrator" and not (isinstance(v, str) and v in INTEGRATORS):
            problems.append(f"options.integrator: must be one of {list(INTEGRATORS)}, got {v!r}")
    for k, v in params.items():
        if _has_bool(v):
            problems.append(f"params.{k}: must be a number or a list of numbers, got {v!r} (true/false is not a number)")
            continue
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            problems.append(f"params.{k}: must be a number or a list of numbers, got {v!r}"[:200])
            continue
        if not np.all(np.isfinite(a)):
            problems.append(f"params.{k}: values must be finite")
        elif k in POSITIVE_PARAMS.get(model, ()) and not np.all(a > 0):
            problems.append(f"params.{k}: must be > 0, got {v!r}")
        elif k in NONNEGATIVE_PARAMS.get(model, ()) and not np.all(a >= 0):
            problems.append(f"params.{k}: hysteretic stiffness must be >= 0 [N/m]{_where_bad(a, a >= 0)}")
    for k in STIFFNESS_PARAMS.get(model, ()):
        v = params.get(k, MODELS[model].defaults.get(k, 0.0))
        if _has_bool(v):
            continue                        # reported above
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            continue                        # reported above
        if np.all(np.isfinite(a)) and not np.all(a > 0):
            missing = "" if k in params else f" (not given: the default is {v!r})"
            problems.append(f"params.{k}: the elastic stiffness must be > 0 for every cable"
                            f"{_where_bad(a, a > 0)}{missing}")
    if model == "amplitude":
        for k in REQUIRED_TABLES:
            if k not in tables:
                problems.append(f"tables.{k}: required for the amplitude model")
    for k, v in tables.items():
        if _has_bool(v):
            problems.append(f"tables.{k}: must be a list of numbers, got {v!r} (true/false is not a number)"[:200])
            continue
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            problems.append(f"tables.{k}: must be a list of numbers, got {v!r}"[:200])
            continue
        if k == "amplitudes":
            if a.ndim != 1 or a.size < 1 or not np.all(np.isfinite(a)) or np.any(a <= 0) or np.any(np.diff(a) <= 0):
                problems.append(f"tables.amplitudes: must be a non-empty, strictly increasing list of finite "
                                f"positive amplitudes [m], got {v!r}"[:200])
        elif a.ndim not in (1, 2) or not np.all(np.isfinite(a)):
            problems.append(f"tables.{k}: must be a list of finite numbers (one per level) or a list of "
                            f"per-cable rows")
        elif k in POSITIVE_TABLES and not np.all(a > 0):
            problems.append(f"tables.{k}: the {POSITIVE_TABLES[k]} must be > 0 at every amplitude level "
                            f"and cable{_where_bad(a, a > 0, table=True)}")
    return problems


def _where_bad(a: np.ndarray, ok: np.ndarray, table: bool = False) -> str:
    """``, got -5 (cable 3)`` for the first value of ``a`` that fails ``ok``: a scalar, one
    value per cable, or (``table``) one per level or per-cable rows of levels."""
    bad = np.argwhere(~np.broadcast_to(ok, a.shape))
    if bad.size == 0:
        return ""
    idx = tuple(int(i) for i in bad[0])
    v = float(a[idx]) if a.ndim else float(a)
    if not idx:
        where = ""
    elif table:
        where = f" (level {idx[-1]}" + (f", cable {idx[0]}" if len(idx) == 2 else ", every cable") + ")"
    else:
        where = f" (cable {idx[0]})"
    return f", got {v:g}{where}"


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
        problems = _content_problems(self.model, self.params, self.options, self.tables)
        if problems:
            raise ParamFileError(self.source, problems)
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
        except ValueError as e:      # not expected after the checks above; never a traceback
            raise ParamFileError(self.source, [f"{self.model} model: {e}"]) from None

    def amplitude_range(self) -> tuple[float, float] | None:
        """Elongation amplitudes [m] the parameters were identified on, if known."""
        r = self.identification.get("amplitude_range")
        if r is None and self.model == "amplitude" and "amplitudes" in self.tables:
            a = np.asarray(self.tables["amplitudes"], dtype=float)
            return float(a.min()), float(a.max())
        if r is None:
            return None
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
        names = set(cls.param_names) if model != "polynomial" else None
        for k in raw.get("params", {}):
            if names is not None and k not in names:
                problems.append(f"params.{k}: not a parameter of the {model} model (parameters: {sorted(names)})")
        for k in raw.get("tables", {}):
            if k != "amplitudes" and k not in TABLE_COLUMNS:
                problems.append(f"tables.{k}: unknown table (known: amplitudes, {', '.join(TABLE_COLUMNS)})")
        if raw.get("tables") and model != "amplitude":
            problems.append(f"tables: only the amplitude model has tables, not {model!r}")
        known_tables = {k: v for k, v in raw.get("tables", {}).items() if k == "amplitudes" or k in TABLE_COLUMNS}
        problems += _content_problems(model, raw.get("params", {}), raw.get("options", {}),
                                      known_tables if model == "amplitude" else {})
    if "amplitude_range" in raw.get("identification", {}):
        problems += _amplitude_range_problems(raw["identification"]["amplitude_range"])
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
