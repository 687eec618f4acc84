"""Construction of :class:`~cablesvc.kinematics.ik.InverseKinematics`: the per-cable
constants of the pulley model, the flat work buffer's layout, the two constant matrices the
pose enters through (K1: pose -> anchors, rotation, gravity wrench; K2: anchor offsets ->
each pulley's local coordinates) and the gather indices of the per-call path. Everything
here runs once per instance; the per-call path is in :mod:`cablesvc.kinematics.ik`, whose
docstring derives the model and describes the buffer.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics.rotation import QUAT_OUTER_TO_MATRIX

__all__ = ["EPS_SWIVEL", "MONOMIALS", "Layout", "cable_constants", "declare_layout", "fill_constants",
           "gather_indices", "local_matrix", "moment_matrix", "pose_matrix"]

#: m; size of the fixed reference direction added to d_perp before normalising.
EPS_SWIVEL = 1e-12
#: rad; round-off tolerance of the wrap-angle fold into [0, 2 pi).
FOLD_TOL = 1e-9
_TWO_PI = 2.0 * np.pi
#: m; added to the copy of d2 used for |d_perp + EPS_SWIVEL ref| (so that norm is never 0;
#: the same guard as adding 1e-300 to its square).
_NORM_GUARD = 1e-150
#: Monomials q_k q_l (k <= l, q = [x, y, z, w]) fed to the pose matrix product, in order.
MONOMIALS = ((0, 0), (1, 1), (2, 2), (3, 3), (0, 1), (0, 2), (1, 2), (0, 3), (1, 3), (2, 3))


def swivel_reference(geom: RobotGeometry, e: np.ndarray) -> np.ndarray:
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


def _monomial_map() -> np.ndarray:
    """(9, 10): flattened R = this @ [q_k q_l / |q|^2 for (k, l) in MONOMIALS] (unitless),
    the symmetric form of QUAT_OUTER_TO_MATRIX."""
    T = np.asarray(QUAT_OUTER_TO_MATRIX)
    M = np.zeros((9, len(MONOMIALS)))
    for c, (k, l) in enumerate(MONOMIALS):
        M[:, c] = T[4 * k + l] + (T[4 * l + k] if k != l else 0.0)
    return M


def moment_matrix(mg: np.ndarray) -> np.ndarray:
    """S = -[mg]_x (3,3) [N], so that S x = x cross mg for any lever arm x [m]."""
    return np.array([[0.0, mg[2], -mg[1]], [-mg[2], 0.0, mg[0]], [mg[1], -mg[0], 0.0]])


class Layout:
    """Construction-time helper: one flat float64 buffer cut into named contiguous
    segments, in declaration order (the order matters: several numpy calls work on
    windows spanning neighbouring segments), plus the index arithmetic of its blocks.

    With N poses and m cables there are S = m*N slots; slot (i, n) is cable i of pose n.
    A *row* holds one value per slot, in (i, n) order; a *vector* block holds a 3-vector
    per slot, in (i, j, n) order; a *paired* row or vector interleaves two values per
    slot (planes 0 and 1: the real and imaginary parts of its complex128 view)."""

    def __init__(self, N: int, m: int):
        self.N, self.m, self.S = N, m, m * N
        self.off: dict[str, int] = {}
        self.size = 0

    def add(self, name: str, rows: int) -> None:
        """Next segment: ``rows`` rows of S values."""
        self.off[name] = self.size
        self.size += rows * self.S

    def add_pose(self, name: str, rows: int) -> None:
        """Next segment: ``rows`` rows of N values (one per pose)."""
        self.off[name] = self.size
        self.size += rows * self.N

    def row(self, name: str, q: int = 0) -> np.ndarray:
        """(m, N) indices of plain row q of segment ``name``."""
        return self.off[name] + q * self.S + np.arange(self.S).reshape(self.m, self.N)

    def vec(self, name: str) -> np.ndarray:
        """(m, 3, N) indices of the plain vector block ``name``."""
        return self.off[name] + np.arange(3 * self.S).reshape(self.m, 3, self.N)

    def prow(self, name: str, plane: int) -> np.ndarray:
        """(m, N) indices of plane ``plane`` of the paired row ``name``."""
        return self.off[name] + 2 * np.arange(self.S).reshape(self.m, self.N) + plane

    def pvec(self, name: str, plane: int) -> np.ndarray:
        """(m, 3, N) indices of plane ``plane`` of the paired vector block ``name``."""
        return self.off[name] + 2 * np.arange(3 * self.S).reshape(self.m, 3, self.N) + plane

    # -- the buffer (after every segment is declared) -----------------------------------
    def allocate(self) -> np.ndarray:
        """The flat buffer, zeros, as :attr:`buf`."""
        self.buf = np.zeros(self.size)
        return self.buf

    def seg(self, name: str, start: int = 0, rows: int = 1) -> np.ndarray:
        """Flat view of ``rows`` rows of segment ``name`` from row ``start``."""
        s = self.off[name] + start * self.S
        return self.buf[s : s + rows * self.S]

    def plane(self, name: str, p: int, rows: int = 1, start: int = 0) -> np.ndarray:
        """Plane ``p`` of ``rows`` paired rows from row ``start`` of ``name``, as a
        stride-2 view."""
        s = self.off[name] + 2 * start * self.S + p
        return self.buf[s : s + 2 * rows * self.S : 2]

    def cplx(self, name: str, rows: int) -> np.ndarray:
        """complex128 view of ``rows`` paired rows from ``name`` on."""
        o = self.off[name]
        return self.buf[o : o + 2 * rows * self.S].view(np.complex128)

    def per_slot(self, vals) -> np.ndarray:
        """(m,) per-cable values as an (m, N) slot array."""
        return np.repeat(np.asarray(vals, dtype=np.float64)[:, None], self.N, axis=1)

    @property
    def d2_range(self) -> tuple[int, int]:
        """[start, stop) of the buffer the local-coordinate product (K2) writes."""
        return self.off["w_lf"], self.off["bl"]


def cable_constants(geom: RobotGeometry) -> SimpleNamespace:
    """Per-cable constants of the pulley model (m cables): anchors b, entry points C,
    pulley mask and radius r (0 without pulley), unit swivel axis e with its fixed
    reference ref and s2 = e x ref, the projector P off e; the platform weight mg, its
    centre of gravity cog and moment matrix Smg."""
    f8 = np.float64
    b = np.array(geom.platform_anchors, dtype=f8)
    C = np.array(geom.pulley_center, dtype=f8)
    pulley = np.asarray(geom.has_pulley, dtype=bool)
    mask = pulley.astype(f8)
    r = np.array(geom.pulley_radius, dtype=f8) * mask
    e = np.array(geom.pulley_axis, dtype=f8)
    e[~pulley] = (0.0, 0.0, 1.0)  # straight cables: any unit e
    # the local basis must be orthonormal; robot files give unit axes within 1e-6
    # (exactly for the shipped robots, where this division changes nothing)
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    ref = swivel_reference(geom, e)
    s2 = np.cross(e, ref)
    P = np.eye(3)[None] - e[:, :, None] * e[:, None, :]  # (m,3,3) projector off e
    mg = np.asarray(geom.gravity, dtype=f8) * float(geom.mass)
    cog = np.array(geom.center_of_gravity, dtype=f8)
    Smg = moment_matrix(mg)
    return SimpleNamespace(b=b, C=C, pulley=pulley, mask=mask, r=r, e=e, ref=ref, s2=s2, P=P, mg=mg, cog=cog,
                           Smg=Smg)


def declare_layout(N: int, m: int) -> Layout:
    """The flat work buffer's segments, in the order the per-call numpy windows need
    (see :class:`Layout`), allocated."""
    L = Layout(N, m)
    L.add("C", 3)
    L.add("awp", 3)  # pose product: R b_i + r        (i, j, n)
    L.add("aw", 3)  #               R b_i            (i, j, n)
    L.add_pose("r9", 9)  #          R (row-major)
    L.add_pose("wr", 6)  #          [m g; (R c) x m g]
    L.add("d", 3)  # d = (R b_i + r) - C          (i, j, n)
    L.add_pose("one", 1)  # [d; 1] feeds the local-coordinate product
    # paired rows [r, vx, lf, de, -r] (plane 0): arctan2 of [r, vx, lf] / [lf, de, -r];
    # complex [vx + i r, lf + 0i, de + 0i] squared gives vx^2 - r^2 and de^2
    L.add("w_r", 2)
    L.add("w_vx", 2)
    L.add("w_lf", 2)  # local-coordinate product (D2) from here ...
    L.add("w_de", 2)
    L.add("w_nr", 2)
    L.add("d1", 1)
    L.add("p1", 1)  # d1 + EPS_SWIVEL
    L.add("d2", 1)
    L.add("d2g", 1)  # d2 + _NORM_GUARD
    L.add("bu", 6)  # complex -e_j + i x_j (i, j, n) ... to here
    L.add("bl", 2)  # complex 1 + i wa
    L.add("ho", 2)  # [|d_perp|, |x|]
    L.add("sqc", 6)
    L.add("lfc", 2)  # complex lf^2 + 0i
    L.add("o3", 3)  # [delta, atan2(vx, de), delta + pi/2]
    L.add("a2", 2)  # [alpha, alpha + pi/2]
    L.add("sc", 2)  # [sin a, cos a]
    L.add("lw1", 1)  # (lazy) (1 - cos a) / |x|; must follow sc
    for name in ("t", "tol", "per", "sp", "mask", "ones", "zero"):
        L.add(name, 1)
    L.add("outc", 8)  # complex [u_j + i ..., lf + r wa + i ...]
    L.add("ps", 6)  # structure matrix products
    L.add("lyc", 3)  # (lazy) [r, 0, r]
    L.add("lk", 3)  # (lazy) [r sin a, 0, r (1 - cos a) / |x|]
    L.add("la", 6)  # (lazy)
    L.add("lp", 3)  # (lazy) leave point (i, j, n)
    L.add("sw", 1)  # (lazy) swivel angle
    L.allocate()
    return L


def fill_constants(L: Layout, c: SimpleNamespace) -> None:
    """The constant rows of the buffer (pulley radii, fold periods, masks, ones, the
    gravity force)."""
    M, o, N, per_slot = L.buf, L.off, L.N, L.per_slot
    C, r, pulley, mask, mg = c.C, c.r, c.pulley, c.mask, c.mg
    M[L.vec("C")] = np.repeat(C[:, :, None], N, axis=2)
    M[o["one"] : o["one"] + N] = 1.0
    M[L.prow("w_r", 0)] = per_slot(r)
    M[L.prow("w_vx", 1)] = per_slot(r)
    M[L.row("tol")] = FOLD_TOL
    M[L.row("per")] = per_slot(np.where(pulley, _TWO_PI, FOLD_TOL))
    M[L.row("mask")] = per_slot(mask)
    M[L.row("ones")] = 1.0
    M[L.prow("bl", 0)] = 1.0
    M[o["wr"] : o["wr"] + 3 * N] = np.repeat(mg, N)  # (also before the first call)
    M[L.row("lyc", 0)] = per_slot(r)
    M[L.row("lyc", 2)] = per_slot(r)


def pose_matrix(L: Layout, c: SimpleNamespace) -> np.ndarray:
    """K1: v = [q_k q_l / |q|^2, r, 1] -> [R b + r, R b, R, wrench] (rows in buffer order
    from segment ``awp``)."""
    m, N, o = L.m, L.N, L.off
    b, mg, Smg, cog = c.b, c.mg, c.Smg, c.cog
    Rmap = _monomial_map()
    unit3 = np.eye(3)

    def k1_row(Acoef: np.ndarray, Bcoef=(0.0, 0.0, 0.0), c: float = 0.0) -> np.ndarray:
        """Row of K1 for sum_ab Acoef_ab R_ab + Bcoef . r + c."""
        return np.concatenate([np.ravel(Acoef) @ Rmap, Bcoef, [c]])

    rows1 = [k1_row(np.outer(unit3[j], b[i]), unit3[j]) for i in range(m) for j in range(3)]
    rows1 += [k1_row(np.outer(unit3[j], b[i])) for i in range(m) for j in range(3)]
    rows1 += [k1_row(np.outer(unit3[a], unit3[c])) for a in range(3) for c in range(3)]
    rows1 += [k1_row(np.zeros((3, 3)), c=mg[j]) for j in range(3)]
    rows1 += [k1_row(np.outer(Smg[j], cog)) for j in range(3)]  # (S R c)_j
    K1 = np.array(rows1)
    assert K1.shape[0] * N == o["d"] - o["awp"]
    return K1


def local_matrix(L: Layout, c: SimpleNamespace) -> tuple[np.ndarray, np.ndarray]:
    """K2: [d; 1] -> local coordinates of d in each pulley's basis (and constants), rows
    sorted in buffer order (pose 0). Returns (dest, K2): ``dest`` (R2, N) the buffer index
    of each row's values per pose."""
    m = L.m
    e, r, ref, s2, P = c.e, c.r, c.ref, c.s2, c.P
    d2_start, d2_stop = L.d2_range
    n_d = 3 * m + 1
    dest, rows2 = [], []  # index of pose 0's value in M, and its row of K2

    def k2(coef=None, const: float = 0.0, i: int = 0) -> np.ndarray:
        row = np.zeros(n_d)
        if coef is not None:
            row[3 * i : 3 * i + 3] = coef
        row[-1] = const
        return row

    spec = []  # (index array (m, N) or (m, 3, N), callable (i[, j]) -> K2 row)
    spec.append((L.prow("w_lf", 0), lambda i: k2()))
    spec.append((L.prow("w_lf", 1), lambda i: k2()))
    spec.append((L.prow("w_de", 0), lambda i: k2(e[i], 0.0, i)))
    spec.append((L.prow("w_de", 1), lambda i: k2()))
    spec.append((L.prow("w_nr", 0), lambda i: k2(None, -r[i])))
    spec.append((L.prow("w_nr", 1), lambda i: k2()))
    spec.append((L.row("d1"), lambda i: k2(ref[i], 0.0, i)))
    spec.append((L.row("p1"), lambda i: k2(ref[i], EPS_SWIVEL, i)))
    spec.append((L.row("d2"), lambda i: k2(s2[i], 0.0, i)))
    spec.append((L.row("d2g"), lambda i: k2(s2[i], _NORM_GUARD, i)))
    for idx, fn in spec:
        for i in range(m):
            dest.append(idx[i])
            rows2.append(fn(i))
    for p, fn in (
        (0, lambda i, j: k2(None, -e[i, j])),
        (1, lambda i, j: k2(P[i, j], EPS_SWIVEL * ref[i, j], i)),  # x = d_perp + eps ref
    ):
        idx = L.pvec("bu", p)
        for i in range(m):
            for j in range(3):
                dest.append(idx[i, j])
                rows2.append(fn(i, j))
    dest = np.array(dest)  # (R2, N)
    order = np.argsort(dest[:, 0], kind="stable")
    dest, K2 = dest[order], np.array(rows2)[order]
    assert np.array_equal(np.sort(dest.ravel()), np.arange(d2_start, d2_stop))
    return dest, K2


def gather_indices(L: Layout) -> tuple[np.ndarray, ...]:
    """Indices of the per-call ``take`` gathers: (idx1, idx2, idx3, u_idx, aw_idx): idx1
    the complex factors of length and unit vector, idx2 the structure matrix's inputs
    component-major, idx3 the lazy leave point's; u_idx and aw_idx the unit vectors' and
    anchors' blocks."""
    # complex (cos a + i sin a / |x|) per (i, j, n), then (lf - i r) per slot
    rep3 = lambda a: np.repeat(a[:, None, :], 3, axis=1)  # noqa: E731  (m,N)->(m,3,N)
    idx1 = np.concatenate(
        [
            np.stack([rep3(L.row("sc", 1)), rep3(L.row("sp"))], axis=-1).ravel(),
            np.stack([L.prow("w_lf", 0), L.prow("w_nr", 0)], axis=-1).ravel(),
        ]
    )
    # structure matrix, component-major (j, i, n): u_j, u_{j+2}, u_{j+1}, aw_{j+1}, aw_{j+2}
    u_idx = L.pvec("outc", 0)  # real parts (the S lengths follow)
    aw_idx = L.vec("aw")

    def jmajor(idx: np.ndarray, shift: int) -> np.ndarray:
        return np.roll(idx, -shift, axis=1).transpose(1, 0, 2).ravel()

    idx2 = np.concatenate(
        [jmajor(u_idx, 0), jmajor(u_idx, 2), jmajor(u_idx, 1)]
        + [jmajor(aw_idx, 1), jmajor(aw_idx, 2)]
    )
    # (lazy) leave point: [r sin a x3, r (1 - cos a)/|x| x3, -e, x]
    idx3 = np.concatenate(
        [
            rep3(L.row("lk", 0)).ravel(),
            rep3(L.row("lk", 2)).ravel(),
            L.pvec("bu", 0).ravel(),
            L.pvec("bu", 1).ravel(),
        ]
    )
    return idx1, idx2, idx3, u_idx, aw_idx
