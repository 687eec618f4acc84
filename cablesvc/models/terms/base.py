"""The term protocol (:class:`Term`: parameter spec, offline form, live form), the default
library it registers into (:data:`LIBRARY`, :func:`register`, :func:`library`), and the
generic live form (:class:`LiveTerm`) every term whose law is :meth:`Term.columns` /
:meth:`Term.fixed_part` runs in the kernel.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from cablesvc.models.terms.signals import CableView, Design, Signals, cable_view, make_design

__all__ = ["Term", "LIBRARY", "register", "library", "LiveTerm"]


class Term:
    """One candidate piece of physics: its parameter spec, its offline form (the design
    columns discovery fits) and its live form (:meth:`live`, what the kernel runs every
    tick), in one class.

    ``name``: short id (JSON, parameter files, the bench's labels); ``label``: plain-words
    description; ``equation``: formula with the paper reference; ``variable``: the state
    variable the term says the residual follows (for the evidence sentence and the plot).

    The law is written once, in :meth:`columns` (the linear parameters' columns) and
    :meth:`fixed_part` (a part with no free coefficient), with numpy ufuncs writing into
    ``out``: offline they run over one cable's (N,) signals, live over the kernel's
    (lanes, cables) buffers with per-cable parameters, references and hyper-parameters
    broadcast along the last axis. ``refs`` are the values the design takes from the
    training ticks (a mean elongation, a mean wrap angle...): they are saved with the fitted
    parameters, so the live form uses the very same numbers.
    """

    name: str = ""
    label: str = ""
    equation: str = ""
    variable: str = ""
    #: the linear parameters, in column order, with units and lower bounds
    params: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    lower: Optional[tuple[float, ...]] = None
    #: the nonlinear hyper-parameters
    hypers: tuple[str, ...] = ()
    #: the reference values :meth:`refs` returns
    ref_names: tuple[str, ...] = ()
    #: whether :meth:`fixed_part` contributes
    has_fixed: bool = False
    #: nonlinear hyper-parameter refined continuously after the grid (None: grid only)
    refine_hyper: Optional[str] = None
    refine_bounds: tuple[float, float] = (0.0, 0.0)

    @property
    def design_key(self) -> str:
        """What tells this term's designs apart from another's of the same recording,
        cable and hyper-parameters (a design cache's key): its name, unless one term has
        variants with other columns."""
        return self.name

    def applies(self, s: Signals, c: int) -> bool:
        """Whether the term can act on cable ``c`` of this recording (e.g. a pulley term
        needs a pulley, the temperature term a temperature channel)."""
        return True

    def grid(self, s: Signals) -> list[dict[str, float]]:
        """Candidate values of the nonlinear hyper-parameters ([{}] when there are none)."""
        return [{}]

    def refs(self, s: Signals, c: int, h: dict[str, float]) -> dict[str, float]:
        """Reference values of cable ``c`` taken from the training ticks (default none)."""
        return {}

    def columns(self, g: CableView, R: dict[str, Any], h: dict[str, Any], out: np.ndarray) -> None:
        """Write the columns of the linear parameters into ``out`` (p, *shape)."""

    def fixed_part(self, g: CableView, R: dict[str, Any], h: dict[str, Any], out: np.ndarray) -> None:
        """Write the part with no free coefficient into ``out`` (*shape) (when ``has_fixed``)."""

    def design(self, s: Signals, c: int, h: dict[str, float]) -> Design:
        """The offline form: the columns over the recording's ticks."""
        g = cable_view(s, c)
        R = self.refs(s, c, h)
        X = np.empty((len(self.params), s.n))
        self.columns(g, R, h, X)
        fx = None
        if self.has_fixed:
            fx = np.empty(s.n)
            self.fixed_part(g, R, h, fx)
        return make_design(list(X), self.params, self.units, lower=self.lower, fixed=fx, refs=R, held=self.held)

    def live(self, table: dict[str, np.ndarray], lanes: int, m: int) -> "LiveTerm":
        """The live form over (lanes, m) from the parameter file's table (per cable arrays
        of the parameters, hyper-parameters and references; a cable without the term has
        zero parameters and contributes exactly 0)."""
        return LiveTerm(self, table, lanes, m)

    #: number of nonlinear parameters (counted in the parameter penalty)
    n_hyper: int = 0
    #: names of this term's *generic* linear columns (a plain gain f or a constant), which
    #: any sensor error also produces. They are the shared nuisance: the selector drops them
    #: when a term that owns the nuisance (``owns_nuisance``) is fitted on the same cable,
    #: and a term is only accepted when its specific columns beat its nuisance ones alone.
    nuisance: tuple[str, ...] = ()
    #: names of linear columns held within the range they took on the ticks they were fitted
    #: on (an empirical correction with no law outside its support; ``Design.held``)
    held: tuple[str, ...] = ()
    #: True for the one term the generic offset/gain columns belong to (``offset_gain``)
    owns_nuisance: bool = False
    #: True for a term that only reshapes the baseline's own hysteresis or calibration
    #: (amplitude, asymmetric, Bouc-Wen loop, sensor offset/gain): with an identified,
    #: imperfect baseline these are inside its recalibration nuisance
    #: (:mod:`cablesvc.discover.nuisance`), not concealed effects
    model_form: bool = False
    #: True for a term whose force takes the sign of the direction of motion, a loop in
    #: force against elongation (pulley friction, viscous damping): a rope's own friction
    #: loop draws the same shape, and such a term must also beat the loop that grows with
    #: the force (``Recalibration.confronts``)
    follows_direction: bool = False
    #: True for a term whose force is the force times a slow course over the recording
    #: (temperature): a rope's own viscoelastic relaxation leaves a slow force too, and such
    #: a term must also beat it (``Recalibration(relax=True)``)
    follows_slow_course: bool = False
    #: True for a term that settles from the recording's start (creep's a (1 - exp(-t/tau))):
    #: the rope's loop with its unknown state at the start settles too, so such a term is
    #: not asked to beat that state (``Recalibration(spare_time=True)``)
    settles: bool = False
    #: the linear parameters whose columns carry the term's own explaining variable, where
    #: the term also has columns of another kind (the pulley: its bearing friction ``mu``,
    #: the wrap-angle load times the direction of sliding, beside a stiffness that varies
    #: with the wrap angle). Discovery names such a term only where these columns carry
    #: evidence beside the rest of it (:meth:`without_signature`); () for a term all of
    #: whose columns follow its own variable
    signature: tuple[str, ...] = ()
    #: True for a term that delays the elongation by its hyper-parameter ``tau``: the
    #: other terms on the cable are then built on the delayed signals (:meth:`Signals.delayed`)
    delays_input: bool = False

    def evidence(self, s: Signals, c: int, h: dict[str, float]) -> np.ndarray:
        """The explaining variable (N,) for the evidence correlation and the plot: by default
        the term's own fitted shape is used by the selector; terms may override it with a
        raw state variable (wrap angle x direction, temperature, time...)."""
        d = self.design(s, c, h)
        base = np.zeros(s.n) if d.fixed is None else d.fixed
        return base + (d.X[:, 0] if d.p else 0.0)

    def without_signature(self) -> "Term":
        """This term with its :attr:`signature` columns left out (held at 0): what is left
        when its own explaining variable is taken away (the pulley term's wrap-angle
        stiffness without its bearing friction). The yardstick the term must beat."""
        return _WithoutSignature(self)

    def physical(self, params: dict[str, float], h: dict[str, float], s: Signals, c: int) -> dict[str, Any]:
        """Physical parameters with units for the report (default: the fitted ones)."""
        return {**{k: v for k, v in params.items()}, **h}


class _WithoutSignature(Term):
    """:meth:`Term.without_signature`: the same term, its signature columns held at 0
    (same name, hyper-parameters and nuisance columns; a design key of its own)."""

    def __init__(self, term: Term):
        self.term = term
        self.name = term.name
        self.label = f"{term.label} without {', '.join(term.signature)}"
        self.params = tuple(n for n in term.params if n not in term.signature)
        self.hypers = term.hypers
        self.nuisance = term.nuisance
        self.held = term.held
        self.owns_nuisance = term.owns_nuisance
        self.delays_input = term.delays_input
        self.n_hyper = term.n_hyper

    @property
    def design_key(self) -> str:
        return f"{self.term.design_key}-without-{'-'.join(self.term.signature)}"

    def applies(self, s: Signals, c: int) -> bool:
        return self.term.applies(s, c)

    def grid(self, s: Signals) -> list[dict[str, float]]:
        return self.term.grid(s)

    def design(self, s: Signals, c: int, h: dict[str, float]) -> Design:
        return self.term.design(s, c, h).without(self.term.signature)


LIBRARY: dict[str, Term] = {}


def register(term: Term) -> Term:
    """Add ``term`` to the default library (its ``name`` must be new)."""
    if not term.name or term.name in LIBRARY:
        raise ValueError(f"term name {term.name!r} missing or already registered")
    LIBRARY[term.name] = term
    return term


def library(names: Optional[list[str]] = None) -> list[Term]:
    """The default library, or the named subset of it."""
    if names is None:
        return list(LIBRARY.values())
    unknown = [n for n in names if n not in LIBRARY]
    if unknown:
        raise KeyError(f"unknown term(s) {unknown}; known: {', '.join(LIBRARY)}")
    return [LIBRARY[n] for n in names]


class LiveTerm:
    """The live form of a term whose law is :meth:`Term.columns` / :meth:`Term.fixed_part`:
    per-cable parameters P (p, m), references and hyper-parameters (m,), and its rows
    ``cols`` (rows, lanes, m) with their coefficients ``coef`` (rows, 1, m): the p columns
    of the linear parameters times P, then ``n_fixed`` rows of a part with no free
    coefficient times 1. :meth:`write` writes the rows of this tick; the force is
    sum over the rows of coef * cols. In the kernel, :class:`~cablesvc.models.terms.live.TermStack`
    gives every term its slice of one buffer (:meth:`bind`) and sums all the terms' rows
    at once (the only place the live force is summed)."""

    #: rows of a part with no free coefficient that :meth:`write` writes after the columns
    n_fixed: int = 0

    def __init__(self, term: Term, table: dict[str, Any], lanes: int, m: int):
        self.term = term
        self.m, self.lanes = m, lanes

        def col(k: str) -> np.ndarray:
            v = np.zeros(m) if k not in table else np.asarray(table[k], float).reshape(-1)
            if v.size != m:
                raise ValueError(f"term_{term.name}.{k}: {v.size} values for {m} cables")
            return np.ascontiguousarray(v)

        self.P = np.stack([col(k) for k in term.params]) if term.params else np.zeros((0, m))
        # references and hyper-parameters as (1, m): a ufunc on (lanes, m) buffers takes its
        # fast path with them at lanes = 1 (a (m,) operand costs the broadcast machinery,
        # ~0.8 us a call on 8 cables)
        self.R = {k: col(k).reshape(1, m) for k in term.ref_names}
        # a cable without the term has scale-like references at 0: keep its columns finite
        if "x_scale" in self.R:
            self.R["x_scale"][self.R["x_scale"] <= 0] = 1.0
        self.H = {k: col(k).reshape(1, m) for k in term.hypers}
        self._fix_hypers()
        p = len(term.params)
        self.rows = p + self.n_fixed
        self.cols = np.zeros((self.rows, lanes, m))
        self.coef = np.ones((self.rows, 1, m))      # (rows, 1, m): broadcast over lanes
        self.coef[:p, 0, :] = self.P

    def _fix_hypers(self) -> None:
        """Hyper-parameters of cables without the term: values that keep the law finite
        (their parameters are 0, so they contribute exactly 0)."""
        for k, v in self.H.items():
            if k in ("v_s", "tau"):
                v[v <= 0] = 1.0

    def bind(self, cols: np.ndarray, coef: np.ndarray) -> None:
        """Write from now on into ``cols`` (rows, lanes, m), a slice of the stack's buffer,
        with this term's coefficients copied into ``coef`` (rows, 1, m), its slice."""
        np.copyto(coef, self.coef)
        self.cols, self.coef = cols, coef

    def write(self, g: CableView) -> None:
        """The rows of this tick into ``cols`` (the law's columns; a term with state
        advances it here, once per tick)."""
        if self.P.shape[0]:
            self.term.columns(g, self.R, self.H, self.cols)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {}

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        pass
