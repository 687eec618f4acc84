"""Bouc-Wen hysteresis with a cubic term (eqs 1-5 of 000) and its integrators; the one home
of the Bouc-Wen law (section "the law" below) that the models, the discovery term
(models/terms/hysteresis.py), the benchmark oscillator (simulate/oscillator.py) and the beam
(beam/solver.py) all call."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from cablesvc.models.base import CableModel, ModelParameterError, ModelState, is_int
from cablesvc.models.space import (FitStats, Space, hysteresis_search_columns, hysteresis_to_model,
                                   hysteresis_to_search)

INTEGRATORS = ("semi-implicit", "rk4")
_TINY = 1e-300

# ---- sub-steps the live tick can afford -------------------------------------------------
# A sub-step is a fixed sequence of numpy calls on (lanes, cables) arrays (counted in
# BoucWenIntegrator.advance: the right-hand side is 8 calls; semi-implicit = rhs + 11 for the
# linearised backward-Euler update + 2 for the projection; rk4 = 4 rhs + 15 for the stages
# and their sum + 2 for the projection). On the live service's arrays (1 lane, <= 8 cables)
# a call costs its dispatch overhead, about 0.24 us on a fast machine (issue 20 measured
# 1000 semi-implicit sub-steps = 21 000 calls at 5 ms per tick). The live tick is 1 ms
# (1 kHz, the embedded controller's rate and the fastest documented one) and the model may
# take at most half of it (IK, FK, alarms and publishing need the rest: docs/performance.md).
# So at most LIVE_TICK_S * LIVE_MODEL_SHARE / (NUMPY_CALL_S * calls) sub-steps: 99
# semi-implicit, 42 rk4. More can never meet the tick on any machine; whether fewer meet it
# on a given machine is measured by `cablesvc bench kernel --params FILE`. Offline uses
# (identification, convergence references) may build the model with more.
CALLS_PER_SUBSTEP = {"semi-implicit": 8 + 11 + 2, "rk4": 4 * 8 + 15 + 2}
LIVE_TICK_S = 1e-3
LIVE_MODEL_SHARE = 0.5
NUMPY_CALL_S = 0.24e-6


def max_live_substeps(integrator: str) -> int:
    """The most Bouc-Wen sub-steps per tick the live service accepts for ``integrator`` (see
    the derivation above): 99 semi-implicit, 42 rk4."""
    return int(LIVE_TICK_S * LIVE_MODEL_SHARE / (NUMPY_CALL_S * CALLS_PER_SUBSTEP[integrator]))


# ---- the law -------------------------------------------------------------------------
# Eq 1 of 000 (= eq 2 of the Bouc-Wen benchmark, = eq 4.1 of 001, = the beam's moment law,
# eq 16 of 000, with z = M_h and x = mu), written once:
#
#     dz/dx = k - (gamma + beta sgn(z dx)) |z|^n          (rate independent, per increment)
#     z'    = k x' - beta |x'| |z|^(n-1) z - gamma x' |z|^n  (the same law in time)
#
# k [z/x], beta and gamma [1/(x z^(n-1))], n [-]. Forms:
# * bouc_wen_slope: numpy, dz/dx on (lanes, cables) arrays into given buffers (the live
#   kernel's models: BoucWenIntegrator);
# * bouc_wen_rate: scalar numba kernel, z' and its derivatives in x' and z (the oscillator's
#   Newmark-Newton loop with v = y'; the beam's hysteresis update with v = sgn(dmu), where
#   dz'/dv is the slope dz/dx);
# * the backward-Euler step for n = 1 (the discovery term's normalised z, k = 1):
#   bouc_wen_step_n1 (numba, offline over a record) and bouc_wen_step_n1_np (numpy, live, tick
#   by tick); the same arithmetic, so offline and live agree to the last bit.
# numba's on-disk cache (cache=True) of a caller checks only the caller's own file: after an
# edit of a numba form here, delete the callers' cached entries (the *.nbi / *.nbc of
# simulate/oscillator.py, beam/solver.py and models/terms/hysteresis.py in their __pycache__) or they
# keep running the old law.

def bouc_wen_slope(z, sdx, k, beta, gamma, n, out, c, a):
    """out = dz/dx = k - (gamma + beta sgn(z sdx)) |z|^n (numpy, in place; sdx = sgn(dx));
    leaves c = gamma + beta sgn(z sdx) in ``c`` and |z|^n in ``a``. Returns out."""
    np.multiply(z, sdx, c)
    np.sign(c, c)
    np.multiply(c, beta, c)
    np.add(c, gamma, c)
    np.absolute(z, a)
    np.power(a, n, a)
    np.multiply(c, a, out)
    np.subtract(k, out, out)
    return out


@numba.njit(cache=True, inline="always")
def bouc_wen_rate(k, beta, gamma, n, v, z):
    """z' = k v - beta |v| |z|^(n-1) z - gamma v |z|^n for the rate v = x' (scalar numba).
    Returns (z', dz'/dv, dz'/dz, |z|^(n-1)); dz'/dv is the slope dz/dx of the increment's
    direction sgn(v) (also at v = 0, where it is the slope of the no-sign branch)."""
    az = abs(z)
    if n == 1.0:
        p = 1.0
    elif az > 0.0:
        p = az ** (n - 1.0)
    else:
        p = 0.0 if n > 1.0 else 1e300
    sv = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    sz = 1.0 if z > 0.0 else (-1.0 if z < 0.0 else 0.0)
    pz = p * z                      # |z|^(n-1) z
    paz = p * az                    # |z|^n
    g = k * v - beta * abs(v) * pz - gamma * v * paz
    gv = k - beta * sv * pz - gamma * paz
    gz = -n * p * (beta * abs(v) + gamma * v * sz)
    return g, gv, gz, p


@numba.njit(cache=True, inline="always")
def bouc_wen_step_n1(z, dx, k, beta, gamma):
    """z after the increment dx by the backward-Euler step of the law with n = 1, the sign
    taken at the start: z1 = (z + k dx) / (1 + (gamma + beta sgn(z dx)) |dx|) (implicit in
    |z|, so stable for any dx when gamma > |beta|; z saturates at k / (gamma + beta))."""
    p = z * dx
    s = 1.0 if p > 0 else (-1.0 if p < 0 else 0.0)
    return (z + k * dx) / (1.0 + (gamma + beta * s) * abs(dx))


def bouc_wen_step_n1_np(z, dx, beta, gamma, s, den):
    """:func:`bouc_wen_step_n1` with k = 1 on arrays, z updated in place (``s``, ``den``:
    buffers of z's shape). The same operations in the same order as the numba form."""
    np.multiply(z, dx, out=s)
    np.sign(s, out=s)
    np.multiply(s, beta, out=den)
    np.add(den, gamma, out=den)
    np.abs(dx, out=s)
    np.multiply(den, s, out=den)
    np.add(den, 1.0, out=den)
    np.add(z, dx, out=z)
    np.divide(z, den, out=z)
    return z


class BoucWenIntegrator:
    """Advances the Bouc-Wen hysteretic variable over an elongation increment.

    Eq 1 of 000 is rate independent: dividing by dt gives (eq 2)
    ``dz/dx = k_d - (gamma + beta sgn(z dx)) |z|^n``, so z is integrated in the
    displacement increment dx of each tick, split into ``substeps`` equal parts.

    ``semi-implicit``: one linearised backward-Euler update per sub-step,
    ``z1 = z0 + dx g(z0) / (1 + |dx g'(z0)|)`` with ``g' = -c n |z|^(n-1) sgn z`` and
    ``c = gamma + beta sgn(z dx)``. Unconditionally stable for stiff parameter sets
    (large k_d, large n, large steps), first-order accurate.
    Both project z onto the model's invariant interval after each sub-step.
    ``rk4``: classical Runge-Kutta per sub-step, fourth-order accurate, needs enough
    sub-steps for |dx/substeps * g'| below ~2.

    The choice is made when the model is built (``integrator=``, ``substeps=``), never per
    tick, so every step costs the same. All buffers are allocated here.
    """

    def __init__(self, shape, k_d, beta, gamma, n, integrator: str = "semi-implicit", substeps: int = 1):
        if integrator not in INTEGRATORS:
            raise ModelParameterError(f"Bouc-Wen integrator must be one of {INTEGRATORS}, got {integrator!r}")
        if (isinstance(substeps, (bool, np.bool_)) or not isinstance(substeps, (int, np.integer))
                or substeps < 1):
            raise ModelParameterError(f"Bouc-Wen substeps must be an integer >= 1, got {substeps!r}")
        self.k_d, self.beta, self.gamma, self.n = k_d, beta, gamma, n
        self.integrator = integrator
        self.substeps = int(substeps)
        self.n_minus_1 = n - 1.0
        self._h = np.empty(shape)
        self._sdx = np.empty(shape)
        self._c = np.empty(shape)
        self._a = np.empty(shape)
        self._b = np.empty(shape)
        self._k = [np.empty(shape) for _ in range(4)]
        self._zs = np.empty(shape)
        self._acc = np.empty(shape)
        # The exact solution never leaves [-z_u, z_u], z_u = (k_d/(gamma+beta))^(1/n) when
        # gamma + beta > 0 (Sec 2 of 000); each sub-step is projected back onto it so that
        # large increments on stiff parameter sets cannot overshoot. inf when unbounded.
        self.z_bound = np.ascontiguousarray(np.broadcast_to(bouc_wen_bound(k_d, beta, gamma, n), shape), dtype=float)
        self._neg_bound = -self.z_bound

    def _rhs(self, z, out):
        """out = dz/dx (:func:`bouc_wen_slope`); also leaves c in self._c and |z|^n in self._a."""
        return bouc_wen_slope(z, self._sdx, self.k_d, self.beta, self.gamma, self.n, out, self._c, self._a)

    def advance(self, z: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """Update z in place over the elongation increment dx [m]."""
        h = self._h
        np.multiply(dx, 1.0 / self.substeps, h)
        np.sign(dx, self._sdx)
        if self.integrator == "semi-implicit":
            g, b = self._k[0], self._b
            for _ in range(self.substeps):
                self._rhs(z, g)
                # |g'| * |h| = |c| n |z|^(n-1) |h|, with |z|^(n-1) = |z|^n / (|z| + tiny)
                np.absolute(z, b)
                np.add(b, _TINY, b)
                np.divide(self._a, b, b)
                np.multiply(b, self._c, b)
                np.multiply(b, self.n, b)
                np.multiply(b, h, b)
                np.absolute(b, b)
                np.add(b, 1.0, b)
                np.multiply(g, h, g)
                np.divide(g, b, g)
                np.add(z, g, z)
                np.maximum(z, self._neg_bound, out=z)
                np.minimum(z, self.z_bound, out=z)
        else:
            k1, k2, k3, k4 = self._k
            zs, acc = self._zs, self._acc
            for _ in range(self.substeps):
                self._rhs(z, k1)
                np.multiply(k1, 0.5, zs); np.multiply(zs, h, zs); np.add(z, zs, zs)
                self._rhs(zs, k2)
                np.multiply(k2, 0.5, zs); np.multiply(zs, h, zs); np.add(z, zs, zs)
                self._rhs(zs, k3)
                np.multiply(k3, h, zs); np.add(z, zs, zs)
                self._rhs(zs, k4)
                np.add(k2, k3, acc); np.multiply(acc, 2.0, acc)
                np.add(acc, k1, acc); np.add(acc, k4, acc)
                np.multiply(acc, h, acc); np.multiply(acc, 1.0 / 6.0, acc)
                np.add(z, acc, z)
                np.maximum(z, self._neg_bound, out=z)
                np.minimum(z, self.z_bound, out=z)
        return z


def bouc_wen_bound(k_d, beta, gamma, n):
    """Ultimate hysteretic force ``[k_d / (gamma + beta)]^(1/n)`` (Sec 2 of 000), valid for
    gamma + beta > 0; inf otherwise."""
    s = np.asarray(gamma, float) + np.asarray(beta, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(s > 0, (np.asarray(k_d, float) / np.where(s > 0, s, 1.0)) ** (1.0 / np.asarray(n, float)), np.inf)


@dataclass
class BoucWenState(ModelState):
    x_prev: np.ndarray
    z: np.ndarray


class BoucWenFamily(CableModel):
    """Shared machinery of models whose memory is one Bouc-Wen variable z (eq 1 of 000):
    build options, the integrator, the state and the z update. A subclass names the
    parameter playing k_d in ``hysteretic_stiffness`` and writes ``self.force`` from x
    and z in ``_force``."""

    hysteretic_stiffness = "k_d"

    @classmethod
    def extra_options(cls):
        return ("integrator", "substeps")

    @classmethod
    def option_problem(cls, key, value, options):
        if key == "substeps" and not (is_int(value) and value >= 1):
            return f"options.substeps: must be an integer >= 1, got {value!r}"
        if key == "substeps":
            integ = options.get("integrator", "semi-implicit")
            most = max_live_substeps(integ if integ in INTEGRATORS else "semi-implicit")
            if value > most:
                return (f"options.substeps: {value} sub-steps per tick cannot fit the live tick; the {integ} "
                        f"integrator allows at most {most} (half of a 1 kHz tick, derivation in "
                        f"cablesvc/models/boucwen.py)")
        elif key == "integrator" and not (isinstance(value, str) and value in INTEGRATORS):
            return f"options.integrator: must be one of {list(INTEGRATORS)}, got {value!r}"
        return None

    @classmethod
    def unfitted_values(cls, m, ea, length, names):
        """The defaults, the elastic stiffness E*A / L and no hysteresis (hysteretic
        stiffness 0, beta = gamma = 0, n = 1)."""
        values = {nm: np.full(m, float(cls.defaults.get(nm, 0.0))) for nm in cls.param_names}
        values.update({cls.stiffness_params[0]: np.asarray(ea, float) / length,
                       cls.hysteretic_stiffness: np.zeros(m), "beta": np.zeros(m), "gamma": np.zeros(m),
                       "n": np.ones(m)})
        return values

    def check_params(self):
        if np.any(self.params["n"] <= 0):
            raise ModelParameterError(f"{self.name}: n must be > 0")
        p = self.params
        self.integrator = BoucWenIntegrator(
            self.shape, p[self.hysteretic_stiffness], p["beta"], p["gamma"], p["n"],
            self._options.get("integrator", "semi-implicit"), self._options.get("substeps", 1))
        self._dx = np.empty(self.shape)
        self._xi = np.empty(self.shape)
        self._t = np.empty(self.shape)

    def create_state(self, x0=0.0, z0=0.0) -> BoucWenState:
        return BoucWenState(x_prev=self._x0(x0), z=np.broadcast_to(np.asarray(z0, float), self.shape).copy())

    def step(self, state: BoucWenState, x, dt, l0=None):
        np.subtract(x, state.x_prev, self._dx)
        self.integrator.advance(state.z, self._dx)
        np.subtract(x, self.params["x_center"], self._xi)
        self._force(state.z)
        np.copyto(state.x_prev, x)
        return self.force

    def _force(self, z: np.ndarray) -> None:
        raise NotImplementedError


class BoucWen(BoucWenFamily):
    """Bouc-Wen model enhanced with a cubic term, eqs 1-2 of 000:

    ``f = f0 + k_e xi + k3 xi^3 + z``,  ``z' = [k_d - (gamma + beta sgn(z xi')) |z|^n] xi'``

    xi = x - x_center [m]; k_e elastic (post-elastic) stiffness [N/m], k_d initial
    hysteretic stiffness [N/m], k3 cubic coefficient [N/m^3], beta and gamma
    [N^-n m^-1... i.e. units of k_d / N^n], n dimensionless, f0 [N], z [N]. The tangent
    stiffness at the origin is k_e + k_d and |z| stays below [k_d/(gamma+beta)]^(1/n)
    when gamma + beta > 0. Rate independent. Integrated per :class:`BoucWenIntegrator`.
    Non-dimensional form (eqs 3-5): see :func:`to_nondimensional` /
    :func:`from_nondimensional`; the benchmark convention: :func:`from_benchmark` /
    :func:`to_benchmark`.
    """

    name = "boucwen"
    param_names = ("k_e", "k_d", "beta", "gamma", "n", "k3", "f0", "x_center")
    defaults = {"k3": 0.0, "f0": 0.0, "x_center": 0.0, "n": 1.0}
    param_docs = {
        "k_e": "elastic stiffness [N/m]", "k_d": "hysteretic stiffness at z = 0 [N/m]",
        "beta": "shape parameter beta [1/(m N^(n-1))]", "gamma": "shape parameter gamma [1/(m N^(n-1))]",
        "n": "smoothness exponent [-]", "k3": "cubic stiffness [N/m^3]", "f0": "force offset [N]",
        "x_center": "elongation where xi = 0 [m]",
    }
    stiffness_params = ("k_e",)         # k_e of eq 1 of 000
    nonnegative_params = ("k_d",)

    @classmethod
    def search_space(cls, s: FitStats, *, degree: int = 3) -> Space:
        """``k_e, k_d, beta, gamma, n, f0`` searched as k_e, log10 k_d, log10 beta,
        g = gamma / beta in [-0.95, 1] (bounded z, 000 Sec 2), n, f0; ``x_center`` fixed to
        the mean elongation (with k3 = 0, f0 and x_center are redundant: only
        f0 - k_e x_center acts) and ``k3 = 0`` as in 000 Sec 6."""
        K, f = s.K, s.f
        names = ["k_e", "k_d", "beta", "gamma", "n", "f0"]
        hlo, hhi = hysteresis_search_columns(s)
        slb = np.column_stack([np.zeros(K), hlo, f.mean(axis=0) - s.fr])
        sub = np.column_stack([3 * s.kk, hhi, f.mean(axis=0) + s.fr])
        lb = np.column_stack([np.zeros(K), np.zeros(K), np.zeros(K), np.full(K, -np.inf), np.full(K, 0.3),
                              np.full(K, -np.inf)])
        ub = np.column_stack([np.full(K, np.inf)] * 4 + [np.full(K, 6.0), np.full(K, np.inf)])
        start = hysteresis_to_model(0.5 * (slb + sub))
        return Space(cls.name, names, ["N/m", "N/m", "1/(m N^(n-1))", "1/(m N^(n-1))", "-", "N"], slb, sub,
                     hysteresis_to_model, hysteresis_to_search, lb, ub, {"x_center": s.xm, "k3": np.zeros(K)},
                     start,
                     notes=["boucwen: x_center fixed to the mean elongation (f0 and x_center are redundant "
                            "when k3 = 0) and k3 = 0 (as in 000 Sec 6); identified in the form of 000 eq 1, "
                            "whose beta and gamma are the benchmark's beta*gamma and beta*delta"])

    def check_params(self):
        # a negative stiffness makes the cable push back less the more it is stretched: no
        # cable does that (k_e = 0, k_d = 0 are the limits identification's search reaches)
        for k in ("k_e", "k_d"):
            if np.any(self.params[k] < 0):
                raise ModelParameterError(f"boucwen: {k} must be >= 0 [N/m] ({self.param_docs[k]}), "
                                          f"got {self.params[k].min():g}")
        super().check_params()

    def _force(self, z):
        p, xi, t = self.params, self._xi, self._t
        np.multiply(xi, xi, t)
        np.multiply(t, p["k3"], t)
        np.add(t, p["k_e"], t)
        np.multiply(t, xi, t)
        np.add(t, p["f0"], t)
        np.add(t, z, self.force)


# ---- conventions -------------------------------------------------------------------

def from_benchmark(alpha, beta, gamma, delta, nu, k_lin=0.0):
    """Parameters of the benchmark convention ``z' = alpha y' - beta (gamma |y'| |z|^(nu-1) z
    + delta y' |z|^nu)`` (Noel & Schoukens Bouc-Wen benchmark; restoring force k_lin y + z)
    converted to eq 1 of 000. Since ``|y'| |z|^(nu-1) z = y' |z|^nu sgn(z y')`` the two
    agree with k_d = alpha, beta_000 = beta*gamma, gamma_000 = beta*delta, n = nu,
    k_e = k_lin. Returns a dict of BoucWen parameters."""
    return {"k_e": float(k_lin), "k_d": float(alpha), "beta": float(beta) * float(gamma),
            "gamma": float(beta) * float(delta), "n": float(nu)}


def to_benchmark(k_d, beta, gamma, n, k_e=0.0):
    """Inverse of :func:`from_benchmark`. Only beta*gamma and beta*delta are identifiable,
    so the benchmark's beta is set to 1 and gamma, delta carry the products."""
    return {"alpha": float(k_d), "beta": 1.0, "gamma": float(beta), "delta": float(gamma), "nu": float(n),
            "k_lin": float(k_e)}


def to_nondimensional(k_e, k_d, beta, gamma, n, k3, x0):
    """Non-dimensional parameters of eqs 3-5 of 000 for characteristic displacement x0 [m]:
    delta = k_e/(k_e+k_d), k3~ = k3 x0^2/(k_e+k_d), (gamma~, beta~) = (gamma, beta) x0 z0^(n-1)
    with z0 = k_d x0. Returns a dict."""
    z0 = k_d * x0
    return {"delta": k_e / (k_e + k_d), "k3": k3 * x0 ** 2 / (k_e + k_d),
            "gamma": gamma * x0 * z0 ** (n - 1), "beta": beta * x0 * z0 ** (n - 1), "n": n}


def from_nondimensional(delta, k3, gamma, beta, n, x0, k_total):
    """Inverse of :func:`to_nondimensional` given x0 [m] and k_total = k_e + k_d [N/m]."""
    k_e = delta * k_total
    k_d = k_total - k_e
    z0 = k_d * x0
    scale = x0 * z0 ** (n - 1)
    return {"k_e": k_e, "k_d": k_d, "beta": beta / scale, "gamma": gamma / scale, "n": n,
            "k3": k3 * k_total / x0 ** 2}
