"""Truth model of the digital twin: a base cable model plus switchable extra physics.

The twin (:mod:`cablesvc.simulate.twin`) plays a controller that commands elongations from
a *nominal* cable model. The forces it records come from the *truth* model defined here:

    truth force = force effects( base model( input effects(elongation) ) )
    measured    = sensor effects(truth force) + noise

* The **base model** is any :class:`~cablesvc.config.params.ModelParams` (a parameter file),
  by default the nominal amplitude-dependent hysteresis model of
  :func:`~cablesvc.config.params.default_params` for the robot's E*A and its cable lengths at
  the home pose (``base_model="amplitude"``), or the non-hysteretic linear elastic model
  (``base_model="linear"``: a recording *without* hysteresis; the opposite case, a recording
  *with* hysteresis that a linear model misses, is the default).
* **Effects** are small classes (:data:`~cablesvc.simulate.effects.EFFECTS`, in
  :mod:`cablesvc.simulate.effects`), each with a ``magnitude`` (its one
  headline number, unit in its docstring) and the ``cables`` it acts on (default: all).
  A magnitude of 0 switches an effect off exactly; on the other cables it is exactly the
  identity. The effect names are the API that benchmarks use as concealed labels.

Per tick the truth model runs these stages, vectorised over the cables (arrays ``(m,)``);
the order is fixed by each effect's stage, not by the order they are listed in:

1. ``input``       ``deadtime``: the elongation the cable sees is the one of tau seconds ago.
2. (rates)         ``v_in`` = rate of that elongation [m/s]; ``v_slide`` = speed the cable is
                   hauled in over the pulley, -d(motor_length)/dt [m/s].
3. base model      ``model.step(state, x_in, dt, l0=motor_length)``.
4. ``force``       ``sag``, ``creep``, ``temperature``, ``pulley``, ``viscous`` (in this
                   order): the true cable force. Effects that change the cable's length
                   (creep, sag) act here, linearised with the nominal stiffness k = EA/L,
                   not through the base model's elongation: the amplitude model reacts to
                   sub-micrometre elongation changes with spurious reversals (see Sag).
5. ``sensor``      ``offset_gain``: what the force sensor makes of it; then Gaussian noise
                   of ``noise_std`` N (drawn once for the whole run from the seed).

Units: SI (m, s, N, K, rad) throughout.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from cablesvc.config.params import ModelParams, default_params
from cablesvc.config.robot import RobotGeometry
from cablesvc.errors import SimulationError
from cablesvc.models import MODELS
from cablesvc.simulate.effects import STAGES, Effect, RunInfo, TickState, stage_order
from cablesvc.simulate.elastic import ElasticCurve

__all__ = ["BASE_MODELS", "TruthConfig", "TruthModel", "TruthOutput"]

#: Base models a :class:`TruthConfig` can ask for by name when it has no ``base`` params.
BASE_MODELS = tuple(name for name, cls in MODELS.items() if cls.has_nominal)


@dataclass
class TruthConfig:
    """How the twin's measured forces are made.

    ``base``: parameters of the base cable model (None: nominal parameters of ``base_model``
    from :func:`default_params` for the robot's E*A and its cable lengths at the home pose);
    ``base_model``: "amplitude" (hysteretic, default) or "linear" (no hysteresis);
    ``effects``: extra physics (:data:`EFFECTS`); ``noise_std``: Gaussian force-sensor noise
    [N]; ``seed``: seed of the noise (None: the simulation's seed).
    """

    base: Optional[ModelParams] = None
    effects: list[Effect] = field(default_factory=list)
    noise_std: float = 0.1
    seed: Optional[int] = None
    base_model: str = "amplitude"

    def __post_init__(self) -> None:
        self.effects = list(self.effects)
        for e in self.effects:
            if not isinstance(e, Effect):
                raise SimulationError(f"TruthConfig.effects: {e!r} is not an Effect (use effect_from_spec)")
        if not (math.isfinite(self.noise_std) and self.noise_std >= 0):
            raise SimulationError(f"TruthConfig.noise_std must be >= 0 N, got {self.noise_std!r}")
        if self.base is None and self.base_model not in BASE_MODELS:
            raise SimulationError(f"TruthConfig.base_model must be one of {BASE_MODELS}, got {self.base_model!r}")


@dataclass
class TruthOutput:
    """Result of :meth:`TruthModel.run`, arrays (N, m) [N] / [m].

    ``measured``: what the force sensors report (sensor effects and noise included);
    ``force``: the true cable force (all physical effects, no sensor error, no noise);
    ``base_force``: the base model's output (before the force-stage effects);
    ``x_in``: the elongation the base model was given (after dead time) [m].
    """

    measured: np.ndarray
    force: np.ndarray
    base_force: np.ndarray
    x_in: np.ndarray


class TruthModel:
    """The base model plus the bound effects for one robot; :meth:`run` simulates a run.

    ``cable_length`` (m,) [m]: typical free length per cable (the twin uses the IK length
    at the home pose) for the nominal parameters and the nominal stiffness EA/L.
    """

    def __init__(self, config: TruthConfig, geom: RobotGeometry, cable_length: np.ndarray):
        self.config = config
        self.geom = geom
        self.n_cables = m = int(geom.n_cables)
        self.cable_length = np.asarray(cable_length, dtype=np.float64).reshape(m)
        self.params = config.base if config.base is not None else default_params(
            geom.ea, self.cable_length, config.base_model)
        self.params.build(m, 1)  # fail early, naming the parameter file
        self.elastic = ElasticCurve(self.params, m)
        self.stiffness = np.asarray(geom.ea, dtype=np.float64) / self.cable_length
        self.effects: list[Effect] = []

    def describe(self) -> dict[str, Any]:
        """Ground truth as JSON-able data (base model, noise, effects with their cables)."""
        p = self.params
        return {
            "base": {"model": p.model, "source": "nominal" if self.config.base is None else p.source,
                     "hysteresis": MODELS[p.model].hysteretic},
            "noise_std": self.config.noise_std,
            "effects": [e.to_dict() for e in (self.effects or self.config.effects)],
        }

    def check_effects(self) -> None:
        """Raise SimulationError now for effects that cannot act on this robot (cables out of
        range, a pulley effect without pulleys), before any simulation work."""
        m = self.n_cables
        run = RunInfo(n_cables=m, dt=1e-3, n_ticks=2, duration=1.0, stiffness=self.stiffness,
                      has_pulley=np.asarray(self.geom.has_pulley, dtype=bool))
        for e in self.config.effects:
            copy.deepcopy(e).bind(run)

    def run(self, *, t: np.ndarray, dt: float, elongation: np.ndarray, motor_length: np.ndarray,
            wrap_angle: np.ndarray, free_length: np.ndarray, temperature: np.ndarray,
            rng: np.random.Generator) -> TruthOutput:
        """Simulate N ticks (one Python loop over ticks, numpy over cables).

        ``t`` (N,) [s], ``dt`` [s] the tick period (the base model gets 0 at the first tick,
        as :func:`cablesvc.models.simulate` does), ``elongation`` (N,m) x = l - motor_length
        [m], ``motor_length`` (N,m) [m], ``wrap_angle`` (N,m) [rad], ``free_length`` (N,m)
        [m], ``temperature`` (N,) [deg C]; ``rng`` draws the sensor noise.
        """
        x = np.asarray(elongation, dtype=np.float64)
        N, m = x.shape
        run = RunInfo(n_cables=m, dt=float(dt), n_ticks=N, duration=float(t[-1] - t[0]) if N > 1 else float(dt),
                      stiffness=self.stiffness, has_pulley=np.asarray(self.geom.has_pulley, dtype=bool),
                      cable_names=tuple(self.geom.cable_names))
        effects = [copy.deepcopy(e) for e in self.config.effects]
        for e in effects:
            e.bind(run)
        self.effects = effects
        effects = sorted(effects, key=stage_order)
        act = [e for e in effects if e.active]
        by_stage = {s: [e for e in act if e.stage == s] for s in STAGES}
        need_v_in = any(e.name == "viscous" for e in act)

        model = self.params.build(m, 1)
        measured = np.empty((N, m))
        force = np.empty((N, m))
        base_force = np.empty((N, m))
        x_in = np.empty((N, m))
        tick = TickState()
        tick.dt = float(dt)
        xin = np.empty(m)
        fb = np.empty(m)
        zero = np.zeros(m)
        state = None
        ml = np.asarray(motor_length, dtype=np.float64)
        for k in range(N):
            tick.k = k
            tick.t = float(t[k])
            tick.x = x[k]
            tick.motor_length = ml[k]
            tick.wrap_angle = wrap_angle[k]
            tick.free_length = free_length[k]
            tick.temperature = float(temperature[k])
            np.copyto(xin, x[k])
            for e in by_stage["input"]:
                e.step(tick, xin)
            x_in[k] = xin
            xk = x_in[k:k + 1]                      # (1, m): the model's (lanes, cables)
            tick.x_in = x_in[k]
            if k == 0:
                tick.v_in = zero
                tick.v_slide = zero
            else:
                if need_v_in:
                    tick.v_in = (x_in[k] - x_in[k - 1]) / dt
                tick.v_slide = (ml[k - 1] - ml[k]) / dt
            if state is None:
                state = model.create_state(xk)
            f = model.step(state, xk, float(dt) if k else 0.0, ml[k:k + 1])
            base_force[k] = f[0]
            np.copyto(fb, f[0])
            for e in by_stage["force"]:
                e.step(tick, fb)
            force[k] = fb
            for e in by_stage["sensor"]:
                e.step(tick, fb)
            measured[k] = fb
        if self.config.noise_std > 0:
            measured += self.config.noise_std * rng.standard_normal((N, m))
        return TruthOutput(measured=measured, force=force, base_force=base_force, x_in=x_in)
