"""Amplitude-dependent cable model with velocity-dependent damping (eqs 8, 9, 15-17 of 002)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy.special import gammaln

from cablesvc.models.base import CableModel, ModelParameterError, ModelState, as_numbers, where_bad
from cablesvc.models.space import FitStats, Space, identity
from cablesvc.models.reversal import REVERSAL_DEADBAND, track_reversals

TABLE_COLUMNS = ("K0", "K1", "K2", "K3", "S_a", "alpha")
#: the amplitude levels [m] of the nominal tables (the range 002 reports for Dyneema)
NOMINAL_AMPLITUDES = (1e-4, 2.5e-4, 5e-4, 1e-3, 1.5e-3)
#: points of the uniform amplitude grid the tables are resampled on when the model is built
GRID_POINTS = 1024
#: default |xi| limit of the backbone's polynomial part [m]: no limit in practice
XI_UNBOUNDED = 1.0
#: largest normalised speed |v| / (A w) the damping law is evaluated at: a sine's peak, the
#: most 002 Sec 4's calibration shows it (|v| / (A w) = |sin|). Beyond it the damping is held
#: at its value there, as the tables hold their end values beyond the amplitude range. The
#: online w = pi / T_h is stale after a hold (T_h then spans the hold): resuming a 1 mm,
#: 0.5 Hz sine after a 120 s hold, sine-calibrated baselines of the realistic bench (robot 0
#: of fleet 161803) were 30-255 N off the same sine without the hold over its first 4 s
#: with alpha 1.1-1.5 (Bouc-Wen truth) and 3.7-10.8 N with alpha 0.3-0.5; held, 0.09-0.18 N
#: and 0.9-1.5 N
SPEED_RATIO_MAX = 1.0


def sine_power_integral(alpha: np.ndarray) -> np.ndarray:
    """I(alpha) = int_0^pi sin(u)^(alpha+1) du = sqrt(pi) G(alpha/2 + 1) / G(alpha/2 + 3/2).

    The integral of eqs 9 and 17 of 002 (dimensionless)."""
    a = np.asarray(alpha, dtype=np.float64)
    return np.sqrt(np.pi) * np.exp(gammaln(a / 2 + 1) - gammaln(a / 2 + 1.5))


def backbone(xi: np.ndarray, K0: np.ndarray, K1: np.ndarray, K2: np.ndarray, K3: np.ndarray,
             out: Optional[np.ndarray] = None, *, lo: Optional[np.ndarray] = None, hi: Optional[np.ndarray] = None,
             scratch: Optional[tuple[np.ndarray, np.ndarray]] = None) -> np.ndarray:
    """The backbone of eq 8 of 002, its spring part: K0 + K1 xi + K2 xi^2 + K3 xi^3 [N] at
    xi = x - x_center [m], by Horner's rule (into ``out``, nothing allocated when given).

    With ``lo``, ``hi`` [m] (the elongations about x_center the parameters were identified
    on), the polynomial holds inside [lo, hi] and continues along its tangent outside:
    P(xi_c) + P'(xi_c) (xi - xi_c) with xi_c = xi held within [lo, hi], so value and
    stiffness are continuous at the edges and the stiffness outside is the one at the edge
    (as the amplitude tables hold their end values). A cubic fitted on +-1.5 mm is an
    interpolant there; extrapolated to the 20 mm of a trajectory, its K2 xi^2 + K3 xi^3 grew
    to tens or hundreds of newtons the data never showed. Inside [lo, hi] the result is the
    unbounded one bit for bit. ``scratch``: two arrays of the output's shape (the live
    kernel passes them so nothing is allocated).

    The one home of this law: :meth:`AmplitudeDependent.step` and
    :meth:`AmplitudeDependent.backbone_force` (the twin's elastic curve) evaluate it here."""
    p = np.empty(np.broadcast_shapes(*(np.shape(a) for a in (xi, K0, K1, K2, K3)))) if out is None else out
    if lo is None and hi is None:
        xc = xi
    else:
        xc, t = scratch if scratch is not None else (np.empty(p.shape), np.empty(p.shape))
        np.maximum(xi, -np.inf if lo is None else lo, out=xc)
        np.minimum(xc, np.inf if hi is None else hi, out=xc)
    np.multiply(K3, xc, p)
    np.add(p, K2, p)
    np.multiply(p, xc, p)
    np.add(p, K1, p)
    np.multiply(p, xc, p)
    np.add(p, K0, p)
    if xc is not xi:
        # P'(xi_c) = ((1.5 K3 xi_c + K2) xi_c) 2 + K1, times (xi - xi_c): exactly 0 inside
        np.multiply(K3, xc, t)
        np.multiply(t, 1.5, t)
        np.add(t, K2, t)
        np.multiply(t, xc, t)
        np.multiply(t, 2.0, t)
        np.add(t, K1, t)
        np.subtract(xi, xc, xc)
        np.multiply(t, xc, t)
        np.add(p, t, p)
    return p


def damping_normaliser(alpha: np.ndarray) -> np.ndarray:
    """q(alpha) = 1 / (2 I(alpha)): with it the damping term of eq 8 dissipates exactly
    S_a per cycle of a sinusoid of amplitude A (see AmplitudeDependent)."""
    return 1.0 / (2.0 * sine_power_integral(alpha))


@dataclass
class AmplitudeState(ModelState):
    x_prev: np.ndarray
    direction: np.ndarray      # sgn(v) with a dead-band: +1 rising, -1 falling
    memory: np.ndarray         # (6, lanes, cables): last reversal point [m], amplitude A [m],
                               # half period [s], time of the last reversal [s], running
                               # extremum of the current half-cycle [m] and its time [s]
    clock: np.ndarray          # (1,) time since create_state [s]

    @property
    def amplitude(self) -> np.ndarray:
        """Amplitude estimate A [m]: half the distance between the last two reversal points."""
        return self.memory[1]

    @property
    def half_period(self) -> np.ndarray:
        return self.memory[2]


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

    Outside the elongations it was identified on (``xi_lo`` <= xi <= ``xi_hi``, written by
    ``cablesvc identify``), the polynomial part continues along its tangent
    (:func:`backbone`); without them (default +-1 m) it is the plain polynomial.

    K0..K3, S_a and alpha are functions of A given as tables on an amplitude grid
    (``amplitudes`` [m], one table value per grid point, per cable, or per lane and cable),
    interpolated linearly and held constant outside the grid (eq 10 is one row of the
    table; the table is ``p_M,i = f_A,i(A)`` of Sec 3). For fixed-time lookup the tables
    are resampled once, at build time, on a uniform grid of GRID_POINTS points and read at
    the nearest grid point (error at most half a step: 0.05 % of the amplitude range).

    A and w are estimated online from the last reversal points of the elongation:
    A = |last reversal point - the one before| / 2 and w = pi / (time between the last two
    reversals). The normalised speed |v| / (A w) is held at most SPEED_RATIO_MAX (1, a
    sine's peak, the most a calibration by 002 Sec 4's sines shows): after a hold, w is
    stale until two reversals have passed, and (|v| / (A w))^alpha ran to hundreds of
    newtons of damping on the first move. Until two reversals have been seen, ``amplitude_init`` and
    ``omega_init`` are used. A reversal is declared when the elongation has moved back by
    more than ``reversal_deadband`` [m] from the extremum of the current half-cycle, and
    the reversal point and time are that extremum's (:mod:`cablesvc.models.reversal`):
    quantised or noisy elongations then neither flip sgn(v) nor corrupt A and w.
    """

    name = "amplitude"
    param_names = ("x_center", "amplitude_init", "omega_init", "reversal_deadband", "xi_lo", "xi_hi")
    defaults = {"x_center": 0.0, "amplitude_init": 5e-4, "omega_init": 2 * np.pi * 0.5,
                "reversal_deadband": REVERSAL_DEADBAND, "xi_lo": -XI_UNBOUNDED, "xi_hi": XI_UNBOUNDED}
    param_docs = {
        "x_center": "elongation at the pretension working point, where xi = 0 [m]",
        "amplitude_init": "amplitude assumed before two reversals are seen [m]",
        "omega_init": "angular frequency assumed before two reversals are seen [rad/s]",
        "reversal_deadband": "motion back from the last extremum that counts as a reversal [m]",
        "xi_lo": "smallest xi the backbone was identified on; below it the backbone continues along its "
                 "tangent [m] (default -1 m: no limit)",
        "xi_hi": "largest xi the backbone was identified on; above it the backbone continues along its "
                 "tangent [m] (default 1 m: no limit)",
    }
    #: the kernel divides by them
    positive_params = ("amplitude_init", "omega_init")
    table_names = ("amplitudes",) + TABLE_COLUMNS
    #: tables a parameter file must give
    required_tables = ("amplitudes", "K0", "K1")
    #: tables that are stiffnesses: > 0 at every amplitude level and cable
    positive_tables = {"K1": "linear stiffness K1(A) of eq 8 of 002 [N/m]"}
    has_nominal = True
    fit_by_levels = True

    # -- the parameter file -----------------------------------------------------------------
    @classmethod
    def table_problems(cls, tables):
        problems = [f"tables.{k}: required for the amplitude model" for k in cls.required_tables if k not in tables]
        for k, v in tables.items():
            a = as_numbers(f"tables.{k}", v, problems, "a list of numbers")
            if a is None:
                continue
            if k == "amplitudes":
                if a.ndim != 1 or a.size < 1 or not np.all(np.isfinite(a)) or np.any(a <= 0) or np.any(np.diff(a) <= 0):
                    problems.append(f"tables.amplitudes: must be a non-empty, strictly increasing list of finite "
                                    f"positive amplitudes [m], got {v!r}"[:200])
            elif a.ndim not in (1, 2) or not np.all(np.isfinite(a)):
                problems.append(f"tables.{k}: must be a list of finite numbers (one per level) or a list of "
                                f"per-cable rows")
            elif k in cls.positive_tables and not np.all(a > 0):
                problems.append(f"tables.{k}: the {cls.positive_tables[k]} must be > 0 at every amplitude level "
                                f"and cable{where_bad(a, a > 0, table=True)}")
        return problems

    @classmethod
    def from_file(cls, shape, params, options, tables):
        return cls(shape, **tables, **params, **options)

    @classmethod
    def table_range(cls, tables):
        if "amplitudes" not in tables:
            return None
        a = np.asarray(tables["amplitudes"], dtype=float)
        return float(a.min()), float(a.max())

    # -- nominal parameters -------------------------------------------------------------------
    @classmethod
    def nominal(cls, ea, cable_length):
        """K1 = k = EA / L at every amplitude, a loss factor of 0.1 (S_a = 0.1 pi k A^2) and
        alpha = 0.3: values of the order 002 reports for Dyneema at 60 N pretension
        (amplitudes 0.1-1.5 mm). K1 is kept constant because with K0 = 0 and x_center = 0 the
        polynomial carries the whole tension, and an amplitude-dependent K1 would make the
        predicted tension jump whenever the amplitude estimate changes."""
        k = np.asarray(ea, float) / np.asarray(cable_length, float)
        amps = np.array(NOMINAL_AMPLITUDES)
        n = len(amps)
        K1 = np.outer(k, np.ones(n))
        Sa = 0.1 * np.pi * K1 * amps ** 2
        return {"tables": {"amplitudes": amps.tolist(), "K0": [0.0] * n, "K1": K1.tolist(), "K2": [0.0] * n,
                           "K3": [0.0] * n, "S_a": Sa.tolist(), "alpha": [0.3] * n},
                "identification": {"nominal": True, "amplitude_range": [float(amps[0]), float(amps[-1])]}}

    # -- identification (a recording without amplitude levels: one constant table row) ----------
    @classmethod
    def search_space(cls, s: FitStats, *, degree: int = 3) -> Space:
        """One constant table row ``K0..K3, S_a, alpha``; ``x_center`` fixed to the mean
        elongation. (A hold-sine recording is fitted level by level instead:
        :attr:`fit_by_levels`, :mod:`cablesvc.identify.amplitude_fit`.)"""
        K, x, f, kk = s.K, s.x, s.f, s.kk
        names = list(TABLE_COLUMNS)
        X = np.maximum(np.abs(x - s.xm).max(axis=0), 1e-6)
        fm = f.mean(axis=0)
        slb = np.column_stack([fm - s.fr, np.zeros(K), -kk / X, -kk / X ** 2, np.zeros(K), np.zeros(K)])
        sub = np.column_stack([fm + s.fr, 3 * kk, kk / X, kk / X ** 2, kk * X ** 2 * 2, np.full(K, 2.0)])
        lb = np.column_stack([np.full(K, -np.inf)] * 4 + [np.zeros(K), np.zeros(K)])
        ub = np.column_stack([np.full(K, np.inf)] * 5 + [np.full(K, 3.0)])
        start = np.column_stack([fm, kk, np.zeros(K), np.zeros(K), 0.1 * np.pi * kk * X ** 2, np.full(K, 0.3)])
        return Space(cls.name, names, ["N", "N/m", "N/m^2", "N/m^3", "J", "-"], slb, sub, identity, identity, lb, ub,
                     {"x_center": s.xm}, start,
                     notes=["amplitude (no amplitude levels in the recording): one constant table row; "
                            "x_center fixed to the mean elongation"])

    @classmethod
    def build_lanes(cls, shape, kwargs, options, x):
        """Table columns given per lane as one level; before two reversals the amplitude is
        half the recorded elongation span."""
        kw = dict(kwargs)
        tab = {k: kw.pop(k)[..., None] for k in TABLE_COLUMNS}
        span = np.ptp(x, axis=0)
        kw.setdefault("amplitude_init", np.broadcast_to(np.maximum(0.5 * span, 1e-7), shape))
        return cls(shape, amplitudes=[1e-12], **tab, **kw)

    @classmethod
    def file_sections(cls, m, ea, length, fitted, names, V, fixed, options):
        """Constant table rows for the fitted cables on the nominal amplitude grid; the
        other cables keep the nominal tables."""
        nom = cls.nominal(ea, length)["tables"]
        amps = np.asarray(nom["amplitudes"], float)
        tables = {"amplitudes": amps.tolist()}
        for k in TABLE_COLUMNS:
            rows = np.broadcast_to(np.asarray(nom[k], float), (m, amps.size)).copy()
            j = names.index(k)
            rows[fitted] = V[:, j][:, None]
            tables[k] = rows.tolist()
        xc = np.zeros(m)
        xc[fitted] = fixed["x_center"]
        return {"params": {"x_center": xc.tolist()}, "options": {}, "tables": tables}

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
        if np.any(self.params["reversal_deadband"] < 0):
            raise ModelParameterError("amplitude: reversal_deadband must be >= 0 [m]")
        # the damping term divides by A and (A w)^alpha: a non-positive start value makes every
        # force NaN until two reversals have been seen
        if np.any(self.params["amplitude_init"] <= 0):
            raise ModelParameterError("amplitude: amplitude_init must be > 0 [m]")
        if np.any(self.params["omega_init"] <= 0):
            raise ModelParameterError("amplitude: omega_init must be > 0 [rad/s]")
        if np.any(self.params["xi_lo"] >= self.params["xi_hi"]):
            raise ModelParameterError("amplitude: xi_lo must be < xi_hi [m] (the identified elongation range "
                                      "about x_center)")
        # the tangent continuation costs nine ufuncs a tick: only where a limit is set
        bounded = bool(np.any(self.params["xi_lo"] > -XI_UNBOUNDED) or np.any(self.params["xi_hi"] < XI_UNBOUNDED))
        self._xi_lo = self.params["xi_lo"] if bounded else None
        self._xi_hi = self.params["xi_hi"] if bounded else None
        self.amplitude_grid = grid
        self.tables = {k: np.array(v) for k, v in tables.items()}
        # uniform resampling, nearest-point lookup: with GRID_POINTS points the lookup error is
        # at most half a grid step, 0.05 % of the amplitude range
        G = GRID_POINTS if nA > 1 else 1
        lo, hi = grid[0], grid[-1]
        ug = np.linspace(lo, hi, G) if nA > 1 else grid[:1]
        ncol = 6   # K0, K1, K2, K3, S_a * q(alpha), alpha
        res = np.empty((lanes, cables, G, ncol))
        for j, name in enumerate(("K0", "K1", "K2", "K3", "S_a", "alpha")):
            flat = tables[name].reshape(-1, nA)
            res[..., j] = np.stack([np.interp(ug, grid, row) for row in flat]).reshape(lanes, cables, G)
        res[..., 4] *= damping_normaliser(res[..., 5])
        self._amin = float(lo)
        LC = lanes * cables
        inv_da = (G - 1) / (hi - lo) if nA > 1 else 0.0
        self._inv_da = inv_da
        # table (column, lane*cables*G + cable*G + g): one np.take along axis 1 with the flat
        # row index reads all six columns of every cable at once, into contiguous rows
        self._tab = np.ascontiguousarray(np.moveaxis(res, -1, 0).reshape(ncol, LC * G))
        # u = A * inv_da - shift[c] is the row index in that table (nearest grid point:
        # shift = lo * inv_da - 0.5 - c * G); u <= umax[c] keeps it inside the cable's block
        # (A is clamped to >= lo first, so u >= c * G + 0.5)
        sh = self.shape
        rows0 = (np.arange(LC, dtype=np.float64) * G).reshape(sh)
        self._shift = lo * inv_da - 0.5 - rows0
        self._umax = rows0 + (G - 1) + 0.25
        # scratch: every operand has the step's shape, so no ufunc broadcasts (broadcasting
        # with out= makes numpy allocate iterator buffers)
        e = lambda: np.empty(sh)
        self._dx, self._nd, self._e, self._u, self._xi, self._p, self._r, self._aeff = (
            e(), e(), e(), e(), e(), e(), e(), e())
        self._bb_scratch = (e(), e())
        self._speed_max = np.full(sh, SPEED_RATIO_MAX)     # an operand of the step's shape: nothing allocated
        self._rev = np.empty(sh, dtype=bool)
        self._newext = np.empty(sh, dtype=bool)
        self._idx = np.empty(sh, dtype=np.intp)
        self._vals = np.empty((ncol, LC))
        self._new = np.empty((6,) + sh)
        self._cols = [self._vals[j].reshape(sh) for j in range(ncol)]
        # flat views made once (a reshape per step would allocate a view object)
        self._idx_flat = self._idx.reshape(-1)

    def create_state(self, x0=0.0) -> AmplitudeState:
        x0a = self._x0(x0)
        A0 = self.params["amplitude_init"]
        mem = np.empty((6,) + self.shape)
        mem[0] = x0a - A0                               # last reversal point
        mem[1] = A0                                     # amplitude
        mem[2] = np.pi / self.params["omega_init"]      # half period
        mem[3] = 0.0                                    # time of the last reversal
        mem[4] = x0a                                    # extremum of the current half-cycle
        mem[5] = 0.0                                    # ... and its time
        return AmplitudeState(x_prev=x0a, direction=np.ones(self.shape), memory=mem, clock=np.zeros(1))

    def step(self, state: AmplitudeState, x, dt, l0=None):
        sub, mul, add = np.subtract, np.multiply, np.add
        dx, nd, e, r = self._dx, self._nd, self._e, self._r
        mem, new = state.memory, self._new
        A, T = mem[1], mem[2]
        t_now = float(state.clock[0]) + dt
        state.clock[0] = t_now
        sub(x, state.x_prev, dx)
        s_dir, ext = state.direction, mem[4]
        track_reversals(x, s_dir, ext, self.params["reversal_deadband"], e, self._rev)
        # the extremum's time: where x is a new extremum (moved back by exactly 0)
        new[5].fill(t_now)
        np.less_equal(e, 0.0, self._newext)
        np.copyto(mem[5], new[5], where=self._newext)
        # at a reversal the extremum is the turning point: A <- |extremum - last reversal
        # point| / 2, half period <- t_extremum - t_rev, last reversal point <- extremum,
        # t_rev <- t_extremum, and the new half-cycle's extremum starts at (x, t_now); all
        # six rows as one masked copy (the mask broadcasts over the rows: same dtype, no
        # iterator buffer, nothing allocated)
        sub(ext, mem[0], e)
        np.absolute(e, new[1])
        mul(new[1], 0.5, new[1])
        np.copyto(new[0], ext)
        sub(mem[5], mem[3], new[2])
        np.copyto(new[3], mem[5])
        np.copyto(new[4], x)
        np.copyto(mem, new, where=self._rev)
        np.negative(s_dir, nd)
        np.copyto(s_dir, nd, where=self._rev)
        # A not below the table's smallest amplitude
        aeff = self._aeff
        np.maximum(A, self._amin, out=aeff)
        # table lookup at A: nearest point of the uniform grid, all six columns in one take
        u, idx = self._u, self._idx
        mul(aeff, self._inv_da, u)
        sub(u, self._shift, u)
        np.minimum(u, self._umax, out=u)
        np.copyto(idx, u, casting="unsafe")             # truncation = floor (u >= 0)
        np.take(self._tab, self._idx_flat, axis=1, out=self._vals, mode="clip")
        K0, K1, K2, K3, Sq, alpha = self._cols
        # polynomial spring part: the backbone
        xi, p = self._xi, self._p
        sub(x, self.params["x_center"], xi)
        backbone(xi, K0, K1, K2, K3, out=p, lo=self._xi_lo, hi=self._xi_hi, scratch=self._bb_scratch)
        # damping S_a q / A (|v| / (A w))^alpha sgn(v), with |v| / (A w) = |dx| T_half / (dt pi A),
        # held at SPEED_RATIO_MAX
        np.absolute(dx, r)
        mul(r, T, r)
        mul(aeff, max(dt, 1e-12) * np.pi, e)
        np.divide(r, e, r)
        np.minimum(r, self._speed_max, out=r)
        np.power(r, alpha, r)
        mul(r, Sq, r)
        np.divide(r, aeff, r)
        mul(r, s_dir, r)
        add(p, r, self.force)
        np.copyto(state.x_prev, x)
        return self.force

    def backbone_force(self, x, amplitude, *, interpolation: str, lane: int = 0) -> np.ndarray:
        """The backbone (elastic, rate-independent part of eq 8) F_el(x; A) [N] of lane
        ``lane``: :func:`backbone` at xi = x - x_center with K0..K3 read at the amplitude
        ``amplitude`` [m] (broadcast to x), A held at the table's range.

        ``x`` [m] (..., cables). ``interpolation`` says how K0..K3 are read at A, explicitly,
        because the two users deliberately differ:

        * ``"nearest"``: the nearest point of the uniform grid the tables are resampled on
          at build time, exactly what :meth:`step` reads (fixed-time lookup);
        * ``"linear"``: linear interpolation in the raw tables (:attr:`tables` on
          :attr:`amplitude_grid`). The digital twin's truth uses this
          (:class:`cablesvc.simulate.elastic.ElasticCurve`): its truth is meant to differ
          slightly from the model identification fits, and its numbers must not move.
        """
        x = np.asarray(x, dtype=np.float64)
        A = np.broadcast_to(np.asarray(amplitude, dtype=np.float64), x.shape)
        xi = x - self.params["x_center"][lane]
        out = np.zeros(x.shape)
        g = self.amplitude_grid
        for i in range(self.shape[1]):
            Ai = A[..., i]
            if interpolation == "linear":
                rows = [self.tables[c][lane, i] for c in ("K0", "K1", "K2", "K3")]
                K = [np.interp(Ai, g, r) if g.size > 1 else np.full(Ai.shape, r[0]) for r in rows]
            elif interpolation == "nearest":          # the index arithmetic of step()
                u = np.maximum(Ai, self._amin) * self._inv_da - self._shift[lane, i]
                idx = np.minimum(u, self._umax[lane, i]).astype(np.intp)
                K = [self._tab[j, idx] for j in range(4)]
            else:
                raise ValueError(f"backbone_force: interpolation must be 'nearest' or 'linear', got {interpolation!r}")
            out[..., i] = backbone(xi[..., i], *K, lo=None if self._xi_lo is None else self._xi_lo[lane, i],
                                   hi=None if self._xi_hi is None else self._xi_hi[lane, i])
        return out

    @staticmethod
    def amplitude(state: "AmplitudeState") -> np.ndarray:
        """Current amplitude estimate [m] (a view of the state)."""
        return state.memory[1]

    def omega(self, state: AmplitudeState) -> np.ndarray:
        """Current angular-frequency estimate [rad/s]."""
        return np.pi / state.half_period
