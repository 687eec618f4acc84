"""The fixed-time per-tick kernel: one robot, one cable model, every control tick.

Per tick it takes (t, pose or none, motor_length [m], optional measured force [N],
optional temperature [deg C]) and returns, per cable: predicted force [N], elongation
x = l(pose) - motor_length [m] (recording spec), wrap angle [rad], slack flag; the
wrench residual A^T f + w [N, N m] (eq 2 of 002) and, with measured forces, the residual
measured - predicted [N].

All buffers are allocated in ``__init__``; a tick runs the same numpy operations
whatever the data, with no Python branch on values and no array allocation (the pose
path; see ``tests/test_kernel.py``). Outputs are views of the kernel's buffers that the
next tick overwrites: copy what you keep.

Without a pose on the bus the pose is found from the motor lengths by an elasto-static
forward kinematics: a fixed number of damped Gauss-Newton (Levenberg-Marquardt) steps
on the platform equilibrium A^T f + w = 0 with linear cable forces f = EA/l0 * x,
warm-started from the last pose (first tick: the geometric FK of
:class:`cablesvc.kinematics.ForwardKinematics` on the motor lengths). The step is
dp = (A^T K A + lambda diag(A^T K A))^-1 (A^T f + w) with K = diag(EA/l0), since moving
the platform by dp changes the lengths by -A dp; the rotation part of dp is a rotation
vector applied in the world frame. Hysteresis shifts the forces by a few newtons, which
moves the equilibrium pose by a second-order amount; the residual |A^T f + w| after the
last step is reported. This path too is fixed time and allocation-free after the first
tick: the same numpy calls on preallocated buffers every step (the r x r solve, r = 6 or
3 for planar robots, is LAPACK's Cholesky solve ``dposv`` through scipy.linalg.lapack,
overwriting the preallocated system and right-hand side: A^T K A plus the damping is
symmetric positive definite), and the pose update in Python floats, as
:class:`~cablesvc.kinematics.InverseKinematics` loads poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cablesvc.config.params import ModelParams
from cablesvc.config.robot import RobotGeometry
from cablesvc.kinematics import ForwardKinematics, InverseKinematics
from cablesvc.kinematics.ik import PLANAR_WRENCH_ROWS
from cablesvc.models import CableModel
from cablesvc.models.terms import TermStack

from scipy.linalg.lapack import dposv as _dposv

#: dp's scale after the Cholesky solve, by "the factorisation failed" (a system that is not
#: positive definite): NaN then, as a singular LU solve gives, so the FK reports divergence
_SOLVE_SCALE = (1.0, math.nan)


@dataclass
class TickOutput:
    """Outputs of one tick. Arrays are the kernel's buffers (overwritten next tick)."""

    t: float
    force: np.ndarray            # (m,) predicted tension [N], never negative
    elongation: np.ndarray       # (m,) x = l(pose) - motor_length [m]
    wrap_angle: np.ndarray       # (m,) pulley wrap angle alpha [rad]
    slack: np.ndarray            # (m,) bool: predicted tension below the slack threshold
    wrench_residual: np.ndarray  # (6,) A^T f + w [N, N m]
    measured: np.ndarray         # (m,) measured force [N], NaN when the bus has none
    residual: np.ndarray         # (m,) measured - predicted [N], NaN without measurements
    position: np.ndarray         # (3,) pose used [m]
    orientation: np.ndarray      # (4,) [qx, qy, qz, qw]
    amplitude: np.ndarray        # (m,) elongation amplitude estimate [m] (amplitude model; NaN otherwise)
    temperature: float           # deg C, NaN when absent
    pose_from_fk: bool           # True when the pose came from the elasto-static FK
    fk_residual: float           # |A^T f + w| after the FK [N]; 0 with a measured pose


class Predictor:
    """Fixed-time force predictor for one robot. See the module docstring."""

    def __init__(self, geom: RobotGeometry, params: ModelParams, *, fk_iterations: int = 4,
                 fk_damping: float = 1e-3, slack_threshold: float | np.ndarray | None = None,
                 max_rate_hz: float = 2000.0):
        self.geom = geom
        self.params = params
        m = self.n_cables = geom.n_cables
        self.model: CableModel = params.build(m, lanes=1)
        # the parameter file's discovered terms (and baseline recalibration), live: None without
        self.terms: TermStack | None = TermStack.from_params(params.identification, m, lanes=1,
                                                             max_rate_hz=max_rate_hz)
        self.ik = InverseKinematics(geom, 1)
        self.fk_geometric = ForwardKinematics(geom)
        self.fk_iterations = int(fk_iterations)
        self.fk_damping = float(fk_damping)
        self._rows = np.array(PLANAR_WRENCH_ROWS if geom.planar else range(6))
        thr = np.asarray(geom.force_min if slack_threshold is None else slack_threshold, float)
        self.slack_threshold = np.ascontiguousarray(np.broadcast_to(thr, (m,)))
        self._ea = np.ascontiguousarray(geom.ea, dtype=float)
        # input buffers
        self._pos = np.zeros((1, 3))
        self._quat = np.zeros((1, 4))
        self._quat[0, 3] = 1.0
        self._ml = np.zeros((1, m))
        # output buffers
        self._x = np.zeros((1, m))
        self._f = np.zeros(m)
        self._ft = np.zeros(m)                     # baseline + terms, before the slack clamp
        self._slack = np.zeros(m, dtype=bool)
        self._wres = np.zeros(6)
        self._meas = np.full(m, np.nan)
        self._res = np.full(m, np.nan)
        self._nan_m = np.full(m, np.nan)
        self._amp = np.full(m, np.nan)
        self._ml0 = self._ml[0]
        self._pos0 = self._pos[0]
        self._quat0 = self._quat[0]
        self._x0 = self._x[0]
        self._AT0 = self.ik.AT[0]
        self._w0 = self.ik.wrench[0]
        self._wrap0 = self.ik.state.wrap_angle[0]
        self._amp_src = None
        # elasto-static FK buffers (r = number of wrench rows solved for)
        r = self._rows.size
        self._fk_k = np.empty(m)                 # EA / l0 [N/m]
        self._fk_x = np.empty(m)
        self._fk_f = np.empty(m)
        self._fk_g6 = np.empty(6)
        self._fk_g = np.empty(r)
        self._fk_ATr = np.empty((r, m))
        self._fk_ATrT = self._fk_ATr.T
        self._fk_ATk = np.empty((r, m))
        self._fk_K = np.empty((r, r))
        self._fk_Kdiag = self._fk_K.reshape(-1)[:: r + 1]
        self._fk_KT = self._fk_K.T                 # Fortran-ordered view for LAPACK (K symmetric)
        self._fk_dp = np.empty(r)
        self._fk_dp6 = np.zeros(6)
        self._fk_scatter = np.eye(6)[:, self._rows]   # (6, r): dp_r -> dp
        self._len0 = self.ik.state.length[0]
        # one output object, updated in place every tick
        self.out = TickOutput(
            t=0.0, force=self._f, elongation=self._x0, wrap_angle=self._wrap0, slack=self._slack,
            wrench_residual=self._wres, measured=self._meas, residual=self._res, position=self._pos0,
            orientation=self._quat0, amplitude=self._amp, temperature=float("nan"), pose_from_fk=False,
            fk_residual=0.0)
        self.state = None
        self._t_prev = None
        self._have_pose = False
        self.ticks = 0

    # -- state ------------------------------------------------------------------------
    def reset(self, x0: np.ndarray | None = None) -> None:
        """Forget the history: the next tick starts the model at rest, and without a pose
        on the bus the FK starts again from the geometric FK (from the last pose when it is
        finite, else from the home pose)."""
        self.state = None
        self._t_prev = None
        self._have_pose = False
        if self.terms is not None:                   # the terms' history too (clock, delay line, z)
            self.terms = TermStack.from_params(self.params.identification, self.n_cables, lanes=1,
                                               max_rate_hz=self.terms.max_rate_hz)
        if not (np.isfinite(self._pos).all() and np.isfinite(self._quat).all()):
            self._home_pose()

    def _home_pose(self) -> None:
        self._pos.fill(0.0)
        self._quat.fill(0.0)
        self._quat[0, 3] = 1.0

    def state_dict(self) -> dict[str, np.ndarray]:
        """Everything needed to continue exactly where this kernel is (hysteresis state,
        last pose, last time): for atomic snapshots."""
        if self.state is None:
            return {}
        d = {f"model.{k}": v for k, v in self.state.as_dict().items()}
        d["pose.position"] = self._pos.copy()
        d["pose.orientation"] = self._quat.copy()
        d["t_prev"] = np.array([self._t_prev])
        d["last.elongation"] = self._x.copy()
        d["last.motor_length"] = self._ml.copy()
        if self.terms is not None:
            d.update({f"terms.{k}": v for k, v in self.terms.state_dict().items()})
        return d

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        self.state = self.model.create_state(0.0)
        self.state.load_dict({k[6:]: v for k, v in d.items() if k.startswith("model.")})
        self._pos[...] = d["pose.position"]
        self._quat[...] = d["pose.orientation"]
        self._t_prev = float(d["t_prev"][0])
        self._have_pose = True
        self._amp_src = self._amplitude_view()
        if self.terms is not None:
            self.terms.load_state_dict({k[6:]: v for k, v in d.items() if k.startswith("terms.")})
            if "last.motor_length" in d:   # a kernel without these terms before: their rates start right
                self.terms.prime(self._t_prev, d["last.elongation"], d["last.motor_length"])

    def _amplitude_view(self) -> np.ndarray | None:
        a = self.model.amplitude(self.state)
        return None if a is None else a[0]

    # -- the tick ---------------------------------------------------------------------
    def tick(self, t: float, motor_length, position=None, orientation=None, force=None,
             temperature: float | None = None) -> TickOutput:
        """One control tick. ``motor_length`` (m,) [m]; ``position`` (3,) [m] and
        ``orientation`` (4,) [qx, qy, qz, qw] or None (then the elasto-static FK runs);
        ``force`` (m,) measured [N] or None; ``temperature`` [deg C] or None. Inputs must be
        numpy float arrays of the right shape (the service checks them before the kernel).
        Returns ``self.out``, updated in place."""
        ml = self._ml
        np.copyto(self._ml0, motor_length)
        from_fk = position is None or orientation is None
        if from_fk:
            fk_res = self._elastostatic_fk()         # ends with the IK at the pose it found
            ik = self.ik.state
        else:
            np.copyto(self._pos0, position)
            np.copyto(self._quat0, orientation)
            fk_res = 0.0
            ik = self.ik(self._pos, self._quat)
        x = self._x
        np.subtract(ik.length, ml, x)
        if self.state is None:
            self.state = self.model.create_state(x)
            self._t_prev = t
            self._amp_src = self._amplitude_view()
        dt = max(t - self._t_prev, 0.0)             # time going backwards is the source's to reject
        self._t_prev = t
        fm = self.model.step(self.state, x, dt, ml)[0]
        if self.terms is not None:                   # fixed when built, not a data branch
            np.add(fm, self.terms.step(t, fm[None, :], x, ml, ik.wrap_angle, ik.free_length, temperature)[0],
                   out=self._ft)
            fm = self._ft
        f = self._f
        np.maximum(fm, 0.0, out=f)                   # a cable cannot push
        np.less(fm, self.slack_threshold, out=self._slack)
        self.ik.structure_matrix()
        self.ik.platform_wrench()
        np.matmul(self._AT0, f, out=self._wres)
        np.add(self._wres, self._w0, self._wres)
        np.copyto(self._meas, self._nan_m if force is None else force)
        np.subtract(self._meas, f, self._res)
        if self._amp_src is not None:                 # fixed by the model, not a data branch
            np.copyto(self._amp, self._amp_src)
        self.ticks += 1
        out = self.out
        out.t = t
        out.temperature = float("nan") if temperature is None else float(temperature)
        out.pose_from_fk = from_fk
        out.fk_residual = fk_res
        return out

    def _elastostatic_fk(self) -> float:
        """Pose from motor lengths: fixed-count damped Gauss-Newton on A^T f + w = 0 (see
        the module docstring). Leaves the IK evaluated at the pose found; returns
        |A^T f + w| there [N] (over the solved rows). Raises FloatingPointError if the
        pose is no longer finite (the next tick then starts again from the geometric FK)."""
        ml0 = self._ml0
        if not self._have_pose:
            res = self.fk_geometric.solve(self._ml, self._pos, self._quat)
            self._pos[...] = res.position
            self._quat[...] = res.orientation
            self._have_pose = True
        rows, k, g = self._rows, self._fk_k, self._fk_g
        ATr, ATrT, ATk, K, Kdiag = self._fk_ATr, self._fk_ATrT, self._fk_ATk, self._fk_K, self._fk_Kdiag
        KT = self._fk_KT
        dp, dp6, scatter, AT = self._fk_dp, self._fk_dp6, self._fk_scatter, self._AT0
        pos0, quat0 = self._pos0, self._quat0
        np.divide(self._ea, ml0, out=k)
        damp = 1.0 + self.fk_damping
        for _ in range(self.fk_iterations):          # a fixed count, not a data-dependent loop
            self._fk_wrench()
            AT.take(rows, 0, ATr)
            np.multiply(ATr, k, out=ATk)
            np.matmul(ATk, ATrT, out=K)               # A^T K A over the solved rows
            np.multiply(Kdiag, damp, out=Kdiag)
            # dp = K^-1 g in place: LAPACK's Cholesky solve on the preallocated buffers (K is
            # symmetric, so its transpose is the Fortran-ordered view LAPACK takes without a copy)
            np.copyto(dp, g)
            info = _dposv(KT, dp, overwrite_a=1, overwrite_b=1)[2]
            np.multiply(dp, _SOLVE_SCALE[info != 0], out=dp)
            np.matmul(scatter, dp, out=dp6)
            # r <- r + dp[:3]; q <- q(dp[3:]) q, the rotation vector dp[3:] in the world frame
            dx, dy, dz, wx, wy, wz = dp6.tolist()
            (px, py, pz), = self._pos.tolist()
            (qx, qy, qz, qw), = self._quat.tolist()
            h = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz) + 1e-300   # half angle; > 0
            sc = math.sin(h) / (2.0 * h)                                # sin(theta/2) / theta
            ax, ay, az, aw = wx * sc, wy * sc, wz * sc, math.cos(h)
            nx = aw * qx + ax * qw + ay * qz - az * qy
            ny = aw * qy - ax * qz + ay * qw + az * qx
            nz = aw * qz + ax * qy - ay * qx + az * qw
            nw = aw * qw - ax * qx - ay * qy - az * qz
            inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz + nw * nw)
            pos0[0] = px + dx
            pos0[1] = py + dy
            pos0[2] = pz + dz
            quat0[0] = nx * inv
            quat0[1] = ny * inv
            quat0[2] = nz * inv
            quat0[3] = nw * inv
        self._fk_wrench()
        res = math.sqrt(float(np.dot(g, g)))
        if not math.isfinite(res):
            # (a singular system gives NaN, not an exception): do not warm-start from it
            self._have_pose = False
            self._home_pose()
            raise FloatingPointError(f"elasto-static FK diverged (residual {res}); the next tick starts again "
                                     "from the geometric FK")
        return res

    def _fk_wrench(self) -> None:
        """IK at the current pose, linear forces f = EA/l0 x, and the wrench residual
        A^T f + w over the solved rows, into ``_fk_g``."""
        ik, g6 = self.ik, self._fk_g6
        ik(self._pos, self._quat)
        np.subtract(self._len0, self._ml0, self._fk_x)
        np.multiply(self._fk_k, self._fk_x, self._fk_f)
        ik.structure_matrix()
        np.matmul(self._AT0, self._fk_f, out=g6)
        np.add(g6, self._w0, g6)
        g6.take(self._rows, None, self._fk_g)
