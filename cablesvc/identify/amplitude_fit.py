"""The amplitude-dependent cable model of paper 002 Sec 3, identified from a hold recording.

Eq 8 of 002 for one cable, with xi = x - x_center [m] and v = dxi/dt [m/s]::

    F = K0 + K1(A) xi + K2(A) xi^2 + K3(A) xi^3 + S_a(A) |v|^alpha(A) sgn(v) / (A (A w)^alpha(A) l pi)

(K_k in N/m^k, S_a the loop area [J], alpha dimensionless, A the amplitude [m], w the
angular frequency [rad/s]; the damping normalisation is the kernel's, see
:class:`cablesvc.models.AmplitudeDependent`).

What is per level (decided from the paper): Sec 3 says that for a given amplitude level
eq 8 has a five-dimensional parameter space in which K0 "determines the pretensioned
cable state with A = 0 and v = 0", leaving ``p_M = [K1 K2 K3 S_a]`` (eq 10), and eq 8 also
writes ``alpha(A)``. So K0 is ONE constant (eq 8 writes K0, not K0(A)) and K1, K2, K3,
S_a, alpha are the amplitude functions ``p_M,i = f_A,i(A)`` of Sec 3.

Forms of f_A: the paper gives none (eqs 15-17 fix the excitation ``-A cos wt`` and the
damping normalisation ``2 A (A w)^alpha int sin^(alpha+1)``, which eq 8 already contains,
not how the parameters vary with A). We use, with u = A / A_max (A_max the largest fitted
level):

* K1, K2, K3, alpha: polynomials in u of degree 0..2;
* S_a = A^2 g(u), g a polynomial in u of degree 0..2 [N/m]: the loop area of a hysteresis
  whose force amplitude is proportional to A grows like A^2 (for a loss factor eta and a
  stiffness K it is pi eta K A^2); g carries the amplitude dependence of eta K.

Degrees (model selection, per cable): forward selection starting from all degrees 0; at
each step the candidate "one more degree for one parameter" with the largest score
(Lagrange-multiplier) statistic is accepted when that statistic exceeds the chi^2(1)
quantile at ``significance`` (default 1 %) Bonferroni-divided by the number of candidates
tested in the step over all cables, so that the chance of giving any parameter of any
cable an amplitude dependence the data do not show stays below ``significance`` per step.
The noise variance of the statistic comes from the fit with every degree at its maximum.

Pipeline (:func:`fit_amplitude_model`):

1. elongation from inverse kinematics on the recorded pose minus the motor lengths;
2. :func:`segment_levels`: reversal points of each cable's elongation, half-cycles of equal
   amplitude and centre grouped into levels (at least ``min_half_cycles`` of them);
3. x_center per cable: the median of the level centres (the pretension working point);
4. per level (:func:`fit_levels`): eq 8 with constant K0, K1, K2, K3, S_a, alpha. The
   kernel's amplitude model is run ONCE per level to record its amplitude/half-period
   estimate and direction at every sample (they depend on the elongation only); the damping
   regressor of any alpha is then ``q(alpha) base^alpha pref`` (the kernel's damping term
   with S_a = 1, exactly, see :func:`level_trace`). An alpha grid with linear least squares
   for the other five (variable projection), then :func:`~cablesvc.identify.local.refine`
   (002 eqs 12-14) with the analytic Jacobian, gives per-level values and standard errors;
5. joint fit (:func:`fit_joint`): the coefficients of every f_A and K0 are fitted against
   ALL fitted levels' samples at once (one least-squares problem per cable, LM of 002
   eq 14, analytic Jacobian), started from weighted polynomial fits to the per-level
   values; degrees by the forward selection above;
6. the tables: every f_A sampled on ``table_points`` geometrically spaced amplitudes
   between the smallest and the largest fitted level (the kernel interpolates linearly
   between them and holds the end values outside), a ModelParams built by the caller.

The model state of each level starts at the level's first reversal point as if that
reversal had just been detected (last reversal point = the start, amplitude and half
period from the segmentation), so the kernel's online amplitude/frequency estimator is
exact from the first sample of the window; residuals count from the level's second
reversal (before it the recorded system's own estimate still holds the previous level).
Levels listed in ``hold_out`` are never used by any fit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from cablesvc.identify.result import IdentifyResult
from cablesvc.identify.amplitude_joint import AmplitudeFunction, fit_joint
from cablesvc.identify.amplitude_levels import ALPHA_MAX, PER_LEVEL, Level, LevelFit, fit_levels, segment_levels

__all__ = ["AmplitudeFit", "fit_amplitude_model"]


@dataclass
class AmplitudeFit:
    """Result of :func:`fit_amplitude_model`.

    ``cables``: fitted robot cable indices; ``levels[c]``: the levels found on cable column
    c; ``fits``: one :class:`LevelFit` per amplitude level used (in order of amplitude);
    ``held_out``: amplitudes [m] excluded from every fit; ``functions[c][name]``: f_A from
    the joint fit; ``joint[c]``: its IdentifyResult; ``selection[c]``: the degree-selection log;
    ``x_center`` (m_fit,) [m]; ``table_amplitudes`` [m] and ``tables[name]`` (m_fit, n) the
    table written; ``params``: ModelParams for the whole robot (cables not fitted keep the
    nominal parameters given as ``fallback``)."""

    cables: list[int]
    levels: list[list[Level]]
    fits: list[LevelFit]
    held_out: list[float]
    functions: list[dict[str, AmplitudeFunction]]
    x_center: np.ndarray
    table_amplitudes: np.ndarray
    tables: dict[str, np.ndarray]
    joint: list[IdentifyResult] = field(default_factory=list)
    selection: list[list[dict[str, Any]]] = field(default_factory=list)
    params: Any = None
    t: np.ndarray | None = None
    x: np.ndarray | None = None
    force: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    #: (m_fit, 2) [m]: the smallest and largest xi = x - x_center of the fitted samples, per
    #: cable: the backbone's polynomial holds there and continues along its tangent outside
    #: (:func:`cablesvc.models.amplitude.backbone`)
    xi_range: np.ndarray | None = None

    def level_table(self, cable_col: int) -> dict[str, np.ndarray]:
        """Per-level fitted values and standard errors of one cable column:
        ``{"A": (L,), name: (L,), name + "_se": (L,)}``."""
        out: dict[str, np.ndarray] = {"A": np.array([f.amplitude[cable_col] for f in self.fits])}
        for j, k in enumerate(PER_LEVEL):
            out[k] = np.array([f.results[cable_col].x[j] for f in self.fits])
            out[k + "_se"] = np.array([f.results[cable_col].stderr[j] for f in self.fits])
        return out


def _match_levels(levels_per_cable: list[list[Level]], rel_tol: float = 0.05) -> list[list[Level]]:
    """Group the levels of all cables by amplitude: returns a list of groups, each with
    one level per cable (only amplitudes every cable has; first occurrence per cable)."""
    ref = levels_per_cable[0]
    groups = []
    used = [set() for _ in levels_per_cable]
    for lv in ref:
        grp = [lv]
        for c in range(1, len(levels_per_cable)):
            cand = [(i, o) for i, o in enumerate(levels_per_cable[c])
                    if i not in used[c] and abs(o.amplitude - lv.amplitude) <= rel_tol * lv.amplitude]
            if not cand:
                grp = None
                break
            # the one closest in time
            i, o = min(cand, key=lambda io: abs(io[1].start - lv.start))
            used[c].add(i)
            grp.append(o)
        if grp is not None:
            groups.append(grp)
    return groups


def fit_amplitude_model(t: np.ndarray, x: np.ndarray, force: np.ndarray, *, cables: Sequence[int] | None = None,
                        hold_out: Sequence[float] = (), table_points: int = 64, rel_tol: float = 0.05,
                        min_half_cycles: int = 4, max_degree: int = 2, significance: float = 0.01, progress: Any = None,
                        max_levels_per_amplitude: int = 1) -> AmplitudeFit:
    """Identify the amplitude model of 002 Sec 3 from elongations ``x`` (N, m_fit) [m] and
    measured forces ``force`` (N, m_fit) [N] at times ``t`` (N,) [s] (columns = the robot
    cables listed in ``cables``, default 0..m_fit-1).

    ``hold_out``: amplitudes [m] whose levels are NOT used (matched within ``rel_tol``), for
    validation (never used by any fit). ``max_degree``, ``significance``: the f_A degree
    selection (module docstring). Raises ValueError when fewer than one level remains. ``progress``: optional
    callable ``(done, total, text)``. See the module docstring for the method."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    force = np.asarray(force, float)
    m = x.shape[1]
    cables = list(range(m)) if cables is None else [int(c) for c in cables]
    lv_per_cable = [segment_levels(x[:, c], t, cable=cables[c], rel_tol=rel_tol, min_half_cycles=min_half_cycles)
                    for c in range(m)]
    if any(len(lv) == 0 for lv in lv_per_cable):
        bad = [cables[c] for c in range(m) if not lv_per_cable[c]]
        raise ValueError(f"no amplitude levels (>= {min_half_cycles} equal half-cycles) found on cable(s) {bad}: "
                         "the amplitude-model fit needs a hold-sine recording (cablesvc simulate --scenario hold-sine)")
    groups = _match_levels(lv_per_cable, rel_tol)
    held = []
    use = []
    seen: dict[float, int] = {}
    for g in groups:
        A = float(np.median([lv.amplitude for lv in g]))
        if any(abs(A - h) <= rel_tol * h for h in hold_out):
            if not any(abs(A - h) <= rel_tol * h for h in held):
                held.append(A)
            continue
        key = next((k for k in seen if abs(k - A) <= rel_tol * A), None)
        if key is not None and seen[key] >= max_levels_per_amplitude:
            continue
        seen[A if key is None else key] = seen.get(A if key is None else key, 0) + 1
        use.append(g)
    if not use:
        raise ValueError("no amplitude level left to fit (all held out?)")
    use.sort(key=lambda g: np.median([lv.amplitude for lv in g]))
    # x_center: the pretension working point, median of all level centres per cable
    xc = np.array([np.median([lv.center for lv in lv_per_cable[c]]) for c in range(m)])
    fits = []
    for i, g in enumerate(use):
        if progress is not None:
            progress(i, len(use) + 1, f"level {np.median([lv.amplitude for lv in g]) * 1e3:.3g} mm")
        fits.append(fit_levels(t, x, force, g, xc))
    if progress is not None:
        progress(len(use), len(use) + 1, "joint fit of the amplitude functions")
    functions, joint, logs = fit_joint(fits, max_degree=max_degree, significance=significance)
    if progress is not None:
        progress(len(use) + 1, len(use) + 1, "done")
    A_lv = np.array([[f.amplitude[c] for f in fits] for c in range(m)])      # (m, L)
    lo, hi = float(A_lv.min()), float(A_lv.max())
    grid = np.geomspace(lo, hi, table_points) if hi > lo else np.array([lo])
    tables = {k: np.empty((m, grid.size)) for k in PER_LEVEL}
    for c in range(m):
        for k in PER_LEVEL:
            tables[k][c] = functions[c][k](grid)
        tables["S_a"][c] = np.maximum(tables["S_a"][c], 0.0)
        tables["alpha"][c] = np.clip(tables["alpha"][c], 0.0, ALPHA_MAX)
    xi_range = np.array([[min(float(f.data[c].xi.min()) for f in fits), max(float(f.data[c].xi.max()) for f in fits)]
                         for c in range(m)])
    return AmplitudeFit(cables=cables, levels=lv_per_cable, fits=fits, held_out=held, functions=functions,
                        x_center=xc, table_amplitudes=grid, tables=tables, joint=joint, selection=logs, t=t, x=x,
                        force=force, xi_range=xi_range)
