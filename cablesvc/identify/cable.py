"""Cable models identified from recordings.

:func:`identify_cable` fits one of the kernel's cable models (``linear``, ``polynomial``,
``amplitude``, ``boucwen``, ``asymmetric``) to a recording and returns a :class:`CableFit`
whose ``params`` (a :class:`~cablesvc.config.params.ModelParams`) can be saved and loaded
by ``cablesvc run --params``.

Data (:func:`cable_data`): the elongation is what the kernel computes,
``x = l(pose) - motor_length`` [m] with ``l`` from :func:`~cablesvc.kinematics.inverse_kinematics`
on the recorded pose (see kernel/predictor.py); the unstretched length passed to the
models is the motor length [m]; the target is the measured force [N]. Ticks without pose
or force are dropped; for the global search the data may be thinned to every ``stride``-th
tick (dt scales with it), the final LM refinement uses all of them.

Method (``method``):

* ``"pso+lm"`` (default): particle swarm of 000 Sec 5 on the normalised MSE of eq 25 (one
  swarm per cable, all swarms advanced in lockstep: particle i of cable c is lane i, cable
  c of ONE model instance of shape (particles, cables)), then least squares
  (:func:`~cablesvc.identify.local.refine`, 002 eqs 12-14) from the swarm's best;
* ``"lm"``: least squares alone from a data-driven start (002: fine for tracking, risky
  for a first identification of hysteretic models);
* ``"sqp"``: multi-start SLSQP of 001 Ch 5 on the sum of squared errors, per cable, with
  the model sign conditions as constraints (positive tangent stiffness at a mesh of
  elongations over the recorded range).

The Jacobian of every least-squares step is a forward difference computed in one model
call (lane 0 the current parameters, lane j+1 parameter j perturbed, all cables at once),
so the Jacobian is block diagonal across cables.

Per model (what is identified, what is fixed, and why; each model class owns its search
space, :meth:`~cablesvc.models.base.CableModel.search_space`, and what identification
writes for the cables it did not fit, :meth:`~cablesvc.models.base.CableModel.file_sections`):

* ``linear`` (002 eq 3): ``ea`` [N]; ``slack_width`` fixed at its default, ``l_ref`` unused
  (the motor length is passed as l0, as the kernel does).
* ``polynomial`` (002 eqs 4-7, degree 3 by default): ``a0..a3`` and ``x_center`` (g has only
  odd powers, so the pretension needs x_center as the zero-force elongation).
* ``boucwen`` (000 eqs 1-2): ``k_e, k_d, beta, gamma, n, f0``; ``x_center`` fixed to the
  mean elongation (with k3 = 0, f0 and x_center are redundant: only f0 - k_e x_center
  acts) and ``k3 = 0`` as in 000 Sec 6. Searched as ``log10 k_d``, ``log10 beta`` and
  ``g = gamma / beta`` in [-0.95, 1] (bounded z, 000 Sec 2).
* ``asymmetric`` (001 Ch 4): ``c, alpha, beta, gamma, n, k1, k2, k3, x_center`` with
  ``b = 1`` fixed: scaling z by s and (b, c) by 1/s (alpha by s, beta and gamma by s^(1-n))
  leaves the force unchanged, so only the products are identifiable.
* ``amplitude`` (002 eq 8): from a hold-sine recording, the per-level fits of
  :mod:`cablesvc.identify.amplitude_fit` (tables of K0..K3, S_a, alpha over A); from
  any other recording one constant table row (K0..K3, S_a, alpha), x_center fixed to the
  mean elongation.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from cablesvc.config import Robot, load_robot
from cablesvc.config.params import ModelParams, home_lengths, nominal_params
from cablesvc.errors import IdentifyError
from cablesvc.identify.local import multistart_sqp, refine
from cablesvc.identify.identifiability import jacobian_statistics
from cablesvc.identify.pso import normalized_mse, pso, pso_lockstep
from cablesvc.identify.result import IdentifyResult
from cablesvc.kinematics import inverse_kinematics
from cablesvc.models import MODELS
from cablesvc.models.amplitude import TABLE_COLUMNS, XI_UNBOUNDED
from cablesvc.models.space import FitStats, Space

__all__ = ["CableData", "CableFit", "IdentifyError", "cable_data", "identify_cable", "MODEL_CHOICES",
           "METHODS", "elongation_from_recording"]

#: the models identification fits (every one in the registry, each with its search space)
MODEL_CHOICES = tuple(MODELS)
METHODS = ("pso+lm", "lm", "sqp")


# --------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------


@dataclass
class CableData:
    """What identification fits: ``t`` (N,) [s], ``x`` elongation (N, k) [m], ``l0`` motor
    length (N, k) [m], ``force`` measured (N, k) [N], for robot cables ``cables`` (k of them)."""

    t: np.ndarray
    x: np.ndarray
    l0: np.ndarray
    force: np.ndarray
    cables: list[int]
    robot: str
    n_cables: int

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.t))) if self.t.size > 1 else 1e-3

    def thin(self, stride: int) -> "CableData":
        s = max(1, int(stride))
        return CableData(self.t[::s], self.x[::s], self.l0[::s], self.force[::s], self.cables, self.robot,
                         self.n_cables)


def _robot(robot: Robot | str | os.PathLike) -> Robot:
    return robot if isinstance(robot, Robot) else load_robot(robot)


def elongation_from_recording(recording: Any, robot: Robot | str | os.PathLike) -> np.ndarray:
    """``x = l(pose) - motor_length`` (N, m) [m] for every tick of a recording with a pose
    (NaN rows where a tick has no pose)."""
    rob = _robot(robot)
    geom = rob.geometry()
    if not recording.has_pose:
        raise IdentifyError("the recording has no platform pose: the elongation x = l(pose) - motor_length "
                            "needs it (record the pose, or identify on a hold recording)")
    pos, quat = recording.position, recording.orientation
    ok = np.all(np.isfinite(pos), axis=1) & np.all(np.isfinite(quat), axis=1)
    x = np.full(recording.motor_length.shape, np.nan)
    if np.any(ok):
        L = inverse_kinematics(geom, pos[ok], quat[ok]).length
        x[ok] = L - recording.motor_length[ok]
    return x


def cable_data(recording: Any, robot: Robot | str | os.PathLike, cables: Sequence[int] | None = None) -> CableData:
    """Elongation, motor length and force of the selected cables, ticks with pose and force only."""
    rob = _robot(robot)
    m = rob.n_cables
    if recording.n_cables != m:
        raise IdentifyError(f"the recording has {recording.n_cables} cables but robot {rob.name!r} has {m}")
    if not recording.has_force:
        raise IdentifyError("the recording has no measured forces: nothing to identify against")
    sel = list(range(m)) if cables is None else [int(c) for c in cables]
    bad = [c for c in sel if not 0 <= c < m]
    if bad:
        raise IdentifyError(f"cable index {bad[0]} out of range: robot {rob.name!r} has cables 0..{m - 1}")
    if len(set(sel)) != len(sel) or not sel:
        raise IdentifyError(f"cables must be a non-empty list of distinct indices, got {sel}")
    x = elongation_from_recording(recording, rob)[:, sel]
    l0 = recording.motor_length[:, sel]
    f = recording.force[:, sel]
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(f), axis=1) & np.all(np.isfinite(l0), axis=1)
    if ok.sum() < 10:
        raise IdentifyError(f"only {int(ok.sum())} ticks have pose, motor lengths and forces; need at least 10")
    t = np.asarray(recording.t, float)[ok]
    if np.any(np.diff(t) <= 0):
        raise IdentifyError("recording time stamps are not strictly increasing")
    return CableData(t=t, x=x[ok], l0=l0[ok], force=f[ok], cables=sel, robot=rob.name, n_cables=m)


# --------------------------------------------------------------------------------------
# model parameter spaces
# --------------------------------------------------------------------------------------


def _space(model: str, data: CableData, degree: int = 3) -> Space:
    """The model class's search space (:meth:`~cablesvc.models.base.CableModel.search_space`)
    scaled by the fitted cables' data."""
    if model not in MODELS:
        raise IdentifyError(f"unknown model {model!r}; known: {', '.join(MODEL_CHOICES)}")
    return MODELS[model].search_space(FitStats.of(data.x, data.force, data.l0), degree=degree)


# --------------------------------------------------------------------------------------
# batched simulation
# --------------------------------------------------------------------------------------


class _Simulator:
    """Runs one model over the data with parameters per (lane, cable)."""

    def __init__(self, space: Space, data: CableData):
        self.space = space
        self.data = data
        self.dt = data.dt
        self.cls = MODELS[space.model]

    def build(self, V: np.ndarray):
        return self.cls.build_lanes((V.shape[0], V.shape[1]), self.space.kwargs(V), self.space.options,
                                    self.data.x)

    def run(self, V: np.ndarray) -> np.ndarray:
        """Force (T, L, K) [N] for model values V (L, K, n)."""
        model = self.build(V)
        L, K = model.shape
        x, l0 = self.data.x, self.data.l0
        st = model.create_state(np.broadcast_to(x[0], (L, K)))
        out = np.empty((x.shape[0], L, K))
        dt = self.dt
        with np.errstate(all="ignore"):
            for k in range(x.shape[0]):
                out[k] = model.step(st, np.broadcast_to(x[k], (L, K)), dt if k else 0.0,
                                    np.broadcast_to(l0[k], (L, K)))
        return out


def _objective_lockstep(sim: _Simulator, space: Space) -> Callable[[np.ndarray], np.ndarray]:
    """PSO objective, per-cable swarms: S (K, p, n) -> (K, p) normalised MSE (eq 25)."""
    Fm = sim.data.force.T                                  # (K, T)

    def fun(S):
        V = space.to_model(np.transpose(S, (1, 0, 2)))   # (p, K, n)
        F = sim.run(V)                                     # (T, p, K)
        return normalized_mse(np.transpose(F, (2, 1, 0)), Fm[:, None, :])   # (K, p)
    return fun


def _objective_shared(sim: _Simulator, space: Space) -> Callable[[np.ndarray], np.ndarray]:
    """PSO objective, one parameter set for all cables: S (p, n) -> (p,) mean of eq 25 over cables."""
    Fm = sim.data.force.T
    K = Fm.shape[0]

    def fun(S):
        V = space.to_model(np.repeat(S[:, None, :], K, axis=1))
        F = sim.run(V)
        return np.mean(normalized_mse(np.transpose(F, (2, 1, 0)), Fm[:, None, :]), axis=0)
    return fun


def _fd_steps(V: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Forward-difference steps: 1e-6 relative, but at least 1e-10 of the parameter's scale
    (largest magnitude in its search box), so that a parameter at 0 still moves the force."""
    return 1e-6 * np.maximum(np.abs(V), 1e-4 * scale) + 1e-300


def _least_squares(sim: _Simulator, space: Space, V0: np.ndarray, shared: bool, method: str,
                   max_nfev: int | None = None) -> tuple[IdentifyResult, list[IdentifyResult]]:
    """Refine (002 eqs 12-14) all cables at once; returns the stacked result and one
    result per cable (or one shared) with its own Jacobian statistics."""
    K, n = V0.shape
    Fm = sim.data.force
    T = Fm.shape[0]
    scale = np.maximum(np.abs(space.to_model(space.search_lb)), np.abs(space.to_model(space.search_ub)))
    scale = np.where(np.isfinite(scale), scale, 1.0)

    def values(p):
        return np.broadcast_to(p.reshape(1, n), (K, n)).copy() if shared else p.reshape(K, n)

    def residuals(p):
        F = sim.run(values(p)[None])[:, 0, :]           # (T, K)
        return (F - Fm).T.reshape(-1)                   # cable after cable

    def jac(p):
        V = values(p)
        h = _fd_steps(V[0], scale.max(axis=0)) if shared else _fd_steps(V, scale)
        lanes = np.repeat(V[None], n + 1, axis=0)       # (n+1, K, n)
        for j in range(n):
            if shared:
                lanes[j + 1, :, j] += h[j]
            else:
                lanes[j + 1, :, j] += h[:, j]
        F = sim.run(lanes)                              # (T, n+1, K)
        dF = (F[:, 1:, :] - F[:, :1, :])                # (T, n, K)
        if shared:
            dF = dF / h[None, :, None]
            return np.transpose(dF, (2, 0, 1)).reshape(K * T, n)
        dF = dF / h.T[None, :, :]
        J = np.zeros((K * T, K * n))
        for c in range(K):
            J[c * T:(c + 1) * T, c * n:(c + 1) * n] = dF[:, :, c]
        return J

    if shared:
        p0 = V0[0]
        lb, ub = space.lb.max(axis=0), space.ub.min(axis=0)
    else:
        p0 = V0.reshape(-1)
        lb, ub = space.lb.reshape(-1), space.ub.reshape(-1)
    kw: dict[str, Any] = {"jac": jac}
    if max_nfev is not None:
        kw["max_nfev"] = max_nfev
    names = space.names if shared else [f"{nm}[{c}]" for c in sim.data.cables for nm in space.names]
    if method == "lm":
        res = refine(residuals, p0, None, method="lm", names=names, **kw)
    else:
        res = refine(residuals, p0, (lb, ub), method="trf", names=names, **kw)
    per: list[IdentifyResult] = []
    blocks = [(slice(None), slice(None))] if shared else [
        (slice(c * T, (c + 1) * T), slice(c * n, (c + 1) * n)) for c in range(K)]
    for rs, cs in blocks:
        Jc = res.jac[rs, cs]
        rc = res.residual[rs]
        xc = res.x[cs]
        st = jacobian_statistics(Jc, rc, names=space.names, x=xc)
        per.append(IdentifyResult(x=xc.copy(), fun=0.5 * float(rc @ rc), nfev=res.nfev, nit=res.nit,
                                  success=res.success, message=res.message, names=list(space.names),
                                  history=res.history, jac=Jc, residual=rc, stderr=st.stderr,
                                  covariance=st.covariance, correlation=st.correlation, cond=st.cond,
                                  cond_raw=st.cond_raw, sigma2=st.sigma2, redundant=st.groups,
                                  method=res.method, rmse=float(np.sqrt(np.mean(rc ** 2)))))
    return res, per


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------


@dataclass
class CableFit:
    """Result of :func:`identify_cable`.

    ``results``: one IdentifyResult per fitted cable (``shared``: a single one) with the
    model-space parameters, standard errors and statistics; ``swarm``: the PSO results
    (convergence histories) or None; ``params``: ModelParams for the whole robot (ready to
    ``.save()``); ``data``: the CableData fitted; ``predicted``: (N, k) force of the fitted
    model (built from ``params`` like the kernel) [N]; ``rmse`` (k,) [N]; ``amplitude``:
    the :class:`~cablesvc.identify.amplitude_fit.AmplitudeFit` for hold recordings."""

    model: str
    method: str
    shared: bool
    cables: list[int]
    names: list[str]
    units: list[str]
    results: list[IdentifyResult]
    params: ModelParams
    data: CableData
    predicted: np.ndarray
    rmse: np.ndarray
    swarm: list[IdentifyResult] | None = None
    amplitude: Any = None
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0


def _predict(params: ModelParams, data: CableData) -> np.ndarray:
    """Run the saved parameters through the kernel's model for the whole robot and keep
    the fitted cables (what ``cablesvc run --params`` would predict)."""
    model = params.build(data.n_cables, 1)
    N = data.t.size
    x = np.zeros((N, data.n_cables))
    l0 = np.ones((N, data.n_cables))
    x[:, data.cables] = data.x
    l0[:, data.cables] = data.l0
    st = model.create_state(x[0][None])
    out = np.empty((N, data.n_cables))
    dt = np.diff(data.t, prepend=data.t[0])
    with np.errstate(all="ignore"):
        for k in range(N):
            out[k] = model.step(st, x[k][None], float(dt[k]), l0[k][None])[0]
    return out[:, data.cables]


def _params_file(model: str, rob: Robot, data: CableData, names: list[str], V: np.ndarray, space: Space,
                 se: np.ndarray, rmse: np.ndarray, method: str, seed: Any, shared: bool) -> ModelParams:
    """ModelParams for every robot cable: fitted cables get V (k, n); others keep nominal
    values (listed in identification.nominal_cables)."""
    m = rob.n_cables
    geom = rob.geometry()
    home = home_lengths(geom)
    fitted = data.cables
    others = [c for c in range(m) if c not in fitted]
    ident = {"source": "cablesvc identify", "method": method, "seed": -1 if seed is None else int(seed),
             "cables": fitted, "shared": bool(shared),
             "rmse": [float(v) for v in rmse], "nominal_cables": others,
             "amplitude_range": [float(0.5 * np.min(np.ptp(data.x, axis=0))), float(0.5 * np.max(np.ptp(data.x, axis=0)))]}
    for j, nm in enumerate(names):
        ident[f"stderr_{nm}"] = [float(v) if np.isfinite(v) else -1.0 for v in se[:, j]]
    sections = MODELS[model].file_sections(m, np.asarray(geom.ea, float), home, fitted, names, V, space.fixed,
                                           space.options)
    return ModelParams(model=model, params=sections["params"], options=sections["options"],
                       tables=sections["tables"], robot=rob.name, identification=ident)


# --------------------------------------------------------------------------------------
# identify_cable
# --------------------------------------------------------------------------------------


def _stride_for(N: int, max_samples: int) -> int:
    return max(1, int(np.ceil(N / max(int(max_samples), 10))))


def identify_cable(recording: Any, robot: Robot | str | os.PathLike, model: str = "amplitude", *,
                   cables: Sequence[int] | None = None, shared: bool = False, method: str = "pso+lm",
                   seed: int | None = 0, progress: Any = None, particles: int = 10, iterations: int = 75,
                   max_samples: int = 4000, degree: int = 3, max_nfev: int | None = None,
                   sqp_starts: int = 8, hold_out: Sequence[float] = ()) -> CableFit:
    """Identify cable model ``model`` from ``recording`` of ``robot`` (see module docstring).

    ``cables``: robot cable indices to fit (default all); ``shared``: one parameter set for
    all of them; ``method``: ``"pso+lm"``, ``"lm"`` or ``"sqp"``; ``seed``: PSO / SQP starts;
    ``progress``: callable ``(done, total, text)`` or None; ``particles``, ``iterations``:
    PSO p and q (000: 10 and 75); ``max_samples``: the PSO objective uses at most this
    many ticks (every stride-th); ``degree``: polynomial degree; ``max_nfev``: cap on
    least-squares evaluations; ``hold_out``: amplitudes [m] left out of an amplitude-model
    fit. Raises :class:`IdentifyError` with a clear message on bad inputs.
    """
    import time
    t_start = time.perf_counter()
    if model not in MODEL_CHOICES:
        raise IdentifyError(f"unknown model {model!r}; known: {', '.join(MODEL_CHOICES)}")
    if method not in METHODS:
        raise IdentifyError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    rob = _robot(robot)
    data = cable_data(recording, rob, cables)
    say = progress if callable(progress) else (lambda *a: None)

    if MODELS[model].fit_by_levels:
        from cablesvc.identify.amplitude_fit import fit_amplitude_model
        from cablesvc.identify.amplitude_levels import segment_levels
        levels_found = all(len(segment_levels(data.x[:, c], data.t)) > 0 for c in range(len(data.cables)))
        if levels_found and not shared:
            say(0, 1, "amplitude levels")
            af = fit_amplitude_model(data.t, data.x, data.force, cables=data.cables, hold_out=hold_out,
                                     progress=lambda d, tot, txt: say(d, tot, txt))
            params = amplitude_params(af, rob, data, seed)
            pred = _predict(params, data)
            rmse = np.sqrt(np.mean((pred - data.force) ** 2, axis=0))
            params.identification["rmse"] = [float(v) for v in rmse]
            results = [_amplitude_summary(af, c) for c in range(len(data.cables))]
            return CableFit(model=model, method="per-level fits, then one joint least-squares fit of the amplitude functions (002 Sec 3)", shared=False,
                            cables=data.cables, names=list(results[0]["names"]), units=[],
                            results=results, params=params, data=data, predicted=pred, rmse=rmse, swarm=None,
                            amplitude=af, notes=[
                                "amplitude: eq 8 fitted per amplitude level (K0..K3, S_a, alpha), f_A(A) "
                                "per parameter (K0 constant), tables sampled on the fitted amplitude range"],
                            seconds=time.perf_counter() - t_start)

    space = _space(model, data, degree)
    K, n = space.x0.shape
    stride = _stride_for(data.t.size, max_samples)
    coarse = _Simulator(space, data.thin(stride))
    fine = _Simulator(space, data)
    swarm = None
    notes = list(space.notes)
    if stride > 1:
        notes.append(f"global search on every {stride}th tick ({coarse.data.t.size} ticks); refinement on all")
    if method == "pso+lm":
        def cb(it, total, best):
            say(it, total + 1, f"PSO iteration {it}/{total}, best eq-25 MSE {best:.3g}")
        if shared:
            lb, ub = space.search_lb.max(axis=0), space.search_ub.min(axis=0)
            r = pso(_objective_shared(coarse, space), (lb, ub), particles=particles, iterations=iterations,
                    seed=seed, names=space.names, progress=cb)
            swarm = [r]
            V0 = space.to_model(np.repeat(r.x[None, :], K, axis=0))
        else:
            rs = pso_lockstep(_objective_lockstep(coarse, space), [(space.search_lb[c], space.search_ub[c])
                                                                    for c in range(K)],
                              particles=particles, iterations=iterations, seed=seed, names=space.names, progress=cb)
            swarm = rs
            V0 = space.to_model(np.stack([r.x for r in rs]))
        say(iterations, iterations + 1, "least-squares refinement")
        _, per = _least_squares(fine, space, V0, shared, "trf", max_nfev)
    elif method == "lm":
        say(0, 1, "least squares from the data-driven start")
        V0 = space.x0.copy()
        _, per = _least_squares(fine, space, V0, shared, "trf", max_nfev)
    else:
        per = _sqp(coarse, fine, space, shared, seed, sqp_starts, say)
    V = np.stack([p.x for p in per]) if not shared else np.repeat(per[0].x[None], K, axis=0)
    se = np.stack([p.stderr for p in per]) if not shared else np.repeat(per[0].stderr[None], K, axis=0)
    params = _params_file(model, rob, data, space.names, V, space, se, np.zeros(K), method, seed, shared)
    pred = _predict(params, data)
    rmse = np.sqrt(np.mean((pred - data.force) ** 2, axis=0))
    params.identification["rmse"] = [float(v) for v in rmse]
    say(1, 1, "done")
    return CableFit(model=model, method=method, shared=shared, cables=data.cables, names=list(space.names),
                    units=list(space.units), results=per, params=params, data=data, predicted=pred, rmse=rmse,
                    swarm=swarm, notes=notes, seconds=time.perf_counter() - t_start)


def _sqp(coarse: _Simulator, fine: _Simulator, space: Space, shared: bool, seed: Any, starts: int,
         say: Callable) -> list[IdentifyResult]:
    """Multi-start SLSQP (001 Ch 5) in the search space on the sum of squared errors, with
    the sign condition of a positive secant stiffness of the model loop between mesh
    elongations as nonlinear constraints; then least-squares statistics at the optimum."""
    from scipy.optimize import NonlinearConstraint
    K, n = space.x0.shape
    data = coarse.data
    out = []
    groups = [list(range(K))] if shared else [[c] for c in range(K)]
    for gi, grp in enumerate(groups):
        say(gi, len(groups), f"multi-start SQP, cable group {gi + 1}/{len(groups)}")
        sub = CableData(data.t, data.x[:, grp], data.l0[:, grp], data.force[:, grp], [data.cables[c] for c in grp],
                        data.robot, data.n_cables)
        sub_space = space.subspace(grp)
        sim = _Simulator(sub_space, sub)
        Fm = sub.force
        scale = float(np.sum((Fm - Fm.mean(axis=0)) ** 2))
        lb = sub_space.search_lb.max(axis=0)
        ub = sub_space.search_ub.min(axis=0)
        # mesh points: where the elongation is at 9 quantiles of its range on a rising branch
        order = np.argsort(sub.x[:, 0])
        mesh = order[np.linspace(0, order.size - 1, 9).astype(int)]

        def forces(s):
            V = sub_space.to_model(np.repeat(np.asarray(s, float)[None, None, :], len(grp), axis=1))
            return sim.run(V)[:, 0, :]

        def fun(s):
            return float(np.sum((forces(s) - Fm) ** 2)) / scale

        def stiff(s):
            F = forces(s)[mesh, 0]
            xm = sub.x[mesh, 0]
            return np.diff(F) / np.maximum(np.diff(xm), 1e-12)

        cons = [NonlinearConstraint(stiff, 0.0, np.inf)]
        r = multistart_sqp(fun, (lb, ub), constraints=cons, starts=starts, seed=seed, names=space.names)
        V0 = sub_space.to_model(np.repeat(r.x[None, :], len(grp), axis=0))
        sub_fine = CableData(fine.data.t, fine.data.x[:, grp], fine.data.l0[:, grp], fine.data.force[:, grp],
                             sub.cables, data.robot, data.n_cables)
        _, per = _least_squares(_Simulator(sub_space, sub_fine), sub_space, V0, True, "trf", max_nfev=2 * (n + 1))
        for p in per:
            p["sqp"] = r
            p["method"] = "multistart-SLSQP + least_squares"
        out.extend(per)
    return out


def amplitude_params(af: Any, rob: Robot, data: CableData, seed: Any) -> ModelParams:
    """ModelParams of an amplitude-model fit for every robot cable (cables not fitted keep
    nominal values resampled on the fitted amplitude grid)."""
    m = rob.n_cables
    geom = rob.geometry()
    nom = nominal_params(geom)
    grid = af.table_amplitudes
    namps = np.asarray(nom.tables["amplitudes"], float)
    tables: dict[str, Any] = {"amplitudes": grid.tolist()}
    for k in TABLE_COLUMNS:
        nomk = np.broadcast_to(np.asarray(nom.tables[k], float), (m, namps.size))
        rows = np.stack([np.interp(grid, namps, nomk[c]) for c in range(m)])
        rows[data.cables] = af.tables[k]
        tables[k] = rows.tolist()
    xc = np.zeros(m)
    xc[data.cables] = af.x_center
    # the elongations the backbone was fitted on: beyond them it continues along its tangent
    lo, hi = np.full(m, -XI_UNBOUNDED), np.full(m, XI_UNBOUNDED)
    if af.xi_range is not None:
        lo[data.cables], hi[data.cables] = af.xi_range[:, 0], af.xi_range[:, 1]
    A0 = np.full(m, float(grid[0]))
    ident: dict[str, Any] = {"source": "cablesvc identify", "method": "per-level fits, then one joint least-squares fit of the amplitude functions (002 Sec 3)",
                             "cables": data.cables, "nominal_cables": [c for c in range(m) if c not in data.cables],
                             "amplitude_range": [float(grid[0]), float(grid[-1])],
                             "levels_mm": [float(f.amplitude.mean() * 1e3) for f in af.fits],
                             "held_out_mm": [float(a * 1e3) for a in af.held_out]}
    return ModelParams(model="amplitude", params={"x_center": xc.tolist(), "amplitude_init": A0.tolist(),
                                                  "xi_lo": lo.tolist(), "xi_hi": hi.tolist()},
                       tables=tables, robot=rob.name, identification=ident)


def _amplitude_summary(af: Any, c: int) -> IdentifyResult:
    """One IdentifyResult per cable summarising the per-level fits: x = the fitted values at
    the largest level, with ``levels`` = the level table (values and standard errors)."""
    lt = af.level_table(c)
    last = af.fits[-1].results[c]
    res = IdentifyResult(last)
    res["levels"] = lt
    res["x_center"] = float(af.x_center[c])
    res["method"] = "per-level fits, then one joint least-squares fit of the amplitude functions (002 Sec 3)"
    return res
