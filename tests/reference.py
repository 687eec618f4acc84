"""What the live daemon must publish, computed offline: the kernel run over a recording.

Shared by the end-to-end tests (tests/test_daemon.py, test_faults.py, test_fleet.py): a
subscriber's forces are compared with these, tick by tick (seq), to relative 1e-9."""

from __future__ import annotations

import numpy as np

from cablesvc.config.params import nominal_params
from cablesvc.config import load_robot
from cablesvc.kernel import Predictor


def offline_forces(rec, robot: str = "ipanema3", params=None, skip=frozenset()) -> dict[int, np.ndarray]:
    """seq -> predicted forces [N] of the kernel run offline over the recording's inputs,
    with ``params`` (default: the nominal parameters ``cablesvc run`` uses); ticks at
    the row indices in ``skip`` are left out, as the daemon leaves out rejected ticks."""
    geom = load_robot(robot).geometry()
    pred = Predictor(geom, params or nominal_params(geom))
    res = {}
    for k in range(rec.n_ticks):
        if k in skip:
            continue
        out = pred.tick(float(rec.t[k]), rec.motor_length[k],
                        None if rec.position is None else rec.position[k],
                        None if rec.orientation is None else rec.orientation[k],
                        None if rec.force is None else rec.force[k],
                        None if rec.temperature is None else float(rec.temperature[k]))
        res[int(rec.seq[k])] = out.force.copy()
    return res


def assert_matches_offline(forces: list[dict], offline: dict[int, np.ndarray]) -> int:
    """Every received forces payload equals the offline kernel's at its seq (relative
    1e-9); returns how many were checked."""
    for msg in forces:
        ref = offline[msg["seq"]]
        np.testing.assert_allclose(np.array(msg["force"], float), ref, rtol=1e-9, atol=1e-9 * np.max(np.abs(ref)),
                                   err_msg=f"seq {msg['seq']}")
    return len(forces)
