"""The one protocol every cable force model follows.

A model maps the elongation history of each cable to its tension. Everything is an
array of shape ``(lanes, cables)``: *cables* are the cables of one robot, *lanes* are
independent copies of the whole set (PSO particles, robots, Monte-Carlo samples), each
with its own parameters and state. The same code therefore serves the live kernel
(one lane) and identification (one lane per candidate parameter set).

Life cycle::

    model = BoucWen(shape=(lanes, cables), k_e=..., k_d=..., ...)
    state = model.create_state(x0)          # x0: initial elongation, (lanes, cables)
    f = model.step(state, x, dt, l0)        # every tick; returns the model's output buffer

``step`` is fixed-time: the same numpy operations run whatever the data (no Python
branches or loops that depend on values), and after ``create_state`` it allocates no
array memory: all scratch space is allocated when the model is built and the returned
force array is a buffer owned by the model (copy it if you keep it across steps).

Units everywhere: elongation x [m] (x > 0 stretched, as in the recording spec), time
[s], force [N], unstretched length l0 [m].
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

from cablesvc.errors import ModelError


class ModelParameterError(ModelError, ValueError):
    """A model parameter has the wrong shape or an invalid value."""


@dataclass
class ModelState:
    """Base class of model states: a bag of ``(lanes, cables)`` float arrays.

    States are plain data so that the service can snapshot and restore them
    (``as_dict`` / ``load_dict``) and identification can copy them between lanes.
    """

    def as_dict(self) -> dict[str, np.ndarray]:
        return {f.name: np.array(getattr(self, f.name), copy=True) for f in fields(self)}

    def load_dict(self, d: dict[str, np.ndarray]) -> None:
        for f in fields(self):
            if f.name not in d:
                raise KeyError(f"state snapshot lacks field {f.name!r}")
            dst = getattr(self, f.name)
            src = np.asarray(d[f.name], dtype=dst.dtype)
            if src.shape != dst.shape:
                raise ValueError(
                    f"state field {f.name!r}: snapshot shape {src.shape} != model shape {dst.shape}"
                )
            dst[...] = src

    def copy(self) -> "ModelState":
        new = type(self)(**{f.name: np.array(getattr(self, f.name), copy=True) for f in fields(self)})
        return new


def broadcast_param(name: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    """Broadcast a parameter given as scalar, per cable ``(cables,)`` or per lane and cable
    ``(lanes, cables)`` to a contiguous float64 array of ``shape``."""
    arr = np.asarray(value, dtype=np.float64)
    try:
        out = np.ascontiguousarray(np.broadcast_to(arr, shape), dtype=np.float64).copy()
    except ValueError:
        raise ModelParameterError(
            f"parameter {name!r}: shape {arr.shape} cannot be broadcast to (lanes, cables) = {shape}; "
            "give a scalar, one value per cable, or one per lane and cable"
        ) from None
    if not np.all(np.isfinite(out)):
        raise ModelParameterError(f"parameter {name!r}: values must be finite, got {value!r}")
    return out


def is_int(v: Any) -> bool:
    """Whether v is an integer (a TOML integer; booleans are not)."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def has_bool(v: Any) -> bool:
    """Whether v is, or holds, a boolean (TOML true/false): booleans are not numbers here."""
    if isinstance(v, (bool, np.bool_)):
        return True
    if isinstance(v, np.ndarray):
        return v.dtype == bool
    if isinstance(v, (list, tuple)):
        return any(has_bool(x) for x in v)
    return False


def as_numbers(field: str, v: Any, problems: list[str], what: str = "a number or a list of numbers") -> np.ndarray | None:
    """``v`` as a float array, or None after appending why it is not numbers (naming
    ``field``) to ``problems``: booleans (TOML true/false) are not numbers here."""
    if has_bool(v):
        problems.append(f"{field}: must be {what}, got {v!r} (true/false is not a number)"[:200])
        return None
    try:
        return np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        problems.append(f"{field}: must be {what}, got {v!r}"[:200])
        return None


def where_bad(a: np.ndarray, ok: np.ndarray, table: bool = False) -> str:
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


class CableModel(ABC):
    """Abstract cable force model. Subclasses set ``name``, ``param_names`` and
    ``defaults`` and implement ``create_state`` and ``step``.

    The class is the one home of what the service knows of the model: besides the force
    law (``step``), its parameter-file spec (class attributes below, ``file_options``,
    ``file_param_names``, ``option_problem``, ``param_problems``, ``table_problems``,
    ``from_file``), its nominal parameters from a robot file (``nominal``) and its
    identification search space (``search_space``, ``build_lanes``, ``file_sections``).
    Parameter loading (:mod:`cablesvc.config.params`), identification
    (:mod:`cablesvc.identify.cable`), the twin and the kernel read them through
    ``MODELS[name]``, never by the model's name."""

    name: ClassVar[str] = ""
    #: parameter names in the order identification uses them
    param_names: ClassVar[tuple[str, ...]] = ()
    #: default values (SI) used when a parameter is not given
    defaults: ClassVar[dict[str, float]] = {}
    #: short human description of each parameter with its unit
    param_docs: ClassVar[dict[str, str]] = {}
    #: parameters a parameter file must give > 0 for every cable (the step divides by them)
    positive_params: ClassVar[tuple[str, ...]] = ()
    #: the elastic stiffness [N/m] (linear: E*A [N]): > 0 for every cable, the default
    #: applying where a file omits it. A cable's tension grows with its elongation: zero or
    #: a negative stiffness makes the predicted tension fall, or stay put, as it stretches.
    stiffness_params: ClassVar[tuple[str, ...]] = ()
    #: hysteretic stiffnesses [N/m]: >= 0 (0: no hysteresis, what identification writes for
    #: a cable it did not fit)
    nonnegative_params: ClassVar[tuple[str, ...]] = ()
    #: tables a parameter file may give ([tables]); () for a model without tables
    table_names: ClassVar[tuple[str, ...]] = ()
    #: whether the force has memory (hysteresis); False for a purely elastic law
    hysteretic: ClassVar[bool] = True
    #: whether :meth:`nominal` gives parameters from a robot file alone
    has_nominal: ClassVar[bool] = False
    #: whether identification fits the model level by level on a hold-sine recording
    #: (tables over the elongation amplitude) where the recording has such levels
    fit_by_levels: ClassVar[bool] = False

    def __init__(self, shape: tuple[int, int] = (1, 1), **params: Any) -> None:
        if len(shape) != 2 or shape[0] < 1 or shape[1] < 1:
            raise ModelParameterError(f"shape must be (lanes>=1, cables>=1), got {shape!r}")
        self.shape = (int(shape[0]), int(shape[1]))
        unknown = set(params) - set(self.param_names) - set(self.extra_options())
        if unknown:
            raise ModelParameterError(
                f"{self.name}: unknown parameter(s) {sorted(unknown)}; known: {list(self.param_names)}"
            )
        self.params: dict[str, np.ndarray] = {}
        for p in self.param_names:
            if p in params:
                v = params[p]
            elif p in self.defaults:
                v = self.defaults[p]
            else:
                raise ModelParameterError(f"{self.name}: parameter {p!r} is required ({self.param_docs.get(p, '')})")
            self.params[p] = broadcast_param(p, v, self.shape)
        self._options = {k: v for k, v in params.items() if k in self.extra_options()}
        self.check_params()
        self.force = np.zeros(self.shape)

    # -- hooks -------------------------------------------------------------------------
    @classmethod
    def extra_options(cls) -> tuple[str, ...]:
        """Keyword options that are not identified parameters (integrator settings...)."""
        return ()

    def check_params(self) -> None:
        """Raise ModelParameterError for physically invalid parameter values."""

    # -- the parameter file ([options], [params], [tables]) ------------------------------
    @classmethod
    def file_options(cls) -> tuple[str, ...]:
        """Names a parameter file's [options] may give for this model."""
        return cls.extra_options()

    @classmethod
    def file_param_names(cls) -> set[str] | None:
        """Names a parameter file's [params] may give (None: any, checked when built)."""
        return set(cls.param_names)

    @classmethod
    def option_problem(cls, key: str, value: Any, options: dict[str, Any]) -> str | None:
        """The problem with option ``key`` (one of :meth:`file_options`) = ``value``, or None."""
        return None

    @classmethod
    def option_problems(cls, options: dict[str, Any], known: set[str]) -> list[str]:
        """One message per bad [options] entry whose key is in ``known`` (the options of any
        model; the others are reported by the file loader)."""
        allowed = set(cls.file_options())
        problems = []
        for k, v in options.items():
            if k not in known:
                continue
            if k not in allowed:
                problems.append(f"options.{k}: not an option of the {cls.name} model"
                                + (f" (options: {sorted(allowed)})" if allowed else " (it has none)"))
            else:
                msg = cls.option_problem(k, v, options)
                if msg:
                    problems.append(msg)
        return problems

    @classmethod
    def param_problems(cls, params: dict[str, Any]) -> list[str]:
        """Value checks of a parameter file's [params]: one message per problem, naming the
        field (numbers, finite, :attr:`positive_params`, :attr:`nonnegative_params`,
        :attr:`stiffness_params` with the default where a file omits it)."""
        problems = []
        for k, v in params.items():
            a = as_numbers(f"params.{k}", v, problems)
            if a is None:
                continue
            if not np.all(np.isfinite(a)):
                problems.append(f"params.{k}: values must be finite")
            elif k in cls.positive_params and not np.all(a > 0):
                problems.append(f"params.{k}: must be > 0, got {v!r}")
            elif k in cls.nonnegative_params and not np.all(a >= 0):
                problems.append(f"params.{k}: hysteretic stiffness must be >= 0 [N/m]{where_bad(a, a >= 0)}")
        for k in cls.stiffness_params:
            v = params.get(k, cls.defaults.get(k, 0.0))
            if has_bool(v):
                continue                        # reported above
            try:
                a = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                continue                        # reported above
            if np.all(np.isfinite(a)) and not np.all(a > 0):
                missing = "" if k in params else f" (not given: the default is {v!r})"
                problems.append(f"params.{k}: the elastic stiffness must be > 0 for every cable"
                                f"{where_bad(a, a > 0)}{missing}")
        return problems

    @classmethod
    def table_problems(cls, tables: dict[str, Any]) -> list[str]:
        """Value checks of a parameter file's [tables] (only for a model with
        :attr:`table_names`)."""
        return []

    @classmethod
    def from_file(cls, shape: tuple[int, int], params: dict[str, Any], options: dict[str, Any],
                  tables: dict[str, Any]) -> "CableModel":
        """Build the model from a checked parameter file's sections (arrays)."""
        return cls(shape, **params, **options)

    @classmethod
    def table_range(cls, tables: dict[str, Any]) -> tuple[float, float] | None:
        """Elongation amplitudes [m] a file's tables cover, if the model has such tables."""
        return None

    # -- nominal parameters from a robot file ---------------------------------------------
    @classmethod
    def nominal(cls, ea: np.ndarray, cable_length: np.ndarray) -> dict[str, dict[str, Any]]:
        """Nominal parameter-file sections (``params``, ``tables``, ``identification``) for a
        robot without identified parameters, from its cables' E*A [N] and a typical free
        length [m] per cable (only where :attr:`has_nominal`)."""
        raise ValueError(f"no nominal parameters for model {cls.name!r}; identify them with `cablesvc identify`")

    # -- identification --------------------------------------------------------------------
    @classmethod
    def search_space(cls, s: Any, *, degree: int = 3) -> Any:
        """The identification :class:`~cablesvc.models.space.Space` for the data statistics
        ``s`` (:class:`~cablesvc.models.space.FitStats`)."""
        raise NotImplementedError(f"{cls.name}: no identification search space")

    @classmethod
    def build_lanes(cls, shape: tuple[int, int], kwargs: dict[str, np.ndarray], options: dict[str, Any],
                    x: np.ndarray) -> "CableModel":
        """The model with one candidate parameter set per lane (identification), for the
        elongation history ``x`` (N, cables) [m] it will run on."""
        return cls(shape, **kwargs, **options)

    @classmethod
    def unfitted_values(cls, m: int, ea: np.ndarray, length: np.ndarray, names: list[str]) -> dict[str, np.ndarray]:
        """Parameter values (name -> (m,)) written for the cables identification did not fit."""
        raise NotImplementedError(f"{cls.name}: no values for unfitted cables")

    @classmethod
    def file_sections(cls, m: int, ea: np.ndarray, length: np.ndarray, fitted: list[int], names: list[str],
                      V: np.ndarray, fixed: dict[str, np.ndarray], options: dict[str, Any]) -> dict[str, Any]:
        """Parameter-file sections (``params``, ``options``, ``tables``) of an identification:
        the fitted cables get the values ``V`` (k, n) of ``names`` and the ``fixed`` ones, the
        others :meth:`unfitted_values` (E*A ``ea`` [N] and free length ``length`` [m] per cable)."""
        values = cls.unfitted_values(m, ea, length, names)
        for k, v in fixed.items():
            values[k][fitted] = v
        for j, nm in enumerate(names):
            values[nm][fitted] = V[:, j]
        return {"params": {k: v.tolist() for k, v in values.items()}, "options": dict(options), "tables": {}}

    @abstractmethod
    def create_state(self, x0: np.ndarray | float = 0.0) -> ModelState:
        """Allocate and initialise the state at elongation ``x0`` [m], at rest."""

    @staticmethod
    def amplitude(state: ModelState) -> np.ndarray | None:
        """The model's own elongation-amplitude estimate [m], (lanes, m), a view of ``state``
        that each step updates; None for a model without one (the kernel then reports NaN)."""
        return None

    @abstractmethod
    def step(self, state: ModelState, x: np.ndarray, dt: float, l0: np.ndarray | None = None) -> np.ndarray:
        """Advance one tick to elongation ``x`` [m] after ``dt`` [s]; return force [N].

        ``l0`` is the unstretched cable length [m] (motor length); only models whose
        stiffness scales with length use it."""

    # -- helpers ---------------------------------------------------------------------
    def _x0(self, x0: np.ndarray | float) -> np.ndarray:
        return broadcast_param("x0", x0, self.shape)

    def describe(self) -> dict[str, Any]:
        """Model name and parameters as plain lists (for status pages and reports)."""
        return {"model": self.name, "params": {k: v.tolist() for k, v in self.params.items()}}


def simulate(model: CableModel, x: np.ndarray, dt: float | np.ndarray, l0: np.ndarray | None = None,
             state: ModelState | None = None) -> np.ndarray:
    """Run ``model`` over an elongation history.

    x: ``(T, lanes, cables)`` or ``(T, cables)`` or ``(T,)`` [m]; dt: scalar or ``(T,)`` [s]
    (dt[0] is unused); l0 like x or broadcastable to ``(lanes, cables)``.
    Returns the force history with the same leading shape as ``x`` [N]. The state starts
    at rest at ``x[0]`` unless ``state`` is given.
    """
    x = np.asarray(x, dtype=np.float64)
    orig_shape = x.shape
    T = x.shape[0]
    xs = x.reshape(T, *model.shape) if x.ndim != 3 else x
    dts = np.broadcast_to(np.asarray(dt, dtype=np.float64), (T,))
    l0_t = None
    if l0 is not None:
        l0a = np.asarray(l0, dtype=np.float64)
        l0_t = l0a.reshape(T, *model.shape) if l0a.ndim >= 1 and l0a.shape[0] == T and l0a.size == xs.size else np.broadcast_to(l0a, model.shape)
    st = state if state is not None else model.create_state(xs[0])
    out = np.empty_like(xs)
    for k in range(T):
        lk = None if l0_t is None else (l0_t[k] if l0_t.ndim == 3 else l0_t)
        out[k] = model.step(st, xs[k], float(dts[k]) if k else 0.0, lk)
    return out.reshape(orig_shape)


def loop_area(x: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Signed area enclosed by a closed force-elongation loop, ``oint f dx`` [J].

    Positive for a loop traversed clockwise in the (x, f) plane, i.e. energy dissipated.
    x and f: ``(T, ...)`` samples of one period (the loop is closed from last to first).
    Trapezoidal rule."""
    x = np.asarray(x)
    f = np.asarray(f)
    xc = np.concatenate([x, x[:1]], axis=0)
    fc = np.concatenate([f, f[:1]], axis=0)
    return np.sum(0.5 * (fc[1:] + fc[:-1]) * np.diff(xc, axis=0), axis=0)
