"""Particle Swarm Optimisation as used in paper 000, Sec 5 (eqs 25-27).

The swarm has ``p`` particles (parameter vectors) ``x_i``; every iteration all of them are
evaluated with ONE call ``fun(X)`` where ``X`` is ``(p, n)``, so that an objective built on
a cable model can simulate every particle as one lane of a single ``(lanes, cables)``
model instance.

Algorithm (000 Sec 5, with the choices the paper leaves open stated here):

* Initial population: each parameter ``k`` is drawn from a Gaussian with mean
  ``(lb_k + ub_k) / 2`` and standard deviation ``(ub_k - lb_k) / 6`` (so +-3 sigma spans
  the range), then clipped to ``[lb_k, ub_k]``. Optional seed particles ``x0`` replace the
  first rows of that population (the swarm keeps ``particles`` members). Initial
  velocities are zero.
* Velocity, eq 27: ``v_{i,j+1} = w v_{i,j} + c1 r1 o (p_{i,j} - x_{i,j}) + c2 r2 o (p_j - x_{i,j})``
  with ``r1, r2`` uniform on [0, 1] drawn per particle and per parameter, ``p_{i,j}`` the
  best position particle ``i`` has had and ``p_j`` the best of the whole swarm so far.
* Position, eq 26: ``x_{i,j+1} = x_{i,j} + v_{i,j+1}``; an element that leaves its range
  is reset to the closest bound (velocity unchanged, as in the paper).
* Defaults ``w = 0.8, c1 = 2.8, c2 = 1.3, p = 10, q = 75`` are the paper's.
* Stop after ``iterations`` (q) iterations, or as soon as the best objective is
  ``<= tol``. With ``fun`` = :func:`normalized_mse` (eq 25) ``tol`` is the acceptable
  normalised MSE of the paper.

Seeded runs are bit-reproducible: all random numbers come from one
``numpy.random.default_rng(seed)`` stream in the calling process, independent of
``workers``. Non-finite objective values count as ``+inf`` (the particle never becomes a
best).
"""

from __future__ import annotations

import pickle
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np

from cablesvc.identify.bounds import parse_bounds
from cablesvc.identify.result import IdentifyResult
from cablesvc.threads import one_blas_thread

__all__ = ["pso", "pso_lockstep", "normalized_mse", "initial_population", "Swarm"]


def normalized_mse(y_model: np.ndarray, y_meas: np.ndarray) -> np.ndarray:
    """Objective of eq 25 of paper 000: ``sum_k (f_k - f^_k)^2 / (N sigma_f^2)``.

    The mean squared error between model output and measurement divided by the variance
    ``sigma_f^2`` of the measurement (dimensionless: 0 is a perfect fit, 1 is as bad as
    predicting the measurement's mean). ``y_model`` ``(..., N)`` and ``y_meas`` ``(N,)`` or
    ``(..., N)`` broadcast against each other; time is the last axis, every leading index
    (lane, cable) gets its own value. Returns an array of the broadcast leading shape.
    """
    ym = np.asarray(y_model, dtype=np.float64)
    yd = np.asarray(y_meas, dtype=np.float64)
    var = np.var(yd, axis=-1)
    mse = np.mean((yd - ym) ** 2, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = mse / var
    return np.asarray(out)


def initial_population(rng: np.random.Generator, lb: np.ndarray, ub: np.ndarray, particles: int) -> np.ndarray:
    """Gaussian initial swarm of 000 Sec 5: mean mid-range, std = range / 6, clipped."""
    mean = 0.5 * (lb + ub)
    std = (ub - lb) / 6.0
    X = mean + std * rng.standard_normal((particles, lb.size))
    return np.clip(X, lb, ub)


def _eval_rows(fun: Callable[[np.ndarray], np.ndarray], X: np.ndarray) -> np.ndarray:
    return np.asarray(fun(X), dtype=np.float64).reshape(X.shape[0])


class _Evaluator:
    """Evaluates ``fun`` on all particles: in-process, via a map-like, or by splitting the
    rows of ``X`` into ``workers`` contiguous chunks sent to a process pool."""

    def __init__(self, fun: Callable, workers: int | Callable) -> None:
        self.fun = fun
        self.pool: ProcessPoolExecutor | None = None
        self.map = None
        self.workers = 1
        if callable(workers):
            self.map = workers
        else:
            self.workers = int(workers)
            if self.workers < 1:
                raise ValueError(f"workers must be >= 1, got {workers}")
            if self.workers > 1:
                try:
                    pickle.dumps(fun)
                except Exception as e:
                    raise TypeError(f"workers={self.workers} sends fun to worker processes, so it must be picklable "
                                    f"(a module-level function or an instance of a module-level class): {e}") from None
                self.pool = ProcessPoolExecutor(max_workers=self.workers, initializer=one_blas_thread)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        p = X.shape[0]
        if self.pool is None and self.map is None:
            f = _eval_rows(self.fun, X)
        else:
            n_chunks = self.workers if self.pool is not None else p
            chunks = [c for c in np.array_split(X, min(n_chunks, p)) if c.shape[0]]
            mapper = self.pool.map if self.pool is not None else self.map
            parts = list(mapper(_eval_rows, [self.fun] * len(chunks), chunks))
            f = np.concatenate([np.asarray(q, dtype=np.float64).reshape(-1) for q in parts])
        if f.shape != (p,):
            raise ValueError(f"fun must return one value per particle, shape ({p},), got {f.shape}")
        return np.where(np.isfinite(f), f, np.inf)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)
            self.pool = None


class _Progress:
    """Adapter for the ``progress`` hook: None, a callable ``(it, total, best_f)``, a rich
    ``Progress`` (a task is added), or a ``(Progress, task_id)`` pair."""

    def __init__(self, progress: Any, total: int) -> None:
        self.fn = None
        if progress is None:
            return
        if isinstance(progress, tuple) and len(progress) == 2 and hasattr(progress[0], "update"):
            prog, task = progress
            prog.update(task, total=total, completed=0)
            self.fn = lambda it, tot, f: prog.update(task, completed=it, description=f"PSO best {f:.4g}")
        elif hasattr(progress, "add_task"):
            task = progress.add_task("PSO", total=total)
            self.fn = lambda it, tot, f: progress.update(task, completed=it, description=f"PSO best {f:.4g}")
        elif callable(progress):
            self.fn = progress
        else:
            raise TypeError("progress: expected None, a callable, a rich Progress or (Progress, task_id)")

    def __call__(self, it: int, total: int, best: float) -> None:
        if self.fn is not None:
            self.fn(it, total, best)


class Swarm:
    """State of one swarm of 000 Sec 5: positions ``X``, velocities ``V``, personal bests
    ``P``/``Pf``, global best ``G``/``Gf``, its own random stream. :func:`pso` drives one,
    :func:`pso_lockstep` several at once."""

    def __init__(self, lb: np.ndarray, ub: np.ndarray, particles: int, rng: np.random.Generator,
                 x0: np.ndarray | None = None) -> None:
        self.lb, self.ub, self.rng = lb, ub, rng
        self.n = lb.size
        self.particles = particles
        X = initial_population(rng, lb, ub, particles)
        if x0 is not None:
            seeds = np.atleast_2d(np.asarray(x0, dtype=float))
            if seeds.shape[1] != self.n:
                raise ValueError(f"x0: expected {self.n} parameters per seed particle, got {seeds.shape[1]}")
            if seeds.shape[0] > particles:
                raise ValueError(f"x0: {seeds.shape[0]} seed particles but only {particles} particles")
            X[: seeds.shape[0]] = np.clip(seeds, lb, ub)
        self.X = X
        self.V = np.zeros_like(X)
        self.history: list[float] = []

    def start(self, f: np.ndarray) -> None:
        """Take the objective values of the initial population."""
        self.P, self.Pf = self.X.copy(), np.array(f, dtype=float)
        g = int(np.argmin(self.Pf))
        self.G, self.Gf = self.P[g].copy(), float(self.Pf[g])
        self.history.append(self.Gf)

    def move(self, w: float, c1: float, c2: float) -> np.ndarray:
        """Eqs 27 and 26, then reset escaped elements to the closest bound; returns X."""
        shape = (self.particles, self.n)
        r1 = self.rng.random(shape)
        r2 = self.rng.random(shape)
        self.V = w * self.V + c1 * r1 * (self.P - self.X) + c2 * r2 * (self.G - self.X)   # eq 27
        self.X = self.X + self.V                                                          # eq 26
        np.clip(self.X, self.lb, self.ub, out=self.X)
        return self.X

    def update(self, f: np.ndarray) -> None:
        """Take the objective values of the moved particles; update personal/global bests."""
        better = f < self.Pf
        self.P[better] = self.X[better]
        self.Pf[better] = f[better]
        g = int(np.argmin(self.Pf))
        if self.Pf[g] < self.Gf:
            self.G, self.Gf = self.P[g].copy(), float(self.Pf[g])
        self.history.append(self.Gf)


def _check(particles: int, iterations: int, n: int, names: Sequence[str] | None) -> None:
    if names is not None and len(names) != n:
        raise ValueError(f"names: {len(names)} names for {n} parameters")
    if particles < 1:
        raise ValueError(f"particles must be >= 1, got {particles}")
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")


def _finite(f: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    f = np.asarray(f, dtype=np.float64)
    if f.shape != shape:
        raise ValueError(f"fun must return objective values of shape {shape}, got {f.shape}")
    return np.where(np.isfinite(f), f, np.inf)


def pso(fun: Callable[[np.ndarray], np.ndarray], bounds: Any, *, particles: int = 10, iterations: int = 75,
        w: float = 0.8, c1: float = 2.8, c2: float = 1.3, tol: float | None = None, seed: Any = None,
        workers: int | Callable = 1, x0: np.ndarray | None = None,
        callback: Callable[[int, np.ndarray, float], Any] | None = None,
        names: Sequence[str] | None = None, progress: Any = None) -> IdentifyResult:
    """Minimise ``fun`` over a box with the PSO of paper 000 Sec 5 (eqs 26-27).

    Parameters
    ----------
    fun : callable ``fun(X) -> (p,)``; ``X`` is ``(p, n)``, all particles of one iteration.
    bounds : ``(lb, ub)`` or a sequence of ``(lo, hi)`` (see :func:`~cablesvc.identify.bounds.parse_bounds`); finite.
    particles, iterations : ``p`` and ``q`` of the paper (10 and 75).
    w, c1, c2 : inertia, cognitive and social factors of eq 27 (0.8, 2.8, 1.3).
    tol : stop as soon as the best objective is ``<= tol``.
    seed : anything ``numpy.random.default_rng`` accepts; fixes the run bit for bit.
    workers : ``> 1`` splits the rows of ``X`` over a process pool (``fun`` must be
        picklable); or a map-like callable. Same results as ``workers=1``.
    x0 : ``(n,)`` or ``(k, n)`` seed particle(s), clipped to the bounds; they replace the
        first ``k`` Gaussian particles.
    callback : ``callback(iteration, best_x, best_f)`` after every iteration (iteration 0
        is the initial population); returning ``True`` stops the swarm.
    names : parameter names stored in the result.
    progress : optional progress hook (callable ``(it, total, best_f)``, rich ``Progress``
        or ``(Progress, task_id)``).

    Returns
    -------
    IdentifyResult with ``x, fun, nfev, nit, success, message, names, history`` (best
    objective after each iteration, element 0 = initial population) and ``population``
    (final positions), ``population_fun`` (their personal-best values), ``method = "pso"``.
    ``success`` is True when ``tol`` was reached, or, without ``tol``, when the iterations
    completed with a finite objective.
    """
    lb, ub = parse_bounds(bounds, finite=True)
    particles, iterations = int(particles), int(iterations)
    _check(particles, iterations, lb.size, names)
    swarm = Swarm(lb, ub, particles, np.random.default_rng(seed), x0)
    evaluate = _Evaluator(fun, workers)
    prog = _Progress(progress, iterations)
    try:
        swarm.start(evaluate(swarm.X))
        nfev = particles
        reached = tol is not None and swarm.Gf <= tol
        stopped = callback is not None and callback(0, swarm.G.copy(), swarm.Gf) is True
        prog(0, iterations, swarm.Gf)
        it = 0
        while it < iterations and not reached and not stopped:
            it += 1
            swarm.update(evaluate(swarm.move(w, c1, c2)))
            nfev += particles
            prog(it, iterations, swarm.Gf)
            reached = tol is not None and swarm.Gf <= tol
            if callback is not None and callback(it, swarm.G.copy(), swarm.Gf) is True:
                stopped = True
    finally:
        evaluate.close()
    if reached:
        message = f"best objective {swarm.Gf:.6g} <= tol {tol:g}"
    elif stopped:
        message = "stopped by callback"
    else:
        message = f"maximum number of iterations ({iterations}) reached"
    success = bool(reached or (tol is None and np.isfinite(swarm.Gf)))
    return IdentifyResult(x=swarm.G, fun=swarm.Gf, nfev=nfev, nit=it, success=success, message=message,
                          names=list(names) if names is not None else None, history=np.asarray(swarm.history),
                          population=swarm.X, population_fun=swarm.Pf, method="pso")


def pso_lockstep(fun: Callable[[np.ndarray], np.ndarray], bounds: Sequence[Any], *, particles: int = 10,
                 iterations: int = 75, w: float = 0.8, c1: float = 2.8, c2: float = 1.3, tol: float | None = None,
                 seed: Any = None, x0: Sequence[np.ndarray | None] | None = None,
                 names: Sequence[str] | None = None, progress: Any = None) -> list[IdentifyResult]:
    """K independent swarms (one per problem, e.g. one per cable) advanced in lockstep so
    that every iteration evaluates all their particles in ONE call.

    ``fun(X) -> (K, p)`` with ``X`` ``(K, p, n)`` (all problems have n parameters);
    ``bounds``: one bounds spec per problem. Swarm k uses its own random stream, spawned
    from ``numpy.random.SeedSequence(seed)`` (so K = 1 does not reproduce :func:`pso` with
    the same seed, but every run with the same seed and K reproduces bit for bit). A swarm
    that reaches ``tol`` keeps its result; the loop stops when all have, or after
    ``iterations``. Returns one :class:`IdentifyResult` per problem (``nfev`` counts that
    problem's particle evaluations).
    """
    bl = [parse_bounds(b, finite=True) for b in bounds]
    K = len(bl)
    if K == 0:
        return []
    n = bl[0][0].size
    if any(b[0].size != n for b in bl):
        raise ValueError("pso_lockstep: every problem must have the same number of parameters")
    particles, iterations = int(particles), int(iterations)
    _check(particles, iterations, n, names)
    streams = np.random.SeedSequence(seed).spawn(K)
    seeds = list(x0) if x0 is not None else [None] * K
    swarms = [Swarm(lb, ub, particles, np.random.default_rng(ss), s) for (lb, ub), ss, s in zip(bl, streams, seeds)]
    prog = _Progress(progress, iterations)
    F = _finite(fun(np.stack([s.X for s in swarms])), (K, particles))
    for s, f in zip(swarms, F):
        s.start(f)
    done = np.array([tol is not None and s.Gf <= tol for s in swarms])
    nit = np.zeros(K, dtype=int)
    prog(0, iterations, max(s.Gf for s in swarms))
    it = 0
    while it < iterations and not np.all(done):
        it += 1
        X = np.stack([s.move(w, c1, c2) if not d else s.X for s, d in zip(swarms, done)])
        F = _finite(fun(X), (K, particles))
        for k, (s, f) in enumerate(zip(swarms, F)):
            if not done[k]:
                s.update(f)
                nit[k] = it
                done[k] = tol is not None and s.Gf <= tol
        prog(it, iterations, max(s.Gf for s in swarms))
    out = []
    for k, s in enumerate(swarms):
        reached = tol is not None and s.Gf <= tol
        msg = f"best objective {s.Gf:.6g} <= tol {tol:g}" if reached else \
            f"maximum number of iterations ({iterations}) reached"
        out.append(IdentifyResult(x=s.G, fun=s.Gf, nfev=particles * (nit[k] + 1), nit=int(nit[k]),
                                  success=bool(reached or (tol is None and np.isfinite(s.Gf))), message=msg,
                                  names=list(names) if names is not None else None, history=np.asarray(s.history),
                                  population=s.X, population_fun=s.Pf, method="pso"))
    return out
