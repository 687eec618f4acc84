"""The switchable extra physics of the twin's truth model (:data:`EFFECTS`).

Each effect is a small class with a ``magnitude`` (its one headline number, unit in its
docstring) and the ``cables`` it acts on (default: all). A magnitude of 0 switches an
effect off exactly; on the other cables it is exactly the identity. The effect names are
the API that benchmarks use as concealed labels; :func:`effect_from_spec` parses the CLI's
``NAME[:MAGNITUDE][@CABLES]``. :class:`~cablesvc.simulate.truth.TruthModel` runs them per
tick, in the order of their stage (:data:`STAGES`), on a :class:`TickState`.

Units: SI (m, s, N, K, rad) throughout.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Optional

import numpy as np

from cablesvc.errors import SimulationError
from cablesvc.models.catenary import irvine_tension

__all__ = [
    "EFFECTS", "STAGES", "Creep", "Deadtime", "Effect", "OffsetGain", "Pulley", "RunInfo", "Sag", "Temperature",
    "TickState", "Viscous", "effect_from_spec", "list_effects", "stage_order",
]

#: Effect stages in the order the truth model applies them each tick.
STAGES = ("input", "force", "sensor")


# --------------------------------------------------------------------------------------
# run / tick context
# --------------------------------------------------------------------------------------


@dataclass
class RunInfo:
    """What an effect learns about a run when it is bound to it.

    ``stiffness`` (m,) [N/m] is the nominal cable stiffness k_i = EA_i / L_i (L_i: cable
    length at the home pose) that ``creep`` and ``sag`` use to turn lengths into forces.
    """

    n_cables: int
    dt: float
    n_ticks: int
    duration: float
    stiffness: np.ndarray
    has_pulley: np.ndarray
    cable_names: tuple[str, ...] = ()


class TickState:
    """The per-tick inputs every effect can read (arrays (m,), SI units), owned by the loop.

    ``k`` tick index, ``t`` [s], ``dt`` [s]; ``x`` geometric elongation l - motor_length [m];
    ``x_in`` elongation after the input stage [m]; ``v_in`` its rate [m/s] (0 at the first
    tick); ``v_slide`` haul-in speed over the pulley, -d(motor_length)/dt [m/s];
    ``motor_length`` [m]; ``wrap_angle`` [rad]; ``free_length`` [m]; ``temperature`` [deg C].
    """

    __slots__ = ("k", "t", "dt", "x", "x_in", "v_in", "v_slide", "motor_length", "wrap_angle",
                 "free_length", "temperature")

    def __init__(self) -> None:
        for s in self.__slots__:
            setattr(self, s, None)



# --------------------------------------------------------------------------------------
# effects
# --------------------------------------------------------------------------------------


@dataclass(eq=False)
class Effect:
    """One switchable piece of extra physics of the truth model.

    ``magnitude``: the effect's headline number (unit in the subclass docstring; None gives
    ``default_magnitude``, chosen so that on the default ``hold-sine`` scenario of ipanema3
    the effect changes the measured force by well over 4 x the 0.1 N sensor noise, RMS);
    0 switches it off exactly. ``cables``: 0-based cables it acts on (None: every cable it
    can act on). Subclasses implement :meth:`apply`, returning the new value for *all*
    cables; :meth:`step` keeps it on the chosen cables only, so the others are untouched
    bit for bit.
    """

    name: ClassVar[str] = ""
    stage: ClassVar[str] = ""
    unit: ClassVar[str] = ""
    default_magnitude: ClassVar[float] = 0.0
    summary: ClassVar[str] = ""
    #: True when the law is a function of the time since the effect began (creep): an
    #: effect that sets in later starts its clock then, instead of jumping to where it
    #: would have been had it acted from the start
    clocked: ClassVar[bool] = False

    magnitude: Optional[float] = None
    cables: Optional[tuple[int, ...]] = None

    def __init_subclass__(cls, **header: Any) -> None:
        """An effect states its header in its class line, ``class Sag(Effect, name="sag",
        stage="force", unit="N/m", default_magnitude=0.2, summary=...)``: the class
        attributes above (those not given keep what the class body or its base set)."""
        unknown = set(header) - {"name", "stage", "unit", "default_magnitude", "summary", "clocked"}
        if unknown:
            raise TypeError(f"effect {cls.__name__}: unknown header field(s) {sorted(unknown)}")
        super().__init_subclass__()
        for key, value in header.items():
            setattr(cls, key, value)

    def __post_init__(self) -> None:
        if self.magnitude is None:
            self.magnitude = self.default_magnitude
        try:
            self.magnitude = float(self.magnitude)
        except (TypeError, ValueError):
            raise SimulationError(f"effect {self.name}: magnitude must be a number, got {self.magnitude!r}") from None
        if not math.isfinite(self.magnitude):
            raise SimulationError(f"effect {self.name}: magnitude must be finite, got {self.magnitude!r}")
        if self.cables is not None:
            cs = []
            for c in np.atleast_1d(np.asarray(self.cables)).tolist():
                if isinstance(c, bool) or not isinstance(c, int) or c < 0:
                    raise SimulationError(f"effect {self.name}: cables must be 0-based indices, got {self.cables!r}")
                cs.append(c)
            self.cables = tuple(sorted(set(cs)))
        for f in fields(self):
            if f.name not in ("magnitude", "cables"):
                v = getattr(self, f.name)
                if isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isfinite(v):
                    raise SimulationError(f"effect {self.name}: option {f.name} must be finite")
        self.check()
        self._mask: Optional[np.ndarray] = None
        self.applied_cables: Optional[tuple[int, ...]] = None

    # -- hooks ---------------------------------------------------------------------
    def check(self) -> None:
        """Raise SimulationError for invalid options (called at construction)."""

    def default_cables(self, run: RunInfo) -> list[int]:
        """Cables acted on when ``cables`` is None: all of them."""
        return list(range(run.n_cables))

    def setup(self, run: RunInfo) -> None:
        """Allocate per-run state (called by :meth:`bind`)."""

    def apply(self, tick: TickState, value: np.ndarray) -> np.ndarray:
        """New value (m,) for every cable, from ``value`` (m,) and the tick."""
        raise NotImplementedError

    # -- machinery -----------------------------------------------------------------
    @property
    def active(self) -> bool:
        """False when the magnitude is 0 (the effect is skipped) or it acts on no cable."""
        return self.magnitude != 0.0 and (self._mask is None or bool(self._mask.any()))

    def bind(self, run: RunInfo) -> None:
        """Resolve the cables against the run's robot and reset per-run state."""
        sel = self.default_cables(run) if self.cables is None else list(self.cables)
        bad = [c for c in sel if not 0 <= c < run.n_cables]
        if bad:
            raise SimulationError(
                f"effect {self.name}: cable(s) {bad} out of range; the robot has cables 0..{run.n_cables - 1}")
        self._mask = np.zeros(run.n_cables, dtype=bool)
        self._mask[sel] = True
        self.applied_cables = tuple(int(c) for c in sel)
        self.setup(run)

    def step(self, tick: TickState, value: np.ndarray) -> None:
        """Apply in place on the chosen cables (the others keep their value exactly)."""
        new = self.apply(tick, value)
        np.copyto(value, new, where=self._mask)

    def options(self) -> dict[str, Any]:
        """The effect's options besides magnitude and cables (JSON-able)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("magnitude", "cables")}

    def describe(self) -> str:
        """``NAME:MAGNITUDE@CABLES`` (the CLI spec form); cables ``all`` when not chosen."""
        cs = self.applied_cables if self.applied_cables is not None else self.cables
        where = "all" if cs is None else ",".join(str(c) for c in cs)
        return f"{self.name}:{self.magnitude:g}@{where}"

    def to_dict(self) -> dict[str, Any]:
        """Ground-truth record of the effect (name, magnitude, unit, cables, options)."""
        cs = self.applied_cables if self.applied_cables is not None else self.cables
        return {"name": self.name, "magnitude": self.magnitude, "unit": self.unit,
                "cables": None if cs is None else list(cs), "options": self.options()}


@dataclass(eq=False)
class Deadtime(Effect, name="deadtime", stage="input", unit="s", default_magnitude=0.05,
               summary="force follows the elongation of tau seconds ago; magnitude tau [s]"):
    """Dead time between elongation and force: the force follows the elongation of
    ``tau`` seconds ago, x_in(t) = x(t - tau) (linear interpolation between ticks; before
    t = tau the first elongation is held). Models controller/sensor delay (002 Sec 4 warns
    that commanded lengths carry dead time). magnitude = tau [s], >= 0."""

    def check(self) -> None:
        if self.magnitude < 0:
            raise SimulationError(f"effect deadtime: tau must be >= 0 s, got {self.magnitude}")

    def setup(self, run: RunInfo) -> None:
        d = self.magnitude / run.dt
        n = round(d)
        if abs(d - n) < 1e-9:
            self._n, self._frac = int(n), 0.0
        else:
            self._n, self._frac = int(math.floor(d)), float(d - math.floor(d))
        self._size = self._n + 2
        self._hist = np.zeros((self._size, run.n_cables))
        self._x0: Optional[np.ndarray] = None

    def _at(self, j: int) -> np.ndarray:
        return self._x0 if j < 0 else self._hist[j % self._size]

    def apply(self, tick, value):
        k = tick.k
        if k == 0:
            self._x0 = np.array(tick.x)
        self._hist[k % self._size] = tick.x
        j = k - self._n
        if self._frac == 0.0:
            return self._at(j).copy()
        return (1.0 - self._frac) * self._at(j) + self._frac * self._at(j - 1)


@dataclass(eq=False)
class Creep(Effect, name="creep", stage="force", clocked=True, unit="N", default_magnitude=2.0,
            summary="settling + creep lengthen the cable; magnitude = force drop at the end [N]"):
    """Creep and settling of the cable over the recording (002 Fig 6: the force drifted by
    0.4 N against the identified model after a few days). The unstretched length grows by

        delta_l(t) = c (1 - exp(-t / tau)) + r t        [m]

    (settling plus steady creep), which lowers the force by k delta_l (k = nominal EA/L per
    cable): F <- F - k delta_l(t). It is applied to the force, linearised, rather than fed
    through the base model as a lower elongation: the amplitude model would take the slow
    creep during a dwell for a reversal of tiny amplitude and jump to its small-amplitude
    stiffness, an artefact of its amplitude estimate, not creep. magnitude = D [N], the
    force drop k delta_l at the end of the recording; ``settle_fraction`` of it comes from
    the exponential part, with ``tau = tau_fraction`` x duration. Monotone in time."""

    settle_fraction: float = 0.6
    tau_fraction: float = 0.2

    def check(self) -> None:
        if not 0.0 <= self.settle_fraction <= 1.0:
            raise SimulationError("effect creep: settle_fraction must be in [0, 1]")
        if self.tau_fraction <= 0:
            raise SimulationError("effect creep: tau_fraction must be > 0")

    def setup(self, run: RunInfo) -> None:
        T = max(run.duration, run.dt)
        self._k = np.array(run.stiffness, dtype=np.float64)
        D = self.magnitude / self._k                           # (m,) length at the end [m]
        self.tau = self.tau_fraction * T
        self.c = self.settle_fraction * D / (1.0 - math.exp(-T / self.tau))
        self.r = (1.0 - self.settle_fraction) * D / T

    def delta_l(self, t: Any) -> np.ndarray:
        """Growth of the unstretched length [m] at time(s) t [s], per cable (after bind)."""
        t = np.asarray(t, dtype=np.float64)[..., None]
        return self.c * (1.0 - np.exp(-t / self.tau)) + self.r * t

    def apply(self, tick, value):
        dl = self.c * (1.0 - math.exp(-tick.t / self.tau)) + self.r * tick.t
        return value - self._k * dl


@dataclass(eq=False)
class Sag(Effect, name="sag", stage="force", unit="N/m", default_magnitude=0.2,
          summary=("sag: cable longer than its chord by w^2 L^3/(24 F^2), matters at low tension; "
                   "magnitude = weight per length w [N/m]")):
    """Sag of a cable of weight per length w [N/m] (Irvine's taut-cable approximation): a
    cable hanging over a chord L under tension F is longer than the chord by

        s = w^2 L^3 / (24 F^2)        [m]

    The pose fixes the chord (the IK length), so the hanging cable is stretched by x + s,
    not x. Linearised with the nominal stiffness k = EA/L, the force solves

        F = F_base + k s(F)

    (in closed form, per tick, F floored at ``f_floor`` [N]; F - k s(F) is increasing so
    the solution is unique). Sag thus raises the tension at a given elongation and
    lowers the stiffness, dF/dx = k_base / (1 + 2 k s / F) (Ernst's equivalent modulus);
    it matters only at low tension (s ~ 1/F^2), and a slack cable still carries its
    hanging tension. It is applied to the force rather than fed to the base model as
    x + s because the amplitude model's reversal detection and |v|^alpha damping react to
    the sub-micrometre tick-to-tick changes of s (spurious reversals and force jumps of
    several %). L is the free length from the pulley to the platform. magnitude = w [N/m]
    (6 mm Dyneema: about 0.2 N/m)."""

    f_floor: float = 1.0

    def check(self) -> None:
        if self.magnitude < 0:
            raise SimulationError("effect sag: w must be >= 0 N/m")
        if self.f_floor <= 0:
            raise SimulationError("effect sag: f_floor must be > 0 N")

    def setup(self, run: RunInfo) -> None:
        self._k = np.array(run.stiffness, dtype=np.float64)

    def excess_length(self, F: Any, L: Any) -> np.ndarray:
        """s = w^2 L^3 / (24 max(F, f_floor)^2) [m] for tension F [N] and chord L [m]."""
        F = np.maximum(np.asarray(F, dtype=np.float64), self.f_floor)
        return self.magnitude ** 2 * np.asarray(L, dtype=np.float64) ** 3 / (24.0 * F * F)

    def solve(self, f_base: np.ndarray, L: np.ndarray) -> np.ndarray:
        """Tension F [N] with F = f_base + k s(F), per cable, floored at ``f_floor``: the
        closed-form root of :func:`cablesvc.models.catenary.irvine_tension`, the solve the
        sag term uses too."""
        kc = self._k * self.magnitude ** 2 * np.asarray(L, dtype=np.float64) ** 3 / 24.0
        return irvine_tension(np.asarray(f_base, dtype=np.float64), kc, self.f_floor)

    def apply(self, tick, value):
        return self.solve(value, tick.free_length)


@dataclass(eq=False)
class Temperature(Effect, name="temperature", stage="force", unit="1/K", default_magnitude=-0.01,
                  summary="stiffness k(T) = k (1 + c_T (T - T_ref)); magnitude = c_T [1/K]"):
    """Temperature-dependent stiffness: k(T) = k (1 + c_T (T - T_ref)). The whole
    constitutive law of the base model scales with the modulus, so the force becomes
    F (1 + c_T (T - T_ref)) with T the temperature the twin records (its ambient profile)
    and ``T_ref`` [deg C] the temperature the model holds for. HMPE (Dyneema) softens when
    warm: c_T < 0. magnitude = c_T [1/K]."""


    T_ref: float = 21.0

    def apply(self, tick, value):
        return value * (1.0 + self.magnitude * (tick.temperature - self.T_ref))


@dataclass(eq=False)
class Pulley(Effect, name="pulley", stage="force", unit="-", default_magnitude=0.01,
             summary=("pulley bearing friction mu F_b tanh(v/v_s), F_b = 2 f sin(alpha/2) (eq 19), "
                      "and stiffness x (1 + kappa (alpha - alpha_ref)); magnitude = mu [-]")):
    """Redirection pulley: bearing friction and a wrap-angle dependent stiffness (002 Sec 4,
    Figs 9-11, eq 19).

    Eq 19, F_b = f sqrt(2 (1 + cos beta)), is the resultant of the two equal cable forces f
    on the wheel with beta the angle *between* the two cable segments. The kinematics report
    the wrap angle alpha (the arc wrapped, i.e. the deflection of the cable), beta = pi - alpha,
    so F_b = f sqrt(2 (1 - cos alpha)) = 2 f sin(alpha / 2): 0 for a straight cable, 2 f for a
    cable turned back on itself. With mu = magnitude:

        F  <- F (1 + kappa (alpha - alpha_ref))                stiffness change, kappa = stiffness_ratio * mu [1/rad]
        F  <- F + mu F_b tanh(v_slide / v_s)                   bearing friction

    v_slide = -d(motor_length)/dt is the speed the winch hauls the cable in over the wheel
    [m/s]; ``v_s`` [m/s] smooths the sign. Sign convention: the friction resists the winch,
    so it adds to the measured tension while hauling in and subtracts while paying out (the
    force-elongation loop widens with the wrap angle, as Fig 11 of 002 shows). Acts only on
    cables with a pulley (default: all of those; naming a cable without one is an error).
    magnitude = mu [-]."""

    v_s: float = 5e-4
    stiffness_ratio: float = 2.0
    alpha_ref: float = math.pi / 2

    def check(self) -> None:
        if self.v_s <= 0:
            raise SimulationError("effect pulley: v_s must be > 0 m/s")

    def default_cables(self, run: RunInfo) -> list[int]:
        return [i for i in range(run.n_cables) if run.has_pulley[i]]

    def bind(self, run: RunInfo) -> None:
        if self.cables is not None:
            none = [c for c in self.cables if 0 <= c < run.n_cables and not run.has_pulley[c]]
            if none:
                raise SimulationError(f"effect pulley: cable(s) {none} have no pulley in the robot file")
        elif not np.any(run.has_pulley):
            raise SimulationError("effect pulley: the robot file has no pulleys")
        super().bind(run)

    @property
    def kappa(self) -> float:
        """Stiffness change per radian of wrap angle [1/rad]."""
        return self.stiffness_ratio * self.magnitude

    def apply(self, tick, value):
        a = tick.wrap_angle
        f = value * (1.0 + self.kappa * (a - self.alpha_ref))
        fb = np.maximum(f, 0.0) * np.sqrt(2.0 * (1.0 - np.cos(a)))
        return f + self.magnitude * fb * np.tanh(tick.v_slide / self.v_s)


@dataclass(eq=False)
class Viscous(Effect, name="viscous", stage="force", unit="N s/m", default_magnitude=500.0,
              summary="viscous force c_v * dx/dt; magnitude = c_v [N s/m]"):
    """Viscous rate dependence: F <- F + c_v v with v the elongation rate [m/s] (of the
    elongation after dead time). magnitude = c_v [N s/m]."""

    def apply(self, tick, value):
        return value + self.magnitude * tick.v_in


@dataclass(eq=False)
class OffsetGain(Effect, name="offset_gain", stage="sensor", unit="N", default_magnitude=2.0,
                 summary="sensor error measured = (1 + o/600 N) F + o; magnitude = offset o [N]"):
    """Force-sensor offset and gain error: measured = (1 + g) F + o. magnitude = o [N];
    the gain error is tied to it, g = o * ``gain_per_newton`` (default 1/600 per N, i.e.
    g = o / 600 N: a 6 N offset comes with a +1 % gain error). Only the measurement
    changes, not the cable."""

    gain_per_newton: float = 1.0 / 600.0

    @property
    def gain(self) -> float:
        """Gain error g [-]."""
        return self.magnitude * self.gain_per_newton

    def apply(self, tick, value):
        return (1.0 + self.gain) * value + self.magnitude


#: effect name -> class (the names are the API: CLI specs and benchmark labels).
EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (Pulley, Creep, Temperature, Viscous, Deadtime, Sag, OffsetGain)
}
_ORDER = {"input": 0, "force": 1, "sensor": 2}
_WITHIN = {"deadtime": 0, "sag": 0, "creep": 1, "temperature": 2, "pulley": 3, "viscous": 4, "offset_gain": 0}


def stage_order(effect: Effect) -> tuple[int, int]:
    """Sort key of the order the truth model applies effects in: their stage
    (:data:`STAGES`), then a fixed order within it (force stage: sag, creep, temperature,
    pulley, viscous)."""
    return _ORDER[effect.stage], _WITHIN.get(effect.name, 9)


def list_effects() -> list[str]:
    """One line per effect: name, default magnitude with unit, summary."""
    return [f"{c.name:12s} default {c.default_magnitude:g} {c.unit:6s} {c.summary}" for c in EFFECTS.values()]


_SPEC = re.compile(r"^\s*(?P<name>[A-Za-z_-]+)\s*(?::\s*(?P<mag>[^@]+?))?\s*(?:@\s*(?P<cables>.+?))?\s*$")


def _parse_cables(text: str, n_cables: Optional[int]) -> Optional[tuple[int, ...]]:
    text = text.strip()
    if text.lower() == "all":
        return None
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)\s*-\s*(\d+)", part)
        if m:
            a, b = int(m.group(1)), int(m.group(2))
            if b < a:
                raise SimulationError(f"cable range {part!r} is empty")
            out.extend(range(a, b + 1))
        elif part.isdigit():
            out.append(int(part))
        else:
            raise SimulationError(f"cable {part!r} is not a 0-based index or a range like 2-5")
    if n_cables is not None:
        bad = [c for c in out if c >= n_cables]
        if bad:
            raise SimulationError(f"cable(s) {bad} out of range; the robot has cables 0..{n_cables - 1}")
    return tuple(out)


def effect_from_spec(spec: str, n_cables: Optional[int] = None) -> Effect:
    """Parse ``NAME[:MAGNITUDE][@CABLES]`` (the CLI's ``--effect``): e.g. ``pulley``,
    ``pulley:0.02``, ``pulley:0.02@2,5``, ``creep@0-3``, ``offset_gain:-1.5@all``. CABLES are
    0-based, comma separated, ranges allowed. ``n_cables`` (when given) checks the range."""
    m = _SPEC.match(spec or "")
    if not m:
        raise SimulationError(f"effect spec {spec!r}: expected NAME[:MAGNITUDE][@CABLES], e.g. pulley:0.02@2,5")
    name = m.group("name").lower().replace("-", "_")
    if name not in EFFECTS:
        raise SimulationError(f"effect spec {spec!r}: unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    mag = None
    if m.group("mag") is not None:
        try:
            mag = float(m.group("mag"))
        except ValueError:
            raise SimulationError(f"effect spec {spec!r}: magnitude {m.group('mag')!r} is not a number") from None
    cables = None
    if m.group("cables") is not None:
        try:
            cables = _parse_cables(m.group("cables"), n_cables)
        except SimulationError as e:
            raise SimulationError(f"effect spec {spec!r}: {e}") from None
    return EFFECTS[name](magnitude=mag, cables=cables)
