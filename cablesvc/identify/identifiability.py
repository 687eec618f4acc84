"""Is a parameter set identifiable from the data? Statistics of the residual Jacobian,
redundant parameter groups and the sensitivity metric of paper 002 (eq 11).

All functions work on the Jacobian ``J = d r / d p`` ``(N, n)`` of the residual vector
``r(p) = F(p, x_i) - F_M,i`` (eq 12 of 002, force units [N]) at the identified parameters.

* Covariance: ``cov = s^2 (J^T J)^-1`` with the residual variance
  ``s^2 = sum r_i^2 / (N - n)`` (the normal equation of eq 14 linearised at the optimum);
  standard errors are ``sqrt(diag(cov))`` in the parameters' own units; the correlation
  matrix is ``cov_ij / (se_i se_j)``.
* Condition number: of the column-equilibrated Jacobian ``J D^-1`` with ``D`` the column
  norms, i.e. independent of the parameters' units (the raw ``cond(J)`` mixes N/m with
  N/m^3 and says little). ``cond_raw`` is reported too.
* Redundant groups: right singular vectors of ``J D^-1`` whose singular value is below
  ``rtol`` times the largest are directions in parameter space along which the residuals
  (almost) do not change; the parameters with a large component in such a direction form
  a group of which only some combination is identifiable. The direction is also given in
  relative terms ``d ln p_k`` (when ``p`` is known and non-zero), which shows product
  redundancies: ``d ln beta = -d ln gamma`` means only ``beta * gamma`` is determined.

Bouc-Wen: in the benchmark convention ``z' = alpha y' - beta (gamma |y'| |z|^(nu-1) z +
delta y' |z|^nu)`` the output depends on beta, gamma, delta only through beta*gamma and
beta*delta (one redundant direction ``d ln beta = -d ln gamma = -d ln delta``).
cablesvc therefore identifies Bouc-Wen in the form of eq 1 of paper 000, whose beta and
gamma ARE those two products (:func:`boucwen_identifiable`); the benchmark's beta is
then fixed to 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

__all__ = [
    "RedundantGroup", "JacobianStatistics", "jacobian_statistics", "redundant_groups",
    "sensitivity", "boucwen_identifiable", "BOUCWEN_NOTE",
]

BOUCWEN_NOTE = ("Bouc-Wen (benchmark convention alpha, beta, gamma, delta, nu): only beta*gamma and "
                "beta*delta are identifiable; cablesvc identifies eq 1 of 000 with beta_000 = beta*gamma, "
                "gamma_000 = beta*delta (benchmark beta fixed to 1).")


@dataclass
class RedundantGroup:
    """A near-null direction of the (column-equilibrated) Jacobian.

    ``names``: parameters taking part (component >= 10 % of the largest); ``direction``:
    the unit direction in equilibrated coordinates, per name; ``log_direction``: the same
    direction as relative changes ``d ln p_k`` (normalised; None when p is unknown or a
    participating value is 0); ``ratio``: its singular value over the largest one;
    ``identifiable``: for a two-parameter group with a log direction, the monomial
    ``p_a^u * p_b^v`` left unchanged by the direction, i.e. what the data determine.
    """

    names: list[str]
    direction: dict[str, float]
    log_direction: dict[str, float] | None
    ratio: float
    identifiable: str | None = None

    def describe(self) -> str:
        d = self.log_direction or self.direction
        kind = "d ln " if self.log_direction else "d"
        combo = " : ".join(f"{kind}{k} {v:+.2f}" for k, v in d.items())
        s = (f"unidentifiable combination of {', '.join(self.names)} (singular-value ratio {self.ratio:.1e}): "
             f"moving along {combo} leaves the residuals unchanged")
        if self.identifiable:
            s += f"; only {self.identifiable} is determined by the data"
        return s


@dataclass
class JacobianStatistics:
    """Result of :func:`jacobian_statistics` (units: those of the parameters)."""

    stderr: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    cond: float
    cond_raw: float
    sigma2: float
    dof: int
    singular_values: np.ndarray
    groups: list[RedundantGroup] = field(default_factory=list)
    names: list[str] | None = None

    def highly_correlated(self, threshold: float = 0.95) -> list[tuple[str, str, float]]:
        """Parameter pairs with |correlation| above ``threshold``."""
        n = self.correlation.shape[0]
        names = self.names or [f"p{i}" for i in range(n)]
        out = []
        for i in range(n):
            for j in range(i + 1, n):
                c = self.correlation[i, j]
                if np.isfinite(c) and abs(c) > threshold:
                    out.append((names[i], names[j], float(c)))
        return out


def _names(n: int, names: Sequence[str] | None) -> list[str]:
    return [f"p{i}" for i in range(n)] if names is None else [str(s) for s in names]


def redundant_groups(jac: np.ndarray, names: Sequence[str] | None = None, x: np.ndarray | None = None,
                     rtol: float = 1e-4) -> list[RedundantGroup]:
    """Near-singular directions of ``J^T J`` (see module docstring).

    ``rtol``: singular values of the equilibrated Jacobian below ``rtol * s_max`` count as
    null (the corresponding direction changes the residual by less than ``rtol`` of the
    best-determined direction, for a unit relative step). Parameters whose Jacobian column
    is zero form a group of their own (they do not act on the residuals at all)."""
    J = np.asarray(jac, dtype=float)
    n = J.shape[1]
    nm = _names(n, names)
    norms = np.linalg.norm(J, axis=0)
    groups: list[RedundantGroup] = []
    dead = norms <= 1e-300
    for k in np.flatnonzero(dead):
        groups.append(RedundantGroup(names=[nm[k]], direction={nm[k]: 1.0}, log_direction=None, ratio=0.0))
    live = np.flatnonzero(~dead)
    if live.size == 0:
        return groups
    Js = J[:, live] / norms[live]
    _, s, Vt = np.linalg.svd(Js, full_matrices=False)
    smax = s[0] if s.size else 0.0
    for i in range(s.size):
        if smax == 0 or s[i] >= rtol * smax:
            continue
        v = Vt[i]
        big = np.abs(v) >= 0.1 * np.max(np.abs(v))
        idx = live[big]
        sign = np.sign(v[big][np.argmax(np.abs(v[big]))])
        direction = {nm[k]: float(sign * vk) for k, vk in zip(idx, v[big])}
        log_dir = None
        ident = None
        if x is not None:
            xv = np.asarray(x, dtype=float)[idx]
            if np.all(xv != 0):
                dp = v[big] / norms[idx]          # step in parameter units
                dl = dp / xv
                dl = dl / np.linalg.norm(dl)
                dl = dl * np.sign(dl[np.argmax(np.abs(dl))])     # largest component positive
                log_dir = {nm[k]: float(c) for k, c in zip(idx, dl)}
                if idx.size == 2:
                    # p_a^u p_b^w is constant along (dl_a, dl_b) when u dl_a + w dl_b = 0
                    u, w = -dl[1], dl[0]
                    if u < 0:
                        u, w = -u, -w
                    sc = max(abs(u), abs(w))
                    u, w = u / sc, w / sc
                    ident = f"{nm[idx[0]]}^{u:.3g} * {nm[idx[1]]}^{w:.3g}"
        groups.append(RedundantGroup(names=[nm[k] for k in idx], direction=direction, log_direction=log_dir,
                                     ratio=float(s[i] / smax), identifiable=ident))
    return groups


def jacobian_statistics(jac: np.ndarray, residual: np.ndarray, *, names: Sequence[str] | None = None,
                        x: np.ndarray | None = None, rtol: float = 1e-4) -> JacobianStatistics:
    """Standard errors, covariance, correlation, condition number and redundant groups
    from the residual Jacobian ``jac`` ``(N, n)`` and the residuals ``residual`` ``(N,)``
    at the optimum (see module docstring). Directions with a singular value below
    ``1e-12 * s_max`` are treated as undetermined: parameters taking part in them get an
    infinite standard error and NaN correlations."""
    J = np.asarray(jac, dtype=float)
    r = np.asarray(residual, dtype=float).reshape(-1)
    N, n = J.shape
    dof = max(N - n, 1)
    sigma2 = float(r @ r) / dof
    norms = np.linalg.norm(J, axis=0)
    safe = np.where(norms > 0, norms, 1.0)
    Js = J / safe
    _, s, Vt = np.linalg.svd(Js, full_matrices=False)
    smax = s[0] if s.size else 0.0
    keep = s > 1e-12 * smax if smax > 0 else np.zeros_like(s, dtype=bool)
    cov_s = (Vt[keep].T / s[keep] ** 2) @ Vt[keep]
    cov = sigma2 * cov_s / np.outer(safe, safe)
    var = np.diag(cov).copy()
    undetermined = np.zeros(n, dtype=bool)
    for i in np.flatnonzero(~keep):
        undetermined |= np.abs(Vt[i]) > 1e-6
    undetermined |= norms == 0
    var[undetermined] = np.inf
    stderr = np.sqrt(np.maximum(var, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.sqrt(np.diag(cov))
        corr = cov / np.outer(d, d)
    corr[undetermined, :] = np.nan
    corr[:, undetermined] = np.nan
    np.fill_diagonal(corr, 1.0)
    cond = float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")
    sr = np.linalg.svd(J, compute_uv=False) if J.size else np.zeros(0)
    cond_raw = float(sr[0] / sr[-1]) if sr.size and sr[-1] > 0 else float("inf")
    groups = redundant_groups(J, names, x, rtol=rtol)
    return JacobianStatistics(stderr=stderr, covariance=cov, correlation=corr, cond=cond, cond_raw=cond_raw,
                              sigma2=sigma2, dof=dof, singular_values=s, groups=groups,
                              names=None if names is None else list(names))


def sensitivity(output: Callable[[np.ndarray], np.ndarray], p: np.ndarray, *, rel_step: float = 0.1,
                names: Sequence[str] | None = None) -> dict[str, Any]:
    """Parameter sensitivity of eq 11 of paper 002:

        S = (O_2 - O_1) / O_12  *  ((I_2 - I_1) / I_12)^-1

    the relative change of a scalar model output O over the relative change of one input
    (parameter) I, both normalised by their averages ``O_12 = (O_1 + O_2)/2`` and
    ``I_12 = (I_1 + I_2)/2``; S is dimensionless (units of O and I cancel). Each parameter
    ``p_j`` in turn is set to ``I_1 = p_j (1 - rel_step)`` and ``I_2 = p_j (1 + rel_step)``,
    all others at ``p``. ``output(P)`` gets all perturbed parameter sets at once, ``P``
    ``(2n, n)`` (rows 2j and 2j+1 perturb parameter j), and returns ``(2n,)`` values of O.
    A parameter equal to 0 has ``I_12 = 0``: eq 11 is undefined and S is NaN.

    Returns ``{"S": (n,), "O1": (n,), "O2": (n,), "I1": (n,), "I2": (n,), "names": [...]}``.
    """
    p = np.asarray(p, dtype=float).reshape(-1)
    n = p.size
    P = np.repeat(p[None, :], 2 * n, axis=0)
    I1 = p * (1.0 - rel_step)
    I2 = p * (1.0 + rel_step)
    for j in range(n):
        P[2 * j, j] = I1[j]
        P[2 * j + 1, j] = I2[j]
    O = np.asarray(output(P), dtype=float).reshape(2 * n)
    O1, O2 = O[0::2], O[1::2]
    with np.errstate(divide="ignore", invalid="ignore"):
        S = ((O2 - O1) / (0.5 * (O1 + O2))) / ((I2 - I1) / (0.5 * (I1 + I2)))
    S = np.where(p == 0, np.nan, S)
    return {"S": S, "O1": O1, "O2": O2, "I1": I1, "I2": I2, "names": _names(n, names)}


def boucwen_identifiable(alpha: float, beta: float, gamma: float, delta: float, nu: float,
                         k_lin: float = 0.0) -> dict[str, float]:
    """Benchmark-convention Bouc-Wen parameters reduced to the identifiable set of eq 1 of
    000: ``k_d = alpha`` [N/m], ``beta_000 = beta*gamma``, ``gamma_000 = beta*delta``
    [1/(m N^(nu-1))], ``n = nu``, ``k_e = k_lin`` (see :data:`BOUCWEN_NOTE`)."""
    from cablesvc.models.boucwen import from_benchmark
    return from_benchmark(alpha, beta, gamma, delta, nu, k_lin)
