"""Forward kinematics: platform pose from measured cable lengths, fixed time.

Solves  min_pose || L(pose) - L_measured ||^2  where L is the pulley-aware inverse
kinematics of :mod:`cablesvc.kinematics.ik` (eq 1 of paper 002 plus the pulley model),
with Levenberg-Marquardt steps and a FIXED number of iterations (no early exit, no
step rejection), warm-started from the last pose.

Jacobian: analytic. Because the free cable segment is tangent to the pulley wheel, the
derivative of the geometric length with respect to the platform anchor is -u_i, so for a
position increment dr and a small world-frame rotation vector dtheta (R <- exp(dtheta) R)

    dL_i = -u_i . dr - ((R b_i) x u_i) . dtheta,     i.e.  J = -A  (A^T of eq 2 of 002).

Step:  (J^T J + damping * diag(J^T J) + 1e-12 I) delta = -J^T (L - L_measured);
pose update: position += delta[:3], q <- rotvec_to_quat(delta[3:]) * q (then normalised).
Planar robots solve only x, y and yaw (columns 0, 1, 5); z, roll and pitch stay as given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics.ik import InverseKinematics
from cablesvc.kinematics.rotation import quat_multiply, rotvec_to_quat

__all__ = ["FKResult", "ForwardKinematics"]


@dataclass(frozen=True)
class FKResult:
    """Forward-kinematics result for N poses (fresh arrays).

    ``position`` (N,3) [m]; ``orientation`` (N,4) unit [qx,qy,qz,qw]; ``residual`` (N,m) [m]
    = L(solved pose) - measured lengths; ``residual_rms`` (N,) [m] = RMS of ``residual``.
    """

    position: np.ndarray
    orientation: np.ndarray
    residual_rms: np.ndarray
    residual: np.ndarray


class ForwardKinematics:
    """Fixed-iteration Levenberg-Marquardt forward kinematics (analytic Jacobian J = -A).

    ``geom``: the robot; ``iterations``: LM steps per solve (always all of them);
    ``damping``: Marquardt factor lambda (unitless) scaling diag(J^T J).
    """

    def __init__(self, geom: RobotGeometry, iterations: int = 8, damping: float = 1e-6):
        if iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        if not damping >= 0.0:
            raise ValueError(f"damping must be >= 0, got {damping}")
        self.geom = geom
        self.iterations = int(iterations)
        self.damping = float(damping)
        self.planar = bool(geom.planar)
        self._dofs = np.array([0, 1, 5]) if self.planar else np.arange(6)
        self._ik: dict[int, InverseKinematics] = {}

    def _ik_for(self, batch: int) -> InverseKinematics:
        """The cached :class:`InverseKinematics` for ``batch`` poses (built on first use)."""
        ik = self._ik.get(batch)
        if ik is None:
            ik = self._ik[batch] = InverseKinematics(self.geom, batch)
        return ik

    def solve(
        self, lengths: np.ndarray, position0: np.ndarray, orientation0: np.ndarray
    ) -> FKResult:
        """Pose whose IK lengths match ``lengths`` (N,m) [m], starting from ``position0``
        (N,3) [m] and ``orientation0`` (N,4) [qx,qy,qz,qw] (e.g. the last solution).
        Runs exactly ``iterations`` LM steps plus one final IK for the residual."""
        lengths = np.asarray(lengths, dtype=np.float64)
        N, m = lengths.shape
        if m != self.geom.n_cables:
            raise ValueError(
                f"lengths has {m} cables, robot {self.geom.name} has {self.geom.n_cables}"
            )
        p = np.array(position0, dtype=np.float64).reshape(N, 3)
        q = np.array(orientation0, dtype=np.float64).reshape(N, 4)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        ik = self._ik_for(N)
        dofs = self._dofs
        n = dofs.size
        J = np.empty((N, m, 6))
        eye = np.eye(n)
        for _ in range(self.iterations):  # fixed count, no early exit
            st = ik(p, q)
            res = st.length - lengths
            AT = ik.structure_matrix()  # (N,6,m)
            np.negative(AT.transpose(0, 2, 1), out=J)
            Jr = J[:, :, dofs]
            JtJ = np.einsum("bmi,bmj->bij", Jr, Jr)
            g = np.einsum("bmi,bm->bi", Jr, res)
            diag = np.einsum("bii->bi", JtJ)
            A = JtJ + (self.damping * diag)[:, :, None] * eye + 1e-12 * eye
            delta = -np.linalg.solve(A, g[:, :, None])[:, :, 0]
            full = np.zeros((N, 6))
            full[:, dofs] = delta
            p += full[:, :3]
            q = quat_multiply(rotvec_to_quat(full[:, 3:]), q)
            q /= np.linalg.norm(q, axis=1, keepdims=True)
        st = ik(p, q)
        res = st.length - lengths
        rms = np.sqrt(np.mean(res * res, axis=1))
        return FKResult(position=p, orientation=q, residual_rms=rms, residual=res.copy())
