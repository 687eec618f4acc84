"""Quaternions and rotation matrices, vectorised over any leading batch shape.

Quaternions are stored as ``[qx, qy, qz, qw]`` (ROS / scipy order, scalar last) and
describe the rotation R of the platform frame into the world frame (R b_i in eq 1 of 002).
Rotation vectors are axis * angle in rad. All functions are pure numpy.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "QUAT_OUTER_TO_MATRIX",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_multiply",
    "quat_conjugate",
    "rotvec_to_quat",
    "quat_to_rotvec",
    "quat_angle",
]


def _outer_to_matrix() -> np.ndarray:
    """Constant (16, 9) map from the outer product q q^T (flattened, index 4k+l with
    q = [x, y, z, w]) to the flattened rotation matrix times |q|^2 (unitless)."""
    x, y, z, w = range(4)
    T = np.zeros((4, 4, 3, 3))

    def put(i: int, j: int, terms: list[tuple[float, int, int]]) -> None:
        """Add coefficient c of q_k q_l to entry R_ij (unitless)."""
        for c, k, l in terms:
            T[k, l, i, j] += c

    # homogeneous form: R * |q|^2, exact for any non-zero q
    put(0, 0, [(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)])
    put(1, 1, [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)])
    put(2, 2, [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)])
    put(0, 1, [(2, x, y), (-2, w, z)])
    put(1, 0, [(2, x, y), (2, w, z)])
    put(0, 2, [(2, x, z), (2, w, y)])
    put(2, 0, [(2, x, z), (-2, w, y)])
    put(1, 2, [(2, y, z), (-2, w, x)])
    put(2, 1, [(2, y, z), (2, w, x)])
    T = T.reshape(16, 9)
    T.setflags(write=False)
    return T


#: (16, 9): flattened q q^T  ->  flattened |q|^2 R(q/|q|). Used by the allocation-free IK.
QUAT_OUTER_TO_MATRIX = _outer_to_matrix()


def quat_to_matrix(q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Rotation matrix of quaternion(s) ``q`` (..., 4) [x, y, z, w] -> (..., 3, 3), unitless.

    ``q`` need not be unit: the homogeneous formula R = (q q^T mapped) / |q|^2 normalises it.
    A zero quaternion gives NaN.
    """
    q = np.asarray(q, dtype=np.float64)
    lead = q.shape[:-1]
    outer = (q[..., :, None] * q[..., None, :]).reshape(lead + (16,))
    r9 = outer @ QUAT_OUTER_TO_MATRIX
    r9 /= np.einsum("...k,...k->...", q, q)[..., None]
    if out is None:
        return r9.reshape(lead + (3, 3))
    out[...] = r9.reshape(lead + (3, 3))
    return out


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) [x, y, z, w] with w >= 0 of rotation matrices ``R`` (..., 3, 3).

    Shepperd's method: the largest of 4w^2, 4x^2, 4y^2, 4z^2 picks the well-conditioned
    branch, so it is accurate for every rotation (including 180 deg).
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack(
        [
            # rows: 4*[x, y, z, w] * (component chosen), one row per branch
            np.stack([1 + m00 - m11 - m22, R[..., 0, 1] + R[..., 1, 0],
                      R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] - R[..., 1, 2]], -1),
            np.stack([R[..., 0, 1] + R[..., 1, 0], 1 - m00 + m11 - m22,
                      R[..., 1, 2] + R[..., 2, 1], R[..., 0, 2] - R[..., 2, 0]], -1),
            np.stack([R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1],
                      1 - m00 - m11 + m22, R[..., 1, 0] - R[..., 0, 1]], -1),
            np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                      R[..., 1, 0] - R[..., 0, 1], 1 + tr], -1),
        ],
        axis=-2,
    )  # (..., 4, 4)
    diag = np.stack([1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + tr], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product q1 * q2 of quaternions [x, y, z, w] (..., 4); R(q1 q2) = R(q1) R(q2)."""
    q1 = np.asarray(q1, dtype=np.float64)
    q2 = np.asarray(q2, dtype=np.float64)
    x1, y1, z1, w1 = np.moveaxis(q1, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(q2, -1, 0)
    return np.stack(
        [
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate [-x, -y, -z, w] (the inverse rotation for a unit quaternion), (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def rotvec_to_quat(v: np.ndarray) -> np.ndarray:
    """Unit quaternion [x, y, z, w] of rotation vector(s) ``v`` (..., 3) [rad] (axis * angle).

    Uses sin(theta/2)/theta = 0.5 * sinc(theta / (2 pi)), exact and finite at theta = 0,
    which makes it suitable for the small-angle pose updates of forward kinematics.
    """
    v = np.asarray(v, dtype=np.float64)
    theta = np.sqrt(np.einsum("...k,...k->...", v, v))
    s = 0.5 * np.sinc(theta / (2.0 * np.pi))
    return np.concatenate([v * s[..., None], np.cos(0.5 * theta)[..., None]], axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector(s) [rad] (..., 3) of quaternion(s) [x, y, z, w]; angle in [0, pi]."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:4] < 0, -q, q)
    vn = np.linalg.norm(q[..., :3], axis=-1)
    theta = 2.0 * np.arctan2(vn, q[..., 3])
    # theta / sin(theta/2) with sin(theta/2) = vn; finite limit 2 at theta -> 0
    scale = np.where(vn > 1e-300, theta / np.where(vn > 1e-300, vn, 1.0), 2.0)
    return q[..., :3] * scale[..., None]


def quat_angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Angle [rad] in [0, pi] of the rotation between orientations q1 and q2 (..., 4)."""
    q1 = np.asarray(q1, dtype=np.float64)
    q2 = np.asarray(q2, dtype=np.float64)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    q2 = q2 / np.linalg.norm(q2, axis=-1, keepdims=True)
    rel = quat_multiply(quat_conjugate(q1), q2)
    vn = np.linalg.norm(rel[..., :3], axis=-1)
    return 2.0 * np.arctan2(vn, np.abs(rel[..., 3]))
