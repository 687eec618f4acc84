"""Inverse/forward kinematics, pulleys, structure matrix (pure numpy, SI units).

Quaternions are [qx, qy, qz, qw] (ROS order). See :mod:`cablesvc.kinematics.ik` for the
pulley model and eq 1 / eq 2 of paper 002.
"""

from cablesvc.kinematics.fk import FKResult, ForwardKinematics
from cablesvc.kinematics.ik import (
    PLANAR_WRENCH_ROWS,
    IKState,
    InverseKinematics,
    inverse_kinematics,
    platform_wrench,
    structure_matrix,
    wrench_residual,
)
from cablesvc.kinematics.rotation import (
    matrix_to_quat,
    quat_angle,
    quat_conjugate,
    quat_multiply,
    quat_to_matrix,
    quat_to_rotvec,
    rotvec_to_quat,
)

__all__ = [
    "FKResult",
    "ForwardKinematics",
    "IKState",
    "InverseKinematics",
    "PLANAR_WRENCH_ROWS",
    "inverse_kinematics",
    "matrix_to_quat",
    "platform_wrench",
    "quat_angle",
    "quat_conjugate",
    "quat_multiply",
    "quat_to_matrix",
    "quat_to_rotvec",
    "rotvec_to_quat",
    "structure_matrix",
    "wrench_residual",
]
