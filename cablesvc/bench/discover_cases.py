"""Cases of the realistic discovery bench: an imperfect, identified baseline and a recording
from another simulator (:mod:`cablesvc.bench.truth`).

Interface (used by ``cablesvc bench discover`` and by whoever develops discovery)::

    from cablesvc.bench.discover_cases import make_realistic_case, case_plan, iter_cases
    case = make_realistic_case("single", ["creep"], seed=11)          # one case
    d = discover(case.recording, "ipanema3", case.baseline)           # what the bench does
    case.truth   # answer key: {"kind", "effects": [{"name", "cables", ...}], "cables", "ool"}
    for case in iter_cases(cases=7, seed=123): ...                    # a whole plan

:class:`RealisticCase` fields: ``calib`` the calibration recording and ``recording`` the
case's trajectory recording (:class:`~cablesvc.recording.Recording`, no ``truth``
metadata: discovery sees only what a user has), ``baseline`` the
:class:`~cablesvc.config.params.ModelParams` identified from ``calib`` by
:func:`cablesvc.identify.cable.identify_cable` with the defaults of
``cablesvc identify --model amplitude`` (the function the CLI calls), ``truth`` the answer
key (effect names and cables; ``kind`` in ``single``, ``pair``, ``control``, ``ool``),
plus the robot, magnitudes, effect RMS, equilibrium figures and timings.

How a case is made:

1. **A robot** of the fleet (:func:`calibrated_robot`, cached per process): a draw of the
   truth cable law (:func:`cablesvc.bench.truth.draw_variant`: non-polynomial backbone,
   Prandtl-Ishlinskii + Maxwell hysteresis, stiffness +-10 % per cable), calibrated once
   as in 002 Sec 4: platform clamped at home, ``hold-sine`` with each winch in turn
   (``mode="sequential"``), six amplitude levels 0.1-1.5 mm at 60 N pretension, 0.5 Hz,
   3 cycles, 100 Hz, 0.1 N noise, no concealed effect; then the amplitude model is
   identified from that recording. Several cases share a robot (``fleet`` robots per
   run, cases assigned in turn), as a user calibrates a robot once and records many runs.
2. **A trajectory** (``trajectory`` scenario, 30 s at 100 Hz; path ``ptp`` or ``sines``
   drawn per case; tensions 40-380 N, far from the 60 N calibration point, with moves of
   centimetres instead of millimetre sines). The winches hold the commanded motor
   lengths; the platform settles to static equilibrium with the truth forces
   (:func:`cablesvc.bench.truth.equilibrium_run`); the recorded pose is the balanced one.
3. **Effects**: the library's (twin) effects and the out-of-library ones
   (:data:`cablesvc.bench.truth.OOL_EFFECTS`) on random cables, each scaled so that what
   it leaves for a perfect baseline (the measured force minus the truth law without the
   effect, on the elongation computed from the recording) has an RMS on its weakest
   cable that is a log-uniform draw in 3-10 x the 0.1 N noise (one pilot run at the
   effect's reference magnitude, re-checked for the non-linear ones).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any, Iterator, Optional

import numpy as np

from cablesvc.bench.truth import (
    HYSTERESIS,
    OOL_EFFECTS,
    CableVariant,
    EquilibriumRun,
    OolEffect,
    cable_law,
    draw_variant,
    equilibrium_run,
    solve_ik,
    wrench_rows,
)
from cablesvc.config import Robot, load_robot
from cablesvc.config.robot import RobotGeometry
from cablesvc.config.params import ModelParams, home_lengths, nominal_params
from cablesvc.jsonable import jsonable
from cablesvc.kinematics import inverse_kinematics, platform_wrench, structure_matrix
from cablesvc.recording import Recording
from cablesvc.simulate import EFFECTS
from cablesvc.simulate.effects import Effect
from cablesvc.simulate.elastic import ElasticCurve
from cablesvc.simulate.noise import ar1, lowpass_phi
from cablesvc.simulate.scenarios import ScenarioContext, hold_sine, trajectory
from cablesvc.simulate.twin import Ambient

__all__ = ["NOISE", "ROBOT", "RATE", "DURATION", "CAL_AMPLITUDES", "RATIO", "KINDS", "SimRobot",
           "RealisticCase", "CaseSpec", "calibrated_robot", "robot_variant", "make_realistic_case", "case_plan", "iter_cases",
           "strip_truth", "wrench_rms"]

NOISE = 0.1                 # N
ROBOT = "ipanema3"
RATE = 100.0                # Hz
DURATION = 30.0             # s
CAL_AMPLITUDES = (1e-4, 2.5e-4, 5e-4, 7.5e-4, 1e-3, 1.5e-3)   # m, six levels of 002 Sec 4
RATIO = (3.0, 10.0)         # effect RMS / noise on the weakest affected cable
TENSION = (40.0, 380.0)     # N, trajectory tension limits
KINDS = ("single", "pair", "control", "ool")
SIGNED = {"offset_gain", "temperature"}
POWER = {"sag": 2.0}
NONLINEAR = {"sag", "deadtime", "mount"}
GENERATOR = "cablesvc.bench.truth"
PILOT_SWEEPS = 0            # sweeps of the equilibrium in the magnitude pilots (0: at the balanced
                            # pose without the effect; what the effect leaves for a perfect
                            # baseline hardly depends on the small correction it brings)


def strip_truth(rec: Recording) -> Recording:
    """A shallow copy of ``rec`` without the ``truth`` metadata (the answer key)."""
    r = copy.copy(rec)
    r.metadata = {k: v for k, v in rec.metadata.items() if k != "truth"}
    return r


def wrench_rms(geom: Any, position: np.ndarray, orientation: np.ndarray, *forces: np.ndarray) -> list[float]:
    """Per force array (N, m) [N]: the RMS over ticks of |force rows of A^T f + w| [N]
    (002 eq 2, quasi-static), with the robot file's geometry at the recorded pose."""
    ik = solve_ik(geom, position, orientation)
    AT = structure_matrix(ik.unit, ik.anchor_world)
    w = platform_wrench(geom, ik.rotation)
    rows = [r for r in wrench_rows(geom) if r < 3]
    out = []
    for f in forces:
        R = np.einsum("nim,nm->ni", AT, f) + w
        out.append(float(np.sqrt(np.mean(np.sum(R[:, rows] ** 2, axis=1)))))
    return out


# --------------------------------------------------------------------------------------
# robots of the fleet
# --------------------------------------------------------------------------------------


@dataclass
class SimRobot:
    """One simulated robot: ``variant`` its true cable law, ``calib`` its calibration
    recording (truth stripped), ``baseline`` the amplitude model identified from it,
    ``calib_rmse`` the identification's per-cable RMSE [N], ``seconds`` (simulate, identify)."""

    index: int
    fleet_seed: int
    robot: Robot
    geom: Any
    variant: CableVariant
    home_length: np.ndarray
    calib: Recording
    baseline: ModelParams
    calib_rmse: np.ndarray
    seconds: dict[str, float]


_FLEET: dict[tuple[int, int, float, str], SimRobot] = {}


def _nominal_elastic(geom: Any) -> ElasticCurve:
    """The controller's model: the nominal amplitude model's elastic curve (as the twin)."""
    return ElasticCurve(nominal_params(geom), geom.n_cables)


def robot_variant(index: int, fleet_seed: int = 0, damping: float = 1.0,
                  geom: Optional[RobotGeometry] = None, hysteresis: str = "envelope") -> CableVariant:
    """The true cable law of robot ``index`` of fleet ``fleet_seed`` (:func:`draw_variant`
    about the robot file's EA / L at home), its damping ``beta`` scaled by ``damping``;
    ``hysteresis`` the law's rate part (:data:`~cablesvc.bench.truth.HYSTERESIS`:
    "envelope", the default, or "boucwen", a rate-independent Bouc-Wen loop of the same
    level in its place; the other draws are the same)."""
    geom = geom if geom is not None else load_robot(ROBOT).geometry()
    k = np.asarray(geom.ea, float) / home_lengths(geom)
    variant = draw_variant(k, np.random.default_rng([fleet_seed, index, 41]))
    if damping != 1.0:
        variant = dataclasses.replace(variant, beta=variant.beta * float(damping))
    if hysteresis not in HYSTERESIS:
        raise ValueError(f"truth hysteresis must be one of {', '.join(HYSTERESIS)}, got {hysteresis!r}")
    if hysteresis != variant.hysteresis:
        variant = dataclasses.replace(variant, hysteresis=hysteresis)
    return variant


def calibrated_robot(index: int, fleet_seed: int = 0, damping: float = 1.0,
                     hysteresis: str = "envelope") -> SimRobot:
    """Robot ``index`` of fleet ``fleet_seed``: its cable law, calibration recording and
    identified baseline (computed once per process, then cached). ``damping`` scales the
    truth law's rate-dependent damping h (``beta``), the largest part of what the
    identified baseline leaves on a trajectory: 1 as drawn; below 1 a milder model-form
    error (the same robot otherwise, as the draws do not change). ``hysteresis``: the truth
    law's loop (:func:`robot_variant`)."""
    key = (int(index), int(fleet_seed), float(damping), str(hysteresis))
    if key in _FLEET:
        return _FLEET[key]
    from cablesvc.identify.cable import identify_cable
    t0 = time.perf_counter()
    rob = load_robot(ROBOT)
    geom = rob.geometry()
    home = home_lengths(geom)
    variant = robot_variant(index, fleet_seed, damping, geom, hysteresis)
    seed = int(np.random.default_rng([fleet_seed, index, 42]).integers(0, 2 ** 31 - 1))
    ctx = ScenarioContext(geom=geom, rate=RATE, duration=None, rng=np.random.default_rng([seed, 1]),
                          elastic=_nominal_elastic(geom))
    plan = hold_sine(ctx, amplitudes=CAL_AMPLITUDES, mode="sequential")
    ik = inverse_kinematics(geom, plan.position, plan.orientation)
    ml = ik.length - plan.elongation
    temp = Ambient().profile(plan.t, np.random.default_rng([seed, 2]))
    eq = equilibrium_run(geom, variant, [], [], t=plan.t, dt=1.0 / RATE, position=plan.position,
                         orientation=plan.orientation, motor_length=ml, temperature=temp, balance=False)
    meas = eq.measured + NOISE * np.random.default_rng([seed, 3]).standard_normal(eq.measured.shape)
    N = plan.t.size
    meta = {"generator": GENERATOR, "scenario": "hold-sine", "seed": str(seed), "rate": repr(RATE),
            "scenario_params": json.dumps(jsonable(plan.params), sort_keys=True),
            "truth": json.dumps(jsonable({"variant": variant.describe(), "noise_std": NOISE, "effects": [],
                                          "platform": "clamped at home"}), sort_keys=True)}
    rec = Recording(robot=rob.name, metadata=meta, t=plan.t, seq=np.arange(N, dtype=np.int64), motor_length=ml,
                    position=plan.position, orientation=plan.orientation, force=meas, temperature=temp)
    calib = strip_truth(rec)
    t1 = time.perf_counter()
    fit = identify_cable(calib, rob, "amplitude")
    t2 = time.perf_counter()
    sr = SimRobot(index=int(index), fleet_seed=int(fleet_seed), robot=rob, geom=geom, variant=variant, home_length=home,
                  calib=calib, baseline=fit.params, calib_rmse=np.asarray(fit.rmse, float),
                  seconds={"simulate": t1 - t0, "identify": t2 - t1})
    _FLEET[key] = sr
    return sr


# --------------------------------------------------------------------------------------
# one case
# --------------------------------------------------------------------------------------


@dataclass
class RealisticCase:
    """One case of the realistic bench (see the module docstring)."""

    kind: str
    names: list[str]
    seed: int
    robot: SimRobot
    calib: Recording
    baseline: ModelParams
    recording: Recording
    truth: dict[str, Any]
    effects: list[Any]
    effect_rms: dict[str, float]
    wrench: dict[str, float]
    seconds: dict[str, float]
    clean_force: np.ndarray = field(repr=False, default=None)   # measured forces of the same run without effects, no noise
    #: what the effects leave for a perfect baseline, no noise: the measured force minus the
    #: truth law without them on the elongation every tool computes from the recording (as
    #: :func:`_effect_rms`; not the run without effects, whose platform stood elsewhere)
    effect_force: np.ndarray = field(repr=False, default=None)
    #: a single effect's RMS on each of its cables [N] (the weakest one is ``effect_rms``);
    #: empty for pairs, where the two effects' forces mix on shared cables
    effect_rms_cables: dict[int, float] = field(default_factory=dict)


@dataclass
class _Traj:
    t: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    motor_length: np.ndarray
    temperature: np.ndarray
    params: dict[str, Any]


def draw_trajectory(sr: SimRobot, seed: int, rng: np.random.Generator, duration: float = DURATION) -> _Traj:
    """A trajectory of ``duration`` s for robot ``sr`` (point-to-point or sines, drawn from
    ``rng``; poses, motor lengths and temperature from ``seed``)."""
    geom = sr.geom
    ctx = ScenarioContext(geom=geom, rate=RATE, duration=float(duration), rng=np.random.default_rng([seed, 1]),
                          elastic=_nominal_elastic(geom))
    kind = "ptp" if rng.random() < 0.6 else "sines"
    plan = trajectory(ctx, kind=kind, min_tension=TENSION[0], max_tension=TENSION[1])
    ik = inverse_kinematics(geom, plan.position, plan.orientation)
    ml = ik.length - plan.elongation
    temp = Ambient().profile(plan.t, np.random.default_rng([seed, 2]))
    return _Traj(t=plan.t, position=plan.position, orientation=plan.orientation, motor_length=ml, temperature=temp,
                 params=plan.params)


def _run(sr: SimRobot, tr: _Traj, effects: list[Any], start: Optional[EquilibriumRun] = None,
         sweeps: int = 8) -> EquilibriumRun:
    lib = [e for e in effects if isinstance(e, Effect)]
    ool = [e for e in effects if isinstance(e, OolEffect)]
    P = tr.position if start is None else start.position
    Q = tr.orientation if start is None else start.orientation
    return equilibrium_run(sr.geom, sr.variant, lib, ool, t=tr.t, dt=1.0 / RATE, position=P,
                           orientation=Q, motor_length=tr.motor_length, temperature=tr.temperature,
                           max_sweeps=sweeps)


def _make_effect(name: str, magnitude: float, cables: tuple[int, ...], opts: dict[str, Any]) -> Any:
    if name in EFFECTS:
        return EFFECTS[name](magnitude=magnitude, cables=cables)
    return OOL_EFFECTS[name](magnitude=magnitude, cables=cables, **opts)


def _draw_effect(name: str, m: int, rng: np.random.Generator) -> tuple[tuple[int, ...], float, dict[str, Any]]:
    """Cables, signed reference magnitude and options of an effect."""
    opts: dict[str, Any] = {}
    if name == "mount":
        i = int(rng.integers(0, m // 2))
        cables = (i, i + m // 2)                 # upper and lower pulley on the same frame post (ipanema3)
        ref = OOL_EFFECTS[name].default_magnitude
    elif name == "anchor":
        cables = (int(rng.integers(0, m)),)
        d = rng.standard_normal(3)
        opts["direction"] = tuple((d / np.linalg.norm(d)).tolist())
        ref = OOL_EFFECTS[name].default_magnitude
    elif name == "eccentricity":
        cables = (int(rng.integers(0, m)),)
        opts["drum_radius"] = float(rng.uniform(0.03, 0.08))
        opts["phase"] = float(rng.uniform(0.0, 2.0 * math.pi))
        ref = OOL_EFFECTS[name].default_magnitude
    else:
        k = int(rng.integers(1, 4))
        cables = tuple(sorted(rng.choice(m, size=k, replace=False).tolist()))
        ref = abs(EFFECTS[name].default_magnitude)
        if name in SIGNED and rng.random() < 0.5:
            ref = -ref
    return cables, ref, opts


def _effect_force(run: EquilibriumRun, sr: SimRobot, tr: _Traj) -> np.ndarray:
    """What the effects leave for a perfect baseline (N, m) [N], as :func:`_effect_rms`."""
    x = solve_ik(sr.geom, run.position, run.orientation).length - tr.motor_length
    return run.measured - cable_law(sr.variant, x, 1.0 / RATE)


def _effect_rms_cables(run: EquilibriumRun, sr: SimRobot, tr: _Traj, cables: tuple[int, ...]) -> np.ndarray:
    """What the effect leaves for a perfect baseline, as :func:`_effect_rms`, on each of
    ``cables`` [N]."""
    d = _effect_force(run, sr, tr)
    return np.sqrt(np.mean(d[:, list(cables)] ** 2, axis=0))


def _effect_rms(run: EquilibriumRun, sr: SimRobot, tr: _Traj, cables: tuple[int, ...]) -> float:
    """What the effect leaves for a perfect baseline: the RMS, on its weakest cable, of the
    measured force (noise-free) minus the truth law *without* the effect run on the
    elongation every tool computes from the recording (l(recorded pose) from the robot
    file, minus the recorded motor length) [N]. Comparing forces with those of the run
    without the effect would instead count the platform's equilibrium shift, which moves a
    cable effect onto the other cables and which any baseline sees in the pose."""
    return float(np.min(_effect_rms_cables(run, sr, tr, cables)))


def sensor_noise(shape: tuple, seed: int, dt: float, filter_hz: Optional[float] = None) -> np.ndarray:
    """The force sensors' noise [N], std NOISE per channel, from the case's ``seed``. White
    by default; with ``filter_hz`` it has passed a first-order low-pass filter of that
    cut-off (a load-cell amplifier's: y_n = phi y_(n-1) + sqrt(1 - phi^2) e_n, phi =
    exp(-2 pi filter_hz dt), started in its stationary state), so its std stays NOISE
    while its ticks are correlated over about 1 / (2 pi filter_hz) s."""
    if filter_hz is None:
        return NOISE * np.random.default_rng([seed, 3]).standard_normal(shape)
    e = np.random.default_rng([seed, 3, 1]).standard_normal((shape[0] + 1,) + tuple(shape[1:]))
    return NOISE * ar1(e[1:], lowpass_phi(filter_hz, dt), e[0])


def make_realistic_case(kind: str, names: list[str], seed: int, *, robot: Optional[SimRobot] = None,
                        robot_index: int = 0, fleet_seed: int = 0,
                        rng: Optional[np.random.Generator] = None, duration: float = DURATION,
                        noise_filter_hz: Optional[float] = None) -> RealisticCase:
    """Simulate one case: ``kind`` in :data:`KINDS`, ``names`` the concealed effects (twin
    effect names, or for ``ool`` one of :data:`~cablesvc.bench.truth.OOL_EFFECTS`),
    ``seed`` the trajectory/noise seed, ``robot`` (default: robot ``robot_index`` of fleet
    ``fleet_seed``), ``rng`` the draws of cables and magnitudes (default from ``seed``),
    ``duration`` [s] the recording's length (the effects' RMS is drawn against the noise over
    the whole recording, whatever its length), ``noise_filter_hz`` the cut-off [Hz] of a
    first-order low-pass filter the sensor noise passes through (:func:`sensor_noise`; None:
    white)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    unknown = [n for n in names if n not in EFFECTS and n not in OOL_EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {', '.join(list(EFFECTS) + list(OOL_EFFECTS))}")
    rng = rng if rng is not None else np.random.default_rng([seed, 77])
    t0 = time.perf_counter()
    sr = robot if robot is not None else calibrated_robot(robot_index, fleet_seed)
    t1 = time.perf_counter()
    geom = sr.geom
    m = geom.n_cables
    tr = draw_trajectory(sr, seed, rng, duration)
    base = _run(sr, tr, [])
    effects, rms, mags = [], {}, {}
    for name in names:
        cables, ref, opts = _draw_effect(name, m, rng)
        target = NOISE * math.exp(rng.uniform(math.log(RATIO[0]), math.log(RATIO[1])))
        p = POWER.get(name, 1.0)
        # pilots run at the balanced pose without the effect; the case itself is balanced
        e0 = _effect_rms(_run(sr, tr, [_make_effect(name, ref, cables, opts)], base, PILOT_SWEEPS), sr, tr, cables)
        mag = ref * (target / max(e0, 1e-12)) ** (1.0 / p)
        e1 = target
        for _ in range(3 if name in NONLINEAR else 0):
            e1 = _effect_rms(_run(sr, tr, [_make_effect(name, mag, cables, opts)], base, PILOT_SWEEPS), sr, tr,
                             cables)
            if abs(e1 / target - 1.0) < 0.15:
                break
            mag = mag * (target / max(e1, 1e-12)) ** (1.0 / p)
        eff = _make_effect(name, mag, cables, opts)
        effects.append(eff)
        rms[name] = e1
        mags[name] = mag
    final = _run(sr, tr, effects, base) if effects else base
    per_cable: dict[int, float] = {}
    if len(effects) == 1:       # measured on the case itself (balanced), not the pilot
        cs = tuple(effects[0].applied_cables or effects[0].cables)
        each = _effect_rms_cables(final, sr, tr, cs)
        rms[effects[0].name] = float(np.min(each))
        per_cable = {int(c): float(v) for c, v in zip(cs, each)}
    noise = sensor_noise(final.measured.shape, seed, 1.0 / RATE, noise_filter_hz)
    meas = final.measured + noise
    N = tr.t.size
    cables = sorted({c for e in effects for c in (e.applied_cables or e.cables)})
    truth = {"kind": kind, "effects": [e.to_dict() for e in effects], "names": sorted(names), "cables": cables,
             "ool": kind == "ool", "robot": sr.index, "variant": sr.variant.describe(), "noise_std": NOISE,
             "noise_filter_hz": noise_filter_hz, "trajectory": tr.params}
    meta = {"generator": GENERATOR, "scenario": "trajectory", "seed": str(seed), "rate": repr(RATE),
            "scenario_params": json.dumps(jsonable(tr.params), sort_keys=True),
            "truth": json.dumps(jsonable(truth), sort_keys=True)}
    rec = Recording(robot=sr.robot.name, metadata=meta, t=tr.t, seq=np.arange(N, dtype=np.int64),
                    motor_length=tr.motor_length, position=final.position, orientation=final.orientation,
                    force=meas, temperature=tr.temperature)
    w_true, w_clean, w_meas = wrench_rms(geom, final.position, final.orientation, final.force, final.measured, meas)
    wr = {"true_force_N": w_true, "measured_noise_free_N": w_clean, "measured_N": w_meas,
          "sweeps": final.sweeps, "pose_shift_mm": 1e3 * float(np.max(np.linalg.norm(
              final.position - tr.position, axis=1)))}
    t2 = time.perf_counter()
    return RealisticCase(kind=kind, names=list(names), seed=int(seed), robot=sr, calib=sr.calib,
                         baseline=sr.baseline, recording=strip_truth(rec), truth=truth, effects=effects,
                         effect_rms=rms, wrench=wr, seconds={"calibrate": t1 - t0, "simulate": t2 - t1},
                         clean_force=base.measured, effect_force=_effect_force(final, sr, tr),
                         effect_rms_cables=per_cable)


# --------------------------------------------------------------------------------------
# a plan of cases
# --------------------------------------------------------------------------------------


@dataclass
class CaseSpec:
    """One planned case: ``kind``, effect ``names``, ``seed``, ``robot_index``, ``index``,
    the truth's ``damping`` scale (:func:`calibrated_robot`), the recording's ``duration`` [s]
    and the sensor noise's ``noise_filter_hz`` (:func:`sensor_noise`)."""

    kind: str
    names: list[str]
    seed: int
    robot_index: int
    index: int
    damping: float = 1.0
    duration: float = DURATION
    hysteresis: str = "envelope"
    noise_filter_hz: Optional[float] = None


def case_plan(cases: int = 40, seed: int = 0, fleet: int = 4, damping: float = 1.0,
              duration: float = DURATION, hysteresis: str = "envelope",
              noise_filter_hz: Optional[float] = None) -> list[CaseSpec]:
    """``cases`` single-effect cases (the seven twin effects in turn), as many pairs
    (pairs of different effects, drawn in turn from a shuffled list of all pairs), as many
    controls, and ``cases // 2`` (at least 1) out-of-library cases (the three in turn);
    robots of the fleet assigned in turn, so every kind meets every robot."""
    rng = np.random.default_rng([seed, 6])
    names = list(EFFECTS)
    ool = list(OOL_EFFECTS)
    plan: list[tuple[str, list[str]]] = [("single", [names[i % len(names)]]) for i in range(cases)]
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    order = rng.permutation(len(pairs))
    plan += [("pair", list(pairs[order[i % len(pairs)]])) for i in range(cases)]
    plan += [("control", []) for _ in range(cases)]
    plan += [("ool", [ool[i % len(ool)]]) for i in range(max(1, cases // 2))]
    out = []
    for i, (kind, nm) in enumerate(plan):
        out.append(CaseSpec(kind=kind, names=nm, seed=int(rng.integers(0, 2 ** 31 - 1)),
                            robot_index=i % max(1, int(fleet)), index=i, damping=float(damping),
                            duration=float(duration), hysteresis=str(hysteresis),
                            noise_filter_hz=None if noise_filter_hz is None else float(noise_filter_hz)))
    return out


def planned_case(spec: CaseSpec, seed: int) -> RealisticCase:
    """Simulate the planned case ``spec`` of :func:`case_plan` with ``seed`` (the plan's
    seed, which is also the fleet's): its robot calibrated (once per process), its draws of
    cables and magnitudes from [seed, 7, index]. What the bench runs for every case, and
    what a test that replays one bench case builds."""
    sr = calibrated_robot(spec.robot_index, seed, spec.damping, spec.hysteresis)
    return make_realistic_case(spec.kind, spec.names, spec.seed, robot=sr,
                               rng=np.random.default_rng([seed, 7, spec.index]), duration=spec.duration,
                               noise_filter_hz=spec.noise_filter_hz)


def iter_cases(cases: int = 40, seed: int = 0, fleet: int = 4) -> Iterator[RealisticCase]:
    """Yield the cases of :func:`case_plan` (robots of fleet ``seed``, calibrated on first use)."""
    for spec in case_plan(cases, seed, fleet):
        yield make_realistic_case(spec.kind, spec.names, spec.seed, robot_index=spec.robot_index, fleet_seed=seed,
                                  rng=np.random.default_rng([seed, 7, spec.index]))
