"""Digital twin: recordings a real controller would log, from a truth model with switchable physics.

``cablesvc simulate --robot R --scenario S --out rec.mcap`` calls :func:`simulate_recording`.

* :mod:`~cablesvc.simulate.scenarios`: what the robot does (:data:`SCENARIOS`: ``hold-sine``,
  ``hold-triangle``, ``hold-trapezoid`` as in the experiment of 002 Sec 4, ``trajectory``).
* :mod:`~cablesvc.simulate.truth`: how the measured forces are made (:class:`TruthConfig`:
  base cable model, extra physics, sensor noise); :mod:`~cablesvc.simulate.effects` the
  extra physics :data:`EFFECTS` ``pulley``, ``creep``, ``temperature``, ``viscous``,
  ``deadtime``, ``sag``, ``offset_gain``; :mod:`~cablesvc.simulate.elastic` the base
  model's elastic curve the twin's controller inverts.
* :mod:`~cablesvc.simulate.twin`: runs them and builds the :class:`~cablesvc.recording.Recording`;
  its metadata key ``truth`` is the benchmark's answer key, which tools under test must not read.

Example::

    from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording
    truth = TruthConfig(effects=[effect_from_spec("pulley:0.02@2,5")], noise_std=0.1)
    rec = simulate_recording("ipanema3", "trajectory", "traj.mcap", truth=truth, duration=30, seed=1)
"""

from cablesvc.errors import SimulationError
from cablesvc.simulate.effects import (
    EFFECTS,
    Creep,
    Deadtime,
    Effect,
    OffsetGain,
    Pulley,
    Sag,
    Temperature,
    Viscous,
    effect_from_spec,
    list_effects,
)
from cablesvc.simulate.elastic import ElasticCurve
from cablesvc.simulate.scenarios import (
    DEFAULT_AMPLITUDES,
    SCENARIOS,
    ScenarioContext,
    ScenarioPlan,
    tension_distribution,
)
from cablesvc.simulate.truth import TruthConfig, TruthModel, TruthOutput
from cablesvc.simulate.twin import TRUTH_NOTICE, Ambient, TwinRun, simulate_recording, simulate_twin

__all__ = [
    "Ambient", "Creep", "DEFAULT_AMPLITUDES", "Deadtime", "EFFECTS", "Effect", "ElasticCurve", "OffsetGain",
    "Pulley", "SCENARIOS", "Sag", "ScenarioContext", "ScenarioPlan", "SimulationError", "TRUTH_NOTICE",
    "Temperature", "TruthConfig", "TruthModel", "TruthOutput", "TwinRun", "Viscous", "effect_from_spec",
    "list_effects", "simulate_recording", "simulate_twin", "tension_distribution",
]
