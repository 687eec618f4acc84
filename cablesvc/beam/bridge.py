"""Bridge from the hysteretic beam (000 Sec 3) to the live kernel's lumped cable model.

The kernel cannot run a finite-element beam every tick; it runs the scalar Bouc-Wen
model with cubic term of 000 eqs 1-2 (``cablesvc.models.boucwen.BoucWen``):

    f = k_e x + k3 x^3 + z,   dz = [k_d - (gamma + beta sgn(z dx)) |z|^n] dx

(x [m], f and z [N], k_e, k_d [N/m], k3 [N/m^3], gamma, beta [1/(m N^(n-1))], n [-]).
:func:`fit_lumped` fits these six numbers to the beam's stabilised loops over several
amplitudes at once (bounded least squares, :func:`cablesvc.identify.local.refine`, on the
force residuals of every loop, each loop normalised by its force standard deviation so
that small amplitudes count as much as large ones), reports the per-amplitude fit error
as eq 25 of 000 (MSE / variance, %) and an RMS error [N], and :func:`write_params` writes a
``model = "boucwen"`` parameter file that ``cablesvc run --params`` loads.

The lumped model is simulated exactly the way the kernel runs it: same class, same
integrator option (RK4 with sub-steps, written into the file's ``[options]``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from cablesvc.beam.solver import OMEGA, BeamParams, Section, SolverOptions, stabilised_loop

__all__ = ["LumpedFit", "fit_lumped", "simulate_lumped", "write_params", "LUMPED_NAMES"]

LUMPED_NAMES = ("k_e", "k_d", "beta", "gamma", "n", "k3")
INTEGRATOR = {"integrator": "rk4", "substeps": 8}


def simulate_lumped(theta, amplitudes, steps_per_cycle: int, cycles: int = 2, *, omega: float = OMEGA):
    """Stabilised loops of the lumped Bouc-Wen model for x = A sin(omega t), one lane per
    amplitude, driven with the same samples as the beam. Returns x, f of shape
    (n_amplitudes, steps_per_cycle + 1)."""
    from cablesvc.models.boucwen import BoucWen
    A = np.asarray(amplitudes, dtype=float)
    k_e, k_d, beta, gamma, n, k3 = [float(v) for v in theta]
    model = BoucWen((A.size, 1), k_e=k_e, k_d=k_d, beta=beta, gamma=gamma, n=n, k3=k3, **INTEGRATOR)
    state = model.create_state(0.0, 0.0)
    T = 2 * np.pi / omega
    nst = steps_per_cycle * cycles
    t = np.arange(1, nst + 1) * (T / steps_per_cycle)
    X = A[:, None] * np.sin(omega * t)[None, :]
    rec0 = nst - steps_per_cycle - 1
    F = np.empty((A.size, nst - rec0))
    dt = T / steps_per_cycle
    for k in range(nst):
        f = model.step(state, X[:, k:k + 1], dt)
        if k >= rec0:
            F[:, k - rec0] = f[:, 0]
    return X[:, rec0:], F


@dataclass
class LumpedFit:
    """Result of :func:`fit_lumped`: ``params`` {name: value} (SI), per-amplitude
    ``mse_percent`` (eq 25 x 100) and ``rms`` [N], the beam loops ``x_beam``/``f_beam``
    and the fitted ``f_fit``, the source beam description in ``source``."""

    params: dict
    amplitudes: np.ndarray
    mse_percent: np.ndarray
    rms: np.ndarray
    x_beam: np.ndarray
    f_beam: np.ndarray
    f_fit: np.ndarray
    source: dict = field(default_factory=dict)

    def report(self) -> str:
        lines = ["lumped Bouc-Wen (000 eqs 1-2) fitted to the beam's loops:"]
        for k, v in self.params.items():
            lines.append(f"  {k:6s} = {v:.6g}")
        for A, m, r in zip(self.amplitudes, self.mse_percent, self.rms):
            lines.append(f"  A = {1e3 * A:5.1f} mm: eq-25 error {m:.3f} %, RMS {r:.3g} N")
        return "\n".join(lines)


def _initial_guess(x: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Start values read off the largest loop: k_e from the slope of the mid part of the
    ascending branch, z_sat from half the force gap at x = 0, k_d = 20 k_e, n = 1.2."""
    xi, fi = x[-1], f[-1]
    A = np.max(np.abs(xi))
    up = np.gradient(xi) > 0
    sel = up & (np.abs(xi) < 0.5 * A)
    k_e = float(np.polyfit(xi[sel], fi[sel], 1)[0]) if sel.sum() > 3 else float(np.ptp(fi) / np.ptp(xi))
    f_up = np.interp(0.0, xi[sel], fi[sel]) if sel.sum() > 3 else 0.0
    zsat = max(abs(float(f_up)), 1e-3 * float(np.max(np.abs(fi))))
    k_d = 20.0 * k_e
    n = 1.2
    g = 0.5 * k_d / zsat ** n
    return np.array([k_e, k_d, g, g, n, 0.0])


def fit_lumped(section: Section, length: float, params: BeamParams, amplitudes: Sequence[float] = (0.005, 0.010, 0.015, 0.020),
               *, options: SolverOptions | None = None, omega: float = OMEGA) -> LumpedFit:
    """Fit the lumped Bouc-Wen cable model to the beam's stabilised loops at ``amplitudes`` [m]."""
    from cablesvc.identify.local import refine
    opt = options or SolverOptions()
    A = np.asarray(amplitudes, dtype=float)
    lp = stabilised_loop(section, length, params, A, omega=omega, options=opt)
    if np.any(lp.status != 0):
        raise RuntimeError(f"beam simulation failed: status {lp.status.tolist()}")
    xb, fb = lp.x, lp.f
    sd = np.std(fb, axis=1)
    spc = opt.steps_per_cycle
    x0 = _initial_guess(xb, fb)
    # work in log-space for the positive scale parameters (k_e, k_d, beta, gamma)
    def unpack(p):
        return np.array([np.exp(p[0]), np.exp(p[1]), np.exp(p[2]), np.exp(p[3]), p[4], p[5] * x0[0] / A.max() ** 2])

    def residuals(p):
        _, F = simulate_lumped(unpack(p), A, spc, omega=omega)
        r = ((F - fb) / sd[:, None] / np.sqrt(fb.shape[1] * A.size)).ravel()
        return np.where(np.isfinite(r), r, 1e3)

    p0 = np.array([np.log(max(x0[0], 1e-9)), np.log(x0[1]), np.log(x0[2]), np.log(x0[3]), x0[4], 0.0])
    lb = np.array([p0[0] - 5, p0[1] - 5, p0[2] - 12, p0[3] - 12, 1.0, -5.0])
    ub = np.array([p0[0] + 5, p0[1] + 5, p0[2] + 12, p0[3] + 12, 3.0, 5.0])
    res = refine(residuals, p0, (lb, ub), statistics=False, max_nfev=400)
    th = unpack(res.x)
    _, F = simulate_lumped(th, A, spc, omega=omega)
    mse = 100.0 * np.mean((F - fb) ** 2, axis=1) / np.var(fb, axis=1)
    rms = np.sqrt(np.mean((F - fb) ** 2, axis=1))
    pars = {k: float(v) for k, v in zip(LUMPED_NAMES, th)}
    src = {"rope_diameter_m": section.diameter, "E_Pa": section.E, "poisson": section.poisson,
           "length_m": float(length), "beam_params": {k: float(v) for k, v in zip(
               ("psi", "delta", "gamma", "beta", "n", "k3"), params.as_array())},
           "n_elements": opt.n_elements, "steps_per_cycle": spc, "omega_rad_s": omega}
    return LumpedFit(params=pars, amplitudes=A, mse_percent=mse, rms=rms, x_beam=xb, f_beam=fb, f_fit=F, source=src)


def write_params(fit: LumpedFit, path: str | Path, *, robot: str | None = None, n_ropes: float = 1.0) -> Path:
    """Write the fit as a ``boucwen`` cable-model parameter file (every cable gets the
    same parameters). ``n_ropes`` parallel ropes scale k_e, k_d, k3 and the force z
    (gamma, beta scale by n_ropes^-n so that the shape is kept)."""
    from cablesvc.config.params import ModelParams
    p = dict(fit.params)
    if n_ropes != 1.0:
        for k in ("k_e", "k_d", "k3"):
            p[k] *= n_ropes
        for k in ("beta", "gamma"):
            p[k] *= n_ropes ** (1.0 - p["n"])
    ident = {
        "source": "hysteretic beam of paper 000 (cablesvc.beam), lumped Bouc-Wen fit",
        "amplitude_range": [float(fit.amplitudes.min()), float(fit.amplitudes.max())],
        "amplitudes_m": [float(a) for a in fit.amplitudes],
        "fit_mse_percent": [float(v) for v in fit.mse_percent],
        "fit_rms_N": [float(v) for v in fit.rms],
        "n_ropes": float(n_ropes),
        "beam": fit.source,
    }
    mp = ModelParams(model="boucwen", params=p, options=dict(INTEGRATOR), robot=robot, identification=ident)
    path = Path(path)
    mp.save(path)
    return path
