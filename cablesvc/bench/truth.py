"""A second simulator for the realistic discovery bench: a truth cable law outside the
baseline family, forces that balance the platform, and out-of-library effects.

cablesvc's twin (:mod:`cablesvc.simulate`) makes its forces with cablesvc's own amplitude
model (002 eq 8) at a prescribed pose. Discovery benchmarked on it starts from a baseline
that is the truth. This module is the "other simulator" of ``cablesvc bench discover``
(realistic mode, :mod:`cablesvc.bench.discover_cases`): same recording format, same robot,
same sensor noise, but

* **a different cable law** (:class:`CableVariant`, :func:`cable_law`), following 002 in
  spirit (an elastic backbone plus amplitude-dependent, partly rate-dependent hysteresis)
  but not its equation 8. Per cable i, with x the elongation [m] and k_i = EA_i / L_i the
  nominal stiffness [N/m] (L_i: cable length at home)::

      F = F_bb(x) + sum_j k_ij z_ij + k_m,i y_i                                  [N]

  - backbone F_bb, stiffening (Dyneema stiffens with strain), one of
    ``exp``:  s_i k_i (x + c x_s (exp(x / x_s) - 1 - x / x_s))
    ``tanh``: s_i k_i (x + c x_s ln cosh(x / x_s))
    (tangent stiffness s_i k_i (1 + c (exp(x/x_s) - 1)) or s_i k_i (1 + c tanh(x/x_s)));
    s_i the per-cable stiffness factor (+-10 %), c chosen so the tangent stiffness at
    25 mm is (1 + g) times the one at 0 (g = 3-12 %); 002's backbone is a cubic
    polynomial about the pretension point (eq 8), this one is not a polynomial;
  - J = 4 Jenkins (spring-slider) elements, a discrete Prandtl-Ishlinskii operator:
    z_ij = clip(z_ij + dx, -r_ij, r_ij), spring k_ij, slip elongations r_ij log-spaced
    between 0.03-0.08 mm and 0.5-1.2 mm. The hysteresis depends on the amplitude through
    which elements slip: there is no amplitude *estimate* from reversal points (002's
    A) and no |v|^alpha damping (002 eq 8's S_a, alpha);
  - one Maxwell branch (spring k_m in series with a dashpot, relaxation time tau):
    dy/dt = dx/dt - y / tau, integrated exactly for a piecewise-linear x. It makes the
    loop and the dynamic stiffness depend on the frequency, and relaxes during dwells.

  Each simulated robot draws its own variant (:func:`draw_variant`).
* **Forces that balance the platform** (:func:`equilibrium_run`). The twin prescribes the
  pose; a real platform moves until the cable forces balance it. Here the winches hold
  the commanded motor lengths and the platform pose is corrected per tick by
  dq = (A^T K A)^-1 (A^T f + w) (002 eq 2 with the quasi-static platform of the twin's
  ``trajectory`` scenario: its tension distribution neglects inertia, and the robot file
  has no inertia tensor; K = diag of the cable stiffness, A^T the structure matrix, dq
  translation [m] and small rotation [rad]), elongation and forces are recomputed, and the
  passes repeat over the whole recording (history-dependent law) until the wrench
  residual is below ``tol``. The recorded pose is the corrected one (as a pose tracker or
  an exact forward kinematics would give it). The cable's own physics (the law, creep,
  temperature, sag, viscous, dead time, pulley friction and the out-of-library effects)
  acts *before* equilibrium, so its forces still balance; a sensor offset/gain
  (``offset_gain``) acts after it and breaks the balance. **Pulley friction** acts between
  the winch and the force sensor: 002 Sec 4 mounts the force sensors "between the cables
  and the platform", so the sensors read the tension of the free segment, the one the
  platform feels, whatever the pulley does upstream.
* **Out-of-library effects** (:data:`OOL_EFFECTS`, not in discovery's term library):
  drum eccentricity, a frame anchor off by a fraction of a millimetre, a compliant pulley
  mount shared by two cables.

The library's effects (:data:`cablesvc.simulate.EFFECTS`) are reused as they are (their
``step`` on a :class:`~cablesvc.simulate.physics.TickState`), in the twin's stage order.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Optional

import numba
import numpy as np

from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics import inverse_kinematics, platform_wrench, structure_matrix
from cablesvc.kinematics.rotation import quat_multiply, rotvec_to_quat
from cablesvc.simulate.physics import Effect, RunInfo, TickState

__all__ = ["CableVariant", "OOL_EFFECTS", "Eccentricity", "AnchorShift", "MountCompliance", "OolEffect",
           "EquilibriumRun", "cable_law", "draw_variant", "equilibrium_run", "run_cable_truth", "wrench_rows"]

JENKINS = 4          # Jenkins elements per cable
X_REF = 0.025        # m: elongation at which the backbone's stiffening g is defined


# --------------------------------------------------------------------------------------
# the cable law
# --------------------------------------------------------------------------------------


@dataclass
class CableVariant:
    """One robot's true cable law (see the module docstring), arrays per cable (m,).

    ``k`` nominal stiffness EA/L [N/m]; ``scale`` s [-]; ``backbone`` "exp" | "tanh";
    ``c`` [-] and ``x_s`` [m] its shape; ``stiffening`` g [-]; damping ``beta`` [-],
    ``a_sat`` [m], ``alpha`` [-], envelope time ``t_env`` [s]; ``jk`` (m, J) Jenkins springs
    [N/m], ``jr`` (m, J) their slip elongations [m]; ``km`` Maxwell spring [N/m], ``tau``
    its relaxation time [s]."""

    k: np.ndarray
    scale: np.ndarray
    backbone: str
    c: np.ndarray
    x_s: np.ndarray
    stiffening: np.ndarray
    beta: np.ndarray
    a_sat: np.ndarray
    alpha: np.ndarray
    t_env: np.ndarray
    jk: np.ndarray
    jr: np.ndarray
    km: np.ndarray
    tau: np.ndarray

    @property
    def n_cables(self) -> int:
        return int(self.k.size)

    def stiffness(self) -> np.ndarray:
        """Stiffness used for the pose correction: backbone at 0 plus the Maxwell spring [N/m]."""
        return self.scale * self.k + self.km

    def describe(self) -> dict[str, Any]:
        return {"law": "non-polynomial backbone + envelope damping + Jenkins + Maxwell", "backbone": self.backbone,
                "stiffness_scale": self.scale.tolist(), "stiffening_at_25mm": self.stiffening.tolist(),
                "x_s_m": self.x_s.tolist(), "damping_beta": self.beta.tolist(), "damping_a_sat_m": self.a_sat.tolist(),
                "damping_alpha": self.alpha.tolist(), "envelope_s": self.t_env.tolist(),
                "jenkins_fraction": (self.jk.sum(axis=1) / self.k).tolist(), "jenkins_slip_m": self.jr.tolist(),
                "maxwell_fraction": (self.km / self.k).tolist(), "maxwell_tau_s": self.tau.tolist()}


def draw_variant(k: np.ndarray, rng: np.random.Generator) -> CableVariant:
    """Draw a robot's cable law around the nominal stiffness ``k`` (m,) [N/m]."""
    k = np.asarray(k, dtype=np.float64)
    m = k.size
    backbone = "exp" if rng.random() < 0.5 else "tanh"
    g = rng.uniform(0.03, 0.12, m)
    if backbone == "exp":
        xs = rng.uniform(0.015, 0.03, m)
        c = g / (np.exp(X_REF / xs) - 1.0)
    else:
        xs = rng.uniform(0.005, 0.015, m)
        c = g / np.tanh(X_REF / xs)
    scale = rng.uniform(0.9, 1.1, m)
    beta = rng.uniform(0.06, 0.10, m)
    a_sat = rng.uniform(1.5e-3, 4e-3, m)
    alpha = rng.uniform(0.2, 0.5, m)
    t_env = rng.uniform(20.0, 60.0, m)
    frac = rng.uniform(0.01, 0.03, m)                       # Jenkins springs, fraction of k
    jr = np.exp(np.linspace(np.log(rng.uniform(1e-4, 3e-4, m)), np.log(rng.uniform(6e-4, 1.2e-3, m)),
                            JENKINS, axis=1))                                 # (m, J) [m]
    w = rng.uniform(0.5, 1.5, (m, JENKINS))
    jk = (frac * k)[:, None] * w / w.sum(axis=1, keepdims=True)
    km = rng.uniform(0.005, 0.02, m) * k
    tau = np.exp(rng.uniform(np.log(0.05), np.log(0.5), m))
    return CableVariant(k=k, scale=scale, backbone=backbone, c=c, x_s=xs, stiffening=g, beta=beta, a_sat=a_sat,
                        alpha=alpha, t_env=t_env, jk=jk, jr=jr, km=km, tau=tau)


@numba.njit(cache=True)
def _law(x, dt, kind, sk, c, xs, beta, a_sat, alpha, t_env, jk, jr, km, tau):   # pragma: no cover - compiled
    N, m = x.shape
    J = jk.shape[1]
    out = np.empty((N, m))
    for i in range(m):
        a = math.exp(-dt / tau[i])
        b = tau[i] / dt * (1.0 - a)
        shrink = dt / t_env[i]
        z = np.zeros(J)
        y = 0.0
        hi = x[0, i]
        lo = x[0, i]
        ve = 1e-6
        for n in range(N):
            xv = x[n, i]
            u = xv / xs[i]
            if kind == 0:
                fb = sk[i] * (xv + c[i] * xs[i] * (math.exp(u) - 1.0 - u))
            else:
                au = abs(u)
                lc = au + math.log1p(math.exp(-2.0 * au)) - math.log(2.0)    # ln cosh(u), stable
                fb = sk[i] * (xv + c[i] * xs[i] * lc)
            dx = 0.0 if n == 0 else xv - x[n - 1, i]
            # running envelope: peak-to-peak of x whose gap shrinks with time constant t_env,
            # and the peak speed, decaying alike
            gap = hi - lo
            hi = max(xv, hi - 0.5 * gap * shrink)
            lo = min(xv, lo + 0.5 * gap * shrink)
            v = dx / dt
            ve = max(abs(v), ve * (1.0 - shrink), 1e-6)
            ae = max(0.5 * (hi - lo), 1e-6)
            h = beta[i] * sk[i] * a_sat[i] * math.tanh(ae / a_sat[i])
            fd = 0.0
            if v != 0.0:
                fd = h * (abs(v) / ve) ** alpha[i] * (1.0 if v > 0 else -1.0)
            s = 0.0
            for j in range(J):
                zz = z[j] + dx
                r = jr[i, j]
                if zz > r:
                    zz = r
                elif zz < -r:
                    zz = -r
                z[j] = zz
                s += jk[i, j] * zz
            y = a * y + b * dx
            out[n, i] = fb + fd + s + km[i] * y
    return out


def cable_law(variant: CableVariant, x: np.ndarray, dt: float) -> np.ndarray:
    """Force (N, m) [N] of the variant's law over the elongation history ``x`` (N, m) [m]
    sampled every ``dt`` [s]; every element starts relaxed at x[0]."""
    v = variant
    x = np.ascontiguousarray(x, dtype=np.float64)
    return _law(x, float(dt), 0 if v.backbone == "exp" else 1, v.scale * v.k, v.c, v.x_s, v.beta, v.a_sat, v.alpha,
                v.t_env, v.jk, v.jr, v.km, v.tau)


# --------------------------------------------------------------------------------------
# out-of-library effects
# --------------------------------------------------------------------------------------


@dataclass(eq=False)
class OolEffect:
    """An effect outside discovery's term library. ``magnitude`` its headline number (unit
    in the subclass), ``cables`` the cables it acts on, ``phase`` options drawn per case."""

    name: ClassVar[str] = ""
    unit: ClassVar[str] = ""
    default_magnitude: ClassVar[float] = 0.0

    magnitude: float = 0.0
    cables: tuple[int, ...] = ()

    @property
    def applied_cables(self) -> tuple[int, ...]:
        return tuple(self.cables)

    def geometry(self, geom: RobotGeometry) -> RobotGeometry:
        """The truth geometry (default: unchanged)."""
        return geom

    def length_error(self, motor_length: np.ndarray, unit: np.ndarray, force: Optional[np.ndarray]) -> np.ndarray:
        """Change of the elongation (N, m) [m] (default none)."""
        return np.zeros(motor_length.shape)

    def describe(self) -> str:
        return f"{self.name}:{self.magnitude:g}@{','.join(str(c) for c in self.cables)}"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "magnitude": self.magnitude, "unit": self.unit, "cables": list(self.cables),
                "options": {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                            if f.name not in ("magnitude", "cables")}}


@dataclass(eq=False)
class Eccentricity(OolEffect):
    """Drum eccentricity: the length the drum pays out differs from the motor length the
    controller reports by e sin(theta + phi), theta = motor_length / r_drum the drum angle
    [rad]. The elongation becomes x - e sin(l_m / r_drum + phi). magnitude = e [m]."""

    name: ClassVar[str] = "eccentricity"
    unit: ClassVar[str] = "m"
    default_magnitude: ClassVar[float] = 5e-5
    drum_radius: float = 0.04
    phase: float = 0.0

    def length_error(self, motor_length, unit, force):
        d = np.zeros(motor_length.shape)
        cs = list(self.cables)
        d[:, cs] = -self.magnitude * np.sin(motor_length[:, cs] / self.drum_radius + self.phase)
        return d


@dataclass(eq=False)
class AnchorShift(OolEffect):
    """A frame anchor (and its pulley) of cable ``cables[0]`` is off by ``magnitude`` [m]
    along the unit ``direction``: the truth geometry differs from the robot file's, so the
    true cable length is not the l(pose) every tool computes."""

    name: ClassVar[str] = "anchor"
    unit: ClassVar[str] = "m"
    default_magnitude: ClassVar[float] = 3e-4
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def geometry(self, geom):
        d = self.magnitude * np.asarray(self.direction, dtype=np.float64)
        fa = np.array(geom.frame_anchors)
        pc = np.array(geom.pulley_center)
        for c in self.cables:
            fa[c] += d
            pc[c] += d
        return dataclasses.replace(geom, frame_anchors=fa, pulley_center=pc)


@dataclass(eq=False)
class MountCompliance(OolEffect):
    """Two cables' pulleys share a compliant mount of compliance C [m/N]: the mount gives
    way to the pull of both, delta = -C (F_i u_i + F_j u_j) (u: unit vector from the
    platform to the frame), which shortens cable i's path by C (F_i + F_j u_i . u_j) (and
    likewise j): each cable's force depends on the other's. magnitude = C [m/N]."""

    name: ClassVar[str] = "mount"
    unit: ClassVar[str] = "m/N"
    default_magnitude: ClassVar[float] = 1e-6

    def length_error(self, motor_length, unit, force):
        d = np.zeros(motor_length.shape)
        if force is None:
            return d
        i, j = self.cables[:2]
        cij = np.einsum("nk,nk->n", unit[:, i], unit[:, j])
        d[:, i] = -self.magnitude * (force[:, i] + force[:, j] * cij)
        d[:, j] = -self.magnitude * (force[:, j] + force[:, i] * cij)
        return d


#: out-of-library effects by name
OOL_EFFECTS: dict[str, type[OolEffect]] = {c.name: c for c in (Eccentricity, AnchorShift, MountCompliance)}


# --------------------------------------------------------------------------------------
# truth pipeline and equilibrium
# --------------------------------------------------------------------------------------

_ORDER = {"input": 0, "force": 1, "sensor": 2}
_WITHIN = {"deadtime": 0, "sag": 0, "creep": 1, "temperature": 2, "pulley": 3, "viscous": 4, "offset_gain": 0}


def run_cable_truth(variant: CableVariant, effects: list[Effect], *, t: np.ndarray, dt: float, x: np.ndarray,
                    motor_length: np.ndarray, wrap_angle: np.ndarray, free_length: np.ndarray,
                    temperature: np.ndarray, has_pulley: np.ndarray, stiffness: np.ndarray,
                    cable_names: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """True cable force and sensor reading (both (N, m) [N], no noise) for elongation ``x``.

    Stages as the twin's :class:`~cablesvc.simulate.physics.TruthModel`: input effects
    (dead time) on x, the variant's law, force effects, sensor effects; the effects are
    the twin's own classes, bound afresh (deep copies) for this run."""
    N, m = x.shape
    run = RunInfo(n_cables=m, dt=float(dt), n_ticks=N, duration=float(t[-1] - t[0]) if N > 1 else float(dt),
                  stiffness=np.asarray(stiffness, float), has_pulley=np.asarray(has_pulley, bool),
                  cable_names=tuple(cable_names))
    effs = [copy.deepcopy(e) for e in effects]
    for e in effs:
        e.bind(run)
    effs = sorted([e for e in effs if e.active], key=lambda e: (_ORDER[e.stage], _WITHIN.get(e.name, 9)))
    by = {s: [e for e in effs if e.stage == s] for s in ("input", "force", "sensor")}
    tick = TickState()
    tick.dt = float(dt)
    zero = np.zeros(m)
    ml = np.asarray(motor_length, float)

    def fill(k: int) -> None:
        tick.k, tick.t = k, float(t[k])
        tick.x, tick.motor_length = x[k], ml[k]
        tick.wrap_angle, tick.free_length = wrap_angle[k], free_length[k]
        tick.temperature = float(temperature[k])
        tick.v_slide = zero if k == 0 else (ml[k - 1] - ml[k]) / dt

    x_in = np.array(x, dtype=np.float64)
    if by["input"]:
        for k in range(N):
            fill(k)
            v = x[k].copy()
            for e in by["input"]:
                e.step(tick, v)
            x_in[k] = v
    force = cable_law(variant, x_in, dt)
    measured = force.copy()
    if by["force"] or by["sensor"]:
        for k in range(N):
            fill(k)
            tick.x_in = x_in[k]
            tick.v_in = zero if k == 0 else (x_in[k] - x_in[k - 1]) / dt
            v = force[k]
            for e in by["force"]:
                e.step(tick, v)
            mv = v.copy()
            for e in by["sensor"]:
                e.step(tick, mv)
            measured[k] = mv
    return force, measured


def wrench_rows(geom: RobotGeometry) -> list[int]:
    """Rows of the wrench that count (planar robots: fx, fy, mz)."""
    return [0, 1, 5] if geom.planar else list(range(6))


@dataclass
class EquilibriumRun:
    """Result of :func:`equilibrium_run` (N ticks, m cables, SI units).

    ``position`` (N,3) / ``orientation`` (N,4): the balanced pose (what is recorded);
    ``force`` true cable forces [N]; ``measured`` the sensor reading without noise [N];
    ``elongation`` the true elongation [m] (truth geometry, effects' length errors
    included); ``residual`` (N,6) A^T f + w of the true forces [N, N m]; ``passes``;
    ``pose_shift`` max |translation| of the correction [m]."""

    position: np.ndarray
    orientation: np.ndarray
    force: np.ndarray
    measured: np.ndarray
    elongation: np.ndarray
    residual: np.ndarray
    passes: int
    pose_shift: float
    info: dict[str, Any] = field(default_factory=dict)


def _truth_pass(geom_truth, variant, effects, ool, P, Q, ml, t, dt, temperature, prev_force, stiffness, geom):
    ik = inverse_kinematics(geom_truth, P, Q)
    x = ik.length - ml
    for o in ool:
        x = x + o.length_error(ml, ik.unit, prev_force)
    f, meas = run_cable_truth(variant, effects, t=t, dt=dt, x=x, motor_length=ml, wrap_angle=ik.wrap_angle,
                              free_length=ik.free_length, temperature=temperature,
                              has_pulley=np.asarray(geom.has_pulley, bool), stiffness=stiffness,
                              cable_names=tuple(geom.cable_names))
    AT = structure_matrix(ik.unit, ik.anchor_world)
    w = platform_wrench(geom_truth, ik.rotation)
    R = np.einsum("nim,nm->ni", AT, f) + w
    return x, f, meas, AT, R


def equilibrium_run(geom: RobotGeometry, variant: CableVariant, effects: list[Effect], ool: list[OolEffect], *,
                    t: np.ndarray, dt: float, position: np.ndarray, orientation: np.ndarray,
                    motor_length: np.ndarray, temperature: np.ndarray, balance: bool = True,
                    tol: float = 1e-4, max_passes: int = 12) -> EquilibriumRun:
    """Simulate the truth with the winches at ``motor_length`` (N, m) [m] and the platform
    at the commanded pose corrected to static equilibrium (``balance``; False: the pose
    is held, e.g. a platform clamped for calibration). Passes repeat until the largest
    force row of A^T f + w is below ``tol`` [N] (moments: [N m]) or ``max_passes``."""
    gt = geom
    for o in ool:
        gt = o.geometry(gt)
    stiff = np.asarray(variant.k, float)           # nominal EA/L [N/m], what creep and sag use
    P = np.array(position, dtype=np.float64)
    Q = np.array(orientation, dtype=np.float64)
    ml = np.asarray(motor_length, dtype=np.float64)
    rows = wrench_rows(geom)
    prev = None
    kk = np.broadcast_to(variant.stiffness(), ml.shape).copy()
    x_prev = f_prev = None
    passes = 0
    P0 = P.copy()
    need_ool_iter = any(isinstance(o, MountCompliance) for o in ool)
    while True:
        x, f, meas, AT, R = _truth_pass(gt, variant, effects, ool, P, Q, ml, t, dt, temperature, prev, stiff, geom)
        passes += 1
        if not balance:
            if need_ool_iter and passes < 4:
                prev = f
                continue
            break
        err = float(np.max(np.abs(R[:, rows])))
        if (err <= tol and (not need_ool_iter or passes >= 4)) or passes >= max_passes:
            break
        if x_prev is not None:                  # secant stiffness per tick and cable, kept near the law's
            dx = x - x_prev
            ok = np.abs(dx) > 1e-9
            ks = np.where(ok, (f - f_prev) / np.where(ok, dx, 1.0), kk)
            kk = np.clip(ks, 0.5 * variant.stiffness(), 2.0 * variant.stiffness())
        x_prev, f_prev, prev = x, f, f
        A = AT[:, rows, :]
        H = np.einsum("nim,nm,njm->nij", A, kk, A)
        dq = np.zeros((P.shape[0], 6))
        dq[:, rows] = np.linalg.solve(H, R[:, rows][..., None])[..., 0]
        P = P + dq[:, :3]
        Q = quat_multiply(rotvec_to_quat(dq[:, 3:]), Q)
        Q /= np.linalg.norm(Q, axis=1, keepdims=True)
    return EquilibriumRun(position=P, orientation=Q, force=f, measured=meas, elongation=x, residual=R,
                          passes=passes, pose_shift=float(np.max(np.linalg.norm(P - P0, axis=1))))
