"""Fleets: ``cablesvc discover`` and ``cablesvc identify`` over many recordings, on Dask.

A fleet's nightly logs (several paths, a directory or a glob) run as one job per recording
on Dask distributed: a ``LocalCluster`` on this machine by default, or an existing cluster
(``--scheduler tcp://host:8786``). Each worker reads its own recordings (paths go through
the scheduler, never arrays); the result is one row per recording and a fleet summary
(which robots and cables drift, which effects, since when), the same numbers as a serial
run. See docs/cluster.md.

* :mod:`~cablesvc.batch.inputs`: paths, directories and globs -> recordings;
* :mod:`~cablesvc.batch.jobs`: one recording's job (what a worker runs) and its row;
* :mod:`~cablesvc.batch.run`: serial or Dask execution, :class:`FleetResult`;
* :mod:`~cablesvc.batch.summary`: the fleet summary;
* :mod:`~cablesvc.batch.report`: ``fleet.json`` and ``index.html``;
* :mod:`~cablesvc.batch.cli`: the command-line side.

(Not :mod:`cablesvc.service.fleet`, which runs several robots live in one daemon.)
"""

from cablesvc.batch.inputs import FleetInputError, expand_recordings
from cablesvc.batch.run import FleetEngineError, FleetResult, comparable, run_fleet, run_on_dask, run_serial

__all__ = ["FleetEngineError", "FleetInputError", "FleetResult", "comparable", "expand_recordings", "run_fleet",
           "run_on_dask", "run_serial"]
