"""The physics library of discovery: one small class per candidate term.

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
``label``, ``equation``, ``applies``, ``grid`` and ``design`` (and optionally
``physical``/``evidence``), registered with :func:`register`. Terms only see the
:class:`Signals` of a recording (what a controller logs, the kinematics and the
baseline's prediction), never any simulation ground truth.

Units: SI throughout (m, s, N, K, rad).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numba
import numpy as np

from cablesvc.identify.amplitude_fit import reversal_amplitude

__all__ = [
    "LIBRARY", "Signals", "Term", "Design", "register", "library", "PulleyFriction", "Creep",
    "TemperatureStiffness", "Viscous", "AmplitudeStiffness", "AsymmetricHardening", "Sag", "DeadTime",
    "OffsetGain", "BoucWenHysteresis", "reversal_amplitude", "bouc_wen_z",
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
                      dropped=self.dropped + gone)

    def only(self, names: tuple[str, ...]) -> "Design":
        """Only the columns ``names`` (no fixed part)."""
        keep = [i for i, n in enumerate(self.names) if n in names]
        return Design(fixed=None, X=self.X[:, keep], names=tuple(self.names[i] for i in keep),
                      units=tuple(self.units[i] for i in keep), lower=self.lower[keep], upper=self.upper[keep])


def _design(cols: list[np.ndarray], names, units, lower=None, upper=None, fixed=None) -> Design:
    n = len(cols)
    X = np.column_stack(cols) if cols else np.zeros((0, 0))
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    return Design(fixed=fixed, X=X, names=tuple(names), units=tuple(units), lower=lo, upper=hi)


def smooth_sign(v: np.ndarray, v_s: float) -> np.ndarray:
    """tanh(v / v_s): the sign of v, smoothed over the speed ``v_s`` [m/s]."""
    return np.tanh(v / v_s)


@numba.njit(cache=True)
def _bw_z(x, beta, gamma, n_exp):
    """Normalised Bouc-Wen state z [m] driven by x [m] (000 eq 2 with A = 1), semi-implicit
    per tick on the increment dx (rate independent)."""
    N = x.shape[0]
    z = np.zeros(N)
    zk = 0.0
    for k in range(1, N):
        dx = x[k] - x[k - 1]
        # a few sub-steps keep the explicit update stable for large beta*dx
        sub = 1 + int(abs(dx) * (abs(beta) + abs(gamma)) * 4.0)
        if sub > 50:
            sub = 50
        h = dx / sub
        for _ in range(sub):
            az = abs(zk) ** n_exp
            sgn = 1.0 if h * zk > 0 else (-1.0 if h * zk < 0 else 0.0)
            zk = zk + h * (1.0 - (beta * sgn + gamma) * az)
        z[k] = zk
    return z


def bouc_wen_z(x: np.ndarray, beta: float, gamma: float, n: float = 1.0) -> np.ndarray:
    """Bouc-Wen hysteretic displacement z [m] driven by the elongation x [m] (N,):
    dz = dx (1 - (beta sgn(z dx) + gamma) |z|^n) (000 eq 2, A = 1); z saturates at
    (beta + gamma)^(-1/n) [m]. ``beta``, ``gamma`` [1/m^n]."""
    return _bw_z(np.ascontiguousarray(x, dtype=np.float64), float(beta), float(gamma), float(n))


# --------------------------------------------------------------------------------------
# the term protocol
# --------------------------------------------------------------------------------------


class Term:
    """One candidate piece of physics. Subclasses set the class attributes and implement
    :meth:`design`; the selector does the fitting.

    ``name``: short id (JSON, parameter files, the bench's labels); ``label``: plain-words
    description; ``equation``: formula with the paper reference; ``variable``: the state
    variable the term says the residual follows (for the evidence sentence and the plot).
    """

    name: str = ""
    label: str = ""
    equation: str = ""
    variable: str = ""
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

    def design(self, s: Signals, c: int, h: dict[str, float]) -> Design:
        raise NotImplementedError

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
    n_hyper = 1
    nuisance = ("k0",)

    def applies(self, s, c):
        return bool(s.has_pulley[c]) and float(np.max(s.wrap[:, c])) > 1e-6

    refine_hyper = "v_s"
    refine_bounds = (1e-5, 0.05)

    def grid(self, s):
        return [{"v_s": float(v)} for v in np.geomspace(1e-4, 1e-2, 7)]

    def design(self, s, c, h):
        f, a = s.f0[:, c], s.wrap[:, c]
        Fb = 2.0 * np.maximum(f, 0.0) * np.sin(0.5 * a)
        am = s.train_mean(a)
        return _design([Fb * smooth_sign(s.v_slide[:, c], h["v_s"]), f * (a - am), f],
                       ("mu", "k_alpha", "k0"), ("-", "1/rad", "-"), lower=[0.0, -np.inf, -np.inf])

    def evidence(self, s, c, h):
        return 2.0 * np.maximum(s.f0[:, c], 0.0) * np.sin(0.5 * s.wrap[:, c]) * np.sign(s.v_slide[:, c])


class Creep(Term):
    """Creep and settling (002 Fig 6: the force drifts away from the identified model over
    time). The unstretched length grows by a settling part and a steady creep,

        delta_l(t) = a (1 - exp(-t / tau)) + b t,        delta_f = -k delta_l(t)

    with k = EA / L the nominal stiffness at the mean free length. a [m] >= 0, b [m/s] >= 0,
    tau [s] on a grid of fractions of the recording."""

    name = "creep"
    label = "creep and settling drift"
    equation = "-k (a (1 - exp(-t/tau)) + b t), k = EA/L  (002 Fig 6)"
    variable = "time since start [s]"
    n_hyper = 1

    def grid(self, s):
        T = float(s.t[-1] - s.t[0]) or 1.0
        return [{"tau": fr * T} for fr in (0.03, 0.1, 0.25, 0.6)]

    def design(self, s, c, h):
        k = s.ea[c] / s.train_mean(s.free_length[:, c])
        t = s.t - s.t[0]
        return _design([-k * (1.0 - np.exp(-t / h["tau"])), -k * t], ("a", "b"), ("m", "m/s"), lower=[0.0, 0.0])

    def evidence(self, s, c, h):
        return s.t - s.t[0]


class TemperatureStiffness(Term):
    """Temperature-dependent stiffness: the cable's modulus scales as
    k(T) = k (1 + c_T (T - T_ref)), so the force becomes f (1 + c_T (T - T_ref)):

        delta_f = f (c_T (T - T_mean) + g),   g = c_T (T_mean - T_ref)

    c_T [1/K], g [-]; needs the recording's temperature channel."""

    name = "temperature"
    label = "temperature-dependent stiffness"
    equation = "f (c_T (T - T_mean) + g)"
    variable = "temperature x force, (T - T_mean) f [K N]"
    nuisance = ("g",)

    def applies(self, s, c):
        return s.temperature is not None and float(np.ptp(s.temperature)) > 0.05

    def design(self, s, c, h):
        f = s.f0[:, c]
        dT = s.temperature - s.train_mean(s.temperature)
        return _design([f * dT, f], ("c_T", "g"), ("1/K", "-"))

    def evidence(self, s, c, h):
        return (s.temperature - np.mean(s.temperature)) * s.f0[:, c]


class Viscous(Term):
    """Viscous rate dependence (Kelvin-Voigt damper in parallel with the cable):

        delta_f = c_v dx/dt,   c_v [N s/m] >= 0."""

    name = "viscous"
    label = "viscous rate dependence"
    equation = "c_v dx/dt (Kelvin-Voigt)"
    variable = "elongation rate dx/dt [m/s]"

    def design(self, s, c, h):
        return _design([s.v[:, c]], ("c_v",), ("N s/m",), lower=[0.0])

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

    def applies(self, s, c):
        return float(np.ptp(s.amplitude[:, c])) > 1e-6

    def design(self, s, c, h):
        A, x = s.amplitude[:, c], s.x[:, c]
        return _design([(A - s.train_mean(A)) * (x - s.train_mean(x)), A * smooth_sign(s.v[:, c], 1e-4)],
                       ("K1_A", "d_A"), ("N/m^2", "N/m"))

    def evidence(self, s, c, h):
        return s.amplitude[:, c] * np.sign(s.v[:, c])


class AsymmetricHardening(Term):
    """Asymmetric hardening (001 Ch 4: the elastic backbone k1 x + k2 x^2 + k3 x^3 of the
    modified asymmetric Bouc-Wen model; k2 makes loading and unloading sides differ,
    k3 hardens). Around the mean elongation the baseline misses

        delta_f = k2 (x - x_mean)^2 + k3 (x - x_mean)^3,   k2 [N/m^2], k3 [N/m^3]."""

    model_form = True
    name = "asymmetric"
    label = "asymmetric hardening of the elastic backbone"
    equation = "k2 (x - mean x)^2 + k3 (x - mean x)^3  (001 Ch 4)"
    variable = "elongation x - mean x [m]"

    def design(self, s, c, h):
        x = s.x[:, c]
        xi = x - s.train_mean(x)
        sc = max(float(np.std(xi[s.train])), 1e-12)
        return _design([xi ** 2 / sc, xi ** 3 / sc ** 2], ("k2_scaled", "k3_scaled"), ("N/m", "N/m"))

    def physical(self, params, h, s, c):
        xi = s.x[:, c] - s.train_mean(s.x[:, c])
        sc = max(float(np.std(xi[s.train])), 1e-12)
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

    (Newton per tick; f - q L^3 / f^2 increases in f, so the root above f0 is unique).
    q >= 0 is the nonlinear parameter (grid, then bounded scalar search); the report gives
    w = sqrt(24 q / k) with k = EA / (mean free length). L the free length, f >= 1 N."""

    name = "sag"
    label = "sag at low tension"
    equation = "f = f0 + k_c w^2 L^3 / (24 f^2)  (Irvine, taut cable)"
    variable = "1 / tension^2 [1/N^2]"
    refine_hyper = "q"
    refine_bounds = (0.0, 1e8)
    n_hyper = 1

    def grid(self, s):
        return [{"q": q} for q in np.r_[0.0, np.geomspace(1.0, 1e8, 25)]]

    @staticmethod
    def solve(f0: np.ndarray, cc: np.ndarray, floor: float = 1.0) -> np.ndarray:
        """Root f >= f0 of f - f0 - cc / f^2 = 0 (cc [N^3] >= 0), f floored at ``floor`` N."""
        f = np.maximum(f0, floor)
        for _ in range(40):
            f2 = f * f
            step = (f - f0 - cc / f2) / (1.0 + 2.0 * cc / (f2 * f))
            f = np.maximum(f - step, floor)
            if np.max(np.abs(step)) < 1e-10:
                break
        return f

    def design(self, s, c, h):
        f0 = s.f0[:, c]
        cc = h["q"] * s.free_length[:, c] ** 3
        return _design([], (), (), fixed=self.solve(f0, cc) - np.maximum(f0, 1.0))

    def physical(self, params, h, s, c):
        k = s.ea[c] / float(np.mean(s.free_length[:, c]))
        return {"q": h["q"], "unit_q": "N^3/m^3", "w": math.sqrt(24.0 * max(h["q"], 0.0) / k), "unit_w": "N/m"}

    def evidence(self, s, c, h):
        return 1.0 / np.maximum(s.f0[:, c], 1.0) ** 2


class DeadTime(Term):
    """Dead time between length and force: the force follows the elongation of tau seconds
    ago. A time-invariant baseline driven by x(t - tau) gives f0(t - tau), so

        delta_f = f0(t - tau) - f0(t),   tau [s] in [0, 0.5]

    (no linear parameter; tau from a grid of ticks refined by a bounded scalar search)."""

    name = "deadtime"
    label = "dead time between length and force"
    equation = "f0(t - tau) - f0(t)"
    variable = "force rate -df0/dt [N/s]"
    refine_hyper = "tau"
    refine_bounds = (0.0, 0.5)
    n_hyper = 1
    delays_input = True

    def grid(self, s):
        return [{"tau": tau} for tau in np.unique(np.r_[0.0, np.geomspace(s.dt, 0.5, 14)])]

    def design(self, s, c, h):
        f = s.f0[:, c]
        shifted = np.interp(s.t - h["tau"], s.t, f)
        return _design([], (), (), fixed=shifted - f)

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
    owns_nuisance = True

    def design(self, s, c, h):
        return _design([np.ones(s.n), s.f0[:, c]], ("o", "g"), ("N", "-"))

    def evidence(self, s, c, h):
        return s.f0[:, c]


class BoucWenHysteresis(Term):
    """Hysteresis missing altogether (000 eqs 1-2, Bouc-Wen): a hysteretic force alpha_z z
    with z driven by the elongation,

        dz = dx (1 - (beta sgn(z dx) + gamma) |z|),   delta_f = k_z z + k_x (x - x_mean)

    k_z [N/m], k_x [N/m]; the loop shape (beta, gamma) [1/m] on a grid set by the saturation
    z_max = 1 / (beta + gamma) relative to the elongation's spread."""

    model_form = True
    name = "boucwen"
    label = "hysteresis missing (Bouc-Wen)"
    equation = "k_z z + k_x (x - mean x), dz = dx (1 - (beta sgn(z dx) + gamma)|z|)  (000 eqs 1-2)"
    variable = "elongation x [m] (loop)"
    n_hyper = 2

    def grid(self, s):
        sx = float(np.median(np.std(s.x[s.train], axis=0))) or 1e-3
        out = []
        for zmax in (0.05 * sx, 0.2 * sx, 0.8 * sx):
            for ratio in (0.5, 0.0, -0.5):         # gamma / beta: softening, symmetric, pinched
                beta = 1.0 / (zmax * (1.0 + ratio))
                out.append({"beta": beta, "gamma": ratio * beta})
        return out

    def design(self, s, c, h):
        x = s.x[:, c]
        z = bouc_wen_z(x, h["beta"], h["gamma"], 1.0)
        return _design([z, x - s.train_mean(x)], ("k_z", "k_x"), ("N/m", "N/m"))

    def evidence(self, s, c, h):
        return s.x[:, c]


for _t in (PulleyFriction(), Creep(), TemperatureStiffness(), Viscous(), AmplitudeStiffness(),
           AsymmetricHardening(), Sag(), DeadTime(), OffsetGain(), BoucWenHysteresis()):
    register(_t)
