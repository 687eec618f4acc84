"""Offline identification of cable-model parameters from recordings.

scipy.optimize style: functions take arrays and return an :class:`IdentifyResult`
(a dict with attribute access: ``x, fun, nfev, nit, success, message, names, history`` and,
where computed, ``jac, residual, stderr, correlation, cond, method``).

* :func:`pso` - particle swarm of paper 000 Sec 5 (eqs 25-27), one batched objective
  call per iteration; :func:`normalized_mse` is its objective (eq 25);
  :func:`pso_lockstep` runs one swarm per cable with one call for all of them.
* :func:`refine` - least squares / Levenberg-Marquardt (002 eqs 12-14) with standard
  errors and correlations; :func:`track` warm-starts it for periodic re-identification;
  :func:`multistart_sqp` - constrained multi-start SQP of 001 Ch 5.
* :mod:`cablesvc.identify.identifiability` - correlation, condition number, redundant
  parameter groups, sensitivity of 002 eq 11.
* :func:`identify_cable` (:mod:`cablesvc.identify.cable`) - cable models from
  recordings; :mod:`cablesvc.identify.amplitude_fit` - the fits of 002 Sec 3 that build
  the amplitude model's tables (levels and per-level fits in
  :mod:`~cablesvc.identify.amplitude_levels`, the amplitude functions f_A in
  :mod:`~cablesvc.identify.amplitude_joint`); :mod:`cablesvc.identify.bounds` - the one
  reader of parameter bounds; :mod:`cablesvc.identify.report` -
  Markdown + PNG report. (Imported on first use.)
"""

from cablesvc.identify.identifiability import jacobian_statistics, redundant_groups, sensitivity
from cablesvc.identify.local import meshpoint_constraint, multistart_sqp, refine, track
from cablesvc.identify.pso import normalized_mse, pso, pso_lockstep
from cablesvc.identify.result import IdentifyResult

__all__ = [
    "IdentifyResult", "pso", "pso_lockstep", "normalized_mse", "refine", "track", "multistart_sqp",
    "meshpoint_constraint", "jacobian_statistics", "redundant_groups", "sensitivity",
    "identify_cable", "CableFit", "fit_amplitude_model", "write_report",
]

_LAZY = {"identify_cable": "cablesvc.identify.cable", "CableFit": "cablesvc.identify.cable",
         "fit_amplitude_model": "cablesvc.identify.amplitude_fit", "write_report": "cablesvc.identify.report"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'cablesvc.identify' has no attribute {name!r}")
