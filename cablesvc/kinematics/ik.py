"""Inverse kinematics with swivelling redirection pulleys, structure matrix and wrenches.

Units are SI throughout (m, rad, N, N m). Poses are a platform position r (m, world frame)
and an orientation quaternion [qx, qy, qz, qw] (ROS order) giving the rotation R of the
platform frame into the world frame.

Straight cables (no pulley) follow eq 1 of paper 002: l_i = a_i - (r + R b_i), length
|l_i|, unit vector u_i = l_i / |l_i| pointing from the platform anchor to the frame.

Cables with a redirection pulley (the "extended kinematic model" mentioned in 002, Sec 2)
use this model. The pulley swivels about a fixed axis through its entry point C with unit
direction e; the cable arrives from the winch along +e and touches the wheel groove at C,
so the wheel (radius r) is tangent to the axis line at C. Work in the plane spanned by e and
the horizontal direction x' toward the platform anchor B = r + R b_i:

    d      = B - C,   d_perp = d - (d.e) e,   x' = d_perp / |d_perp|
    M      = C + r x'                          (wheel centre)
    v      = B - M,   vx = d.x' - r,   vz = d.e
    lf     = sqrt(vx^2 + vz^2 - r^2)           (free length: tangent from B to the wheel)
    alpha  = atan2(vx, vz) + atan2(r, lf)      (wrap angle, folded into [0, 2 pi))
    P      = M + r (-cos(alpha) x' + sin(alpha) e)   (leave point)
    length = lf + r alpha                     (arc on the wheel from C, plus free segment)
    u      = (P - B) / lf = -(sin(alpha) x' + cos(alpha) e)

Derivation: in (x', e) coordinates with origin C the wheel is centred at (r, 0); the point
at wrap angle phi is M + r(-cos phi, sin phi), which is C at phi = 0 with direction of
travel +e there (so the cable coming along +e runs onto the wheel smoothly). The cable
leaves at phi = alpha along the tangent (sin alpha, cos alpha), so
B - M = r(-cos alpha, sin alpha) + lf (sin alpha, cos alpha). Its norm gives
|v|^2 = r^2 + lf^2; writing lf = rho cos delta, r = rho sin delta gives
v = rho (sin(alpha - delta), cos(alpha - delta)), hence alpha = atan2(vx, vz) + delta with
delta = atan2(r, lf). The free segment is tangent at P: (P - M).(B - P) = 0, and therefore
d length / d B = -u (the arc change cancels the change of the leave point), which the FK
Jacobian uses. For r = 0 the model reduces exactly to eq 1 (alpha is then just the cable
direction angle; it is reported as 0 because there is no pulley).

Guards (fixed time, no branches): x' is computed from d_perp + EPS_SWIVEL * ref, with ref a
fixed unit direction perpendicular to e per cable, so an anchor on the swivel axis gives
x' = ref instead of NaN (bias at most EPS_SWIVEL / |d_perp| rad elsewhere); lf^2 is clamped
at 0 (anchor inside the wheel); alpha is folded with a 1e-9 rad tolerance so that round-off
just below 0 gives 0 and not 2 pi.

The structure matrix is A^T of eq 2 of 002: A^T f + w = 0 at static equilibrium.
"""

from __future__ import annotations

import numpy as np

from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics.rotation import QUAT_OUTER_TO_MATRIX

__all__ = [
    "EPS_SWIVEL",
    "PLANAR_WRENCH_ROWS",
    "IKState",
    "InverseKinematics",
    "inverse_kinematics",
    "structure_matrix",
    "platform_wrench",
    "wrench_residual",
]

#: m; size of the fixed reference direction added to d_perp before normalising.
EPS_SWIVEL = 1e-12
#: rad; round-off tolerance of the wrap-angle fold into [0, 2 pi).
_FOLD_TOL = 1e-9
_TWO_PI = 2.0 * np.pi
#: Rows of a wrench (fx, fy, fz, mx, my, mz) that are meaningful for planar robots.
PLANAR_WRENCH_ROWS = (0, 1, 5)


class IKState:
    """Result of inverse kinematics for a batch of N poses and m cables (SI units).

    Attributes (owned by the :class:`InverseKinematics` that produced them and overwritten
    by its next call; use :meth:`copy` to keep them):

    - ``length`` (N,m) [m]: geometric cable length: arc r*alpha on the pulley from the entry
      point C plus the free segment; without pulley |a_i - (r + R b_i)| (eq 1 of 002).
    - ``free_length`` (N,m) [m]: free segment from the leave point to the platform anchor.
    - ``unit`` (N,m,3): unit vector at the platform anchor toward the leave point (u_i, eq 2).
    - ``wrap_angle`` (N,m) [rad] in [0, 2 pi): arc of the wheel wrapped; 0 without pulley.
    - ``anchor_world`` (N,m,3) [m]: R b_i, platform anchor relative to the platform origin,
      world frame.
    - ``leave_point`` (N,m,3) [m]: where the cable leaves the wheel (C without pulley).
    - ``swivel_angle`` (N,m) [rad] in (-pi, pi]: rotation of the wheel plane about e, from
      the cable's fixed reference direction; 0 without pulley.
    - ``rotation`` (N,3,3): platform rotation matrix R.
    """

    __slots__ = (
        "length",
        "free_length",
        "unit",
        "wrap_angle",
        "anchor_world",
        "leave_point",
        "swivel_angle",
        "rotation",
    )

    def __init__(self, **arrays: np.ndarray):
        for k in self.__slots__:
            setattr(self, k, arrays[k])

    def copy(self) -> "IKState":
        """Independent deep copy (fresh arrays)."""
        return IKState(**{k: getattr(self, k).copy() for k in self.__slots__})


def _swivel_reference(geom: RobotGeometry, e: np.ndarray) -> np.ndarray:
    """Fixed unit reference direction perpendicular to e per cable (unitless): the direction
    from the pulley entry point toward the centroid of the frame anchors, projected
    perpendicular to e; if that is degenerate, the coordinate axis least aligned with e,
    projected."""
    centroid = geom.frame_anchors.mean(axis=0)
    ref = np.empty_like(e)
    for i in range(e.shape[0]):  # construction time only
        cand = centroid - geom.pulley_center[i]
        cand = cand - cand.dot(e[i]) * e[i]
        if np.linalg.norm(cand) < 1e-9:
            cand = np.eye(3)[int(np.argmin(np.abs(e[i])))]
            cand = cand - cand.dot(e[i]) * e[i]
        ref[i] = cand / np.linalg.norm(cand)
    return ref


class InverseKinematics:
    """Pulley-aware inverse kinematics for a fixed batch size, allocation-free per call.

    ``geom``: the robot; ``batch``: number N of poses per call. All work arrays are
    allocated here; :meth:`__call__` only runs numpy ufuncs/einsum/matmul with ``out=`` on
    them (no Python loops over cables or poses, no data-dependent branches), so it runs in
    fixed time and does not allocate array memory.
    """

    def __init__(self, geom: RobotGeometry, batch: int):
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.geom = geom
        self.batch = N = int(batch)
        self.n_cables = m = int(geom.n_cables)
        f8 = np.float64

        # constants per cable
        self._b = np.array(geom.platform_anchors, dtype=f8)
        self._C = np.array(geom.pulley_center, dtype=f8)
        self._mask = np.array(geom.has_pulley, dtype=f8)
        self._r = np.array(geom.pulley_radius, dtype=f8) * self._mask
        self._r2 = self._r * self._r
        e = np.array(geom.pulley_axis, dtype=f8)
        e[~np.asarray(geom.has_pulley)] = (0.0, 0.0, 1.0)  # straight cables: any unit e
        self._e = e
        ref = _swivel_reference(geom, e)
        self._ref = ref
        self._eps_ref = EPS_SWIVEL * ref
        self._s2 = np.cross(e, ref)
        self._T = np.array(QUAT_OUTER_TO_MATRIX)

        # work arrays
        self._q = np.zeros((N, 4))
        self._q_col = self._q[:, :, None]
        self._q_row = self._q[:, None, :]
        self._QQ = np.zeros((N, 4, 4))
        self._QQ16 = self._QQ.reshape(N, 16)
        self._n2 = np.zeros(N)
        self._n2_col = self._n2[:, None]
        self.rotation = np.zeros((N, 3, 3))
        self._R9 = self.rotation.reshape(N, 9)
        self._pos = np.zeros((N, 3))
        self._pos_v = self._pos[:, None, :]

        self._d = np.zeros((N, m, 3))
        self._xp = np.zeros((N, m, 3))
        self._t3 = np.zeros((N, m, 3))
        self._de = np.zeros((N, m))
        self._de_v = self._de[..., None]
        self._ns = np.zeros((N, m))
        self._ns_v = self._ns[..., None]
        self._vx = np.zeros((N, m))
        self._t1 = np.zeros((N, m))
        self._t1_v = self._t1[..., None]
        self._t2 = np.zeros((N, m))
        self._alpha = np.zeros((N, m))
        self._ca = np.zeros((N, m))
        self._ca_v = self._ca[..., None]
        self._sa = np.zeros((N, m))
        self._sa_v = self._sa[..., None]

        # outputs
        self.length = np.zeros((N, m))
        self.free_length = np.zeros((N, m))
        self.unit = np.zeros((N, m, 3))
        self.wrap_angle = np.zeros((N, m))
        self.anchor_world = np.zeros((N, m, 3))
        self.leave_point = np.zeros((N, m, 3))
        self.swivel_angle = np.zeros((N, m))
        self.state = IKState(
            length=self.length,
            free_length=self.free_length,
            unit=self.unit,
            wrap_angle=self.wrap_angle,
            anchor_world=self.anchor_world,
            leave_point=self.leave_point,
            swivel_angle=self.swivel_angle,
            rotation=self.rotation,
        )
        # structure matrix / wrench buffers
        self.AT = np.zeros((N, 6, m))
        self._AT_work = np.zeros((N, m))
        self.wrench = np.zeros((N, 6))
        self._w_work = np.zeros((N, 3))
        self._wrench_moment = self.wrench[:, 3:6]
        mg = np.asarray(geom.gravity, dtype=f8) * float(geom.mass)
        self.wrench[:, 0:3] = mg  # constant force part
        self._S = _moment_matrix(mg)
        self._cog = np.array(geom.center_of_gravity, dtype=f8)

    def __call__(self, position: np.ndarray, orientation: np.ndarray) -> IKState:
        """Cable lengths etc. for N poses: ``position`` (N,3) [m], ``orientation`` (N,4)
        [qx,qy,qz,qw] (any non-zero norm; normalised). Implements eq 1 of 002 with the pulley
        model of this module. Returns :attr:`state`, whose arrays are overwritten next call.
        """
        N = self.batch
        if np.shape(position) != (N, 3) or np.shape(orientation) != (N, 4):
            raise ValueError(
                f"expected position ({N}, 3) and orientation ({N}, 4), got "
                f"{np.shape(position)} and {np.shape(orientation)}"
            )
        q, QQ, R9, n2 = self._q, self._QQ, self._R9, self._n2
        d, xp, t3 = self._d, self._xp, self._t3
        de, ns, vx, t1, t2 = self._de, self._ns, self._vx, self._t1, self._t2
        alpha, ca, sa = self._alpha, self._ca, self._sa
        C, e, r = self._C, self._e, self._r

        # rotation matrix R = (q q^T mapped) / |q|^2
        np.copyto(q, orientation)
        np.multiply(self._q_col, self._q_row, out=QQ)
        np.matmul(self._QQ16, self._T, out=R9)
        np.einsum("bk,bk->b", q, q, out=n2)
        np.divide(R9, self._n2_col, out=R9)

        # anchor_world = R b ; d = r + R b - C
        np.copyto(self._pos, position)
        np.einsum("bij,mj->bmi", self.rotation, self._b, out=self.anchor_world)
        np.add(self.anchor_world, self._pos_v, out=d)
        np.subtract(d, C, out=d)

        # x' = (d_perp + eps ref) / |.|
        np.einsum("bmk,mk->bm", d, e, out=de)
        np.multiply(self._de_v, e, out=t3)
        np.subtract(d, t3, out=xp)
        np.add(xp, self._eps_ref, out=xp)
        np.einsum("bmk,bmk->bm", xp, xp, out=ns)
        np.add(ns, 1e-300, out=ns)
        np.sqrt(ns, out=ns)
        np.divide(xp, self._ns_v, out=xp)

        # vx = d.x' - r ; vz = d.e ; lf = sqrt(vx^2 + vz^2 - r^2)
        np.einsum("bmk,bmk->bm", d, xp, out=vx)
        np.subtract(vx, r, out=vx)
        lf = self.free_length
        np.multiply(vx, vx, out=lf)
        np.multiply(de, de, out=t1)
        np.add(lf, t1, out=lf)
        np.subtract(lf, self._r2, out=lf)
        np.maximum(lf, 0.0, out=lf)
        np.sqrt(lf, out=lf)

        # alpha = atan2(vx, vz) + atan2(r, lf)
        np.arctan2(vx, de, out=alpha)
        np.arctan2(r, lf, out=t1)
        np.add(alpha, t1, out=alpha)
        np.cos(alpha, out=ca)
        np.sin(alpha, out=sa)
        wa = self.wrap_angle
        np.add(alpha, _FOLD_TOL, out=wa)
        np.mod(wa, _TWO_PI, out=wa)
        np.subtract(wa, _FOLD_TOL, out=wa)
        np.maximum(wa, 0.0, out=wa)
        np.multiply(wa, self._mask, out=wa)

        # length = lf + r alpha
        np.multiply(wa, r, out=self.length)
        np.add(self.length, lf, out=self.length)

        # leave point P = C + r (1 - cos a) x' + r sin a e
        lp = self.leave_point
        np.subtract(1.0, ca, out=t1)
        np.multiply(t1, r, out=t1)
        np.multiply(self._t1_v, xp, out=lp)
        np.multiply(sa, r, out=t1)
        np.multiply(self._t1_v, e, out=t3)
        np.add(lp, t3, out=lp)
        np.add(lp, C, out=lp)

        # u = -(sin a x' + cos a e)
        u = self.unit
        np.multiply(self._sa_v, xp, out=u)
        np.multiply(self._ca_v, e, out=t3)
        np.add(u, t3, out=u)
        np.negative(u, out=u)

        # swivel angle of x' about e from ref
        np.einsum("bmk,mk->bm", xp, self._s2, out=t1)
        np.einsum("bmk,mk->bm", xp, self._ref, out=t2)
        np.arctan2(t1, t2, out=self.swivel_angle)
        np.multiply(self.swivel_angle, self._mask, out=self.swivel_angle)
        return self.state

    def structure_matrix(self) -> np.ndarray:
        """A^T (N,6,m) of eq 2 of 002 for the last call, into the preallocated :attr:`AT`:
        rows 0-2 u_i (unitless), rows 3-5 (R b_i) x u_i [m]. Allocation-free."""
        return structure_matrix(self.unit, self.anchor_world, out=self.AT, work=self._AT_work)

    def platform_wrench(self) -> np.ndarray:
        """Gravity wrench w (N,6) [N, N m] of the platform at the last call's orientation,
        into the preallocated :attr:`wrench` (see :func:`platform_wrench`). Allocation-free."""
        np.einsum("bij,j->bi", self.rotation, self._cog, out=self._w_work)  # R c
        np.einsum("ij,bj->bi", self._S, self._w_work, out=self._wrench_moment)
        return self.wrench


def _moment_matrix(mg: np.ndarray) -> np.ndarray:
    """S = -[mg]_x (3,3) [N], so that S x = x cross mg for any lever arm x [m]."""
    return np.array([[0.0, mg[2], -mg[1]], [-mg[2], 0.0, mg[0]], [mg[1], -mg[0], 0.0]])


def structure_matrix(
    unit: np.ndarray,
    anchor_world: np.ndarray,
    out: np.ndarray | None = None,
    work: np.ndarray | None = None,
) -> np.ndarray:
    """Structure matrix A^T (N,6,m) of eq 2 of 002 from ``unit`` (N,m,3) u_i (unitless,
    pointing from the platform anchor to the frame) and ``anchor_world`` (N,m,3) R b_i [m]:
    rows 0-2 are u_i, rows 3-5 are (R b_i) x u_i [m]. A^T f is then the wrench [N; N m]
    the cable forces f (N,m) [N] exert on the platform about its origin.

    With ``out`` (N,6,m) and ``work`` (N,m) given, no memory is allocated.
    """
    N, m, _ = unit.shape
    if out is None:
        out = np.empty((N, 6, m))
    if work is None:
        work = np.empty((N, m))
    np.copyto(out[:, 0:3, :], unit.transpose(0, 2, 1))
    moments = out[:, 3:6, :]  # (N,3,m): component axis 1
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # the 3 components, fixed
        o = moments[:, k, :]
        np.multiply(anchor_world[..., i], unit[..., j], out=o)
        np.multiply(anchor_world[..., j], unit[..., i], out=work)
        np.subtract(o, work, out=o)
    return out


def platform_wrench(
    geom: RobotGeometry,
    R: np.ndarray,
    out: np.ndarray | None = None,
    work: np.ndarray | None = None,
) -> np.ndarray:
    """Gravity wrench on the platform about its origin, w (N,6) = [m g; (R c) x m g]
    [N; N m], the w of eq 2 of 002 when gravity is the only external load. ``R`` (N,3,3)
    platform rotation; m = geom.mass [kg], g = geom.gravity [m/s^2], c = centre of gravity
    [m, platform frame]. With ``out`` (N,6) and ``work`` (N,3) given, nothing is allocated.
    """
    N = R.shape[0]
    if out is None:
        out = np.empty((N, 6))
    if work is None:
        work = np.empty((N, 3))
    mg = np.asarray(geom.gravity, dtype=np.float64) * geom.mass  # (3,) constant
    np.copyto(out[:, 0:3], mg)
    np.einsum("bij,j->bi", R, geom.center_of_gravity, out=work)  # R c
    np.einsum("ij,bj->bi", _moment_matrix(mg), work, out=out[:, 3:6])
    return out


def wrench_residual(
    AT: np.ndarray, f: np.ndarray, w: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """Residual of the structure equation, eq 2 of 002: A^T f + w (N,6) [N; N m].

    ``AT`` (N,6,m), ``f`` (N,m) cable forces [N], ``w`` (N,6) external wrench. Zero at
    static equilibrium. For planar robots only rows PLANAR_WRENCH_ROWS (fx, fy, mz) count.
    """
    N = AT.shape[0]
    if out is None:
        out = np.empty((N, 6))
    np.einsum("bim,bm->bi", AT, f, out=out)
    np.add(out, w, out=out)
    return out


def inverse_kinematics(
    geom: RobotGeometry, position: np.ndarray, orientation: np.ndarray
) -> IKState:
    """Functional inverse kinematics (eq 1 of 002 plus the pulley model) for any batch:
    ``position`` (N,3) or (3,) [m], ``orientation`` (N,4) or (4,) [qx,qy,qz,qw]. Returns a
    fresh :class:`IKState` with a leading batch axis N (1 for single poses). Allocates; use
    :class:`InverseKinematics` in the control loop."""
    position = np.atleast_2d(np.asarray(position, dtype=np.float64))
    orientation = np.atleast_2d(np.asarray(orientation, dtype=np.float64))
    ik = InverseKinematics(geom, position.shape[0])
    return ik(position, orientation).copy()
