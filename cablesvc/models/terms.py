"""Physics terms: the library discovery chooses from and the kernel runs live, one class each.

A term is a small parameterised physical model of the force a baseline cable model leaves
out. It adds, to the baseline prediction ``f0`` of one cable, a correction

    delta_f(t) = fixed(t; h) + X(t; h) @ p          [N]

where ``p`` are the term's *linear* parameters (fitted by bounded linear least squares,
fast and stable) and ``h`` its few *nonlinear* hyper-parameters (a time constant, a dead
time, a regularisation speed, the shape of a Bouc-Wen loop), searched on a short grid
(:meth:`Term.grid`) and, for dead time, refined by a bounded scalar search. Every term
names its paper equation and the units of its parameters; :meth:`Term.physical` turns the
fitted numbers into the physical ones the report prints.

The library (:data:`LIBRARY`) is open: a new term is one subclass with ``name``,
``label``, ``equation``, its parameter spec (``params``, ``units``, ``lower``, ``hypers``,
``ref_names``), ``applies``, ``grid``, ``refs`` and its law in ``columns`` / ``fixed_part``
(and optionally ``physical``/``evidence``), registered with :func:`register`. The same
law gives the offline form (:meth:`Term.design`, the columns discovery fits over a
recording) and the live form (:meth:`Term.live`, run every tick by the kernel through
:class:`TermStack` over (lanes, cables), in fixed time), so a new term runs live without
touching the kernel. Terms with state (Bouc-Wen z, the dead-time line, the amplitude
tracker, the creep clock) keep it in the stack's :meth:`TermStack.state_dict`. Terms only
see the :class:`Signals` of a recording (what a controller logs, the kinematics and the
baseline's prediction), never any simulation ground truth.

Units: SI throughout (m, s, N, K, rad).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numba
import numpy as np

from cablesvc.models.boucwen import bouc_wen_step_n1, bouc_wen_step_n1_np
from cablesvc.models.catenary import SAG_NEWTON, irvine_tension
from cablesvc.models.reversal import REVERSAL_DEADBAND, reversal_amplitude

__all__ = [
    "LIBRARY", "Signals", "Term", "Design", "register", "library", "PulleyFriction", "Creep",
    "TemperatureStiffness", "Viscous", "AmplitudeStiffness", "AsymmetricHardening", "Sag", "DeadTime",
    "OffsetGain", "BoucWenHysteresis", "Recalibration", "reversal_amplitude", "bouc_wen_z", "hysteretic_part",
    "smooth_sign", "CableView", "cable_view", "LiveTerm", "TermStack", "term_class", "SAG_NEWTON", "DELAY_WINDOW_S",
]


# --------------------------------------------------------------------------------------
# what a term sees
# --------------------------------------------------------------------------------------


@dataclass
class Signals:
    """Per-tick signals of one recording, arrays (N,) or (N, m), SI units.

    ``t`` time from the start [s]; ``dt`` tick period [s]; ``y`` measured force [N];
    ``f0`` the baseline model's predicted force [N]; ``x`` elongation l(pose) -
    motor_length [m]; ``v`` its rate dx/dt [m/s]; ``v_slide`` haul-in speed over the pulley
    -d(motor_length)/dt [m/s]; ``wrap`` pulley wrap angle [rad] (0 without pulley);
    ``free_length`` free cable length [m]; ``temperature`` [deg C] (None when not recorded);
    ``ea`` nominal E*A per cable [N]; ``has_pulley`` (m,) bool; ``amplitude`` elongation
    amplitude from the last reversal points [m] (:func:`reversal_amplitude`);
    ``train`` (N,) bool: the ticks a term may use to fix data-dependent references (means)
    so nothing of the held-out blocks leaks into the design.
    """

    t: np.ndarray
    dt: float
    y: np.ndarray
    f0: np.ndarray
    x: np.ndarray
    v: np.ndarray
    v_slide: np.ndarray
    wrap: np.ndarray
    free_length: np.ndarray
    temperature: Optional[np.ndarray]
    ea: np.ndarray
    has_pulley: np.ndarray
    amplitude: np.ndarray
    train: np.ndarray
    cable_names: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def m(self) -> int:
        return int(self.y.shape[1])

    def train_mean(self, a: np.ndarray) -> float:
        return float(np.mean(a[self.train]))

    def delayed(self, tau: float) -> "Signals":
        """These signals with the elongation and what follows from it (x, v, amplitude and
        the baseline force f0) delayed by ``tau`` [s] (held at the first value before
        t0 + tau): what the force-stage terms see when the force follows the elongation
        of tau seconds ago (dead time). Pose-side signals (wrap, v_slide, free length,
        temperature) are not delayed."""
        if tau <= 0:
            return self
        import copy as _copy

        def sh(a):
            a2 = a.reshape(a.shape[0], -1)
            out = np.column_stack([np.interp(self.t - tau, self.t, a2[:, j]) for j in range(a2.shape[1])])
            return out.reshape(a.shape)

        d = _copy.copy(self)
        d.f0, d.x, d.v, d.amplitude = sh(self.f0), sh(self.x), sh(self.v), sh(self.amplitude)
        return d


@dataclass
class Design:
    """What a term contributes to one cable's fit: ``fixed`` (N,) [N] a column with no free
    coefficient (or None), ``X`` (N, p) the columns of the linear parameters, their
    ``names``, ``units`` and bounds ``lower``/``upper``."""

    fixed: Optional[np.ndarray]
    X: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    #: linear parameters left out of the fit (held at 0), e.g. a nuisance gain owned by
    #: another term on the same cable
    dropped: tuple[str, ...] = ()
    #: reference values the columns took from the training ticks (:meth:`Term.refs`)
    refs: dict = field(default_factory=dict)

    @property
    def p(self) -> int:
        return int(self.X.shape[1])

    def without(self, names: tuple[str, ...]) -> "Design":
        """This design with the columns ``names`` left out (held at 0)."""
        keep = [i for i, n in enumerate(self.names) if n not in names]
        gone = tuple(n for n in self.names if n in names)
        if not gone:
            return self
        return Design(fixed=self.fixed, X=self.X[:, keep], names=tuple(self.names[i] for i in keep),
                      units=tuple(self.units[i] for i in keep), lower=self.lower[keep], upper=self.upper[keep],
                      dropped=self.dropped + gone, refs=self.refs)

    def only(self, names: tuple[str, ...]) -> "Design":
        """Only the columns ``names`` (no fixed part)."""
        keep = [i for i, n in enumerate(self.names) if n in names]
        return Design(fixed=None, X=self.X[:, keep], names=tuple(self.names[i] for i in keep),
                      units=tuple(self.units[i] for i in keep), lower=self.lower[keep], upper=self.upper[keep],
                      refs=self.refs)


def make_design(cols: list[np.ndarray], names, units, lower=None, upper=None, fixed=None,
            refs: Optional[dict[str, float]] = None) -> Design:
    n = len(cols)
    X = np.column_stack(cols) if cols else np.zeros((0, 0))
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    return Design(fixed=fixed, X=X, names=tuple(names), units=tuple(units), lower=lo, upper=hi,
                  refs=dict(refs or {}))


def smooth_sign(v: np.ndarray, v_s: Any, out: Optional[np.ndarray] = None) -> np.ndarray:
    """tanh(v / v_s): the sign of v, smoothed over the speed ``v_s`` [m/s] (into ``out``
    when given: the live form's buffers)."""
    out = np.divide(v, v_s, out=out)
    return np.tanh(out, out=out)


@numba.njit(cache=True)
def _bw_z(x, beta, gamma):
    """Normalised Bouc-Wen state z [m] driven by x [m] (000 eq 2 with A = 1, n = 1): one
    backward-Euler step of the law per tick (:func:`cablesvc.models.boucwen.bouc_wen_step_n1`;
    this term's beta is the law's gamma and its gamma the law's beta)."""
    N = x.shape[0]
    z = np.zeros(N)
    zk = 0.0
    for k in range(1, N):
        zk = bouc_wen_step_n1(zk, x[k] - x[k - 1], 1.0, gamma, beta)
        z[k] = zk
    return z


def bouc_wen_z(x: np.ndarray, beta: float, gamma: float) -> np.ndarray:
    """Bouc-Wen hysteretic displacement z [m] driven by the elongation x [m] (N,):
    dz = dx (1 - (beta + gamma sgn(z dx)) |z|) (000 eq 2, A = 1, n = 1, with this term's beta
    and gamma in the roles of 000's gamma and beta), integrated per tick by the backward-Euler
    step z' = (z + dx) / (1 + (beta + gamma sgn(z dx)) |dx|) of
    :func:`cablesvc.models.boucwen.bouc_wen_step_n1` (implicit in |z|, so stable for any dx
    when beta > |gamma|); z saturates at 1 / (beta + gamma) [m]. ``beta``, ``gamma`` [1/m].
    The live form (:class:`BoucWenHysteresis`) runs the same step."""
    return _bw_z(np.ascontiguousarray(x, dtype=np.float64), float(beta), float(gamma))


# --------------------------------------------------------------------------------------
# the term protocol
# --------------------------------------------------------------------------------------


@dataclass
class CableView:
    """One cable's signals (N,) for the offline form of a term (see :class:`Signals`), or
    the live signals (lanes, m): terms write their law once over whatever shape this has."""

    t: Any
    f0: np.ndarray
    x: np.ndarray
    v: np.ndarray
    v_slide: np.ndarray
    wrap: np.ndarray
    free_length: np.ndarray
    temperature: Any
    amplitude: np.ndarray


def cable_view(s: Signals, c: int) -> CableView:
    return CableView(t=s.t - s.t[0], f0=s.f0[:, c], x=s.x[:, c], v=s.v[:, c], v_slide=s.v_slide[:, c],
                     wrap=s.wrap[:, c], free_length=s.free_length[:, c], temperature=s.temperature,
                     amplitude=s.amplitude[:, c])


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
        return make_design(list(X), self.params, self.units, lower=self.lower, fixed=fx, refs=R)

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
    #: True for the one term the generic offset/gain columns belong to (``offset_gain``)
    owns_nuisance: bool = False
    #: True for a term that only reshapes the baseline's own hysteresis or calibration
    #: (amplitude, asymmetric, Bouc-Wen loop, sensor offset/gain): with an identified,
    #: imperfect baseline these are inside its recalibration nuisance
    #: (:mod:`cablesvc.discover.nuisance`), not concealed effects
    model_form: bool = False
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

    def physical(self, params: dict[str, float], h: dict[str, float], s: Signals, c: int) -> dict[str, Any]:
        """Physical parameters with units for the report (default: the fitted ones)."""
        return {**{k: v for k, v in params.items()}, **h}


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


# --------------------------------------------------------------------------------------
# the terms
# --------------------------------------------------------------------------------------


class PulleyFriction(Term):
    """Redirection pulley (002 Sec 4, eq 19, Figs 9-11). The wheel carries the resultant
    F_b = f sqrt(2 (1 + cos beta)) of the two cable segments (eq 19, beta the angle between
    them); with the wrap angle alpha = pi - beta, F_b = 2 f sin(alpha / 2). The bearing's
    Coulomb friction mu F_b opposes the cable sliding over the wheel (sign of the haul-in
    speed v_slide, smoothed over v_s), and the wrapped arc changes the apparent stiffness
    linearly in alpha:

        delta_f = mu F_b tanh(v_slide / v_s) + f (k_0 + k_alpha (alpha - alpha_mean))

    mu [-] >= 0, k_0 [-], k_alpha [1/rad]; v_s [m/s] on a grid."""

    name = "pulley"
    label = "pulley wrap-angle friction and stiffness"
    equation = "mu * 2 f sin(alpha/2) * tanh(v_slide/v_s) + f (k0 + k_alpha (alpha - mean alpha))  (002 Sec 4 eq 19)"
    variable = "wrap-angle bearing load x direction of sliding, 2 f sin(alpha/2) sgn(v_slide) [N]"
    params = ("mu", "k_alpha", "k0")
    units = ("-", "1/rad", "-")
    lower = (0.0, -np.inf, -np.inf)
    hypers = ("v_s",)
    ref_names = ("alpha_mean",)
    n_hyper = 1
    nuisance = ("k0",)

    def applies(self, s, c):
        return bool(s.has_pulley[c]) and float(np.max(s.wrap[:, c])) > 1e-6

    refine_hyper = "v_s"
    refine_bounds = (1e-5, 0.05)

    def grid(self, s):
        return [{"v_s": float(v)} for v in np.geomspace(1e-4, 1e-2, 7)]

    def refs(self, s, c, h):
        return {"alpha_mean": s.train_mean(s.wrap[:, c])}

    def columns(self, g, R, h, out):
        o0, o1, o2 = out
        np.maximum(g.f0, 0.0, out=o0)
        np.multiply(g.wrap, 0.5, out=o1)
        np.sin(o1, out=o1)
        np.multiply(o0, o1, out=o0)
        np.multiply(o0, 2.0, out=o0)                   # F_b = 2 f sin(alpha/2)
        smooth_sign(g.v_slide, h["v_s"], out=o1)
        np.multiply(o0, o1, out=o0)
        np.subtract(g.wrap, R["alpha_mean"], out=o1)
        np.multiply(g.f0, o1, out=o1)
        np.copyto(o2, g.f0)

    def evidence(self, s, c, h):
        return 2.0 * np.maximum(s.f0[:, c], 0.0) * np.sin(0.5 * s.wrap[:, c]) * np.sign(s.v_slide[:, c])


class Creep(Term):
    """Creep and settling (002 Fig 6: the force drifts away from the identified model over
    time). The unstretched length grows by a settling part and a steady creep,

        delta_l(t) = d0 + a (1 - exp(-t / tau)) + b t,        delta_f = -k delta_l(t)

    with k = EA / L the nominal stiffness at the mean free length. a [m] >= 0, b [m/s] >= 0,
    tau [s] on a grid of fractions of the analysed span, then refined by a bounded scalar
    search. t is the time since the analysis' start offline (the recording's start, or
    ``discover --since``), and since the creep clock's start live (``terms_clock_origin``
    of the file, kept in the daemon's snapshot across restarts). d0 [m] is the creep the
    cable already had when the clock started (a cable found creeping after an alarm has
    crept since before it): a constant, so it is a nuisance column, held at 0 where the
    sensor offset (``offset_gain``) already carries the constant, and the creep term must
    explain more than it alone."""

    name = "creep"
    label = "creep and settling drift"
    equation = "-k (d0 + a (1 - exp(-t/tau)) + b t), k = EA/L  (002 Fig 6)"
    variable = "time since start [s]"
    params = ("a", "b", "d0")
    units = ("m", "m/s", "m")
    lower = (0.0, 0.0, -np.inf)
    nuisance = ("d0",)
    hypers = ("tau",)
    ref_names = ("k",)
    n_hyper = 1
    refine_hyper = "tau"
    refine_bounds = (0.1, 1e6)

    def grid(self, s):
        T = float(s.t[-1] - s.t[0]) or 1.0
        return [{"tau": fr * T} for fr in (0.03, 0.1, 0.25, 0.5, 1.0, 2.0)]

    def refs(self, s, c, h):
        return {"k": float(s.ea[c] / s.train_mean(s.free_length[:, c]))}

    def columns(self, g, R, h, out):
        o0, o1, o2 = out
        np.copyto(o2, R["k"])
        np.negative(o2, out=o2)                        # -k (the creep before the clock's start)
        np.divide(g.t, h["tau"], out=o0)
        np.negative(o0, out=o0)
        np.exp(o0, out=o0)
        np.subtract(1.0, o0, out=o0)
        np.multiply(o0, R["k"], out=o0)
        np.negative(o0, out=o0)                        # -k (1 - exp(-t/tau))
        np.multiply(g.t, R["k"], out=o1)
        np.negative(o1, out=o1)                        # -k t

    def evidence(self, s, c, h):
        return s.t - s.t[0]


class TemperatureStiffness(Term):
    """Temperature-dependent stiffness: the cable's modulus scales as
    k(T) = k (1 + c_T (T - T_ref)), so the force becomes f (1 + c_T (T - T_ref)):

        delta_f = f (c_T (T - T_mean) + g),   g = c_T (T_mean - T_ref)

    c_T [1/K], g [-]; needs the recording's temperature channel. Live, a tick without a
    temperature on the bus takes T = T_mean (the temperature part is 0, the gain g stays)."""

    name = "temperature"
    label = "temperature-dependent stiffness"
    equation = "f (c_T (T - T_mean) + g)"
    variable = "temperature x force, (T - T_mean) f [K N]"
    params = ("c_T", "g")
    units = ("1/K", "-")
    ref_names = ("T_mean",)
    nuisance = ("g",)

    def applies(self, s, c):
        return s.temperature is not None and float(np.ptp(s.temperature)) > 0.05

    def refs(self, s, c, h):
        return {"T_mean": s.train_mean(s.temperature)}

    def columns(self, g, R, h, out):
        o0, o1 = out
        np.subtract(g.temperature, R["T_mean"], out=o0)
        np.nan_to_num(o0, copy=False, nan=0.0)         # no temperature: T = T_mean
        np.multiply(o0, g.f0, out=o0)
        np.copyto(o1, g.f0)

    def evidence(self, s, c, h):
        return (s.temperature - np.mean(s.temperature)) * s.f0[:, c]


class Viscous(Term):
    """Viscous rate dependence (Kelvin-Voigt damper in parallel with the cable):

        delta_f = c_v dx/dt,   c_v [N s/m] >= 0

    (dx/dt the backward difference of the elongation, as the live kernel has it)."""

    name = "viscous"
    label = "viscous rate dependence"
    equation = "c_v dx/dt (Kelvin-Voigt)"
    variable = "elongation rate dx/dt [m/s]"
    params = ("c_v",)
    units = ("N s/m",)
    lower = (0.0,)

    def columns(self, g, R, h, out):
        np.copyto(out[0], g.v)

    def evidence(self, s, c, h):
        return s.v[:, c]


class AmplitudeStiffness(Term):
    """Amplitude-dependent stiffness and damping (002 eq 8: K1..K3 and the loop area S_a are
    functions of the elongation amplitude A). To first order in A around its mean the
    baseline misses a stiffness slope and a friction-like loop width that grow with A:

        delta_f = K1_A (A - A_mean) (x - x_mean) + d_A A tanh(v / v_s)

    K1_A [N/m^2], d_A [N/m]; A from the reversal points; v_s = 1e-4 m/s."""

    model_form = True
    name = "amplitude"
    label = "amplitude-dependent stiffness and damping"
    equation = "K1_A (A - mean A)(x - mean x) + d_A A tanh(v/v_s)  (002 eq 8)"
    variable = "amplitude x direction of motion, A sgn(v) [m]"
    params = ("K1_A", "d_A")
    units = ("N/m^2", "N/m")
    ref_names = ("A_mean", "x_mean")

    def applies(self, s, c):
        return float(np.ptp(s.amplitude[:, c])) > 1e-6

    def refs(self, s, c, h):
        return {"A_mean": s.train_mean(s.amplitude[:, c]), "x_mean": s.train_mean(s.x[:, c])}

    def columns(self, g, R, h, out):
        o0, o1 = out
        np.subtract(g.amplitude, R["A_mean"], out=o0)
        np.subtract(g.x, R["x_mean"], out=o1)
        np.multiply(o0, o1, out=o0)
        smooth_sign(g.v, 1e-4, out=o1)
        np.multiply(o1, g.amplitude, out=o1)

    def evidence(self, s, c, h):
        return s.amplitude[:, c] * np.sign(s.v[:, c])


class AsymmetricHardening(Term):
    """Asymmetric hardening (001 Ch 4: the elastic backbone k1 x + k2 x^2 + k3 x^3 of the
    modified asymmetric Bouc-Wen model; k2 makes loading and unloading sides differ,
    k3 hardens). Around the mean elongation the baseline misses

        delta_f = k2 (x - x_mean)^2 + k3 (x - x_mean)^3,   k2 [N/m^2], k3 [N/m^3]

    (fitted on columns scaled by the training std s of x: k2 = k2_scaled / s, k3 =
    k3_scaled / s^2)."""

    model_form = True
    name = "asymmetric"
    label = "asymmetric hardening of the elastic backbone"
    equation = "k2 (x - mean x)^2 + k3 (x - mean x)^3  (001 Ch 4)"
    variable = "elongation x - mean x [m]"
    params = ("k2_scaled", "k3_scaled")
    units = ("N/m", "N/m")
    ref_names = ("x_mean", "x_scale")

    def refs(self, s, c, h):
        xm = s.train_mean(s.x[:, c])
        return {"x_mean": xm, "x_scale": max(float(np.std(s.x[s.train, c] - xm)), 1e-12)}

    def columns(self, g, R, h, out):
        o0, o1 = out
        np.subtract(g.x, R["x_mean"], out=o0)          # xi
        np.divide(o0, R["x_scale"], out=o1)            # xi / s
        np.multiply(o0, o1, out=o0)                    # xi^2 / s
        np.multiply(o0, o1, out=o1)                    # xi^3 / s^2

    def physical(self, params, h, s, c):
        sc = self.refs(s, c, h)["x_scale"]
        return {"k2": params["k2_scaled"] / sc, "k3": params["k3_scaled"] / sc ** 2}

    def evidence(self, s, c, h):
        return s.x[:, c] - np.mean(s.x[:, c])


class Sag(Term):
    """Sag at low tension (Irvine's taut-cable approximation): a cable of weight per length
    w hanging over the chord L under tension f is longer than the chord by
    s = w^2 L^3 / (24 f^2). At a given pose the cable is thus stretched by s more than the
    baseline assumes, and the whole cable path (stiffness k_c, from the winch, unknown:
    it includes the length stored between winch and pulley) takes it up:

        f = f0 + k_c s(f) = f0 + q L^3 / f^2,   q = w^2 k_c / 24 [N^3/m^3],   delta_f = f - f0

    (:data:`SAG_NEWTON` Newton steps per tick; f - q L^3 / f^2 increases in f, so the root
    above f0 is unique). q >= 0 is the nonlinear parameter (grid, then bounded scalar
    search); the report gives w = sqrt(24 q / k) with k = EA / (mean free length). L the
    free length, f >= 1 N."""

    name = "sag"
    label = "sag at low tension"
    equation = "f = f0 + k_c w^2 L^3 / (24 f^2)  (Irvine, taut cable)"
    variable = "1 / tension^2 [1/N^2]"
    hypers = ("q",)
    has_fixed = True
    refine_hyper = "q"
    refine_bounds = (0.0, 1e8)
    n_hyper = 1

    def grid(self, s):
        return [{"q": q} for q in np.r_[0.0, np.geomspace(1.0, 1e8, 25)]]

    #: the tension under sag (:func:`cablesvc.models.catenary.irvine_tension`, by default
    #: :data:`SAG_NEWTON` Newton steps from max(f0, cbrt(cc), 1 N), fixed time)
    solve = staticmethod(irvine_tension)

    def fixed_part(self, g, R, h, out):
        cc = np.empty(np.shape(out))
        tmp = np.empty((2,) + np.shape(out))
        self._fixed(g, h, out, cc, tmp)

    def _fixed(self, g, h, out, cc, tmp):
        np.power(g.free_length, 3, out=cc)
        np.multiply(cc, h["q"], out=cc)
        self.solve(g.f0, cc, out=out, tmp=tmp)
        np.maximum(g.f0, 1.0, out=cc)
        np.subtract(out, cc, out=out)

    def live(self, table, lanes, m):
        return _SagLive(self, table, lanes, m)

    def physical(self, params, h, s, c):
        k = s.ea[c] / float(np.mean(s.free_length[:, c]))
        return {"q": h["q"], "unit_q": "N^3/m^3", "w": math.sqrt(24.0 * max(h["q"], 0.0) / k), "unit_w": "N/m"}

    def evidence(self, s, c, h):
        return 1.0 / np.maximum(s.f0[:, c], 1.0) ** 2


class DeadTime(Term):
    """Dead time between length and force: the force follows the elongation of tau seconds
    ago. A time-invariant baseline driven by x(t - tau) gives f0(t - tau), so

        delta_f = f0(t - tau) - f0(t),   tau [s] in [0, 0.5]

    (no linear parameter; tau from a grid of ticks refined by a bounded scalar search;
    f0(t - tau) linearly interpolated between ticks, held at the first value before the
    start). Live, a delay line of the last :data:`DELAY_WINDOW_S` seconds holds f0, x,
    dx/dt and A (the other terms on the cable see them delayed, as offline)."""

    name = "deadtime"
    label = "dead time between length and force"
    equation = "f0(t - tau) - f0(t)"
    variable = "force rate -df0/dt [N/s]"
    hypers = ("tau",)
    has_fixed = True
    refine_hyper = "tau"
    refine_bounds = (0.0, 0.5)
    n_hyper = 1
    delays_input = True

    def grid(self, s):
        return [{"tau": tau} for tau in np.unique(np.r_[0.0, np.geomspace(s.dt, 0.5, 14)])]

    def design(self, s, c, h):
        f = s.f0[:, c]
        shifted = np.interp(s.t - h["tau"], s.t, f)
        return make_design([], (), (), fixed=shifted - f)

    def evidence(self, s, c, h):
        return -np.gradient(s.f0[:, c], s.t)


class OffsetGain(Term):
    """Force-sensor offset and gain error: measured = (1 + g) f + o:

        delta_f = o + g f,   o [N], g [-]."""

    model_form = True
    name = "offset_gain"
    label = "sensor offset and gain error"
    equation = "o + g f"
    variable = "predicted force f [N]"
    params = ("o", "g")
    units = ("N", "-")
    owns_nuisance = True

    def columns(self, g, R, h, out):
        out[0].fill(1.0)
        np.copyto(out[1], g.f0)

    def evidence(self, s, c, h):
        return s.f0[:, c]


class BoucWenHysteresis(Term):
    """Hysteresis missing altogether (000 eqs 1-2, Bouc-Wen): a hysteretic force alpha_z z
    with z driven by the elongation,

        dz = dx (1 - (beta + gamma sgn(z dx)) |z|),   delta_f = k_z z + k_x (x - x_mean)

    k_z [N/m], k_x [N/m]; the loop shape (beta, gamma) [1/m] on a grid set by the saturation
    z_max = 1 / (beta + gamma) relative to the elongation's spread; z by the semi-implicit
    step of :func:`bouc_wen_z`, offline over the record and live tick by tick."""

    model_form = True
    name = "boucwen"
    label = "hysteresis missing (Bouc-Wen)"
    # the law as the code runs it (the string said (beta sgn(z dx) + gamma), 000's own naming)
    equation = ("k_z z + k_x (x - mean x), dz = dx (1 - (beta + gamma sgn(z dx)) |z|)  "
                "(000 eqs 1-2; this term's beta, gamma are 000's gamma, beta)")
    variable = "elongation x [m] (loop)"
    params = ("k_z", "k_x")
    units = ("N/m", "N/m")
    hypers = ("beta", "gamma")
    ref_names = ("x_mean",)
    n_hyper = 2

    def grid(self, s):
        sx = float(np.median(np.std(s.x[s.train], axis=0))) or 1e-3
        out = []
        for zmax in (0.05 * sx, 0.2 * sx, 0.8 * sx):
            for ratio in (0.5, 0.0, -0.5):         # gamma / beta: softening, symmetric, pinched
                beta = 1.0 / (zmax * (1.0 + ratio))
                out.append({"beta": beta, "gamma": ratio * beta})
        return out

    def refs(self, s, c, h):
        return {"x_mean": s.train_mean(s.x[:, c])}

    @staticmethod
    def law(z, x, x_mean, out):
        np.copyto(out[0], z)
        np.subtract(x, x_mean, out=out[1])

    def design(self, s, c, h):
        R = self.refs(s, c, h)
        X = np.empty((2, s.n))
        self.law(bouc_wen_z(s.x[:, c], h["beta"], h["gamma"]), s.x[:, c], R["x_mean"], X)
        return make_design(list(X), self.params, self.units, refs=R)

    def live(self, table, lanes, m):
        return _BoucWenLive(self, table, lanes, m)

    def evidence(self, s, c, h):
        return s.x[:, c]


for _t in (PulleyFriction(), Creep(), TemperatureStiffness(), Viscous(), AmplitudeStiffness(),
           AsymmetricHardening(), Sag(), DeadTime(), OffsetGain(), BoucWenHysteresis()):
    register(_t)


# --------------------------------------------------------------------------------------
# the baseline's own recalibration (the nuisance of identified-baseline discovery)
# --------------------------------------------------------------------------------------


def _backbone_refs(s: Signals, c: int) -> dict[str, float]:
    x = s.x[:, c]
    xm = s.train_mean(x)
    sx = max(float(np.std(x[s.train] - xm)), 1e-12)
    u = (x - xm) / sx
    V = np.column_stack([np.ones_like(u), u, u ** 2, u ** 3])
    coef, *_ = np.linalg.lstsq(V[s.train], s.f0[s.train, c], rcond=None)
    return {"x_mean": xm, "x_scale": sx, "h0": float(coef[0]), "h1": float(coef[1]), "h2": float(coef[2]),
            "h3": float(coef[3])}


def _hysteretic_part(f0, x, R, out, tmp) -> None:
    """h = f0 - (h0 + h1 u + h2 u^2 + h3 u^3), u = (x - x_mean) / x_scale, into ``out``."""
    np.subtract(x, R["x_mean"], out=tmp)
    np.divide(tmp, R["x_scale"], out=tmp)
    np.multiply(tmp, R["h3"], out=out)
    np.add(out, R["h2"], out=out)
    np.multiply(out, tmp, out=out)
    np.add(out, R["h1"], out=out)
    np.multiply(out, tmp, out=out)
    np.add(out, R["h0"], out=out)
    np.subtract(f0, out, out=out)


def hysteretic_part(s: Signals, c: int) -> np.ndarray:
    """The baseline's hysteretic part h (N,) [N] of cable ``c``: f0 minus the cubic in the
    elongation that fits f0 best on the training ticks (the backbone)."""
    out, tmp = np.empty(s.n), np.empty(s.n)
    _hysteretic_part(s.f0[:, c], s.x[:, c], _backbone_refs(s, c), out, tmp)
    return out


class Recalibration(Term):
    """Recalibration of the baseline's own parameters plus a smooth discrepancy in its own
    state (the nuisance every named term must beat with an identified baseline):

        delta_f = o + k_s f0 + a_h h + c2 xi^2 / s + c3 xi^3 / s^2 + K1_A (A - mean A) xi + d_A A tanh(v / v_s)

    f0 the baseline force [N], xi = x - mean x [m], s its training std [m], h = f0 - P3(x)
    the baseline's hysteretic part (f0 minus its least-squares cubic backbone in x on the
    training ticks) [N], A the reversal amplitude [m] (002 eq 8), v_s = 1e-4 m/s. o [N],
    k_s [-], a_h [-], c2, c3 [N], K1_A [N/m^2], d_A [N/m] (the last two only when A varies).
    Background and references: :mod:`cablesvc.discover.nuisance`."""

    name = "baseline"
    label = "baseline recalibration (its own parameters and a smooth discrepancy in its own state)"
    equation = ("o + k_s f0 + a_h h + c2 xi^2/s + c3 xi^3/s^2 + K1_A (A - mean A) xi + d_A A tanh(v/v_s)"
                "  (002 eq 8, 001 Ch 4; Kennedy & O'Hagan 2001)")
    variable = "baseline force f0 [N]"
    params = ("o", "k_s", "a_h", "c2", "c3", "K1_A", "d_A")
    units = ("N", "-", "-", "N", "N", "N/m^2", "N/m")
    ref_names = ("x_mean", "x_scale", "h0", "h1", "h2", "h3", "A_mean")
    owns_nuisance = True

    def refs(self, s, c, h):
        return {**_backbone_refs(s, c), "A_mean": s.train_mean(s.amplitude[:, c]),
                "has_A": float(float(np.ptp(s.amplitude[:, c])) > 1e-6)}

    def columns(self, g, R, h, out):
        o, ks, ah, c2 = out[:4]
        o.fill(1.0)
        np.copyto(ks, g.f0)
        _hysteretic_part(g.f0, g.x, R, ah, c2)
        # the backbone curvature and the amplitude dependence are the laws of those terms
        _ASYMMETRIC.columns(g, R, h, out[3:5])           # xi^2 / s, xi^3 / s^2
        _AMPLITUDE.columns(g, R, h, out[5:7])            # (A - mean A) xi, A tanh(v / v_s)

    def design(self, s, c, h):
        d = super().design(s, c, h)
        return d if d.refs.get("has_A", 1.0) else d.without(("K1_A", "d_A"))

    def evidence(self, s, c, h):
        return s.f0[:, c]

    def physical(self, params, h, s, c):
        f0 = s.f0[:, c]
        return {**params, "mean_f0_N": float(np.mean(f0)),
                "offset_at_mean_N": float(params.get("o", 0.0) + params.get("k_s", 0.0) * np.mean(f0))}


_ASYMMETRIC = AsymmetricHardening()
_AMPLITUDE = AmplitudeStiffness()


#: terms a parameter file may name, by name (the library and the baseline recalibration)
def term_class(name: str) -> Term:
    if name == Recalibration.name:
        return Recalibration()
    if name not in LIBRARY:
        raise KeyError(f"unknown term {name!r}; known: {', '.join([Recalibration.name, *LIBRARY])}")
    return LIBRARY[name]


# --------------------------------------------------------------------------------------
# the live forms
# --------------------------------------------------------------------------------------


class LiveTerm:
    """The live form of a term whose law is :meth:`Term.columns` / :meth:`Term.fixed_part`:
    per-cable parameters P (p, m), references and hyper-parameters (m,), and buffers
    (p, lanes, m) allocated once. :meth:`step` adds the term's force to ``acc``."""

    def __init__(self, term: Term, table: dict[str, Any], lanes: int, m: int):
        self.term = term
        self.m, self.lanes = m, lanes

        def col(k: str) -> np.ndarray:
            v = np.zeros(m) if k not in table else np.asarray(table[k], float).reshape(-1)
            if v.size != m:
                raise ValueError(f"term_{term.name}.{k}: {v.size} values for {m} cables")
            return np.ascontiguousarray(v)

        self.P = np.stack([col(k) for k in term.params]) if term.params else np.zeros((0, m))
        self.R = {k: col(k) for k in term.ref_names}
        # a cable without the term has scale-like references at 0: keep its columns finite
        if "x_scale" in self.R:
            self.R["x_scale"][self.R["x_scale"] <= 0] = 1.0
        self.H = {k: col(k) for k in term.hypers}
        self._fix_hypers()
        self.cols = np.zeros((len(term.params), lanes, m))
        self.prod = np.zeros_like(self.cols)
        self.buf = np.zeros((lanes, m))

    def _fix_hypers(self) -> None:
        """Hyper-parameters of cables without the term: values that keep the law finite
        (their parameters are 0, so they contribute exactly 0)."""
        for k, v in self.H.items():
            if k in ("v_s", "tau"):
                v[v <= 0] = 1.0

    def step(self, g: CableView, acc: np.ndarray) -> None:
        if self.P.shape[0]:
            self.term.columns(g, self.R, self.H, self.cols)
            np.multiply(self.cols, self.P[:, None, :], out=self.prod)
            np.sum(self.prod, axis=0, out=self.buf)
            np.add(acc, self.buf, out=acc)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {}

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        pass


class _SagLive(LiveTerm):
    def __init__(self, term, table, lanes, m):
        super().__init__(term, table, lanes, m)
        self.cc = np.zeros((lanes, m))
        self.tmp = np.zeros((2, lanes, m))

    def step(self, g, acc):
        self.term._fixed(g, self.H, self.buf, self.cc, self.tmp)
        np.add(acc, self.buf, out=acc)


class _BoucWenLive(LiveTerm):
    """Bouc-Wen z per (lane, cable), the step of :func:`bouc_wen_z` in its numpy form
    (:func:`cablesvc.models.boucwen.bouc_wen_step_n1_np`)."""

    def __init__(self, term, table, lanes, m):
        super().__init__(term, table, lanes, m)
        self.z = np.zeros((lanes, m))
        self.x_prev = np.zeros((lanes, m))
        self.started = np.zeros(1, bool)
        self.dx = np.zeros((lanes, m))
        self.s = np.zeros((lanes, m))
        self.den = np.zeros((lanes, m))

    def step(self, g, acc):
        # first tick: dx = 0, so z stays 0 (offline z[0] = 0)
        np.copyto(self.x_prev, g.x, where=~self.started[0])
        self.started[0] = True
        np.subtract(g.x, self.x_prev, out=self.dx)
        np.copyto(self.x_prev, g.x)
        # the law's beta is this term's gamma, its gamma this term's beta (see _bw_z)
        bouc_wen_step_n1_np(self.z, self.dx, self.H["gamma"], self.H["beta"], self.s, self.den)
        self.term.law(self.z, g.x, self.R["x_mean"], self.cols)
        np.multiply(self.cols, self.P[:, None, :], out=self.prod)
        np.sum(self.prod, axis=0, out=self.buf)
        np.add(acc, self.buf, out=acc)

    def state_dict(self):
        return {"z": self.z.copy(), "x_prev": self.x_prev.copy(), "started": self.started.copy()}

    def load_state_dict(self, d):
        if "z" not in d or np.shape(d["z"]) != self.z.shape:     # a file without this term before
            return
        np.copyto(self.z, d["z"])
        np.copyto(self.x_prev, d["x_prev"])
        np.copyto(self.started, d["started"])


#: seconds of history the live dead-time line keeps (the largest dead time discovery fits)
DELAY_WINDOW_S = 0.5


class _DelayLine:
    """The last ``n`` ticks of (lanes, m) signals with their times, in a doubled ring so
    that the window is always one contiguous, time-ordered slice; :meth:`at` interpolates
    linearly at t - tau per cable exactly as ``np.interp`` does offline (held at the oldest
    value before it)."""

    def __init__(self, n: int, k: int, lanes: int, m: int):
        self.n = int(max(n, 2))
        self.t = np.zeros(2 * self.n)
        self.v = np.zeros((2 * self.n, k, lanes, m))
        self.head = 0          # index of the newest sample in [0, n)
        self.started = False
        self.cols = np.arange(m)

    def push(self, t: float, vals: np.ndarray) -> None:
        if not self.started:
            self.t.fill(t)
            self.v[...] = vals
            self.started = True
            self.head = self.n - 1
            return
        h = (self.head + 1) % self.n
        self.t[h] = self.t[h + self.n] = t
        self.v[h] = vals
        self.v[h + self.n] = vals
        self.head = h

    def at(self, q: np.ndarray, out: np.ndarray) -> None:
        """Values (k, lanes, m) at times q (m,), into ``out``."""
        lo = self.head + 1
        tw = self.t[lo: lo + self.n]
        vw = self.v[lo: lo + self.n]
        j = np.searchsorted(tw, q, side="right") - 1
        np.maximum(j, 0, out=j)                # (np.clip with int bounds keeps a small cache growing)
        np.minimum(j, self.n - 1, out=j)
        j1 = np.minimum(j + 1, self.n - 1)
        ta, tb = tw[j], tw[j1]
        va = vw[j, :, :, self.cols]            # (m, k, lanes)
        vb = vw[j1, :, :, self.cols]
        dtab = tb - ta
        w = np.where(dtab > 0, (q - ta), 0.0)
        safe = np.where(dtab > 0, dtab, 1.0)
        slope = (vb - va) / safe[:, None, None]
        res = slope * w[:, None, None] + va    # np.interp: slope (x - xp[j]) + fp[j]
        np.copyto(out, np.moveaxis(res, 0, -1))

    def state_dict(self, prefix: str) -> dict[str, np.ndarray]:
        return {prefix + "t": self.t.copy(), prefix + "v": self.v.copy(),
                prefix + "head": np.array([self.head, int(self.started)])}

    def load_state_dict(self, d: dict[str, np.ndarray], prefix: str) -> None:
        if prefix + "t" not in d or d[prefix + "t"].shape != self.t.shape:
            return
        np.copyto(self.t, d[prefix + "t"])
        np.copyto(self.v, d[prefix + "v"])
        self.head, started = (int(v) for v in d[prefix + "head"])
        self.started = bool(started)


class _Reversals:
    """Live elongation amplitude A per (lane, cable): the rule of
    :func:`cablesvc.models.reversal.reversal_amplitude` (dead-band ``eps``), tick by tick:
    no direction until x has moved by eps from its first extremes; then a running extremum
    that becomes a reversal point once x is eps back from it; A = half the distance
    between the last two reversal points (0 before two)."""

    def __init__(self, lanes: int, m: int, eps: float):
        shp = (lanes, m)
        self.eps = eps
        self.dir = np.zeros(shp)        # 0 before the first move, +1 rising, -1 falling
        self.hi = np.zeros(shp)
        self.lo = np.zeros(shp)
        self.hi_later = np.zeros(shp, bool)
        self.ext = np.zeros(shp)
        self.last = np.zeros(shp)
        self.prev = np.zeros(shp)
        self.count = np.zeros(shp)
        self.A = np.zeros(shp)
        self.started = False

    def step(self, x: np.ndarray) -> np.ndarray:
        if not self.started:
            np.copyto(self.hi, x)
            np.copyto(self.lo, x)
            self.started = True
            return self.A
        init = self.dir == 0
        up_hi = init & (x > self.hi)
        up_lo = init & (x < self.lo)
        np.copyto(self.hi, x, where=up_hi)
        np.copyto(self.lo, x, where=up_lo)
        self.hi_later[up_hi] = True
        self.hi_later[up_lo] = False
        start = init & ((self.hi - self.lo) > self.eps)
        np.copyto(self.dir, np.where(self.hi_later, 1.0, -1.0), where=start)
        np.copyto(self.ext, np.where(self.hi_later, self.hi, self.lo), where=start)
        run = ~init
        d = self.dir
        further = run & (((d > 0) & (x >= self.ext)) | ((d < 0) & (x <= self.ext)))
        rev = run & ~further & (np.abs(x - self.ext) > self.eps)
        np.copyto(self.ext, x, where=further)
        np.copyto(self.prev, self.last, where=rev)
        np.copyto(self.last, self.ext, where=rev)
        self.count += rev
        np.copyto(self.dir, -d, where=rev)
        np.copyto(self.ext, x, where=rev)
        np.copyto(self.A, 0.5 * np.abs(self.last - self.prev), where=rev & (self.count >= 2))
        return self.A

    def state_dict(self, prefix: str) -> dict[str, np.ndarray]:
        return {prefix + k: np.array(getattr(self, k)) for k in
                ("dir", "hi", "lo", "hi_later", "ext", "last", "prev", "count", "A", "started")}

    def load_state_dict(self, d: dict[str, np.ndarray], prefix: str) -> None:
        for k in ("dir", "hi", "lo", "hi_later", "ext", "last", "prev", "count", "A"):
            if prefix + k in d:
                np.copyto(getattr(self, k), d[prefix + k])
        if prefix + "started" in d:
            self.started = bool(d[prefix + "started"])


class TermStack:
    """The terms of a parameter file, live: every tick, from the kernel's baseline force f0,
    elongation x, motor length, wrap angle, free length and temperature (lanes, m), the
    sum of the terms' forces (lanes, m) [N].

    It keeps the state the terms need: the previous x and motor length (dx/dt and the
    sliding speed over the pulley by backward differences, 0 on the first tick), the
    amplitude tracker, the creep clock (time since the recording's start that the parameter
    file gives as ``terms_clock_origin``, else since the first tick), the dead-time delay line
    (f0, x, dx/dt and A of the last :data:`DELAY_WINDOW_S` s at up to ``max_rate_hz``; the
    other terms of a cable with a dead time see them delayed by its tau, as offline) and
    each term's own state (Bouc-Wen z). All of it is in :meth:`state_dict`."""

    def __init__(self, terms: list[Term], tables: dict[str, dict[str, Any]], m: int, lanes: int = 1,
                 max_rate_hz: float = 2000.0, clock_origin: Optional[float] = None):
        self.m, self.lanes = m, lanes
        self.max_rate_hz = float(max_rate_hz)
        self.delay = next((t for t in terms if t.delays_input), None)
        self.live = [t.live(tables.get(t.name, {}), lanes, m) for t in terms if not t.delays_input]
        shp = (lanes, m)
        self.acc = np.zeros(shp)
        self.v = np.zeros(shp)
        self.v_slide = np.zeros(shp)
        self.x_prev = np.zeros(shp)
        self.ml_prev = np.zeros(shp)
        self.temp = np.full((lanes, 1), np.nan)
        self.clock = np.zeros((lanes, 1))
        #: the creep clock's zero [s, in the ticks' time base]: the recording's start when the
        #: parameter file gives it (``terms_clock_origin``), else the first tick
        self.origin = None if clock_origin is None else float(clock_origin)
        self.t0: Optional[float] = None
        self.t_prev = 0.0
        self.rev = _Reversals(lanes, m, REVERSAL_DEADBAND)
        if self.delay is not None:
            tau = np.asarray(tables.get(self.delay.name, {}).get("tau", np.zeros(m)), float).reshape(-1)
            self.tau = np.clip(tau, 0.0, DELAY_WINDOW_S)
            self.line = _DelayLine(int(math.ceil(DELAY_WINDOW_S * max_rate_hz)) + 2, 4, lanes, m)
            self.packed = np.zeros((4, lanes, m))
            self.delayed = np.zeros((4, lanes, m))
            self.q = np.zeros(m)
            self.dead = np.zeros(shp)
        self.g = CableView(t=self.clock, f0=np.zeros(shp), x=np.zeros(shp), v=self.v, v_slide=self.v_slide,
                           wrap=np.zeros(shp), free_length=np.zeros(shp), temperature=self.temp,
                           amplitude=np.zeros(shp))

    @classmethod
    def from_params(cls, identification: dict[str, Any], m: int, lanes: int = 1,
                    max_rate_hz: float = 2000.0) -> Optional["TermStack"]:
        """The stack of a parameter file's ``[identification]`` section: the baseline's
        recalibration (``term_baseline``) and the ``discovered_terms``; None when it has
        neither."""
        names = [n for n in [Recalibration.name] if f"term_{n}" in identification]
        names += [n for n in identification.get("discovered_terms", []) if n not in names]
        if not names:
            return None
        terms = [term_class(n) for n in names]
        tables = {n: dict(identification.get(f"term_{n}", {})) for n in names}
        origin = identification.get("terms_clock_origin")
        return cls(terms, tables, m, lanes, max_rate_hz, None if origin is None else float(origin))

    def prime(self, t: float, x: np.ndarray, motor_length: np.ndarray) -> None:
        """Start a stack that has seen no tick from the previous tick's time, elongation and
        motor length (a reload mid-run: the kernel before it ran without these terms), so
        that the first tick's dx/dt and sliding speed are the real ones, not 0. No effect on
        a stack that has run."""
        if self.t0 is not None:
            return
        self.t0 = float(t) if self.origin is None else self.origin
        self.t_prev = float(t)
        self.x_prev[...] = x
        self.ml_prev[...] = motor_length

    def step(self, t: float, f0: np.ndarray, x: np.ndarray, motor_length: np.ndarray, wrap: np.ndarray,
             free_length: np.ndarray, temperature: Optional[float]) -> np.ndarray:
        """The terms' force (lanes, m) [N] at this tick (a buffer the next tick overwrites)."""
        first = self.t0 is None
        if first:
            self.t0 = t if self.origin is None else self.origin
            self.t_prev = t
            np.copyto(self.x_prev, x)
            np.copyto(self.ml_prev, motor_length)
        dt = t - self.t_prev
        inv = 1.0 / dt if dt > 0 else 0.0
        np.subtract(x, self.x_prev, out=self.v)
        np.multiply(self.v, inv, out=self.v)
        np.subtract(self.ml_prev, motor_length, out=self.v_slide)
        np.multiply(self.v_slide, inv, out=self.v_slide)
        np.copyto(self.x_prev, x)
        np.copyto(self.ml_prev, motor_length)
        self.t_prev = t
        self.clock.fill(t - self.t0)
        self.temp.fill(np.nan if temperature is None else temperature)
        A = self.rev.step(x)
        g = self.g
        np.copyto(g.wrap, wrap)
        np.copyto(g.free_length, free_length)
        self.acc.fill(0.0)
        if self.delay is not None:
            p = self.packed
            np.copyto(p[0], f0)
            np.copyto(p[1], x)
            np.copyto(p[2], self.v)
            np.copyto(p[3], A)
            rel = t - self.t0                          # relative times, as offline (s.t - t[0])
            self.line.push(rel, p)
            np.subtract(rel, self.tau, out=self.q)
            self.line.at(self.q, self.delayed)
            d = self.delayed
            np.subtract(d[0], f0, out=self.dead)       # f0(t - tau) - f0(t)
            np.add(self.acc, self.dead, out=self.acc)
            np.copyto(g.f0, d[0])
            np.copyto(g.x, d[1])
            np.copyto(self.v, d[2])
            np.copyto(g.amplitude, d[3])
        else:
            np.copyto(g.f0, f0)
            np.copyto(g.x, x)
            np.copyto(g.amplitude, A)
        for lt in self.live:
            lt.step(g, self.acc)
        return self.acc

    def state_dict(self) -> dict[str, np.ndarray]:
        if self.t0 is None:
            return {}
        d = {"t0": np.array([self.t0, self.t_prev]), "x_prev": self.x_prev.copy(), "ml_prev": self.ml_prev.copy()}
        d.update(self.rev.state_dict("rev."))
        if self.delay is not None:
            d.update(self.line.state_dict("delay."))
        for lt in self.live:
            d.update({f"{lt.term.name}.{k}": v for k, v in lt.state_dict().items()})
        return d

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        if "t0" not in d:
            return
        self.t0, self.t_prev = (float(v) for v in d["t0"])
        np.copyto(self.x_prev, d["x_prev"])
        np.copyto(self.ml_prev, d["ml_prev"])
        self.rev.load_state_dict(d, "rev.")
        if self.delay is not None:
            self.line.load_state_dict(d, "delay.")
        for lt in self.live:
            pre = f"{lt.term.name}."
            lt.load_state_dict({k[len(pre):]: v for k, v in d.items() if k.startswith(pre)})
