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

import struct
from functools import partial

import numpy as np

from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics.ik_layout import (
    MONOMIALS,
    Layout,
    cable_constants,
    declare_layout,
    fill_constants,
    gather_indices,
    local_matrix,
    moment_matrix,
    pose_matrix,
)

__all__ = [
    "PLANAR_WRENCH_ROWS",
    "IKState",
    "InverseKinematics",
    "inverse_kinematics",
    "structure_matrix",
    "platform_wrench",
    "wrench_residual",
]

#: Rows of a wrench (fx, fy, fz, mx, my, mz) that are meaningful for planar robots.
PLANAR_WRENCH_ROWS = (0, 1, 5)


_NAN = float("nan")
#: The documented IKState fields, in order.
_STATE_FIELDS = (
    "length",
    "free_length",
    "unit",
    "wrap_angle",
    "anchor_world",
    "leave_point",
    "swivel_angle",
    "rotation",
)
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

    ``leave_point`` and ``swivel_angle`` of a state owned by an :class:`InverseKinematics`
    are computed on their first access after each call (the per-tick path does not need
    them); the arrays returned are still the same preallocated buffers every time. The
    arrays may be non-contiguous views of the owner's work buffer.
    """

    __slots__ = (
        "length",
        "free_length",
        "unit",
        "wrap_angle",
        "anchor_world",
        "rotation",
        "_leave_point",
        "_swivel_angle",
        "_owner",
    )

    def __init__(self, **arrays: np.ndarray):
        self.length = arrays["length"]
        self.free_length = arrays["free_length"]
        self.unit = arrays["unit"]
        self.wrap_angle = arrays["wrap_angle"]
        self.anchor_world = arrays["anchor_world"]
        self.rotation = arrays["rotation"]
        self._leave_point = arrays["leave_point"]
        self._swivel_angle = arrays["swivel_angle"]
        self._owner: InverseKinematics | None = None

    @property
    def leave_point(self) -> np.ndarray:
        """(N,m,3) [m], see the class docstring."""
        owner = self._owner
        if owner is not None:
            owner._fill_leave_point()
        return self._leave_point

    @property
    def swivel_angle(self) -> np.ndarray:
        """(N,m) [rad], see the class docstring."""
        owner = self._owner
        if owner is not None:
            owner._fill_swivel_angle()
        return self._swivel_angle

    def copy(self) -> "IKState":
        """Independent deep copy (fresh arrays)."""
        return IKState(**{k: getattr(self, k).copy() for k in _STATE_FIELDS})


def _noop() -> None:
    """Nothing to do (single-pose instances export nothing)."""


class InverseKinematics:
    """Pulley-aware inverse kinematics for a fixed batch size, allocation-free per call.

    ``geom``: the robot; ``batch``: number N of poses per call. All work arrays are
    allocated here; :meth:`__call__`, :meth:`structure_matrix` and
    :meth:`platform_wrench` only run numpy calls with output arguments on them (no Python
    loops over cables or poses, no data-dependent branches), so they run in fixed time and
    do not allocate array memory. The result arrays may be non-contiguous views.

    Implementation (for speed at N = 1, where a numpy call costs ~0.5 us whatever its
    size, so the number of calls is what counts): every per-cable quantity is a row of
    S = m*N values in one flat buffer, and each call works on a whole window of
    neighbouring rows (no broadcasting, no 2-D strided views, no temporaries):

    - The pose enters through two products with constant matrices. The rotation is
      quadratic in the quaternion, so v = [q_k q_l / |q|^2 (10 products), r, 1] (Python
      floats at N = 1) times K1 gives R b_i + r, R b_i, R and the gravity moment at once.
      d = (R b_i + r) - C_i is one subtraction (the rounding of eq 1, so an anchor exactly
      on a swivel axis gives d_perp = 0 exactly), and a block-diagonal K2 times [d; 1]
      gives the coordinates in the fixed orthonormal basis (e, ref, e x ref) of each
      pulley: de, d1, d2 (plus d1 + EPS_SWIVEL, d_perp + EPS_SWIVEL ref and constants).
    - |d_perp| = hypot(d1, d2), vx = |d_perp| - r; lf^2 = Re[(vx + i r)^2] + de^2 with one
      complex multiplication and one addition, and the clamped square root as the real
      part of one complex square root (sqrt(x + 0i) = sqrt(max(x, 0)) + i ...).
    - One arctan2 on [r, vx, lf] / [lf, de, -r] gives [delta, atan2(vx, de), delta + pi/2],
      one addition [alpha, alpha + pi/2], one sin [sin alpha, cos alpha].
    - The wrap angle is max(mod(alpha + tol, P) - tol, 0) (P = 2 pi; straight cables use
      P = tol, which gives exactly 0). Then one complex multiplication
      (lf - i r)(1 + i wa) and (cos a + i sin a / |x|)(-e_j + i x_j), x = d_perp +
      EPS_SWIVEL ref, gives length = lf + r wa and u_j = -(cos a e_j + sin a x'_j) as
      real parts.
    - :meth:`structure_matrix` gathers u and R b_i in component-major order with one
      ``take`` and forms the moments with one multiplication and one subtraction (the
      same arithmetic as :func:`structure_matrix`); :meth:`platform_wrench` is computed
      by the pose product.

    Batches N > 1 run the same calls on longer rows (the quaternion products are then
    vectorised) and gather the results into contiguous (N, ...) arrays with ``take``.
    """

    def __init__(self, geom: RobotGeometry, batch: int):
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        self.geom = geom
        self.batch = N = int(batch)
        self.n_cables = m = int(geom.n_cables)
        c = cable_constants(geom)                      # per-cable constants of the pulley model
        L = declare_layout(N, m)                       # the flat work buffer (see the class docstring)
        self._buf = L.buf
        fill_constants(L, c)
        d1, d2 = self._pose_products(L, pose_matrix(L, c), *local_matrix(L, c))
        idx1, idx2, idx3, u_idx, aw_idx = gather_indices(L)
        self._bind_call_views(L, d1, d2, idx1, idx2, idx3)
        self._bind_results(L, c, u_idx, aw_idx)
        self.state = IKState(
            length=self.length,
            free_length=self.free_length,
            unit=self.unit,
            wrap_angle=self.wrap_angle,
            anchor_world=self.anchor_world,
            leave_point=self._leave_point,
            swivel_angle=self._swivel_angle,
            rotation=self.rotation,
        )
        self.state._owner = self

    # -- construction steps (cablesvc.kinematics.ik_layout builds the constants) ---------
    def _pose_products(self, L: Layout, K1: np.ndarray, dest: np.ndarray, K2: np.ndarray) -> tuple:
        """How the pose enters: the loader of v (Python floats at N = 1, vectorised
        otherwise) and the argument tuples of the two constant products, K1 v -> [R b + r,
        R b, R, wrench] and K2 [d; 1] -> local coordinates (gathered into buffer order for
        N > 1). Returns (d1, d2)."""
        M, o, N = L.buf, L.off, L.N
        d2_start, d2_stop = L.d2_range
        n_d = 3 * L.m + 1
        d1o = M[o["awp"] : o["d"]]
        d2o = M[d2_start:d2_stop]
        dext = M[o["d"] : o["one"] + N]
        if N == 1:
            self._v = np.zeros(K1.shape[1])
            self._v[-1] = 1.0
            self._pack = struct.Struct(f"{K1.shape[1] - 1}d").pack_into
            self._load = self._load_single
            d1 = (self._v, np.ascontiguousarray(K1.T), d1o)
            d2 = (_dot, dext, np.ascontiguousarray(K2.T), d2o)
        else:
            V = self._V = np.zeros((K1.shape[1], N))
            V[-1] = 1.0
            self._mono = V[0:10].reshape(-1)
            self._mono4 = V[0:4]
            self._vp = V[10:13].reshape(-1)
            self._qab = np.zeros(20 * N)
            self._qa = self._qab[: 10 * N]
            self._qb = self._qab[10 * N :]
            nn = np.arange(N)
            ka = np.array([k for k, _ in MONOMIALS])
            kb = np.array([l for _, l in MONOMIALS])
            self._qab_idx = np.concatenate(
                [(nn[None, :] * 4 + ka[:, None]).ravel(), (nn[None, :] * 4 + kb[:, None]).ravel()]
            )
            self._n2 = np.zeros(N)
            self._n2rep = np.zeros(10 * N)
            self._n2_idx = np.tile(nn, 10)
            self._ones4 = np.ones(4)
            self._p_idx = (nn[None, :] * 3 + np.arange(3)[:, None]).ravel()
            self._load = self._load_batch
            d1 = (K1, V, d1o.reshape(-1, N))
            # the product gives (row of K2, pose) order; gather it into the buffer order
            scratch = np.zeros(K2.shape[0] * N)
            fix = np.empty(d2_stop - d2_start, dtype=np.intp)
            fix[(dest - d2_start).ravel()] = np.arange(K2.shape[0] * N)

            def product_then_gather(a, b, out, _s=scratch.reshape(-1, N), _fix=fix):
                _dot(a, b, _s)
                scratch.take(_fix, None, out, "wrap")

            d2 = (product_then_gather, K2, dext.reshape(n_d, N), d2o)
        return d1, d2

    def _bind_call_views(self, L: Layout, d1: tuple, d2: tuple, idx1: np.ndarray, idx2: np.ndarray,
                         idx3: np.ndarray) -> None:
        """The gather buffers and the tuples of buffer views that :meth:`__call__`,
        :meth:`structure_matrix` and the lazy leave point / swivel angle unpack."""
        M, o, S = L.buf, L.off, L.S
        seg, plane, cplx = L.seg, L.plane, L.cplx
        self._tk1 = np.zeros(8 * S)
        self._tk2 = np.zeros(15 * S)
        self._tk3 = np.zeros(12 * S)
        take = M.take
        t1, t2, t3 = self._tk1, self._tk2, self._tk3
        self._w = (
            *d1,
            M[o["awp"] : o["awp"] + 3 * S],
            M[o["C"] : o["C"] + 3 * S],
            M[o["d"] : o["d"] + 3 * S],
            *d2,
            seg("d1", 0, 2),  # [d1, p1]
            seg("d2", 0, 2),  # [d2, d2g]
            seg("ho", 0, 2),
            seg("ho"),  # |d_perp|
            plane("w_r", 0),  # r
            plane("w_vx", 0),  # vx
            cplx("w_vx", 3),  # [vx + i r, lf + 0i, de + 0i]
            seg("sqc", 0, 6).view(np.complex128),
            plane("sqc", 0),  # vx^2 - r^2
            plane("sqc", 0, 1, start=2),  # de^2
            plane("lfc", 0),
            cplx("lfc", 1),
            cplx("w_lf", 1),  # lf + i junk
            plane("w_r", 0, 3),  # [r, vx, lf]
            plane("w_lf", 0, 3),  # [lf, de, -r]
            seg("o3", 0, 3),
            seg("o3", 1, 2),  # [atan2(vx, de), delta + pi/2]
            seg("o3", 0, 2),  # [delta, atan2(vx, de)]
            seg("a2", 0, 2),
            seg("sc", 0, 2),
            seg("a2"),  # alpha
            seg("t"),
            seg("tol"),
            seg("sc"),  # sin a
            seg("ho", 1),  # |x|
            seg("sp"),
            seg("per"),
            take,
            idx1,
            t1,
            plane("bl", 1),  # wa
            t1.view(np.complex128),
            cplx("bu", 4),  # [-e_j + i x_j, 1 + i wa]
            cplx("outc", 4),
        )
        self._sm = (
            take,
            idx2,
            t2,
            t2[9 * S : 15 * S],  # [aw_{j+1}, aw_{j+2}]
            t2[3 * S : 9 * S],  # [u_{j+2}, u_{j+1}]
            seg("ps", 0, 6),
            seg("ps", 0, 3),
            seg("ps", 3, 3),
            t2[3 * S : 6 * S],  # moment rows of A^T
        )
        self._lazy = (
            seg("ones"),
            seg("sc", 1),  # cos a
            seg("lw1"),
            seg("ho", 1),
            seg("sc", 0, 3),  # [sin a, cos a, lw1]
            seg("lyc", 0, 3),
            seg("lk", 0, 3),
            take,
            idx3,
            t3,
            t3[0 : 6 * S],
            t3[6 * S : 12 * S],
            seg("la", 0, 6),
            seg("la", 3, 3),
            seg("la", 0, 3),
            M[o["C"] : o["C"] + 3 * S],
            seg("lp", 0, 3),
        )
        self._swv = (seg("d2"), seg("p1"), seg("sw"), seg("mask"))
        self._lp_fresh = self._sw_fresh = True  # (zeros until the first call)

    def _bind_results(self, L: Layout, c, u_idx: np.ndarray, aw_idx: np.ndarray) -> None:
        """The result arrays: views of the buffer (N = 1) or contiguous (N, ...) arrays
        gathered after each call (N > 1), and the tails that gather them."""
        M, o, N, m, S = L.buf, L.off, L.N, L.m, L.S
        seg, plane = L.seg, L.plane
        mg = c.mg
        take, t2 = M.take, self._tk2
        if N == 1:

            def view(flat: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
                out = flat.reshape(shape)
                assert np.shares_memory(out, M)  # a view, never a copy
                return out

            self.length = view(plane("outc", 0, 1, start=3), (1, m))
            self.free_length = view(plane("w_lf", 0), (1, m))
            self.wrap_angle = view(plane("bl", 1), (1, m))
            self.unit = view(plane("outc", 0, 3), (1, m, 3))
            self.anchor_world = view(seg("aw", 0, 3), (1, m, 3))
            self.rotation = view(M[o["r9"] : o["r9"] + 9], (1, 3, 3))
            self.wrench = view(M[o["wr"] : o["wr"] + 6], (1, 6))
            self.AT = t2[0 : 6 * S].reshape(1, 6, m)
            self._leave_point = seg("lp", 0, 3).reshape(1, m, 3)
            self._swivel_angle = seg("sw").reshape(1, m)
            self._tail = self._sm_tail = self._lp_tail = self._sw_tail = _noop
        else:
            nm = lambda idx: np.moveaxis(idx, -1, 0).ravel()  # noqa: E731  (..., N) -> (N, ...)
            parts = [
                nm(L.prow("outc", 0) + 6 * S),  # length: real parts after the 3S u_j
                nm(L.prow("w_lf", 0)),
                nm(L.prow("bl", 1)),
                nm(u_idx),
                nm(aw_idx),
                (o["r9"] + np.arange(9 * N).reshape(9, N)).T.ravel(),
                (o["wr"] + np.arange(6 * N).reshape(6, N)).T.ravel(),
            ]
            exp = self._exp = np.zeros(sum(p.size for p in parts))
            cuts = np.cumsum([0] + [p.size for p in parts])
            self.length, self.free_length, self.wrap_angle = (
                exp[cuts[k] : cuts[k + 1]].reshape(N, m) for k in range(3)
            )
            self.unit, self.anchor_world = (
                exp[cuts[k] : cuts[k + 1]].reshape(N, m, 3) for k in (3, 4)
            )
            self.rotation = exp[cuts[5] : cuts[6]].reshape(N, 3, 3)
            self.wrench = exp[cuts[6] : cuts[7]].reshape(N, 6)
            self.wrench[:, 0:3] = mg
            self.AT = np.zeros((N, 6, m))
            self._leave_point = np.zeros((N, m, 3))
            self._swivel_angle = np.zeros((N, m))
            jin = np.arange(6 * S).reshape(6, m, N)  # (j, i, n) in t2
            lp_idx = L.vec("lp")
            self._tail = partial(take, np.concatenate(parts), None, exp, "wrap")
            self._sm_tail = partial(t2.take, nm(jin), None, self.AT.reshape(-1), "wrap")
            self._lp_tail = partial(take, nm(lp_idx), None, self._leave_point.reshape(-1), "wrap")
            sw_idx = nm(L.row("sw"))
            self._sw_tail = partial(take, sw_idx, None, self._swivel_angle.reshape(-1), "wrap")

    # -- pose input --------------------------------------------------------------------
    def _shape_error(self, position, orientation) -> ValueError:
        N = self.batch
        return ValueError(
            f"expected position ({N}, 3) and orientation ({N}, 4), got "
            f"{np.shape(position)} and {np.shape(orientation)}"
        )

    def _load_single(self, position, orientation) -> None:
        """N = 1: the 10 quaternion products / |q|^2 and the position, as Python floats,
        into v (zero quaternion: NaN, like the homogeneous rotation formula)."""
        try:
            (px, py, pz), = position.tolist()
            (x, y, z, w), = orientation.tolist()
        except (AttributeError, TypeError, ValueError):
            if np.shape(position) != (1, 3) or np.shape(orientation) != (1, 4):
                raise self._shape_error(position, orientation) from None
            (px, py, pz), = np.asarray(position, dtype=np.float64).tolist()
            (x, y, z, w), = np.asarray(orientation, dtype=np.float64).tolist()
        xx = x * x
        yy = y * y
        zz = z * z
        ww = w * w
        s = 1.0 / ((xx + yy + zz + ww) or _NAN)
        self._pack(
            self._v, 0,
            xx * s, yy * s, zz * s, ww * s,
            x * y * s, x * z * s, y * z * s, x * w * s, y * w * s, z * w * s,
            px, py, pz,
        )  # fmt: skip

    def _load_batch(self, position, orientation) -> None:
        """N > 1: the same vector v per pose, vectorised (columns of V)."""
        N = self.batch
        if np.shape(position) != (N, 3) or np.shape(orientation) != (N, 4):
            raise self._shape_error(position, orientation)
        pos = np.ascontiguousarray(position, dtype=np.float64)
        ori = np.ascontiguousarray(orientation, dtype=np.float64)
        ori.take(self._qab_idx, None, self._qab, "wrap")
        np.multiply(self._qa, self._qb, self._mono)
        np.dot(self._ones4, self._mono4, self._n2)  # |q|^2
        self._n2.take(self._n2_idx, None, self._n2rep, "wrap")
        np.divide(self._mono, self._n2rep, self._mono)
        pos.take(self._p_idx, None, self._vp, "wrap")

    # -- the per-call path -------------------------------------------------------------
    def __call__(self, position: np.ndarray, orientation: np.ndarray) -> IKState:
        """Cable lengths etc. for N poses: ``position`` (N,3) [m], ``orientation`` (N,4)
        [qx,qy,qz,qw] (any non-zero norm; normalised). Implements eq 1 of 002 with the pulley
        model of this module. Returns :attr:`state`, whose arrays are overwritten next call.
        """
        self._load(position, orientation)
        (
            k1a, k1b, d1o, awp, C, dvec, dot2, k2a, k2b, d2o, hx, hy, ho, dp, r, vx,
            wc3, sqc, sq_vx, sq_de, lf2, lf2c, lfc, num, den, o3, o3a, o3b, a2, sc,
            alpha, t, tol, s_alpha, xabs, sp, per, take, idx1, tk1, wa, acpx, bcpx, outc,
        ) = self._w  # fmt: skip
        add, subtract, multiply = _add, _subtract, _multiply
        _dot(k1a, k1b, d1o)  # [R b + r, R b, R, wrench]
        subtract(awp, C, dvec)  # d = (r + R b) - C
        dot2(k2a, k2b, d2o)  # local coordinates of d (and constants)
        _hypot(hx, hy, ho)  # [|d_perp|, |x|]
        subtract(dp, r, vx)  # vx = |d_perp| - r
        multiply(wc3, wc3, sqc)  # [vx^2 - r^2, 0, de^2] (real parts)
        add(sq_vx, sq_de, lf2)
        _sqrt(lf2c, lfc)  # free length sqrt(max(lf^2, 0)) (real part)
        _arctan2(num, den, o3)  # [delta, atan2(vx, de), delta + pi/2]
        add(o3a, o3b, a2)  # [alpha, alpha + pi/2]
        _sin(a2, sc)  # [sin a, cos a]
        add(alpha, tol, t)
        _divide(s_alpha, xabs, sp)
        _mod(t, per, t)
        take(idx1, None, tk1, "wrap")  # [cos a + i sin a / |x| (x3), lf - i r]
        _maximum(t, tol, out=t)
        subtract(t, tol, wa)  # wrap angle: max(mod(alpha + tol, 2 pi) - tol, 0)
        multiply(acpx, bcpx, outc)  # real parts: [u, lf + r wa]
        self._lp_fresh = self._sw_fresh = False
        self._tail()
        return self.state

    def structure_matrix(self) -> np.ndarray:
        """A^T (N,6,m) of eq 2 of 002 for the last call, into the preallocated :attr:`AT`:
        rows 0-2 u_i (unitless), rows 3-5 (R b_i) x u_i [m]. Allocation-free."""
        take, idx2, t2, awr, ur, ps, ps_a, ps_b, mom = self._sm
        take(idx2, None, t2, "wrap")  # [u, u_{j+2}, u_{j+1}, aw_{j+1}, aw_{j+2}], j-major
        _multiply(awr, ur, ps)
        _subtract(ps_a, ps_b, mom)  # aw_{j+1} u_{j+2} - aw_{j+2} u_{j+1}
        self._sm_tail()
        return self.AT

    def platform_wrench(self) -> np.ndarray:
        """Gravity wrench w (N,6) [N, N m] of the platform at the last call's orientation,
        in the preallocated :attr:`wrench` (see :func:`platform_wrench`; computed by the
        call itself). Allocation-free."""
        return self.wrench

    # -- lazily filled results ----------------------------------------------------------
    @property
    def leave_point(self) -> np.ndarray:
        """(N,m,3) [m] leave points of the last call (see :class:`IKState`)."""
        self._fill_leave_point()
        return self._leave_point

    @property
    def swivel_angle(self) -> np.ndarray:
        """(N,m) [rad] swivel angles of the last call (see :class:`IKState`)."""
        self._fill_swivel_angle()
        return self._swivel_angle

    def _fill_leave_point(self) -> None:
        """P = C + r sin(a) e + r (1 - cos a) x', once per call. Allocation-free."""
        if self._lp_fresh:
            return
        (ones, ca, lw1, xabs, sclw, lyc, lk, take, idx3, t3, k12, ex, la, la_x, la_e, C, lp) = (
            self._lazy
        )
        _subtract(ones, ca, lw1)
        _divide(lw1, xabs, lw1)
        _multiply(sclw, lyc, lk)  # [r sin a, 0, r (1 - cos a) / |x|]
        take(idx3, None, t3, "wrap")
        _multiply(k12, ex, la)  # [-r sin a e, r (1 - cos a) x']
        _subtract(la_x, la_e, lp)
        _add(lp, C, lp)
        self._lp_tail()
        self._lp_fresh = True

    def _fill_swivel_angle(self) -> None:
        """Angle of x' about e from ref (0 without pulley), once per call."""
        if self._sw_fresh:
            return
        d2, p1, sw, mask = self._swv
        _arctan2(d2, p1, sw)
        _multiply(sw, mask, sw)
        self._sw_tail()
        self._sw_fresh = True


_dot = np.dot
_add = np.add
_subtract = np.subtract
_multiply = np.multiply
_divide = np.divide
_hypot = np.hypot
_maximum = np.maximum
_sqrt = np.sqrt
_arctan2 = np.arctan2
_sin = np.sin
_mod = np.mod


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
    np.einsum("ij,bj->bi", moment_matrix(mg), work, out=out[:, 3:6])
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


#: poses per piece of :func:`inverse_kinematics` on a long batch
IK_CHUNK = 4096


def inverse_kinematics(
    geom: RobotGeometry, position: np.ndarray, orientation: np.ndarray
) -> IKState:
    """Functional inverse kinematics (eq 1 of 002 plus the pulley model) for any batch:
    ``position`` (N,3) or (3,) [m], ``orientation`` (N,4) or (4,) [qx,qy,qz,qw]. Returns a
    fresh :class:`IKState` with a leading batch axis N (1 for single poses). Allocates; use
    :class:`InverseKinematics` in the control loop."""
    position = np.atleast_2d(np.asarray(position, dtype=np.float64))
    orientation = np.atleast_2d(np.asarray(orientation, dtype=np.float64))
    n = position.shape[0]
    if n <= IK_CHUNK:
        ik = InverseKinematics(geom, n)
        return ik(position, orientation).copy()
    # a long recording: the solver's work buffers take some 15 KB per pose (530 MB for the
    # 35 000 poses of a calibration), so it runs on pieces and only the results are kept
    out: dict[str, np.ndarray] = {}
    solvers: dict[int, InverseKinematics] = {}
    for a in range(0, n, IK_CHUNK):
        b = min(n, a + IK_CHUNK)
        ik = solvers.get(b - a)
        if ik is None:
            ik = solvers[b - a] = InverseKinematics(geom, b - a)
        st = ik(position[a:b], orientation[a:b])
        for k in _STATE_FIELDS:
            v = getattr(st, k)
            if k not in out:
                out[k] = np.empty((n,) + v.shape[1:], dtype=v.dtype)
            out[k][a:b] = v
    return IKState(**out)
