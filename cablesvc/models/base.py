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


class ModelParameterError(ValueError):
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


class CableModel(ABC):
    """Abstract cable force model. Subclasses set ``name``, ``param_names`` and
    ``defaults`` and implement ``create_state`` and ``step``."""

    name: ClassVar[str] = ""
    #: parameter names in the order identification uses them
    param_names: ClassVar[tuple[str, ...]] = ()
    #: default values (SI) used when a parameter is not given
    defaults: ClassVar[dict[str, float]] = {}
    #: short human description of each parameter with its unit
    param_docs: ClassVar[dict[str, str]] = {}

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

    @abstractmethod
    def create_state(self, x0: np.ndarray | float = 0.0) -> ModelState:
        """Allocate and initialise the state at elongation ``x0`` [m], at rest."""

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
