"""The Bouc-Wen hysteresis identification benchmark (Noel & Schoukens 2016): data, the
benchmark's own simulation of its test sets, the identification pipeline and synthetic
data sets in the same layout for other parameters.

Pipeline (:func:`identify`), on the training multisine only (40960 samples at 750 Hz, five
periods from rest, output noise ~8e-6 m):

1. global stage: :func:`cablesvc.identify.pso` over the box the user gives (search
   coordinates :data:`SEARCH_NAMES`: ln of mL, cL, kL, alpha and of the hysteretic force
   scale z_scale, the loop-shape ratio delta/gamma and nu), on a cheap objective: the eq 25
   normalised MSE of paper 000 over the first ``pso_samples`` samples simulated from rest
   at ``pso_upsample`` x 750 Hz (fine output read every ``pso_upsample`` samples, no
   decimation filter); all particles of an iteration are lanes of one simulation;
2. least-squares descents (:func:`cablesvc.identify.local.refine`, trust-region
   reflective, exact forward sensitivities of :mod:`cablesvc.simulate.oscillator` as the
   Jacobian) on the same cheap model from the best mutually distant points the swarm
   evaluated, until one fits to the noise level: the noise RMS is estimated without a
   model from the spread of the steady-state periods (:func:`estimate_noise`), and a fit
   is accepted when its RMS residual is below twice the hypot of that and of the cheap
   model's own discretisation error at the fitted point;
3. the final least-squares fit with the benchmark's own simulator (15 kHz Newmark, the
   multisine reconstructed band-limited, decimation 2-2-5) on all training samples;
   standard errors and correlations from the Jacobian at the optimum, for the
   identifiable groups (mL, cL, kL, alpha, beta*gamma, beta*delta, nu) and for the search
   coordinates.

The test sets are used only afterwards (:func:`evaluate`), for the benchmark's figure of
merit e_RMS: pure simulation from the test input alone.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any, Callable

import numpy as np

from cablesvc.errors import IdentifyError
from cablesvc.simulate.oscillator import (
    BENCHMARK_TRUTH, FS, PARAM_NAMES, PARAM_UNITS, UPSAMPLE, as_theta, bandlimited_upsample, decimate,
    simulate, simulate_fine,
)
from cablesvc.identify.result import IdentifyResult

__all__ = [
    "DEFAULT_DATA", "DEFAULT_BOUNDS", "PERIOD", "SEARCH_NAMES", "SEARCH_UNITS", "SYNTHETIC_PRESETS",
    "BenchmarkData", "load_benchmark", "data_dir", "simulate_train", "simulate_test_multisine",
    "simulate_test_sweep", "rmse", "ParamSpace", "IdentifyOptions", "identify", "estimate_noise", "evaluate",
    "multisine", "sine_sweep", "generate_benchmark_data",
]

#: The benchmark's own data, shipped as package data (cablesvc/data/boucwen: train.h5,
#: test.h5 and a README with their source and licence note; docs/references.md), so a
#: clone or an installed wheel runs the benchmark offline.
DEFAULT_DATA = Path(str(files("cablesvc") / "data" / "boucwen"))
PERIOD = 8192                # samples per multisine period
MULTISINE_FACTORS = (2, 2, 5)  # decimation of the multisines: MATLAB factor(20), one decimate() each
SWEEP_FACTORS = (20,)          # decimation of the sine sweep: one decimate(y, 20, 'fir')
TAIL = 20                      # coarse samples simulated past the kept ones (decimation end effects)

#: Search coordinates: the identifiable groups with the Bouc-Wen shape written as a force
#: scale and a ratio, ``z_scale = (alpha / (beta*gamma))^(1/nu)`` [N] (the |z| at which
#: the gamma term cancels the initial slope alpha) and ``delta_over_gamma = (beta*delta) /
#: (beta*gamma)`` [-]. Bounds on z_scale keep the swarm out of the degenerate corners where
#: z saturates at a negligible force (or never leaves the linear range), and which the
#: least-squares descents cannot leave (their gradient vanishes there). beta*gamma > 0.
SEARCH_NAMES = ("mL", "cL", "kL", "alpha", "z_scale", "delta_over_gamma", "nu")
SEARCH_UNITS = {"mL": "kg", "cL": "N s/m", "kL": "N/m", "alpha": "N/m", "z_scale": "N", "delta_over_gamma": "-",
                "nu": "-"}

#: Box a user would give without knowing the answer: each parameter one to three decades
#: around an engineering guess from the data's scale (50 N RMS force, ~0.7 mm RMS
#: displacement, so stiffness ~1e4-1e5 N/m; a mass of order 1 kg; light damping; a
#: hysteretic force of the order of the excitation, 1-1000 N; a loop-shape ratio of either
#: sign; nu from 1 to 4: below 1 the Bouc-Wen vector field is not Lipschitz at z = 0). Not
#: centred on the published values (log-centres 1 kg, 31.6 N s/m, 3.2e4 N/m, 3.2e4 N/m,
#: 31.6 N; 0 and 2.5; the benchmark has 2 kg, 10, 5e4, 5e4, 62.5 N, -1.375, 1).
DEFAULT_BOUNDS = {
    "mL": (0.1, 10.0),
    "cL": (1.0, 1000.0),
    "kL": (1e3, 1e6),
    "alpha": (1e3, 1e6),
    "z_scale": (1.0, 1e3),
    "delta_over_gamma": (-3.0, 3.0),
    "nu": (1.0, 4.0),
}


#: Other parameter sets for synthetic benchmark data (:func:`generate_benchmark_data`), in
#: PARAM_NAMES units. nu2 and nu1.5 keep a strong hysteresis at the benchmark's 50 N RMS
#: excitation (z_scale 52 N and 41 N, delta/gamma +0.4 and -0.4, natural frequencies of
#: kL + alpha 27 Hz and 46 Hz).
SYNTHETIC_PRESETS = {
    "benchmark": dict(BENCHMARK_TRUTH),
    "nu2": {"mL": 3.5, "cL": 25.0, "kL": 2e4, "alpha": 8e4, "beta_gamma": 30.0, "beta_delta": 12.0, "nu": 2.0},
    "nu1.5": {"mL": 1.2, "cL": 6.0, "kL": 6e4, "alpha": 4e4, "beta_gamma": 150.0, "beta_delta": -60.0, "nu": 1.5},
}


def data_dir(path: str | os.PathLike | None = None) -> Path:
    """``path``, else ``$CABLESVC_BOUCWEN_DATA``, else :data:`DEFAULT_DATA` (the vendored data)."""
    return Path(path or os.environ.get("CABLESVC_BOUCWEN_DATA") or DEFAULT_DATA)


# ---- data ------------------------------------------------------------------------------

@dataclass
class BenchmarkData:
    """The benchmark files: ``train_u``/``train_y`` (40960,) [N]/[m] at ``fs`` [Hz];
    ``ms_u``/``ms_y`` the multisine test (one steady-state period); ``sw_u``/``sw_y`` the sine
    sweep test (from rest); ``truth`` the parameters of truth.json when present."""

    train_u: np.ndarray
    train_y: np.ndarray
    fs: float
    ms_u: np.ndarray | None = None
    ms_y: np.ndarray | None = None
    sw_u: np.ndarray | None = None
    sw_y: np.ndarray | None = None
    truth: dict[str, float] | None = None
    period: int = PERIOD
    path: Path | None = None


def _read(group, key) -> np.ndarray:
    return np.asarray(group[key][()], dtype=np.float64).reshape(-1)


def load_benchmark(path: str | os.PathLike | None = None, *, tests: bool = True) -> BenchmarkData:
    """Read train.h5 (and test.h5 when ``tests``) and truth.json (if any) from ``path``
    (default :func:`data_dir`). Layout: group ``multisine`` with ``u``, ``y``, ``fs`` in
    train.h5; groups ``multisine`` and ``sinesweep`` in test.h5.
    Missing or unreadable files raise a one-line FileNotFoundError / IdentifyError naming the
    file (and the HDF5 object)."""
    import h5py

    d = data_dir(path)
    train = d / "train.h5"
    if not train.is_file():
        raise FileNotFoundError(f"{train}: no such file (the Bouc-Wen benchmark data directory is --data DIR, "
                                f"$CABLESVC_BOUCWEN_DATA or, by default, the data shipped with cablesvc)")

    def read(file: Path, fn):
        try:
            with h5py.File(file, "r") as f:
                return fn(f)
        except KeyError as e:
            raise IdentifyError(f"{file}: missing HDF5 group or dataset ({e.args[0] if e.args else e})") from None
        except OSError as e:
            raise IdentifyError(f"{file}: not a readable HDF5 file ({e})") from None

    data = read(train, lambda f: BenchmarkData(train_u=_read(f["multisine"], "u"), train_y=_read(f["multisine"], "y"),
                                               fs=float(_read(f["multisine"], "fs")[0]), path=d))
    if data.train_u.size % PERIOD == 0:
        data.period = PERIOD
    if tests and (d / "test.h5").exists():
        data.ms_u, data.ms_y, data.sw_u, data.sw_y = read(
            d / "test.h5", lambda f: (_read(f["multisine"], "u"), _read(f["multisine"], "y"),
                                      _read(f["sinesweep"], "u"), _read(f["sinesweep"], "y")))
    if (d / "truth.json").exists():
        t = json.loads((d / "truth.json").read_text())
        data.truth = {k: float(v) for k, v in (t.get("params", t)).items() if k in PARAM_NAMES}
        if "period" in t:
            data.period = int(t["period"])
    return data


# ---- the benchmark's simulations ------------------------------------------------------

def simulate_train(u_period: np.ndarray, theta, *, samples: int | None = None, periods: int = 5,
                   upsample: int = UPSAMPLE, fs: float = FS, decimated: bool = True, sensitivities: bool = False):
    """Training-set simulation as the benchmark made it: from rest, the multisine period
    ``u_period`` repeated, 15 kHz Newmark, decimation 2-2-5 (with ``TAIL`` extra samples
    instead of the benchmark's whole extra period: the filter reaches ~5 samples); returns
    the first ``samples`` (default ``periods * len(u_period)``) outputs at ``fs``.
    ``decimated=False`` reads every ``upsample``-th fine sample (cheap objective)."""
    n = int(samples) if samples is not None else periods * u_period.size
    reps = -(-(n + TAIL) // u_period.size)
    return simulate(u_period, theta, fs=fs, upsample=upsample, periodic=True, periods=reps,
                    factors=MULTISINE_FACTORS if decimated else None, keep=slice(0, n), sensitivities=sensitivities)


def simulate_test_multisine(u: np.ndarray, theta, *, transient_periods: int = 1, upsample: int = UPSAMPLE,
                            fs: float = FS) -> np.ndarray:
    """Multisine test output (one steady-state period): from rest, ``transient_periods``
    periods to settle, then the kept period, plus ``TAIL`` samples for the decimation
    filter; 15 kHz Newmark, decimation 2-2-5. With the published parameters this matches
    the official test output to 2.5e-16 m (any period after the first does: the transient
    has died out by then; the first period is 4.6e-5 m off). Returns ``(lanes, len(u))``."""
    N = u.size
    k = int(transient_periods)
    y, _, _ = simulate(u, theta, fs=fs, upsample=upsample, periodic=True, periods=k + 1, tail=TAIL,
                       factors=MULTISINE_FACTORS, keep=slice(k * N, (k + 1) * N))
    return y


def simulate_test_sweep(u: np.ndarray, theta, *, upsample: int = UPSAMPLE, fs: float = FS) -> np.ndarray:
    """Sine-sweep test output: from rest, the input reconstructed band-limited from its
    samples (point-reflected ends, windowed sinc), 15 kHz Newmark, one decimate(y, 20,
    'fir'). Returns ``(lanes, len(u))``."""
    y, _, _ = simulate(u, theta, fs=fs, upsample=upsample, periodic=False, factors=SWEEP_FACTORS)
    return y


def rmse(y_model: np.ndarray, y_ref: np.ndarray) -> np.ndarray:
    """Benchmark figure of merit e_RMS = sqrt(mean((y_model - y_test)^2)) [m] over the last axis."""
    return np.sqrt(np.mean((np.asarray(y_model) - np.asarray(y_ref)) ** 2, axis=-1))


# ---- parameter space -------------------------------------------------------------------

class ParamSpace:
    """The search box and the map between search coordinates and the identifiable groups.

    Search coordinates (:data:`SEARCH_NAMES`, the user's bounds are on these) go to the
    optimisers as ``q``: ``ln`` of mL, cL, kL, alpha and z_scale, ``delta_over_gamma`` and
    ``nu`` as they are. ``theta`` (:data:`PARAM_NAMES`) follows from
    ``beta_gamma = alpha / z_scale^nu`` and ``beta_delta = delta_over_gamma * beta_gamma``.
    """

    LOG = (0, 1, 2, 3, 4)

    def __init__(self, bounds: dict[str, tuple[float, float]] | None = None) -> None:
        b = dict(DEFAULT_BOUNDS)
        if bounds:
            b.update({k: tuple(map(float, v)) for k, v in bounds.items()})
        unknown = set(b) - set(SEARCH_NAMES)
        if unknown:
            raise IdentifyError(f"unknown parameter(s) in bounds: {sorted(unknown)}; names are {SEARCH_NAMES}")
        self.lb = np.array([b[n][0] for n in SEARCH_NAMES], float)
        self.ub = np.array([b[n][1] for n in SEARCH_NAMES], float)
        if np.any(self.ub <= self.lb):
            raise IdentifyError("bounds: every upper bound must exceed its lower bound")
        if np.any(self.lb[list(self.LOG)] <= 0):
            raise IdentifyError(f"bounds: {[SEARCH_NAMES[i] for i in self.LOG]} must have positive bounds")
        if self.lb[6] <= 0:
            raise IdentifyError("bounds: nu must be > 0")
        self.qlb = self.search_to_q(self.lb)
        self.qub = self.search_to_q(self.ub)

    def search_to_q(self, s) -> np.ndarray:
        q = np.array(s, float)
        q[..., self.LOG] = np.log(q[..., self.LOG])
        return q

    def q_to_search(self, q) -> np.ndarray:
        s = np.array(q, float)
        s[..., self.LOG] = np.exp(s[..., self.LOG])
        return s

    def to_theta(self, q) -> np.ndarray:
        """theta (..., 7) in :data:`PARAM_NAMES` order from q (..., 7)."""
        s = self.q_to_search(q)
        th = s.copy()
        bg = s[..., 3] / s[..., 4] ** s[..., 6]
        th[..., 4] = bg
        th[..., 5] = s[..., 5] * bg
        return th

    def to_q(self, theta) -> np.ndarray:
        """Inverse of :meth:`to_theta` (needs beta_gamma > 0)."""
        th = np.array(theta, float)
        s = th.copy()
        s[..., 4] = (th[..., 3] / th[..., 4]) ** (1.0 / th[..., 6])
        s[..., 5] = th[..., 5] / th[..., 4]
        return self.search_to_q(s)

    def dtheta_dq(self, q) -> np.ndarray:
        """Jacobian d theta / d q, (7, 7), at one point q."""
        q = np.asarray(q, float)
        s = self.q_to_search(q)
        th = self.to_theta(q)
        J = np.zeros((7, 7))
        for i in range(4):                     # mL, cL, kL, alpha = exp(q_i)
            J[i, i] = s[i]
        J[6, 6] = 1.0
        bg, rho, nu, lnz = th[4], s[5], s[6], q[4]
        # beta_gamma = exp(q3 - nu q4)
        J[4, 3], J[4, 4], J[4, 6] = bg, -nu * bg, -lnz * bg
        J[5, 3], J[5, 4], J[5, 5], J[5, 6] = rho * bg, -nu * rho * bg, bg, -lnz * rho * bg
        return J


# ---- identification --------------------------------------------------------------------

@dataclass
class IdentifyOptions:
    """Settings of :func:`identify` (defaults: the ones measured in docs/boucwen-benchmark.md)."""

    bounds: dict[str, tuple[float, float]] | None = None
    pso_samples: int = 3072          # cheap objective: first samples of the record [750 Hz samples]
    pso_upsample: int = 4            # cheap objective: integration at 4 x 750 Hz
    particles: int = 24
    iterations: int = 50
    starts: int = 12                 # at most this many least-squares descents: best distinct swarm
                                     # points first, then uniform random points of the box
    start_distance: float = 0.25     # distinct: farther apart than this fraction of the box (max norm)
    start_nfev: int = 40
    accept_factor: float = 2.0       # stop the descents once a fit's RMS residual is below
                                     # accept_factor * hypot(noise RMS, cheap-model error)
    polish_samples: int = 8192       # stage 2: cheap model, one period (0 nfev: skip)
    polish_upsample: int = 8
    polish_nfev: int = 0
    final_nfev: int = 25
    final_samples: int | None = None  # stage 3: all samples by default
    seed: int | None = 0
    workers: int | None = None       # numba threads (None: numba's default)


class _CheapObjective:
    """eq 25 normalised MSE of the first ``n`` samples simulated at ``r`` x fs from rest, for
    all particles at once (lanes); q-space input."""

    def __init__(self, space: ParamSpace, u_period, y, n, r, fs):
        self.space, self.n, self.r = space, int(n), int(r)
        reps = -(-self.n // u_period.size)
        uf = np.tile(bandlimited_upsample(u_period, self.r, periodic=True), reps)
        self.uf = np.ascontiguousarray(uf[: (self.n - 1) * self.r + 1])
        self.h = 1.0 / (fs * self.r)
        self.y = np.asarray(y[: self.n], float)
        self.var = float(np.var(self.y))
        self.ycap = 1e3 * float(np.max(np.abs(self.y)))

    def __call__(self, Q):
        th = self.space.to_theta(np.atleast_2d(Q))
        yf, _, ok = simulate_fine(self.uf, self.h, th, ycap=self.ycap)
        ym = yf[:, :: self.r]
        f = np.mean((ym - self.y) ** 2, axis=1) / self.var
        f[~ok] = np.inf
        return np.where(np.isfinite(f), f, np.inf)


class _Residuals:
    """Output-error residuals ``y_model - y_meas`` [m] and their exact Jacobian in q-space,
    one simulation per new q (cached for the Jacobian call at the same point)."""

    def __init__(self, space: ParamSpace, u_period, y, n, r, fs, decimated):
        self.space, self.u, self.n, self.r, self.fs, self.decimated = space, u_period, int(n), int(r), fs, decimated
        self.y = np.asarray(y[: self.n], float)
        self._q = None
        self._r = None
        self._J = None
        self.nsim = 0

    def _eval(self, q):
        q = np.asarray(q, float)
        if self._q is not None and np.array_equal(q, self._q):
            return
        th = self.space.to_theta(q)
        ym, dy, ok = simulate_train(self.u, th[None, :], samples=self.n, upsample=self.r, fs=self.fs,
                                    decimated=self.decimated, sensitivities=True)
        self.nsim += 1
        self._q = q.copy()
        if not ok[0] or not np.all(np.isfinite(ym)):
            self._r = np.full(self.n, 1.0)      # a large, finite residual: trf then shrinks the step
            self._J = np.zeros((self.n, q.size))
            return
        self._r = ym[0] - self.y
        self._Jth = dy[0].T.copy()
        self._J = self._Jth @ self.space.dtheta_dq(q)

    def residuals(self, q):
        self._eval(q)
        return self._r

    def jac(self, q):
        self._eval(q)
        return self._J


def estimate_noise(y: np.ndarray, period: int, skip: int = 1) -> float | None:
    """Non-parametric output-noise RMS [m] of a periodic steady-state record: the spread of
    the periods after the first ``skip`` (transient) around their mean, with the
    ``P / (P - 1)`` correction for P periods. None with fewer than two steady periods."""
    y = np.asarray(y, float).reshape(-1)
    P = y.size // period - skip
    if P < 2:
        return None
    Y = y[skip * period:(skip + P) * period].reshape(P, period)
    return float(np.sqrt(np.sum((Y - Y.mean(axis=0)) ** 2) / ((P - 1) * period)))


def _distinct_best(Q, F, space: ParamSpace, k: int, dist: float) -> list[np.ndarray]:
    """Up to ``k`` points of the archive ``Q`` with the lowest ``F``, greedily skipping
    any closer than ``dist`` (fraction of the box, max norm) to one already taken."""
    span = space.qub - space.qlb
    order = np.argsort(F, kind="stable")
    taken: list[np.ndarray] = []
    for i in order:
        if not np.isfinite(F[i]):
            break
        if all(np.max(np.abs(Q[i] - t) / span) > dist for t in taken):
            taken.append(Q[i])
            if len(taken) >= k:
                break
    return taken


def _local(res_obj: _Residuals, q0, space: ParamSpace, max_nfev: int, names):
    try:
        from cablesvc.identify.local import refine
    except ImportError:                                     # pragma: no cover - local.py ships with the package
        refine = None
    if refine is not None:
        return refine(res_obj.residuals, q0, (space.qlb, space.qub), method="trf", x_scale="jac", names=names,
                      jac=res_obj.jac, max_nfev=max_nfev, xtol=1e-10, ftol=1e-12, gtol=1e-12)
    from scipy.optimize import least_squares
    ls = least_squares(res_obj.residuals, np.clip(q0, space.qlb, space.qub), jac=res_obj.jac,
                       bounds=(space.qlb, space.qub), x_scale="jac", max_nfev=max_nfev, xtol=1e-10, ftol=1e-12,
                       gtol=1e-12)
    return IdentifyResult(x=ls.x, fun=float(ls.cost), nfev=ls.nfev, nit=int(ls.njev or 0), success=bool(ls.success),
                          message=ls.message, names=names, method="least_squares/trf")


def identify(u: np.ndarray, y: np.ndarray, *, options: IdentifyOptions | None = None, fs: float = FS,
             period: int = PERIOD, progress: Callable[[str, dict], Any] | None = None) -> IdentifyResult:
    """Identify ``(mL, cL, kL, alpha, beta*gamma, beta*delta, nu)`` from a training record
    that starts from rest: input ``u`` [N] (whole periods of ``period`` samples of a
    multisine) and measured output ``y`` [m], both at ``fs`` [Hz].

    Returns an :class:`IdentifyResult` with ``x`` (physical units, order
    :data:`PARAM_NAMES`), ``params`` (dict), ``stderr``, ``correlation``, ``cond`` (from the
    Jacobian of the final fit), ``fun`` = 1/2 sum r^2 [m^2], ``rms_residual`` [m],
    ``stages`` (one dict per stage: name, seconds, objective, x), ``seconds`` (wall time).
    """
    from cablesvc.identify.pso import pso

    opt = options or IdentifyOptions()
    if opt.workers:
        import numba
        numba.set_num_threads(max(1, min(int(opt.workers), numba.config.NUMBA_NUM_THREADS)))
    t_start = time.perf_counter()
    u = np.asarray(u, float).reshape(-1)
    y = np.asarray(y, float).reshape(-1)
    if u.size % period:
        raise IdentifyError(f"identify: the record ({u.size} samples) must hold whole periods of {period}")
    u_period = u[:period]
    space = ParamSpace(opt.bounds)
    names = list(PARAM_NAMES)
    qnames = [f"ln {n}" if i in ParamSpace.LOG else n for i, n in enumerate(SEARCH_NAMES)]
    stages = []
    rng = np.random.default_rng(opt.seed)

    def note(name, t0, fun, q, **extra):
        d = {"stage": name, "seconds": time.perf_counter() - t0, "objective": float(fun),
             "params": dict(zip(names, map(float, space.to_theta(q)))), **extra}
        stages.append(d)
        if progress is not None:
            progress(name, d)

    # 1. global: PSO on the cheap objective, then least squares on the same cheap model
    #    from the best distinct points the swarm evaluated (the hysteretic optimum is a
    #    narrow valley next to a wide "equivalent viscous damping" basin; a few
    #    Gauss-Newton descents find it where the swarm alone stalls at the basin).
    t0 = time.perf_counter()
    cheap = _CheapObjective(space, u_period, y, min(opt.pso_samples, y.size), opt.pso_upsample, fs)
    archive_q: list[np.ndarray] = []
    archive_f: list[np.ndarray] = []

    def recorded(Q):
        f = cheap(Q)
        archive_q.append(np.array(Q, float))
        archive_f.append(np.array(f, float))
        return f

    sw = pso(recorded, (space.qlb, space.qub), particles=opt.particles, iterations=opt.iterations,
             seed=int(rng.integers(2**31)), names=qnames)
    note("pso", t0, sw.fun, sw.x, nfev=sw.nfev)
    t0 = time.perf_counter()
    Q = np.concatenate(archive_q)
    F = np.concatenate(archive_f)
    starts = _distinct_best(Q, F, space, opt.starts, opt.start_distance)
    while len(starts) < opt.starts:              # a converged swarm leaves few distinct points
        starts.append(space.qlb + (space.qub - space.qlb) * rng.random(space.qlb.size))
    n1 = min(opt.pso_samples, y.size)
    rc = _Residuals(space, u_period, y, n1, opt.pso_upsample, fs, decimated=False)
    sigma = estimate_noise(y, period)
    best = None
    accepted = False
    tried = 0
    for q0 in starts:
        loc = _local(rc, q0, space, opt.start_nfev, qnames)
        tried += 1
        if best is None or loc.fun < best.fun:
            best = loc
        if sigma is not None and np.isfinite(loc.fun):
            # residual of the cheap model against the noise level plus the cheap model's own
            # discretisation error at this point (cheap vs benchmark simulator)
            th = space.to_theta(np.asarray(loc.x))[None, :]
            y_full = simulate_train(u_period, th, samples=n1)[0][0]
            y_cheap = simulate_train(u_period, th, samples=n1, upsample=opt.pso_upsample, decimated=False)[0][0]
            e_disc = float(np.sqrt(np.mean((y_full - y_cheap) ** 2)))
            rms_fit = float(np.sqrt(2.0 * loc.fun / n1))
            if rms_fit <= opt.accept_factor * math.hypot(sigma, e_disc):
                accepted = True
                break
    note("multistart", t0, best.fun, best.x, starts=tried, accepted=accepted, nfev=rc.nsim,
         noise_rms=float(sigma) if sigma is not None else None)

    # 2. optional polish on the cheap model over a longer segment
    q_start = np.asarray(best.x, float)
    r2 = None
    if opt.polish_nfev > 0:
        t0 = time.perf_counter()
        n2 = min(opt.polish_samples, y.size)
        r2 = _Residuals(space, u_period, y, n2, opt.polish_upsample, fs, decimated=False)
        pol = _local(r2, q_start, space, opt.polish_nfev, qnames)
        q_start = np.asarray(pol.x, float)
        note("polish", t0, pol.fun, pol.x, nfev=r2.nsim)

    # 3. final fit with the benchmark simulator on the whole record
    t0 = time.perf_counter()
    n3 = y.size if opt.final_samples is None else min(opt.final_samples, y.size)
    r3 = _Residuals(space, u_period, y, n3, UPSAMPLE, fs, decimated=True)
    fin = _local(r3, q_start, space, opt.final_nfev, qnames)
    note("final", t0, fin.fun, fin.x, nfev=r3.nsim)

    q = np.asarray(fin.x, float)
    theta = space.to_theta(q)
    r3._eval(q)
    from cablesvc.identify.identifiability import jacobian_statistics
    st = jacobian_statistics(r3._Jth, r3._r, names=names, x=theta)
    # the same statistics in the search coordinates (z_scale, delta_over_gamma ...)
    search = space.q_to_search(q)
    dq_ds = np.ones(7)
    dq_ds[list(ParamSpace.LOG)] = 1.0 / search[list(ParamSpace.LOG)]
    Js = r3._Jth @ space.dtheta_dq(q) * dq_ds[None, :]
    st_s = jacobian_statistics(Js, r3._r, names=list(SEARCH_NAMES), x=search)
    out = IdentifyResult(
        x=theta, fun=float(0.5 * r3._r @ r3._r), nit=int(fin.nit),
        nfev=int(sw.nfev + rc.nsim + (r2.nsim if r2 else 0) + r3.nsim),
        success=bool(fin.success), message=fin.message, names=names, history=np.asarray(sw.history),
        method="pso+least_squares", params=dict(zip(names, map(float, theta))), stderr=st.stderr,
        correlation=st.correlation, cond=st.cond, rms_residual=float(np.sqrt(np.mean(r3._r ** 2))),
        search=dict(zip(SEARCH_NAMES, map(float, search))), search_stderr=st_s.stderr,
        noise_rms=sigma, stages=stages, seconds=time.perf_counter() - t_start, units=dict(PARAM_UNITS))
    return out


def evaluate(theta, data: BenchmarkData) -> dict[str, float]:
    """RMSE [m] of the pure simulation of both test sets from their inputs alone."""
    th = as_theta(theta)
    out = {}
    if data.ms_u is not None:
        out["rmse_multisine"] = float(rmse(simulate_test_multisine(data.ms_u, th)[0], data.ms_y))
    if data.sw_u is not None:
        out["rmse_sinesweep"] = float(rmse(simulate_test_sweep(data.sw_u, th)[0], data.sw_y))
    return out


# ---- synthetic data in the benchmark's layout ------------------------------------------

def multisine(rng: np.random.Generator, n_period: int = PERIOD, fs: float = FS, fmin: float = 5.0,
              fmax: float = 150.0, rms: float = 50.0, upsample: int = UPSAMPLE) -> np.ndarray:
    """One period of a random-phase multisine at ``fs * upsample`` as the benchmark script
    designs it: lines ``floor(fmin/df)..ceil(fmax/df)`` (df = fs / n_period) with unit
    amplitude and uniform random phase, scaled to ``rms`` [N]. Its samples every
    ``upsample`` fine steps are the 750 Hz input."""
    nint = n_period * upsample
    df = fs / n_period
    lines = np.arange(1, int(math.ceil(fmax / df)) + 1)
    lines = lines[lines >= int(math.floor(fmin / df))]
    U = np.zeros(nint // 2 + 1, dtype=complex)
    U[lines] = np.exp(2j * np.pi * rng.random(lines.size))
    u = np.fft.irfft(U, nint)
    return rms * u / np.std(u)


def sine_sweep(n: int = 153000, fs: float = FS, amplitude: float = 40.0, f0: float = 18.0,
               rate: float = 10.0 / 60.0, upsample: int = UPSAMPLE) -> np.ndarray:
    """The benchmark sweep ``u(t) = A sin(2 pi (f0 t + rate t^2 / 2))`` [N] on the fine grid
    (n * upsample points); the official one has A = 40 N, f0 = 18 Hz, rate = 10 Hz/min
    (found from its samples: 18 Hz at t = 0, 52 Hz after 153000 samples)."""
    t = np.arange(n * upsample) / (fs * upsample)
    return amplitude * np.sin(2 * np.pi * (f0 * t + 0.5 * rate * t ** 2))


def generate_benchmark_data(directory: str | os.PathLike, params: dict[str, float] | None = None, seed: int = 0, *,
                            periods: int = 5, n_period: int = PERIOD, noise_rms: float = 8e-6,
                            sweep_samples: int = 153000, rms: float = 50.0, sweep_amplitude: float = 40.0,
                            test_transient_periods: int = 1) -> Path:
    """Write train.h5, test.h5 and truth.json in the benchmark layout, synthesised the way
    the benchmark's data were (see docs/boucwen-benchmark.md):

    * train: a random-phase multisine period designed at 15 kHz (:func:`multisine`),
      ``periods`` + 1 periods simulated from rest with 15 kHz Newmark, decimated 2-2-5
      (MATLAB decimate 'fir'), the last (filter) period dropped; u = every 20th fine
      sample. Noise: white Gaussian at 15 kHz passed through the same decimation, scaled to
      ``noise_rms`` [m] RMS at 750 Hz (band-limited like the official noise, flat to ~200
      Hz, rolling off towards 375 Hz);
    * test multisine: another realisation, ``test_transient_periods`` periods to settle then
      the kept period (plus one filter period), noiseless;
    * test sine sweep: :func:`sine_sweep` over ``sweep_samples`` samples from rest, one
      decimate(y, 20, 'fir'), noiseless.

    ``params``: dict over :data:`PARAM_NAMES` (default: the published ones). The random
    phases and noise come from ``numpy.random.default_rng(seed)``. Returns the directory.
    """
    import h5py

    p = dict(BENCHMARK_TRUTH)
    if params:
        unknown = set(params) - set(PARAM_NAMES)
        if unknown:
            raise IdentifyError(f"unknown parameter(s) {sorted(unknown)}")
        p.update({k: float(v) for k, v in params.items()})
    th = as_theta(p)
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    h = 1.0 / (FS * UPSAMPLE)

    def run(u_fine, factors):
        y, _, ok = simulate_fine(u_fine, h, th)
        if not ok[0]:
            raise IdentifyError(f"generate_benchmark_data: the simulation diverged for {p}")
        return decimate(y[0], factors)

    # train
    uf = multisine(rng, n_period, rms=rms)
    y = run(np.tile(uf, periods + 1), MULTISINE_FACTORS)[: periods * n_period]
    w = rng.standard_normal((periods + 1) * n_period * UPSAMPLE)
    noise = decimate(w, MULTISINE_FACTORS)[: periods * n_period]
    noise *= noise_rms / np.sqrt(np.mean(noise ** 2)) if noise_rms > 0 else 0.0
    train_u = np.tile(uf[::UPSAMPLE], periods)
    train_y = y + noise
    # test multisine
    uf2 = multisine(rng, n_period, rms=rms)
    k = test_transient_periods
    y2 = run(np.tile(uf2, k + 2), MULTISINE_FACTORS)[k * n_period:(k + 1) * n_period]
    # test sweep
    us = sine_sweep(sweep_samples, amplitude=sweep_amplitude)
    y3 = run(us, SWEEP_FACTORS)

    def write(path, groups):
        with h5py.File(path, "w") as f:
            for g, (uu, yy) in groups.items():
                grp = f.create_group(g)
                grp["u"] = uu.reshape(-1, 1)
                grp["y"] = yy.reshape(-1, 1)
                grp["fs"] = np.array([FS])

    write(d / "train.h5", {"multisine": (train_u, train_y)})
    write(d / "test.h5", {"multisine": (uf2[::UPSAMPLE], y2), "sinesweep": (us[::UPSAMPLE], y3)})
    meta = {"params": p, "seed": seed, "noise_rms": noise_rms, "period": n_period,
            "generator": "cablesvc.identify.boucwen_benchmark.generate_benchmark_data"}
    (d / "truth.json").write_text(json.dumps(meta, indent=2))
    return d
