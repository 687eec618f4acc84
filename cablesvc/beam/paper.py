"""Reproduction of the simulated results of paper 000 Sec 6 with the in-house beam solver.

* 7x19 rope (d = 10 mm, E = 206 GPa, Poisson 0.3), lengths 75, 80, 90 mm, amplitudes
  5-20 mm, Table 4 mean parameters (Figs 8-10 model curves);
* 7x7 rope (d = 6 mm), length 100 mm, amplitudes 5-20 mm, Table 6 parameters (Fig 11);
* Fig 6: total and hysteretic bending moment against curvature next to s = 0 (first
  Gauss point, s = h/2) for l = 75 mm, A = 5 mm;
* Fig 7: elastic (EJ_e mu) and hysteretic (M_h) moments along the span, same case.

:func:`hardening_ratio` quantifies the geometric hardening the paper reports at 20 mm: the
tangent stiffness df/dx of the ascending branch near x = +A divided by its smallest value
along the branch. It is 1 for a loop that saturates into a straight post-elastic line
and grows above 1 when the branch curves upward.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cablesvc.beam.solver import (
    ROPE_7x7, ROPE_7x19, TABLE4, TABLE6, Loop, SolverOptions, stabilised_loop,
)

__all__ = ["CASES", "hardening_ratio", "reproduce"]

AMPLITUDES = (0.005, 0.010, 0.015, 0.020)
CASES = {
    "7x19_l75": (ROPE_7x19, 0.075, TABLE4),
    "7x19_l80": (ROPE_7x19, 0.080, TABLE4),
    "7x19_l90": (ROPE_7x19, 0.090, TABLE4),
    "7x7_l100": (ROPE_7x7, 0.100, TABLE6),
}


def hardening_ratio(x: np.ndarray, f: np.ndarray, near: float = 0.9) -> float:
    """Tangent df/dx of the ascending branch averaged over x in [near A, A], divided by the
    smallest tangent on the ascending branch for x in [0, near A] (a 5-point moving average
    smooths the slope). > 1: the branch stiffens towards the turning point."""
    A = float(np.max(x))
    dx = np.diff(x)
    up = dx > 0
    xm = 0.5 * (x[1:] + x[:-1])[up]
    k = (np.diff(f)[up] / dx[up])
    o = np.argsort(xm)
    xm, k = xm[o], k[o]
    ks = np.convolve(k, np.ones(5) / 5, mode="same")
    end = (xm >= near * A)
    mid = (xm >= 0.0) & (xm < near * A)
    return float(np.mean(k[end]) / np.min(ks[mid][2:-2]))


def reproduce(outdir: str | Path | None = None, *, options: SolverOptions | None = None) -> dict:
    """Simulate every case and amplitude; if ``outdir`` is given write the figures
    (loops.png, fig6_moment_curvature.png, fig7_moments_span.png). Returns a summary dict:
    per case and amplitude the force peak [N], loop area [J] and hardening ratio."""
    opt = options or SolverOptions()
    loops: dict[str, Loop] = {}
    summary: dict = {"cases": {}}
    for name, (sec, length, par) in CASES.items():
        lp = stabilised_loop(sec, length, par, np.array(AMPLITUDES), options=opt)
        loops[name] = lp
        rows = []
        for i, A in enumerate(AMPLITUDES):
            rows.append({"amplitude_mm": 1e3 * A, "f_max_N": float(np.max(lp.f[i])),
                         "secant_N_per_mm": float(np.max(lp.f[i]) / (1e3 * A)),
                         "area_J": float(lp.area()[i]), "hardening_ratio": hardening_ratio(lp.x[i], lp.f[i]),
                         "status": int(lp.status[i])})
        summary["cases"][name] = rows
    # Fig 6 / Fig 7 case: l = 75 mm, A = 5 mm, Table 4
    l75 = loops["7x19_l75"]
    g = l75.result.gauss[0]                       # (steps, elements, 5) for A = 5 mm
    sec, length, par = CASES["7x19_l75"]
    EJe = par.delta * par.psi * sec.EJ
    summary["fig6"] = {"s_m": float(l75.result.s[0]), "mu_max": float(np.max(np.abs(g[:, 0, 0]))),
                       "M_max": float(np.max(np.abs(g[:, 0, 1]))), "Mh_max": float(np.max(np.abs(g[:, 0, 2])))}
    if outdir is not None:
        out = Path(outdir)
        out.mkdir(parents=True, exist_ok=True)
        _plots(out, loops, g, l75, EJe)
        summary["figures"] = sorted(str(p) for p in out.glob("*.png"))
    return summary


def _plots(out: Path, loops: dict, g: np.ndarray, l75: Loop, EJe: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 2, figsize=(10, 8))
    for ax, (name, lp) in zip(axs.ravel(), loops.items()):
        for i in range(lp.x.shape[0]):
            ax.plot(1e3 * lp.x[i], lp.f[i], label=f"A = {1e3 * lp.amplitude[i]:g} mm, "
                    f"hardening {hardening_ratio(lp.x[i], lp.f[i]):.2f}")
        ax.set_title(name.replace("_l", ", l = ") + " mm" + (" (Table 4)" if "7x19" in name else " (Table 6)"))
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("f [N] per rope")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Stabilised loops of the hysteretic beam (000 Sec 6, eqs 28-29)")
    fig.tight_layout()
    fig.savefig(out / "loops.png", dpi=110)
    plt.close(fig)

    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    axs[0].plot(g[:, 0, 0], g[:, 0, 1])
    axs[0].set_title(f"(a) total moment M at s = {1e3 * l75.result.s[0]:.2f} mm")
    axs[1].plot(g[:, 0, 0], g[:, 0, 2])
    axs[1].set_title("(b) hysteretic moment M_h")
    for ax in axs:
        ax.set_xlabel("curvature mu [1/m]")
        ax.set_ylabel("[N m]")
        ax.grid(True, alpha=0.3)
    fig.suptitle("Fig 6 of 000: 7x19, l = 75 mm, A = 5 mm, Table 4")
    fig.tight_layout()
    fig.savefig(out / "fig6_moment_curvature.png", dpi=110)
    plt.close(fig)

    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    m = g.shape[0]
    s = 1e3 * l75.result.s
    for k in np.linspace(0, m - 1, 9).astype(int):
        lab = f"t = {l75.t[k]:.1f} s, x = {1e3 * l75.x[0, k]:.1f} mm"
        axs[0].plot(s, EJe * g[k, :, 0], label=lab)
        axs[1].plot(s, g[k, :, 2], label=lab)
    axs[0].set_title("(a) elastic moment EJ_e mu")
    axs[1].set_title("(b) hysteretic moment M_h")
    for ax in axs:
        ax.set_xlabel("s [mm]")
        ax.set_ylabel("[N m]")
        ax.grid(True, alpha=0.3)
    axs[1].legend(fontsize=6)
    fig.suptitle("Fig 7 of 000: moments along the span, 7x19, l = 75 mm, A = 5 mm, Table 4")
    fig.tight_layout()
    fig.savefig(out / "fig7_moments_span.png", dpi=110)
    plt.close(fig)
