"""Hysteretic geometrically exact beam of paper 000 (eqs 6-24, 28-29) for short wire ropes:
quasi-static FE solver batched over parameter sets, PSO identification, the bridge to
the lumped Bouc-Wen cable model. See docs/beam.md."""

from cablesvc.beam.solver import (  # noqa: F401
    MODES, OMEGA, PARAM_NAMES, ROPE_7x7, ROPE_7x19, TABLE3, TABLE4, TABLE6, BeamParams, Loop, PathResult, Section,
    SolverOptions, loop_path, solve_path, stabilised_loop,
)
