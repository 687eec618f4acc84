"""Scenarios of the digital twin: what the platform and the winches do.

A scenario is a function ``fn(ctx, **options) -> ScenarioPlan`` in :data:`SCENARIOS`. It
gets a :class:`ScenarioContext` (robot geometry, tick rate, requested duration, its own
random generator and the *nominal* elastic curve of the truth base model, i.e. what the
controller believes about its cables) and returns the commanded platform poses and cable
elongations per tick. The twin turns the elongations into motor lengths
(motor_length = l(pose) - x, the recording spec's convention) and runs the truth model on
them. Every option has a default; options are overridden by keyword (``--set`` on the
command line). Units SI: m, s, N, rad unless an option's name says otherwise (``_deg``).

Scenarios:

* ``hold-sine``, ``hold-triangle``, ``hold-trapezoid``: the experiment of 002 Sec 4. The
  platform is held at a pose while the winches stretch the cables around a pretension with
  a sine (eq 15, x = x_pre - A cos wt), triangle or trapezoid of rising amplitude levels.
* ``trajectory``: the platform moves through the workspace (minimum-jerk point-to-point
  moves or a sum of sinusoids); the controller commands the elongations of a tension
  distribution that balances the platform's weight above a minimum tension.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np

from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics import (
    PLANAR_WRENCH_ROWS,
    IKState,
    inverse_kinematics,
    platform_wrench,
    rotvec_to_quat,
    structure_matrix,
)
from cablesvc.errors import SimulationError
from cablesvc.simulate.elastic import ElasticCurve

__all__ = [
    "DEFAULT_AMPLITUDES",
    "SCENARIOS",
    "ScenarioContext",
    "ScenarioPlan",
    "hold_sine",
    "hold_trapezoid",
    "hold_triangle",
    "min_jerk",
    "ptp_path",
    "tension_distribution",
    "trajectory",
    "wave_sine",
    "wave_trapezoid",
    "wave_triangle",
]

#: amplitude levels of the hold scenarios [m] (002 Sec 4: 0.1 mm to 1.5 mm)
DEFAULT_AMPLITUDES = (1e-4, 2.5e-4, 5e-4, 1e-3, 1.5e-3)
#: default duration of the trajectory scenario [s]
TRAJECTORY_DURATION = 60.0


@dataclass
class ScenarioContext:
    """What a scenario gets: ``geom`` the robot, ``rate`` [Hz], ``duration`` [s] or None
    (the scenario's own default), ``rng`` its random generator (seeded by the twin),
    ``elastic`` the nominal elastic curve of the truth base model (the controller's model)."""

    geom: RobotGeometry
    rate: float
    duration: Optional[float]
    rng: np.random.Generator
    elastic: ElasticCurve

    @property
    def dt(self) -> float:
        return 1.0 / self.rate

    def ticks(self, duration: float) -> int:
        """Number of ticks of a run of ``duration`` seconds (at least 2)."""
        return max(2, int(round(duration * self.rate)))

    def ik(self, position: np.ndarray, orientation: np.ndarray) -> IKState:
        return inverse_kinematics(self.geom, position, orientation)


@dataclass
class ScenarioPlan:
    """A scenario's output, N ticks and m cables.

    ``t`` (N,) [s], ``position`` (N,3) [m], ``orientation`` (N,4) [qx,qy,qz,qw],
    ``elongation`` (N,m) commanded elongation x [m]; ``params`` the resolved options
    (JSON-able, written to the recording's metadata); ``info`` extra arrays for tests and
    benchmarks, not written (e.g. the hold blocks, the commanded tension distribution).
    """

    t: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    elongation: np.ndarray
    params: dict[str, Any]
    info: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile 10 s^3 - 15 s^4 + 6 s^5 on s in [0, 1] (zero velocity and
    acceleration at both ends); clipped outside."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def wave_sine(u: np.ndarray) -> np.ndarray:
    """Unit sine of eq 15 of 002 over u periods: -cos(2 pi u) (starts at the minimum -1)."""
    return -np.cos(2.0 * np.pi * u)


def wave_triangle(u: np.ndarray) -> np.ndarray:
    """Unit triangle over u periods, starting at -1, +1 at half a period (eq 18 of 002)."""
    ph = np.mod(u, 1.0)
    return np.where(ph < 0.5, -1.0 + 4.0 * ph, 3.0 - 4.0 * ph)


def wave_trapezoid(u: np.ndarray, ramp_fraction: float = 0.25) -> np.ndarray:
    """Unit trapezoid over u periods, starting at -1: ramp up over ``ramp_fraction`` of a
    period, hold +1 until half a period, ramp down, hold -1 (ramp_fraction 0.5 = triangle)."""
    r = float(ramp_fraction)
    ph = np.mod(u, 1.0)
    up = -1.0 + 2.0 * ph / r
    down = 1.0 - 2.0 * (ph - 0.5) / r
    return np.where(ph < r, up, np.where(ph < 0.5, 1.0, np.where(ph < 0.5 + r, down, -1.0)))


def _vec(name: str, v: Any, n: int) -> np.ndarray:
    try:
        a = np.array(v, dtype=np.float64)               # a copy: callers may modify it
    except (TypeError, ValueError):
        raise SimulationError(f"option {name}: expected {n} numbers, got {v!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise SimulationError(f"option {name}: expected {n} finite numbers, got {v!r}")
    return a


def _cable_list(name: str, v: Any, m: int) -> list[int]:
    cs = [v] if isinstance(v, int) else list(v)
    for c in cs:
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 0 <= c < m:
            raise SimulationError(f"option {name}: cables must be 0-based indices 0..{m - 1}, got {v!r}")
    if len(set(cs)) != len(cs) or not cs:
        raise SimulationError(f"option {name}: expected a non-empty list of distinct cables, got {v!r}")
    return [int(c) for c in cs]


def _unit_quat(name: str, q: Any) -> np.ndarray:
    q = _vec(name, q, 4)
    n = np.linalg.norm(q)
    if abs(n - 1.0) > 1e-6:
        raise SimulationError(f"option {name}: must be a unit quaternion [qx, qy, qz, qw], |q| = {n:.6g}")
    return q


# --------------------------------------------------------------------------------------
# hold scenarios (002 Sec 4)
# --------------------------------------------------------------------------------------


def _hold(ctx: ScenarioContext, shape: str, wave: Callable[[np.ndarray], np.ndarray], *,
          pretension: float, amplitudes: Sequence[float], cycles: int, frequency: float, mode: str,
          cables: Optional[Sequence[int]], position: Sequence[float], orientation: Sequence[float],
          settle: float, rest: float, extra: dict[str, Any]) -> ScenarioPlan:
    geom, rate = ctx.geom, ctx.rate
    m = geom.n_cables
    amps = np.atleast_1d(np.asarray(amplitudes, dtype=np.float64))
    if amps.ndim != 1 or amps.size == 0 or np.any(~np.isfinite(amps)) or np.any(amps <= 0):
        raise SimulationError(f"option amplitudes: expected a list of positive amplitudes [m], got {amplitudes!r}")
    if not (math.isfinite(pretension) and pretension > 0):
        raise SimulationError(f"option pretension: must be > 0 N, got {pretension!r}")
    if int(cycles) != cycles or cycles < 1:
        raise SimulationError(f"option cycles: must be a whole number >= 1, got {cycles!r}")
    if not (math.isfinite(frequency) and 0 < frequency <= rate / 4):
        raise SimulationError(f"option frequency: must be in (0, rate/4] Hz, got {frequency!r}")
    if mode not in ("together", "sequential"):
        raise SimulationError(f"option mode: 'together' or 'sequential', got {mode!r}")
    if not (settle > 0 and rest >= 0):
        raise SimulationError("options settle (> 0 s) and rest (>= 0 s) out of range")
    cycles = int(cycles)
    excited = list(range(m)) if cables is None else _cable_list("cables", cables, m)
    pos = _vec("position", position, 3)
    quat = _unit_quat("orientation", orientation)
    L_hold = ctx.ik(pos[None], quat[None]).length[0]
    el = ctx.elastic

    n_cyc = max(4, int(round(rate / frequency)))          # samples per period (whole number)
    n_settle = max(1, int(round(settle * rate)))
    n_rest = int(round(rest * rate))
    n_block = cycles * n_cyc + 1                           # closes at the minimum
    u = np.arange(n_block) / n_cyc

    def x_pre(amp_vec: Optional[np.ndarray]) -> np.ndarray:
        return el.elongation(np.full(m, float(pretension)), amplitude=amp_vec, length=L_hold)

    # amplitude the (amplitude) model believes each cable has: at rest, amplitude_init
    model_amp = None if el.rest_amplitude is None else np.array(el.rest_amplitude, dtype=np.float64)
    current = x_pre(model_amp)
    segs: list[np.ndarray] = []
    blocks: list[dict[str, Any]] = []
    count = 0

    def add(a: np.ndarray) -> None:
        nonlocal count
        segs.append(a)
        count += a.shape[0]

    def ramp(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        s = min_jerk((np.arange(n_settle) + 1.0) / (n_settle + 1.0))[:, None]
        return a[None, :] + (b - a)[None, :] * s

    groups = [[c] for c in excited] if mode == "sequential" else [excited]
    target_n = None if ctx.duration is None else ctx.ticks(ctx.duration)

    def one_pass() -> None:
        nonlocal current
        if n_rest:
            add(np.tile(current, (n_rest, 1)))
        for grp in groups:
            for A in amps.tolist():
                amp_vec = None if model_amp is None else model_amp.copy()
                if amp_vec is not None:
                    amp_vec[grp] = A
                xp = x_pre(amp_vec)
                start = current.copy()
                start[grp] = xp[grp] - A
                add(ramp(current, start))
                seg = np.tile(start, (n_block, 1))
                seg[:, grp] = xp[grp][None, :] + A * wave(u)[:, None]
                blocks.append({"cables": list(grp), "amplitude": A, "start": count, "stop": count + cycles * n_cyc,
                               "pretension_elongation": xp[grp].tolist()})
                add(seg)
                current = seg[-1].copy()
                if model_amp is not None:
                    model_amp[grp] = A
            hold = current.copy()
            hold[grp] = x_pre(model_amp)[grp]
            add(ramp(current, hold))
            current = hold
        if n_rest:
            add(np.tile(current, (n_rest, 1)))

    one_pass()
    while target_n is not None and count < target_n:
        one_pass()
    x = np.concatenate(segs, axis=0)
    if target_n is not None:
        x = x[:target_n]
        blocks = [b for b in blocks if b["stop"] < target_n]
    N = x.shape[0]
    params = {"pretension": float(pretension), "amplitudes": amps.tolist(), "cycles": cycles,
              "frequency": rate / n_cyc, "mode": mode, "cables": excited, "position": pos.tolist(),
              "orientation": quat.tolist(), "settle": float(settle), "rest": float(rest), "shape": shape, **extra}
    return ScenarioPlan(
        t=np.arange(N) / rate, position=np.tile(pos, (N, 1)), orientation=np.tile(quat, (N, 1)),
        elongation=x, params=params, info={"blocks": blocks, "samples_per_cycle": n_cyc})


def hold_sine(ctx: ScenarioContext, *, pretension: float = 60.0, amplitudes: Sequence[float] = DEFAULT_AMPLITUDES,
              cycles: int = 3, frequency: float = 0.5, mode: str = "together", cables: Optional[Sequence[int]] = None,
              position: Sequence[float] = (0.0, 0.0, 0.0), orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
              settle: float = 1.0, rest: float = 1.0) -> ScenarioPlan:
    """Platform held, each winch stretches its cable around a pretension with a sine (002 Sec 4, eq 15).

    The platform stays at ``position`` [m] / ``orientation`` [qx,qy,qz,qw] (default: home).
    Each excited cable (``cables``, default all) goes through the ``amplitudes`` [m] (default
    0.1, 0.25, 0.5, 1.0, 1.5 mm), ``cycles`` periods of x = x_pre(A) - A cos(2 pi f t) each at
    ``frequency`` f [Hz] (rounded so a period is a whole number of ticks), all cables
    together (``mode="together"``) or one cable after the other (``"sequential"``; the others
    hold). x_pre(A) is the elongation at which the truth base model's elastic part gives
    ``pretension`` [N] at amplitude A: the controller re-tensions each block to the
    pretension, because the amplitude model's secant stiffness depends on A. Blocks are
    joined by ``settle`` [s] minimum-jerk ramps; ``rest`` [s] at pretension at the start and
    end of each pass. Given a ``duration``, passes repeat and the last is cut.
    """
    return _hold(ctx, "sine", wave_sine, pretension=pretension, amplitudes=amplitudes, cycles=cycles,
                 frequency=frequency, mode=mode, cables=cables, position=position, orientation=orientation,
                 settle=settle, rest=rest, extra={})


def hold_triangle(ctx: ScenarioContext, *, pretension: float = 60.0,
                  amplitudes: Sequence[float] = DEFAULT_AMPLITUDES, cycles: int = 3, frequency: float = 0.5,
                  mode: str = "together", cables: Optional[Sequence[int]] = None,
                  position: Sequence[float] = (0.0, 0.0, 0.0), orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
                  settle: float = 1.0, rest: float = 1.0) -> ScenarioPlan:
    """Platform held, triangular elongation around a pretension (002 Sec 4 test signal, eq 18).

    As ``hold-sine`` (same options and defaults) with a triangle of amplitude A that starts
    at x_pre(A) - A and reaches x_pre(A) + A at half a period.
    """
    return _hold(ctx, "triangle", wave_triangle, pretension=pretension, amplitudes=amplitudes, cycles=cycles,
                 frequency=frequency, mode=mode, cables=cables, position=position, orientation=orientation,
                 settle=settle, rest=rest, extra={})


def hold_trapezoid(ctx: ScenarioContext, *, pretension: float = 60.0,
                   amplitudes: Sequence[float] = DEFAULT_AMPLITUDES, cycles: int = 3, frequency: float = 0.5,
                   mode: str = "together", cables: Optional[Sequence[int]] = None,
                   position: Sequence[float] = (0.0, 0.0, 0.0), orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
                   settle: float = 1.0, rest: float = 1.0, ramp_fraction: float = 0.25) -> ScenarioPlan:
    """Platform held, trapezoidal elongation around a pretension (002 Sec 4 test signal).

    As ``hold-sine`` (same options and defaults); each period ramps up over
    ``ramp_fraction`` of it, holds x_pre + A, ramps down, holds x_pre - A.
    """
    if not (0 < ramp_fraction <= 0.5):
        raise SimulationError(f"option ramp_fraction: must be in (0, 0.5], got {ramp_fraction!r}")
    return _hold(ctx, "trapezoid", lambda u: wave_trapezoid(u, ramp_fraction), pretension=pretension,
                 amplitudes=amplitudes, cycles=cycles, frequency=frequency, mode=mode, cables=cables,
                 position=position, orientation=orientation, settle=settle, rest=rest,
                 extra={"ramp_fraction": float(ramp_fraction)})


# --------------------------------------------------------------------------------------
# trajectory
# --------------------------------------------------------------------------------------


def tension_distribution(AT: np.ndarray, w: np.ndarray, f_lo: Any, f_hi: Any, f_ref: Any,
                         rows: Optional[Sequence[int]] = None) -> np.ndarray:
    """Cable forces f (N,m) [N] with A^T f + w = 0 and f_lo <= f <= f_hi, closest to f_ref.

    ``AT`` (N,6,m) structure matrix, ``w`` (N,6) external wrench [N, N m]; ``rows`` the
    wrench rows that count (planar robots: fx, fy, mz). Closed form first: the least-squares
    solution of min ||f - f_ref||^2 s.t. A^T f = -w, f = f_ref - pinv(A^T) (A^T f_ref + w)
    (f_ref shifted along the null space). Ticks where it leaves the bounds are solved as a
    bounded least-squares problem (scipy ``lsq_linear`` with the equality weighted in, then
    projected back onto the equality). Raises SimulationError at a pose where no feasible
    distribution exists.
    """
    rows = list(range(AT.shape[1])) if rows is None else list(rows)
    A = AT[:, rows, :]
    b = -w[:, rows]
    N, r, m = A.shape
    lo = np.broadcast_to(np.asarray(f_lo, dtype=np.float64), (m,))
    hi = np.broadcast_to(np.asarray(f_hi, dtype=np.float64), (m,))
    ref = np.broadcast_to(np.asarray(f_ref, dtype=np.float64), (m,))
    P = np.linalg.pinv(A)                                            # (N, m, r)
    f = ref[None, :] - np.einsum("nmr,nr->nm", P, np.einsum("nrm,m->nr", A, ref) - b)
    tol = 1e-6 * max(1.0, float(np.max(hi)))
    bad = np.flatnonzero(np.any(f < lo - tol, axis=1) | np.any(f > hi + tol, axis=1))
    if bad.size:
        from scipy.optimize import lsq_linear

        W = 1e3
        eye = np.eye(m)
        for i in bad.tolist():
            M = np.vstack([W * A[i], eye])
            rhs = np.concatenate([W * b[i], ref])
            res = lsq_linear(M, rhs, bounds=(lo, hi), method="bvls", tol=1e-12)
            fi = res.x + P[i] @ (b[i] - A[i] @ res.x)
            if np.any(fi < lo - 1e-3) or np.any(fi > hi + 1e-3):
                raise SimulationError(
                    f"no tension distribution within [{lo.min():g}, {hi.max():g}] N balances the platform at "
                    f"tick {i}; use a smaller half_width or other tension limits")
            f[i] = fi
    return f


def ptp_path(ctx: ScenarioContext, N: int, center: np.ndarray, hw: np.ndarray, rot_max: np.ndarray,
             speed: float, angular_speed: float, min_move_time: float, dwell: tuple[float, float]):
    """N ticks of point-to-point moves: dwell a random ``dwell`` [s] range, then a
    minimum-jerk move to a random point within ``center`` +- ``hw`` [m] and rotation vector
    within +- ``rot_max`` [rad], with a peak speed of at most ``speed`` [m/s] and
    ``angular_speed`` [rad/s], lasting at least ``min_move_time`` [s]; random numbers from
    ``ctx.rng``. Returns (positions (N, 3),
    rotation vectors (N, 3), waypoints [(t, position, rotation vector)])."""
    rng, rate = ctx.rng, ctx.rate
    P = np.empty((N, 3))
    R = np.empty((N, 3))
    p0, r0 = center.copy(), np.zeros(3)
    k = 0
    waypoints = [(0.0, p0.tolist(), r0.tolist())]
    while k < N:
        nd = int(round(rng.uniform(*dwell) * rate))
        P[k:k + nd] = p0
        R[k:k + nd] = r0
        k += nd
        if k >= N:
            break
        p1 = center + hw * rng.uniform(-1.0, 1.0, 3)
        r1 = rot_max * rng.uniform(-1.0, 1.0, 3)
        T = max(min_move_time, 1.875 * np.linalg.norm(p1 - p0) / speed,
                1.875 * np.linalg.norm(r1 - r0) / angular_speed)
        nm = max(2, int(round(T * rate)))
        s = min_jerk(np.arange(1, nm + 1) / nm)[:, None]
        P[k:k + nm] = (p0 + (p1 - p0) * s)[: N - k]
        R[k:k + nm] = (r0 + (r1 - r0) * s)[: N - k]
        k += nm
        p0, r0 = p1, r1
        waypoints.append((min(k, N) / rate, p1.tolist(), r1.tolist()))
    return P, R, waypoints


def _sines_path(ctx: ScenarioContext, N: int, center: np.ndarray, hw: np.ndarray, rot_max: np.ndarray,
                n_sines: int, band: tuple[float, float]):
    rng = ctx.rng
    t = np.arange(N) / ctx.rate
    win = min_jerk(t / 2.0)                     # start at the centre, at rest
    q = np.zeros((N, 6))
    for d in range(6):
        f = rng.uniform(band[0], band[1], n_sines)
        ph = rng.uniform(0, 2 * np.pi, n_sines)
        a = rng.uniform(0.5, 1.0, n_sines)
        q[:, d] = win * (np.sin(2 * np.pi * t[:, None] * f[None] + ph[None]) @ a) / a.sum()
    return center + hw * q[:, :3], rot_max * q[:, 3:], None


def trajectory(ctx: ScenarioContext, *, kind: str = "ptp", center: Sequence[float] = (0.0, 0.0, 0.0),
               half_width: Optional[Sequence[float]] = None, max_rotation_deg: float = 5.0, speed: float = 0.3,
               angular_speed_deg: float = 10.0, min_move_time: float = 1.0, dwell: Sequence[float] = (0.2, 1.0),
               n_sines: int = 3, frequency_band: Sequence[float] = (0.02, 0.15), min_tension: Optional[float] = None,
               max_tension: Optional[float] = None, f_ref: Optional[float] = None) -> ScenarioPlan:
    """Platform moves through the workspace; cables commanded to a weight-balancing tension distribution.

    Path (``kind``): ``"ptp"`` minimum-jerk moves between random poses with random dwells
    (``dwell`` [s] range; move time from ``speed`` [m/s] and ``angular_speed_deg`` [deg/s]
    peaks, at least ``min_move_time`` [s]) or ``"sines"`` (per degree of freedom a sum of
    ``n_sines`` sinusoids with frequencies in ``frequency_band`` [Hz], faded in over 2 s).
    Poses stay in the box ``center`` +- ``half_width`` [m] (default: 10 % of the frame's x and
    y extent, 3 % of the larger of them in z: inside the wrench-feasible workspace of
    ipanema3 and cogiro) with rotations up to ``max_rotation_deg`` about each axis (planar
    robots: x, y and rotation about z only). Starts at rest at ``center``; default duration
    60 s.

    Tensions: per tick f = argmin ||f - f_ref||^2 s.t. A^T f + w = 0 (eq 2 of 002, w the
    platform weight; quasi-static, inertia neglected) and f_lo <= f <= f_hi with
    f_lo = max(force_min, ``min_tension`` (default 60 N, the pretension of 002)),
    f_hi = min(0.9 force_max, ``max_tension``), ``f_ref`` default min(4 f_lo, (f_lo + f_hi)/2)
    (:func:`tension_distribution`). The commanded elongation is the one at which the truth
    base model's elastic part gives f, at the largest amplitude of its tables (the moves
    are far larger than 1.5 mm of elongation). The measured forces then differ from f by the
    model's hysteresis and any effects.
    """
    geom, rate = ctx.geom, ctx.rate
    m = geom.n_cables
    duration = TRAJECTORY_DURATION if ctx.duration is None else ctx.duration
    N = ctx.ticks(duration)
    if kind not in ("ptp", "sines"):
        raise SimulationError(f"option kind: 'ptp' or 'sines', got {kind!r}")
    c = _vec("center", center, 3)
    ext = np.ptp(np.asarray(geom.frame_anchors), axis=0)
    if half_width is None:
        hw = np.array([0.1 * ext[0], 0.1 * ext[1], 0.03 * max(ext[0], ext[1])])
    else:
        hw = _vec("half_width", half_width, 3)
        if np.any(hw < 0):
            raise SimulationError("option half_width: must be >= 0 m")
    rmax = np.full(3, np.radians(float(max_rotation_deg)))
    if geom.planar:
        hw[2] = 0.0
        c[2] = 0.0
        rmax[:2] = 0.0
    if not (speed > 0 and angular_speed_deg > 0 and min_move_time > 0):
        raise SimulationError("options speed, angular_speed_deg and min_move_time must be > 0")
    dw = (float(dwell[0]), float(dwell[1]))
    if not 0 <= dw[0] <= dw[1]:
        raise SimulationError(f"option dwell: expected [min, max] seconds, got {dwell!r}")
    band = (float(frequency_band[0]), float(frequency_band[1]))
    if kind == "ptp":
        P, Rv, waypoints = ptp_path(ctx, N, c, hw, rmax, float(speed), math.radians(angular_speed_deg),
                                     float(min_move_time), dw)
    else:
        if not (0 < band[0] <= band[1] < rate / 2) or int(n_sines) < 1:
            raise SimulationError("options frequency_band (0 < lo <= hi < rate/2) and n_sines (>= 1) out of range")
        P, Rv, waypoints = _sines_path(ctx, N, c, hw, rmax, int(n_sines), band)
    Q = rotvec_to_quat(Rv)

    ik = ctx.ik(P, Q)
    AT = structure_matrix(ik.unit, ik.anchor_world)
    w = platform_wrench(geom, ik.rotation)
    rows = list(PLANAR_WRENCH_ROWS) if geom.planar else list(range(6))
    f_lo = np.maximum(np.asarray(geom.force_min, dtype=np.float64), 60.0 if min_tension is None else float(min_tension))
    f_hi = 0.9 * np.asarray(geom.force_max, dtype=np.float64)
    if max_tension is not None:
        f_hi = np.minimum(f_hi, float(max_tension))
    if np.any(f_lo >= f_hi):
        raise SimulationError(f"tension limits empty: f_lo {f_lo.tolist()} N >= f_hi {f_hi.tolist()} N")
    ref = np.minimum(4.0 * f_lo.max(), 0.5 * (f_lo + f_hi)) if f_ref is None else np.full(m, float(f_ref))
    f_cmd = tension_distribution(AT, w, f_lo, f_hi, ref, rows)
    amp = ctx.elastic.max_amplitude
    x = ctx.elastic.elongation(f_cmd, amplitude=amp, length=ik.length)
    params = {"kind": kind, "center": c.tolist(), "half_width": hw.tolist(),
              "max_rotation_deg": float(max_rotation_deg), "speed": float(speed),
              "angular_speed_deg": float(angular_speed_deg), "min_move_time": float(min_move_time),
              "dwell": list(dw), "n_sines": int(n_sines), "frequency_band": list(band),
              "min_tension": f_lo.tolist(), "max_tension": f_hi.tolist(), "f_ref": np.asarray(ref).tolist(),
              "duration": N / rate}
    info = {"force_command": f_cmd, "wrench_rows": rows, "f_lo": f_lo, "f_hi": f_hi, "f_ref": ref,
            "waypoints": waypoints, "command_amplitude": amp}
    return ScenarioPlan(t=np.arange(N) / rate, position=P, orientation=Q, elongation=x, params=params, info=info)


#: scenario name -> function(ctx, **options) -> ScenarioPlan (docstrings document the options)
SCENARIOS: dict[str, Callable[..., ScenarioPlan]] = {
    "hold-sine": hold_sine,
    "hold-triangle": hold_triangle,
    "hold-trapezoid": hold_trapezoid,
    "trajectory": trajectory,
}
