"""Amplitude-dependent cable model with velocity-dependent damping (eqs 8, 9, 15-17 of 002)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

from cablesvc.models.base import CableModel, ModelParameterError, ModelState
from cablesvc.models.polynomial import update_direction

TABLE_COLUMNS = ("K0", "K1", "K2", "K3", "S_a", "alpha")
#: points of the uniform amplitude grid the tables are resampled on when the model is built
GRID_POINTS = 256


def sine_power_integral(alpha: np.ndarray) -> np.ndarray:
    """I(alpha) = int_0^pi sin(u)^(alpha+1) du = sqrt(pi) G(alpha/2 + 1) / G(alpha/2 + 3/2).

    The integral of eqs 9 and 17 of 002 (dimensionless)."""
    a = np.asarray(alpha, dtype=np.float64)
    return np.sqrt(np.pi) * np.exp(gammaln(a / 2 + 1) - gammaln(a / 2 + 1.5))


def damping_normaliser(alpha: np.ndarray) -> np.ndarray:
    """q(alpha) = 1 / (2 I(alpha)): with it the damping term of eq 8 dissipates exactly
    S_a per cycle of a sinusoid of amplitude A (see AmplitudeDependent)."""
    return 1.0 / (2.0 * sine_power_integral(alpha))


@dataclass
class AmplitudeState(ModelState):
    x_prev: np.ndarray
    direction: np.ndarray
    hi: np.ndarray             # elongation at the last maximum (reversal from + to -) [m]
    lo: np.ndarray             # elongation at the last minimum [m]
    t_rev: np.ndarray          # time of the last reversal [s]
    half_period: np.ndarray    # time between the last two reversals [s]
    clock: np.ndarray          # (1,) time since create_state [s]
    amplitude: np.ndarray      # current amplitude estimate A [m] (read-only output)


class AmplitudeDependent(CableModel):
    """Amplitude-dependent hysteresis model of 002, eq 8:

    ``F = K0 + K1(A) xi + K2(A) xi^2 + K3(A) xi^3 + S_a(A) |v|^alpha sgn(v) / (A (A w)^alpha l pi)``

    with xi = x - x_center [m], v = dxi/dt [m/s], A the excitation amplitude [m], w its
    angular frequency [rad/s], K_k in N/m^k, S_a the loop area [J = N m] and alpha the
    dimensionless viscoelastic exponent (alpha = 0: dry friction). The normalisation
    ``l pi`` of eqs 8-9 is implemented as ``2 I(alpha)`` with
    ``I(alpha) = int_0^pi sin^(alpha+1)`` (eq 17), i.e. the damping force is
    ``S_a q(alpha) / A * (|v| / (A w))^alpha sgn(v)`` with ``q = 1/(2 I)``, so that under
    ``x = -A cos(w t)`` (eq 15) the damping force is eq 16 and the energy dissipated per
    cycle, the loop area, equals S_a exactly.

    K0..K3, S_a and alpha are functions of A given as tables on an amplitude grid
    (``amplitudes`` [m], one table value per grid point, per cable, or per lane and cable),
    interpolated linearly and held constant outside the grid (eq 10 is one row of the
    table; the table is ``p_M,i = f_A,i(A)`` of Sec 3). For fixed-time lookup the tables
    are resampled once, at build time, on a uniform grid of GRID_POINTS points.

    A and w are estimated online from the last reversal points of the elongation:
    A = (last maximum - last minimum) / 2 and w = pi / (time between the last two
    reversals). Until two reversals have been seen, ``amplitude_init`` and
    ``omega_init`` are used.
    """

    name = "amplitude"
    param_names = ("x_center", "amplitude_init", "omega_init")
    defaults = {"x_center": 0.0, "amplitude_init": 5e-4, "omega_init": 2 * np.pi * 0.5}
    param_docs = {
        "x_center": "elongation at the pretension working point, where xi = 0 [m]",
        "amplitude_init": "amplitude assumed before two reversals are seen [m]",
        "omega_init": "angular frequency assumed before two reversals are seen [rad/s]",
    }

    def __init__(self, shape=(1, 1), *, amplitudes, K0, K1, K2=0.0, K3=0.0, S_a=0.0, alpha=0.0, **params):
        super().__init__(shape, **params)
        grid = np.atleast_1d(np.asarray(amplitudes, dtype=np.float64))
        if grid.ndim != 1 or grid.size < 1 or np.any(grid <= 0) or np.any(np.diff(grid) <= 0):
            raise ModelParameterError("amplitude: amplitudes must be a strictly increasing list of positive values [m]")
        nA = grid.size
        lanes, cables = self.shape
        tables = {}
        for name, val in zip(TABLE_COLUMNS, (K0, K1, K2, K3, S_a, alpha)):
            arr = np.asarray(val, dtype=np.float64)
            if arr.ndim == 0:
                arr = np.full(nA, float(arr))
            if arr.shape[-1] != nA:
                raise ModelParameterError(
                    f"amplitude: table {name} has {arr.shape[-1]} values per cable but the amplitude grid has {nA}")
            try:
                tables[name] = np.broadcast_to(arr, (lanes, cables, nA))
            except ValueError:
                raise ModelParameterError(
                    f"amplitude: table {name} of shape {arr.shape} does not broadcast to (lanes, cables, {nA})") from None
            if not np.all(np.isfinite(tables[name])):
                raise ModelParameterError(f"amplitude: table {name} must be finite")
        if np.any(tables["S_a"] < 0):
            raise ModelParameterError("amplitude: S_a (loop area) must be >= 0")
        if np.any(tables["alpha"] < 0):
            raise ModelParameterError("amplitude: alpha must be >= 0")
        self.amplitude_grid = grid
        self.tables = {k: np.array(v) for k, v in tables.items()}
        # uniform resampling
        G = GRID_POINTS if nA > 1 else 2
        lo, hi = grid[0], (grid[-1] if nA > 1 else grid[0] * 2)
        ug = np.linspace(lo, hi, G)
        res = np.empty((lanes, cables, G, len(TABLE_COLUMNS) + 1))
        for j, name in enumerate(TABLE_COLUMNS):
            t = tables[name]
            if nA == 1:
                res[..., j] = t[..., :1]
            else:
                flat = t.reshape(-1, nA)
                res[..., j] = np.stack([np.interp(ug, grid, row) for row in flat]).reshape(lanes, cables, G)
        res[..., -1] = damping_normaliser(res[..., 5])
        self._a0 = lo
        self._inv_da = (G - 1) / (hi - lo)
        self._umax = (G - 1) - 1e-9
        self._amin = float(lo)
        ncol = len(TABLE_COLUMNS) + 1
        LC = lanes * cables
        # Column-major flat tables: entry (j, lane*cables + cable, g) at j*LC*G + (lane*cables+cable)*G + g.
        # Lookups are 1-D np.take calls on these, which numpy does without temporaries.
        colmajor = np.moveaxis(res, -1, 0).reshape(ncol, LC, G)
        self._tab = np.ascontiguousarray(colmajor).reshape(-1)
        self._slope = np.ascontiguousarray(np.diff(colmajor, axis=2, append=colmajor[:, :, -1:])).reshape(-1)
        self._base = (np.arange(ncol)[:, None] * (LC * G) + np.arange(LC)[None, :] * G).astype(np.intp)  # (ncol, LC)
        self._rep = np.repeat(np.arange(LC, dtype=np.intp)[None, :], ncol, axis=0)            # (ncol, LC) -> lane/cable
        # scratch, every array of the step's shape so that no ufunc broadcasts (broadcasting
        # with out= makes numpy allocate iterator buffers)
        sh = self.shape
        e = lambda: np.empty(sh)
        self._dx, self._nd, self._d, self._mhi, self._mlo, self._e1, self._e2 = e(), e(), e(), e(), e(), e(), e()
        self._u, self._fl, self._xi, self._p, self._r = e(), e(), e(), e(), e()
        self._idx = np.empty(sh, dtype=np.intp)
        self._idx7 = np.empty((ncol, LC), dtype=np.intp)
        self._vals = np.empty((ncol, LC))
        self._dvals = np.empty((ncol, LC))
        self._frac7 = np.empty((ncol, LC))
        self._cols = [self._vals[j].reshape(sh) for j in range(ncol)]

    def create_state(self, x0=0.0) -> AmplitudeState:
        x0a = self._x0(x0)
        A0 = self.params["amplitude_init"]
        return AmplitudeState(
            x_prev=x0a, direction=np.ones(self.shape), hi=x0a + A0, lo=x0a - A0, t_rev=np.zeros(self.shape),
            half_period=np.pi / self.params["omega_init"], clock=np.zeros(1), amplitude=A0.copy())

    def step(self, state: AmplitudeState, x, dt, l0=None):
        sub, mul, add, np_max = np.subtract, np.multiply, np.add, np.maximum
        dx, nd, d, mhi, mlo, e1, e2 = self._dx, self._nd, self._d, self._mhi, self._mlo, self._e1, self._e2
        t_prev = float(state.clock[0])
        state.clock[0] = t_prev + dt
        sub(x, state.x_prev, dx)
        # direction of motion with memory; d = old - new is +2 at a maximum, -2 at a minimum
        update_direction(dx, state.direction, nd)
        sub(state.direction, nd, d)
        mul(d, 0.5, mhi)
        np_max(mhi, 0.0, out=mhi)               # 1 at a maximum, else 0
        mul(d, -0.5, mlo)
        np_max(mlo, 0.0, out=mlo)               # 1 at a minimum, else 0
        # the reversal point is the previous sample: hi += mhi (x_prev - hi), lo likewise
        sub(state.x_prev, state.hi, e1)
        mul(e1, mhi, e1)
        add(state.hi, e1, state.hi)
        sub(state.x_prev, state.lo, e1)
        mul(e1, mlo, e1)
        add(state.lo, e1, state.lo)
        # half period and time of the last reversal, updated at any reversal
        add(mhi, mlo, mhi)
        sub(t_prev, state.t_rev, e1)            # time since last reversal
        sub(e1, state.half_period, e2)
        mul(e2, mhi, e2)
        add(state.half_period, e2, state.half_period)
        mul(e1, mhi, e1)
        add(state.t_rev, e1, state.t_rev)
        # amplitude A = (max - min)/2, not below the table's smallest amplitude
        A = state.amplitude
        sub(state.hi, state.lo, A)
        mul(A, 0.5, A)
        np_max(A, self._amin, out=A)
        # table lookup at A: uniform grid, linear interpolation, 1-D takes only
        u, fl, idx = self._u, self._fl, self._idx
        sub(A, self._a0, u)
        mul(u, self._inv_da, u)
        np.minimum(u, self._umax, out=u)
        np.floor(u, fl)
        sub(u, fl, u)                           # fractional position between grid points
        np.copyto(idx, fl, casting="unsafe")
        np.take(idx.reshape(-1), self._rep, out=self._idx7, mode="clip")
        add(self._idx7, self._base, self._idx7)
        np.take(self._tab, self._idx7, out=self._vals, mode="clip")
        np.take(self._slope, self._idx7, out=self._dvals, mode="clip")
        np.take(u.reshape(-1), self._rep, out=self._frac7, mode="clip")
        mul(self._dvals, self._frac7, self._dvals)
        add(self._vals, self._dvals, self._vals)
        K0, K1, K2, K3, Sa, alpha, q = self._cols
        # polynomial spring part (Horner)
        xi, p = self._xi, self._p
        sub(x, self.params["x_center"], xi)
        mul(K3, xi, p)
        add(p, K2, p)
        mul(p, xi, p)
        add(p, K1, p)
        mul(p, xi, p)
        add(p, K0, p)
        # damping: S_a q / A * (|v| / (A w))^alpha * sgn(v), with |v|/(A w) = |dx| T_half / (dt pi A)
        r = self._r
        np.absolute(dx, r)
        mul(r, state.half_period, r)
        mul(A, max(dt, 1e-12) * np.pi, e1)
        np.divide(r, e1, r)
        np.power(r, alpha, r)
        mul(r, Sa, r)
        mul(r, q, r)
        np.divide(r, A, r)
        mul(r, nd, r)
        add(p, r, self.force)
        np.copyto(state.direction, nd)
        np.copyto(state.x_prev, x)
        return self.force

    def omega(self, state: AmplitudeState) -> np.ndarray:
        """Current angular-frequency estimate [rad/s]."""
        return np.pi / state.half_period
