"""The digital twin: runs a scenario against the truth model and makes a recording.

:func:`simulate_recording` is what ``cablesvc simulate`` calls; :func:`simulate_twin` does
the same and also returns everything the twin knows (plan, true forces, elongations), for
tests and benchmarks.

What a recording from the twin holds (recording format 1, one tick per 1/rate s, t from 0):
the commanded pose (the platform is assumed to be exactly there: position control with a
rigid platform, no elastostatic deflection), the motor lengths l(pose) - x, the measured
forces of the truth model (:mod:`cablesvc.simulate.truth`) with sensor noise, and the
ambient temperature (always written, whether or not the ``temperature`` effect is on, so
that the channel itself gives nothing away).

Metadata (record ``cablesvc``, all values strings): ``generator`` = ``cablesvc.simulate``,
``scenario``, ``seed``, ``rate`` [Hz], ``scenario_params`` (JSON) and ``truth`` (JSON: base
model, sensor noise, the effects switched on with magnitude, unit, cables and options). **``truth`` is the answer key for benchmarks: a discovery or identification
tool under test must not read it**; only the benchmark harness that scores the tool does.

Seeding: everything is reproducible from ``seed``. Independent streams are drawn from
``numpy.random.default_rng([seed, k])``: k = 1 the scenario (trajectory, waypoints),
k = 2 the ambient temperature, k = 3 the force noise (with ``TruthConfig.seed`` in place of
``seed`` when that is set).
"""

from __future__ import annotations

import inspect
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from cablesvc.config.params import home_lengths
from cablesvc.config.robot import Robot, load_robot
from cablesvc.jsonable import jsonable
from cablesvc.kinematics import inverse_kinematics
from cablesvc.recording import Recording, write_recording
from cablesvc.errors import SimulationError
from cablesvc.simulate.truth import TruthConfig, TruthModel, TruthOutput
from cablesvc.simulate.scenarios import SCENARIOS, ScenarioContext, ScenarioPlan

__all__ = ["Ambient", "TRUTH_NOTICE", "TwinRun", "simulate_recording", "simulate_twin"]

TRUTH_NOTICE = ("ground truth of the simulation for benchmark scoring; tools under test "
                "(discovery, identification) must not read it")


@dataclass
class Ambient:
    """Ambient temperature the twin records [deg C]:

        T(t) = mean + swing sin(2 pi t / period + phi) + s drift (t / T_run - 1/2)

    with phi uniform and s = +-1 drawn from the ambient stream, ``period`` [s] default the
    run's duration T_run (one slow swing per recording), ``swing`` and ``drift`` in K.
    """

    mean: float = 21.0
    swing: float = 2.0
    drift: float = 1.0
    period: Optional[float] = None

    def profile(self, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        T_run = max(float(t[-1] - t[0]), 1e-9) if t.size > 1 else 1.0
        period = self.period if self.period is not None else T_run
        if not (period > 0):
            raise SimulationError(f"Ambient.period must be > 0 s, got {self.period!r}")
        phi = rng.uniform(0.0, 2.0 * np.pi)
        s = 1.0 if rng.random() < 0.5 else -1.0
        tau = (t - t[0]) / T_run
        return self.mean + self.swing * np.sin(2.0 * np.pi * (t - t[0]) / period + phi) + s * self.drift * (tau - 0.5)


@dataclass
class TwinRun:
    """Everything one twin run produced.

    ``recording``: what a controller would log (and what :func:`simulate_recording` writes);
    ``plan``: the scenario's commanded poses/elongations, options and extras; ``truth``: the
    truth model (parameters, bound effects); ``output``: true, base and measured forces;
    ``length`` (N,m) IK cable length [m], ``elongation`` (N,m) x = length - motor_length [m]
    (what the truth model was given), ``wrap_angle`` (N,m) [rad], ``free_length`` (N,m) [m].
    """

    recording: Recording
    plan: ScenarioPlan
    truth: TruthModel
    output: TruthOutput
    length: np.ndarray
    elongation: np.ndarray
    wrap_angle: np.ndarray
    free_length: np.ndarray


def _robot(robot: Union[Robot, str, "os.PathLike[str]"]) -> Robot:
    return robot if isinstance(robot, Robot) else load_robot(robot)


def _call_scenario(name: str, ctx: ScenarioContext, kwargs: dict[str, Any]) -> ScenarioPlan:
    fn = SCENARIOS[name]
    accepted = [p for p in inspect.signature(fn).parameters if p != "ctx"]
    unknown = sorted(set(kwargs) - set(accepted))
    if unknown:
        raise SimulationError(f"scenario {name}: unknown option(s) {unknown}; options: {', '.join(accepted)}")
    try:
        return fn(ctx, **kwargs)
    except (TypeError, ValueError) as e:
        if isinstance(e, SimulationError):
            raise SimulationError(f"scenario {name}: {e}") from None
        raise SimulationError(f"scenario {name}: bad option value: {e}") from None


def simulate_twin(robot: Union[Robot, str, "os.PathLike[str]"], scenario: str, *,
                  truth: Optional[TruthConfig] = None, duration: Optional[float] = None, rate: float = 1000.0,
                  seed: int = 0, ambient: Optional[Ambient] = None, **scenario_kwargs: Any) -> TwinRun:
    """Run ``scenario`` on ``robot`` (a :class:`Robot`, a robot name or a .toml path).

    ``truth``: how forces are made (default :class:`TruthConfig`: nominal amplitude model,
    no effects, 0.1 N noise); ``duration`` [s] (None: the scenario's default; the hold
    scenarios then run one pass of their amplitude levels); ``rate`` [Hz]; ``seed``;
    ``ambient`` the temperature profile; further keywords are the scenario's options.
    """
    if scenario not in SCENARIOS:
        raise SimulationError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
        raise SimulationError(f"rate must be > 0 Hz, got {rate!r}")
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise SimulationError(f"duration must be > 0 s, got {duration!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"seed must be an integer >= 0, got {seed!r}")
    seed = int(seed)
    truth = truth if truth is not None else TruthConfig()
    rob = _robot(robot)
    geom = rob.geometry()
    tm = TruthModel(truth, geom, home_lengths(geom))
    tm.check_effects()
    ctx = ScenarioContext(geom=geom, rate=float(rate), duration=duration,
                          rng=np.random.default_rng([seed, 1]), elastic=tm.elastic)
    plan = _call_scenario(scenario, ctx, dict(scenario_kwargs))

    ik = inverse_kinematics(geom, plan.position, plan.orientation)
    length = ik.length
    motor_length = length - plan.elongation
    x = length - motor_length
    temperature = (ambient or Ambient()).profile(plan.t, np.random.default_rng([seed, 2]))
    noise_seed = seed if truth.seed is None else int(truth.seed)
    out = tm.run(t=plan.t, dt=1.0 / float(rate), elongation=x, motor_length=motor_length,
                 wrap_angle=ik.wrap_angle, free_length=ik.free_length, temperature=temperature,
                 rng=np.random.default_rng([noise_seed, 3]))
    truth_doc = {"notice": TRUTH_NOTICE, **tm.describe(), "noise_seed": noise_seed}
    metadata = {
        "generator": "cablesvc.simulate",
        "scenario": scenario,
        "seed": str(seed),
        "rate": repr(float(rate)),
        "scenario_params": json.dumps(jsonable(plan.params), sort_keys=True),
        "truth": json.dumps(jsonable(truth_doc), sort_keys=True),
    }
    N = plan.t.shape[0]
    rec = Recording(robot=rob.name, metadata=metadata, t=plan.t, seq=np.arange(N, dtype=np.int64),
                    motor_length=motor_length, position=plan.position, orientation=plan.orientation,
                    force=out.measured, temperature=temperature)
    return TwinRun(recording=rec, plan=plan, truth=tm, output=out, length=length, elongation=x,
                   wrap_angle=ik.wrap_angle, free_length=ik.free_length)


def simulate_recording(robot: Union[Robot, str, "os.PathLike[str]"], scenario: str,
                       out: Optional[Union[str, "os.PathLike[str]"]] = None, *,
                       truth: Optional[TruthConfig] = None, duration: Optional[float] = None, rate: float = 1000.0,
                       seed: int = 0, ambient: Optional[Ambient] = None, encoding: Optional[str] = None,
                       **scenario_kwargs: Any) -> Recording:
    """Simulate ``scenario`` on ``robot`` and return the :class:`Recording`; when ``out`` is
    given also write it there (``.mcap`` or ``.csv`` by suffix; ``encoding``: the MCAP input
    encoding, ``"protobuf"`` by default or ``"json"``, see ``write_recording``). Arguments as
    :func:`simulate_twin`. The metadata key ``truth`` holds the answer key for benchmarks
    (see the module docstring): tools under test must not read it."""
    if out is not None and Path(out).suffix.lower() not in (".mcap", ".csv"):
        raise SimulationError(f"{out}: output must end in .mcap or .csv")
    run = simulate_twin(robot, scenario, truth=truth, duration=duration, rate=rate, seed=seed, ambient=ambient,
                        **scenario_kwargs)
    if out is not None:
        write_recording(out, run.recording, encoding=encoding)
    return run.recording
