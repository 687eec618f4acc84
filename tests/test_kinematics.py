"""Kinematics: eq 1 / eq 2 of paper 002, the swivelling-pulley model, FK, allocation."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest
from scipy.optimize import lsq_linear
from scipy.spatial.transform import Rotation

from cablesvc.config import load_robot
from cablesvc.kinematics import (
    PLANAR_WRENCH_ROWS,
    ForwardKinematics,
    InverseKinematics,
    inverse_kinematics,
    matrix_to_quat,
    platform_wrench,
    quat_angle,
    quat_multiply,
    quat_to_matrix,
    quat_to_rotvec,
    rotvec_to_quat,
    structure_matrix,
    wrench_residual,
)

IPANEMA = load_robot("ipanema3").geometry()
COGIRO = load_robot("cogiro").geometry()
PLANAR = load_robot("planar4").geometry()


def without_pulleys(g):
    m = g.n_cables
    return dataclasses.replace(
        g, has_pulley=np.zeros(m, bool), pulley_radius=np.zeros(m),
        pulley_center=g.frame_anchors, pulley_axis=np.zeros((m, 3)),
    )


def with_radius(g, r):
    return dataclasses.replace(g, pulley_radius=np.where(g.has_pulley, r, 0.0))


def random_poses(rng, n, box=(0.8, 0.8, 0.3), z0=0.0, max_angle_deg=10.0):
    pos = rng.uniform(-1, 1, (n, 3)) * np.asarray(box) + np.array([0, 0, z0])
    rv = rng.normal(size=(n, 3))
    rv *= np.radians(rng.uniform(0, max_angle_deg, (n, 1))) / np.linalg.norm(rv, axis=1, keepdims=True)
    return pos, Rotation.from_rotvec(rv).as_quat()


def eq1(g, pos, quat, centers=None):
    """Straight-line cable vectors of eq 1 of 002, l = a - (r + R b), with scipy rotations."""
    R = Rotation.from_quat(quat).as_matrix()
    a = g.frame_anchors if centers is None else centers
    B = pos[:, None, :] + np.einsum("nij,mj->nmi", R, g.platform_anchors)
    return a[None] - B, B


# ---------------------------------------------------------------------------------------
# rotations
# ---------------------------------------------------------------------------------------


def test_rotation_helpers_match_scipy():
    rng = np.random.default_rng(0)
    rot = Rotation.random(50, random_state=1)
    q = rot.as_quat()
    np.testing.assert_allclose(quat_to_matrix(q), rot.as_matrix(), atol=1e-14)
    # un-normalised input is normalised
    np.testing.assert_allclose(quat_to_matrix(3.7 * q), rot.as_matrix(), atol=1e-14)
    q2 = matrix_to_quat(rot.as_matrix())
    assert np.all(q2[:, 3] >= 0)
    np.testing.assert_allclose(np.abs(np.sum(q2 * q, axis=1)), 1.0, atol=1e-12)
    other = Rotation.random(50, random_state=2)
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(q, other.as_quat())), (rot * other).as_matrix(), atol=1e-13
    )
    rv = rng.normal(size=(50, 3))
    np.testing.assert_allclose(
        quat_to_matrix(rotvec_to_quat(rv)), Rotation.from_rotvec(rv).as_matrix(), atol=1e-13
    )
    np.testing.assert_array_equal(rotvec_to_quat(np.zeros(3)), [0, 0, 0, 1])
    small = Rotation.from_rotvec(rv * 1e-3)
    np.testing.assert_allclose(quat_to_rotvec(small.as_quat()), rv * 1e-3, atol=1e-15)
    np.testing.assert_allclose(quat_angle(q, q), 0.0, atol=1e-7)
    np.testing.assert_allclose(quat_angle(q, (rot * Rotation.from_rotvec([0, 0, 0.3])).as_quat()), 0.3)
    # 180-degree rotations go through the non-trace branches of matrix_to_quat
    flips = Rotation.from_rotvec(np.pi * np.eye(3))
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(flips.as_matrix())),
                               flips.as_matrix(), atol=1e-14)


# ---------------------------------------------------------------------------------------
# IK without pulleys: eq 1 of 002
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("geom", [COGIRO, without_pulleys(IPANEMA)], ids=["cogiro", "ipanema3_nopulley"])
def test_ik_without_pulleys_is_eq1(geom):
    rng = np.random.default_rng(1)
    pos, quat = random_poses(rng, 64, z0=1.5 if geom is COGIRO else 0.0)
    st = InverseKinematics(geom, 64)(pos, quat)
    l, B = eq1(geom, pos, quat)
    norm = np.linalg.norm(l, axis=2)
    np.testing.assert_allclose(st.length, norm, rtol=0, atol=1e-12)
    np.testing.assert_allclose(st.free_length, norm, rtol=0, atol=1e-12)
    np.testing.assert_allclose(st.unit, l / norm[..., None], rtol=0, atol=1e-10)
    np.testing.assert_allclose(st.anchor_world, B - pos[:, None, :], atol=1e-14)
    np.testing.assert_allclose(st.leave_point, np.broadcast_to(geom.frame_anchors, B.shape), atol=1e-14)
    assert np.all(st.wrap_angle == 0) and np.all(st.swivel_angle == 0)


def test_unit_vectors_are_unit_and_point_to_leave_point():
    rng = np.random.default_rng(2)
    pos, quat = random_poses(rng, 64)
    st = InverseKinematics(IPANEMA, 64)(pos, quat)
    np.testing.assert_allclose(np.linalg.norm(st.unit, axis=2), 1.0, atol=1e-13)
    B = pos[:, None, :] + st.anchor_world
    to_leave = st.leave_point - B
    np.testing.assert_allclose(to_leave, st.unit * st.free_length[..., None], atol=1e-12)


@pytest.mark.parametrize("geom", [IPANEMA, COGIRO], ids=["ipanema3", "cogiro"])
def test_moving_the_whole_robot_rigidly_leaves_lengths_unchanged(geom):
    rng = np.random.default_rng(3)
    pos, quat = random_poses(rng, 32, z0=1.5 if geom is COGIRO else 0.0)
    st = inverse_kinematics(geom, pos, quat)
    Q = Rotation.from_rotvec([0.4, -1.1, 0.7])
    t = np.array([3.0, -2.0, 0.5])
    moved = dataclasses.replace(  # np.array: scipy rejects the read-only geometry arrays
        geom,
        frame_anchors=Q.apply(np.array(geom.frame_anchors)) + t,
        pulley_center=Q.apply(np.array(geom.pulley_center)) + t,
        pulley_axis=Q.apply(np.array(geom.pulley_axis)),
    )
    st2 = inverse_kinematics(moved, Q.apply(pos) + t, (Q * Rotation.from_quat(quat)).as_quat())
    np.testing.assert_allclose(st2.length, st.length, atol=1e-11)
    np.testing.assert_allclose(st2.wrap_angle, st.wrap_angle, atol=1e-11)
    np.testing.assert_allclose(st2.unit, Q.apply(st.unit.reshape(-1, 3)).reshape(st.unit.shape), atol=1e-11)
    np.testing.assert_allclose(st2.leave_point, Q.apply(st.leave_point.reshape(-1, 3)).reshape(st.unit.shape) + t,
                               atol=1e-10)


# ---------------------------------------------------------------------------------------
# structure matrix and wrenches: eq 2 of 002
# ---------------------------------------------------------------------------------------


def test_structure_matrix_times_forces_is_sum_of_forces_and_moments():
    rng = np.random.default_rng(4)
    pos, quat = random_poses(rng, 16)
    st = inverse_kinematics(IPANEMA, pos, quat)
    AT = structure_matrix(st.unit, st.anchor_world)
    assert AT.shape == (16, 6, 8)
    f = rng.uniform(10, 3000, (16, 8))
    force = np.zeros((16, 3))
    moment = np.zeros((16, 3))
    for n in range(16):
        for i in range(8):
            fi = f[n, i] * st.unit[n, i]
            force[n] += fi
            moment[n] += np.cross(st.anchor_world[n, i], fi)
    np.testing.assert_allclose(np.einsum("nim,nm->ni", AT, f), np.hstack([force, moment]), atol=1e-9)
    # the preallocated method gives the same
    ik = InverseKinematics(IPANEMA, 16)
    ik(pos, quat)
    np.testing.assert_array_equal(ik.structure_matrix(), AT)


def test_platform_weight_wrench():
    rng = np.random.default_rng(5)
    _, quat = random_poses(rng, 8, max_angle_deg=30)
    R = Rotation.from_quat(quat).as_matrix()
    w = platform_wrench(COGIRO, R)
    mg = np.array([0, 0, -9.81 * 91.058])
    np.testing.assert_allclose(w[:, :3], np.broadcast_to(mg, (8, 3)))
    np.testing.assert_allclose(w[:, 3:], np.cross(R @ COGIRO.center_of_gravity, mg), atol=1e-10)
    assert np.abs(w[:, 3:]).max() > 1.0  # the cog is off-centre: a real moment
    # ipanema3: cog at the origin -> pure force
    np.testing.assert_allclose(platform_wrench(IPANEMA, R), np.tile([0, 0, -9.81 * 30, 0, 0, 0], (8, 1)))
    ik = InverseKinematics(COGIRO, 8)
    ik(np.zeros((8, 3)), quat)
    np.testing.assert_allclose(ik.platform_wrench(), w, atol=1e-12)
    f = rng.uniform(0, 1, (8, 8))
    AT = rng.normal(size=(8, 6, 8))
    np.testing.assert_allclose(wrench_residual(AT, f, w), np.einsum("nim,nm->ni", AT, f) + w)


def test_static_equilibrium_of_ipanema3_at_origin():
    st = inverse_kinematics(IPANEMA, np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]]))
    AT = structure_matrix(st.unit, st.anchor_world)
    w = platform_wrench(IPANEMA, st.rotation)
    sol = lsq_linear(AT[0], -w[0], bounds=(IPANEMA.force_min, IPANEMA.force_max), tol=1e-14)
    f = sol.x
    assert np.all(f >= IPANEMA.force_min - 1e-9) and np.all(f <= IPANEMA.force_max + 1e-9)
    res = wrench_residual(AT, f[None], w)
    assert np.abs(res).max() < 1e-6, res
    # the weight is really carried: vertical cable force sum equals m g
    assert np.sum(f * AT[0, 2]) == pytest.approx(30 * 9.81, rel=1e-9)


def test_planar_robot_wrench_rows_balance_in_plane():
    st = inverse_kinematics(PLANAR, np.array([[0.1, -0.2, 0.0]]), np.array([[0, 0, np.sin(0.1), np.cos(0.1)]]))
    AT = structure_matrix(st.unit, st.anchor_world)
    assert np.abs(AT[0, [2, 3, 4]]).max() < 1e-12  # no out-of-plane forces or tilting moments
    w = platform_wrench(PLANAR, st.rotation)
    rows = list(PLANAR_WRENCH_ROWS)
    sol = lsq_linear(AT[0][rows], -w[0][rows], bounds=(PLANAR.force_min, PLANAR.force_max), tol=1e-14)
    res = wrench_residual(AT, sol.x[None], w)[0]
    assert np.abs(res[rows]).max() < 1e-8
    assert res[2] == pytest.approx(-2.0 * 9.81)  # the weight acts out of plane


# ---------------------------------------------------------------------------------------
# pulleys
# ---------------------------------------------------------------------------------------


def _pulley_frame(g, B):
    """Independent reconstruction: x' toward B perpendicular to e, wheel centre M."""
    e = g.pulley_axis
    d = B - g.pulley_center
    dperp = d - np.sum(d * e, axis=-1, keepdims=True) * e
    xp = dperp / np.linalg.norm(dperp, axis=-1, keepdims=True)
    M = g.pulley_center + g.pulley_radius[:, None] * xp
    return e, xp, M


@pytest.mark.parametrize("geom", [IPANEMA, PLANAR], ids=["ipanema3", "planar4"])
def test_pulley_geometry_properties(geom):
    rng = np.random.default_rng(6)
    pos, quat = random_poses(rng, 64, box=(0.8, 0.8, 0.2) if geom is IPANEMA else (0.5, 0.5, 0.0))
    if geom is PLANAR:
        quat = Rotation.from_rotvec(np.c_[np.zeros((64, 2)), rng.uniform(-0.3, 0.3, 64)]).as_quat()
    st = InverseKinematics(geom, 64)(pos, quat)
    B = pos[:, None, :] + st.anchor_world
    r = geom.pulley_radius
    e, xp, M = _pulley_frame(geom, B)
    straight = np.linalg.norm(B - geom.pulley_center, axis=2)
    assert np.all(st.length >= straight - 1e-12)
    assert np.all(st.length > straight + 1e-4)  # these poses really wrap the wheels
    assert np.all((st.wrap_angle >= 0) & (st.wrap_angle < 2 * np.pi))
    # leave point on the wheel, in the wheel plane, free segment tangent to the wheel
    np.testing.assert_allclose(np.linalg.norm(st.leave_point - M, axis=2), np.broadcast_to(r, B.shape[:2]), atol=1e-12)
    n_plane = np.cross(e, xp)
    np.testing.assert_allclose(np.sum((st.leave_point - geom.pulley_center) * n_plane, axis=2), 0, atol=1e-11)
    tangency = np.sum((st.leave_point - M) * (B - st.leave_point), axis=2)
    np.testing.assert_allclose(tangency, 0.0, atol=1e-11)
    np.testing.assert_allclose(np.linalg.norm(B - st.leave_point, axis=2), st.free_length, atol=1e-12)
    np.testing.assert_allclose(st.length, st.free_length + r * st.wrap_angle, atol=1e-12)
    # the wrap angle is the deflection of the cable: it arrives along +e and leaves along
    # -u, turning toward x' (cos alpha = e.(-u), sin alpha = x'.(-u))
    np.testing.assert_allclose(np.cos(st.wrap_angle), np.sum(-st.unit * e, axis=2), atol=1e-11)
    np.testing.assert_allclose(np.sin(st.wrap_angle), np.sum(-st.unit * xp, axis=2), atol=1e-11)


def test_ipanema3_wrap_angles_are_plausible_at_origin():
    st = inverse_kinematics(IPANEMA, np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]]))
    # upper pulleys: cable comes up the column, turns over and down toward the platform;
    # lower pulleys: comes down, turns under and up: both turn by 90 deg + the small slope
    B = st.anchor_world[0]
    C = IPANEMA.pulley_center
    slope = np.arctan2(np.abs(C[:, 2] - B[:, 2]), np.linalg.norm((C - B)[:, :2], axis=1))
    np.testing.assert_allclose(st.wrap_angle[0], np.pi / 2 + slope, atol=0.02)


def test_length_converges_to_straight_distance_as_radius_vanishes():
    rng = np.random.default_rng(7)
    pos, quat = random_poses(rng, 16)
    _, B = eq1(IPANEMA, pos, quat)
    straight = np.linalg.norm(B - IPANEMA.pulley_center, axis=2)
    errs = []
    for r in (1e-1, 1e-2, 1e-3, 1e-4, 1e-9):
        st = inverse_kinematics(with_radius(IPANEMA, r), pos, quat)
        errs.append(np.abs(st.length - straight).max())
        assert errs[-1] <= 3.0 * r
    assert errs[-1] < 1e-8
    assert all(a > b for a, b in zip(errs, errs[1:]))


@pytest.mark.parametrize("geom", [IPANEMA, PLANAR], ids=["ipanema3", "planar4"])
def test_length_gradient_is_minus_unit_vector(geom):
    """d length / d position = -u and d length / d rotation = -(R b) x u: the cable is tangent
    at the leave point. A wrong arc term (e.g. r*(pi - alpha), or no arc) breaks this."""
    rng = np.random.default_rng(8)
    n = 8
    pos, quat = random_poses(rng, n, box=(0.5, 0.5, 0.1 if geom is IPANEMA else 0.0))
    ik = InverseKinematics(geom, n)
    st = ik(pos, quat)
    unit = st.unit.copy()
    AT = ik.structure_matrix().copy()
    h = 1e-6
    for k in range(3):
        dp = np.zeros(3)
        dp[k] = h
        lp = ik(pos + dp, quat).length.copy()
        lm = ik(pos - dp, quat).length.copy()
        np.testing.assert_allclose((lp - lm) / (2 * h), -unit[..., k], atol=2e-7)
    for k in range(3):
        rv = np.zeros(3)
        rv[k] = h
        qp = (Rotation.from_rotvec(rv) * Rotation.from_quat(quat)).as_quat()
        qm = (Rotation.from_rotvec(-rv) * Rotation.from_quat(quat)).as_quat()
        lp = ik(pos, qp).length.copy()
        lm = ik(pos, qm).length.copy()
        np.testing.assert_allclose((lp - lm) / (2 * h), -AT[:, 3 + k, :], atol=2e-7)


def test_swivel_follows_the_anchor_around_the_axis():
    """Moving the platform anchor around a pulley's swivel axis turns the swivel by the same
    angle and leaves length and wrap angle unchanged."""
    g = IPANEMA
    i = 0
    C, e = g.pulley_center[i], g.pulley_axis[i]
    q = np.array([[0, 0, 0, 1.0]])
    B0 = np.array([0.3, 0.2, 0.1])
    out = []
    for phi in (0.0, 0.05, -0.1):
        B = C + Rotation.from_rotvec(phi * e).apply(B0 - C)
        pos = B - g.platform_anchors[i]
        st = inverse_kinematics(g, pos[None], q)
        out.append((st.length[0, i], st.wrap_angle[0, i], st.swivel_angle[0, i]))
    L, a, s = np.array(out).T
    np.testing.assert_allclose(L, L[0], atol=1e-12)
    np.testing.assert_allclose(a, a[0], atol=1e-12)
    np.testing.assert_allclose(s - s[0], [0.0, 0.05, -0.1], atol=1e-12)


@pytest.mark.parametrize("h", [1.0, -1.0])
def test_anchor_on_swivel_axis_is_finite(h):
    """Degenerate swivel: the platform anchor lies on the pulley axis. No NaN; above the
    pulley the cable runs straight up the axis (alpha = 0); below it wraps half way round
    plus the tangent angle."""
    g = IPANEMA
    i = 0  # upper pulley, e = +z
    r = g.pulley_radius[i]
    B = g.pulley_center[i] + np.array([0.0, 0.0, h])
    pos = (B - g.platform_anchors[i])[None]
    st = inverse_kinematics(g, pos, np.array([[0, 0, 0, 1.0]]))
    for name in ("length", "free_length", "unit", "wrap_angle", "leave_point", "swivel_angle"):
        assert np.all(np.isfinite(getattr(st, name))), name
    if h > 0:
        assert st.wrap_angle[0, i] == 0.0
        assert st.length[0, i] == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(st.unit[0, i], [0, 0, -1], atol=1e-12)
    else:
        alpha = np.pi + 2 * np.arctan(r / 1.0)
        assert st.wrap_angle[0, i] == pytest.approx(alpha, abs=1e-12)
        assert st.length[0, i] == pytest.approx(1.0 + r * alpha, abs=1e-12)


def test_call_rejects_wrong_batch_and_state_is_reused():
    ik = InverseKinematics(IPANEMA, 2)
    with pytest.raises(ValueError):
        ik(np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)))
    with pytest.raises(ValueError):
        ik(np.zeros(3), np.array([0, 0, 0, 1.0]))
    st = ik(np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    first = st.length.copy()
    kept = st.copy()
    st2 = ik(np.full((2, 3), 0.3), np.tile([0, 0, 0, 1.0], (2, 1)))
    assert st2.length is st.length  # same preallocated arrays, overwritten
    assert not np.allclose(st.length, first)
    np.testing.assert_array_equal(kept.length, first)


def test_ik_call_does_not_grow_memory():
    ik = InverseKinematics(IPANEMA, 4)
    rng = np.random.default_rng(9)
    pos, quat = random_poses(rng, 4)
    for _ in range(20):
        ik(pos, quat)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for _ in range(2000):
            ik(pos, quat)
        growth = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert growth < 1024, growth


@pytest.mark.parametrize("batch", [1, 4])
@pytest.mark.parametrize("with_lazy", [False, True], ids=["tick", "tick+lazy"])
def test_per_tick_path_allocates_nothing(batch, with_lazy):
    """IK + structure matrix + platform wrench (the kernel's per-tick path) allocate no
    memory, not even transiently: a broadcast operand, a strided 2-D view or a temporary
    makes numpy allocate an iterator buffer or an array (>= ~1 KB peak)."""
    ik = InverseKinematics(IPANEMA, batch)
    rng = np.random.default_rng(19)
    pos, quat = random_poses(rng, batch)

    def tick():
        st = ik(pos, quat)
        ik.structure_matrix()
        ik.platform_wrench()
        if with_lazy:
            st.leave_point
            st.swivel_angle

    tracemalloc.start()
    try:
        for _ in range(50):
            tick()
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        for _ in range(10_000):
            tick()
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert current - base < 256, current - base
    assert peak - base < 1024, peak - base


def _reference_ik(g, pos, quat):
    """The pulley model of the ik module docstring evaluated directly, as the implementation
    before the per-call optimisation did (allocating, eq 1 rounding): the reference values."""
    from cablesvc.kinematics.ik_layout import FOLD_TOL, EPS_SWIVEL, swivel_reference

    pulley = np.asarray(g.has_pulley)
    mask = pulley.astype(float)
    r = np.asarray(g.pulley_radius) * mask
    e = np.array(g.pulley_axis, dtype=float)
    e[~pulley] = (0.0, 0.0, 1.0)
    ref = swivel_reference(g, e)
    s2 = np.cross(e, ref)
    C = np.asarray(g.pulley_center)
    R = quat_to_matrix(quat)
    aw = np.einsum("nij,mj->nmi", R, g.platform_anchors)
    d = (pos[:, None, :] + aw) - C
    de = np.einsum("nmk,mk->nm", d, e)
    xp = d - de[..., None] * e + EPS_SWIVEL * ref
    xp /= np.sqrt(np.sum(xp * xp, axis=-1) + 1e-300)[..., None]
    vx = np.sum(d * xp, axis=-1) - r
    lf = np.sqrt(np.maximum(vx * vx + de * de - r * r, 0.0))
    alpha = np.arctan2(vx, de) + np.arctan2(r, lf)
    wa = np.maximum(np.mod(alpha + FOLD_TOL, 2 * np.pi) - FOLD_TOL, 0.0) * mask
    ca, sa = np.cos(alpha), np.sin(alpha)
    return dict(
        length=wa * r + lf,
        free_length=lf,
        unit=-(sa[..., None] * xp + ca[..., None] * e),
        wrap_angle=wa,
        anchor_world=aw,
        leave_point=C + ((1 - ca) * r)[..., None] * xp + (sa * r)[..., None] * e,
        swivel_angle=np.arctan2(np.sum(xp * s2, -1), np.sum(xp * ref, -1)) * mask,
        rotation=R,
    )


@pytest.mark.parametrize("batch", [1, 5])
@pytest.mark.parametrize(
    "geom", [IPANEMA, COGIRO, PLANAR, without_pulleys(IPANEMA)],
    ids=["ipanema3", "cogiro", "planar4", "ipanema3_nopulley"],
)
def test_ik_matches_reference_formulas(geom, batch):
    """Every result of the optimised call equals the direct evaluation of the model to
    1e-12 relative (absolute 1e-14 for components that are ~0), for single poses and
    batches, un-normalised quaternions included."""
    rng = np.random.default_rng(20)
    ik = InverseKinematics(geom, batch)
    for _ in range(20):
        pos, quat = random_poses(rng, batch, z0=1.5 if geom is COGIRO else 0.0, max_angle_deg=20)
        if geom is PLANAR:
            pos[:, 2] = 0.0
        quat = quat * rng.uniform(0.5, 2.0, (batch, 1))
        st = ik(pos, quat)
        ref = _reference_ik(geom, pos, quat)
        for name, want in ref.items():
            np.testing.assert_allclose(getattr(st, name), want, rtol=1e-12, atol=1e-14, err_msg=name)
        AT = structure_matrix(ref["unit"], ref["anchor_world"])
        np.testing.assert_allclose(ik.structure_matrix(), AT, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(
            ik.platform_wrench(), platform_wrench(geom, ref["rotation"]), rtol=1e-12, atol=1e-12
        )


def test_single_pose_path_equals_batched_path():
    """N = 1 evaluates the pose in Python floats, N > 1 vectorised: same results."""
    rng = np.random.default_rng(21)
    pos, quat = random_poses(rng, 6)
    batched = InverseKinematics(IPANEMA, 6)
    st = batched(pos, quat).copy()
    AT = batched.structure_matrix().copy()
    w = batched.platform_wrench().copy()
    single = InverseKinematics(IPANEMA, 1)
    for n in range(6):
        s1 = single(pos[n : n + 1], quat[n : n + 1])
        for name in ("length", "free_length", "unit", "wrap_angle", "anchor_world",
                     "leave_point", "swivel_angle", "rotation"):
            np.testing.assert_allclose(getattr(s1, name)[0], getattr(st, name)[n],
                                       rtol=1e-14, atol=1e-15, err_msg=name)
        np.testing.assert_allclose(single.structure_matrix()[0], AT[n], rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(single.platform_wrench()[0], w[n], rtol=1e-14, atol=1e-12)


@pytest.mark.parametrize("batch", [1, 3])
def test_lazy_results_follow_each_call(batch):
    """leave_point / swivel_angle are filled on first access after each call, into the
    same arrays, also through the InverseKinematics attributes; a NaN pose leaves no
    trace in the next call."""
    rng = np.random.default_rng(22)
    ik = InverseKinematics(IPANEMA, batch)
    p1, q1 = random_poses(rng, batch)
    p2, q2 = random_poses(rng, batch)
    st = ik(p1, q1)
    lp, sw = st.leave_point, st.swivel_angle
    lp1, sw1 = lp.copy(), sw.copy()
    ik(p2, q2)
    assert ik.leave_point is lp and st.swivel_angle is sw
    ref2 = _reference_ik(IPANEMA, p2, q2)
    np.testing.assert_allclose(lp, ref2["leave_point"], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(ik.swivel_angle, ref2["swivel_angle"], rtol=1e-12, atol=1e-14)
    assert not np.allclose(lp, lp1) and not np.allclose(sw, sw1)
    with np.errstate(all="ignore"):
        ik(np.full((batch, 3), np.nan), q1)
        ik.structure_matrix()
        st.leave_point
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        st = ik(p1, q1)
        AT = ik.structure_matrix()
    np.testing.assert_array_equal(st.leave_point, lp1)
    ref1 = _reference_ik(IPANEMA, p1, q1)
    np.testing.assert_allclose(st.length, ref1["length"], rtol=1e-12)
    np.testing.assert_allclose(AT, structure_matrix(ref1["unit"], ref1["anchor_world"]),
                               rtol=1e-12, atol=1e-14)


# ---------------------------------------------------------------------------------------
# forward kinematics
# ---------------------------------------------------------------------------------------


def _perturb(rng, pos, quat, dist=0.02, angle_deg=2.0, planar=False):
    n = len(pos)
    dp = rng.normal(size=(n, 3))
    rv = rng.normal(size=(n, 3))
    if planar:
        dp[:, 2] = 0
        rv[:, :2] = 0
    dp *= dist / np.linalg.norm(dp, axis=1, keepdims=True)
    rv *= np.radians(angle_deg) / np.linalg.norm(rv, axis=1, keepdims=True)
    return pos + dp, (Rotation.from_rotvec(rv) * Rotation.from_quat(quat)).as_quat()


@pytest.mark.parametrize("geom", [IPANEMA, COGIRO], ids=["ipanema3", "cogiro"])
def test_fk_recovers_pose_from_exact_lengths(geom):
    rng = np.random.default_rng(10)
    n = 32
    pos, quat = random_poses(rng, n, box=(1.0, 1.0, 0.3), z0=1.5 if geom is COGIRO else 0.0)
    lengths = inverse_kinematics(geom, pos, quat).length
    p0, q0 = _perturb(rng, pos, quat)
    fk = ForwardKinematics(geom, iterations=8)
    res = fk.solve(lengths, p0, q0)
    assert np.linalg.norm(res.position - pos, axis=1).max() < 1e-6
    assert quat_angle(res.orientation, quat).max() < 1e-6
    np.testing.assert_allclose(np.linalg.norm(res.orientation, axis=1), 1.0, atol=1e-12)
    assert res.residual.shape == (n, geom.n_cables) and res.residual_rms.shape == (n,)
    assert res.residual_rms.max() < 1e-9
    np.testing.assert_allclose(res.residual_rms, np.sqrt(np.mean(res.residual ** 2, axis=1)))
    # the residual is honest: a single iteration from 2 cm off is not yet converged
    one = ForwardKinematics(geom, iterations=1).solve(lengths, p0, q0)
    assert one.residual_rms.max() > 1e-8
    assert np.linalg.norm(one.position - pos, axis=1).max() > 1e-7


def test_fk_planar_solves_x_y_yaw_only():
    rng = np.random.default_rng(11)
    n = 16
    pos = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), np.zeros(n)]
    yaw = rng.uniform(-0.35, 0.35, n)
    quat = Rotation.from_rotvec(np.c_[np.zeros((n, 2)), yaw]).as_quat()
    lengths = inverse_kinematics(PLANAR, pos, quat).length
    p0, q0 = _perturb(rng, pos, quat, planar=True)
    res = ForwardKinematics(PLANAR).solve(lengths, p0, q0)
    assert np.linalg.norm(res.position - pos, axis=1).max() < 1e-6
    assert quat_angle(res.orientation, quat).max() < 1e-6
    assert np.all(res.position[:, 2] == 0.0)
    np.testing.assert_allclose(res.orientation[:, :2], 0.0, atol=1e-15)  # no roll or pitch
    assert res.residual_rms.max() < 1e-9


def test_fk_reports_residual_for_inconsistent_lengths():
    pos = np.zeros((1, 3))
    quat = np.array([[0, 0, 0, 1.0]])
    lengths = inverse_kinematics(IPANEMA, pos, quat).length.copy()
    lengths[0, 3] += 0.01  # 1 cm too long: no pose fits all eight exactly
    res = ForwardKinematics(IPANEMA).solve(lengths, pos, quat)
    assert 1e-4 < res.residual_rms[0] < 0.01
    assert np.all(np.isfinite(res.position))


def test_a_long_batch_runs_in_pieces_with_the_results_of_one(monkeypatch):
    """inverse_kinematics on more poses than IK_CHUNK solves them piece by piece (the
    solver's work buffers took ~15 KB per pose: 530 MB for a 35 000-tick calibration) and
    returns every field as one batch would, the last, shorter piece included."""
    from cablesvc.kinematics import ik as K
    rng = np.random.default_rng(5)
    n = 2 * 64 + 17
    p = rng.normal(0.0, 0.3, (n, 3))
    q = np.c_[rng.normal(0.0, 0.05, (n, 3)), np.ones(n)]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    whole = K.InverseKinematics(IPANEMA, n)(p, q).copy()
    monkeypatch.setattr(K, "IK_CHUNK", 64)
    pieces = K.inverse_kinematics(IPANEMA, p, q)
    for k in K._STATE_FIELDS:
        a, b = getattr(pieces, k), getattr(whole, k)
        assert a.shape == b.shape, k
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12, err_msg=k)
    one = K.inverse_kinematics(IPANEMA, p[-1], q[-1])             # the last pose, alone
    np.testing.assert_allclose(pieces.length[-1], one.length[0], rtol=1e-12, atol=1e-12)
