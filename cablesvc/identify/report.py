"""Identification report: Markdown with PNG plots (matplotlib, Agg backend).

:func:`write_report` writes into a directory:

* ``report.md`` - what was fitted, on which data, the parameters with standard errors,
  identifiability (condition number, strongest correlations, redundant groups), RMSE per
  cable, notes (fixed parameters and why);
* ``loops_cable<i>.png`` - measured vs model force over elongation (hysteresis loops) per cable;
* ``convergence.png`` - PSO: best eq-25 objective per iteration per swarm; amplitude
  model: per-level values with standard errors and the fitted f_A(A) curves;
* ``residuals.png`` - model minus measured force over time and its histogram per cable.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["write_report", "format_value"]


def format_value(v: float, se: float | None = None) -> str:
    """``1.234e+04 +- 12`` style text (standard error with 2 significant digits)."""
    if se is None or not np.isfinite(se):
        return f"{v:.6g}" + ("" if se is None else " +- inf")
    return f"{v:.6g} +- {se:.2g}"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _loops(fit: Any, out: Path) -> list[str]:
    plt = _plt()
    names = []
    d = fit.data
    for j, c in enumerate(fit.cables):
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
        xm = d.x[:, j] * 1e3
        ax.plot(xm, d.force[:, j], ".", ms=1.5, color="0.6", label="measured")
        ax.plot(xm, fit.predicted[:, j], "-", lw=0.8, color="C3", label=f"model ({fit.model})")
        ax.set_xlabel("elongation x [mm]")
        ax.set_ylabel("force [N]")
        ax.set_title(f"cable {c}: RMSE {fit.rmse[j]:.3g} N")
        ax.legend(loc="best")
        # the same loops with the straight-line trend removed, so that the hysteresis shows
        trend = np.polyfit(xm, d.force[:, j], 1)
        ax2.plot(xm, d.force[:, j] - np.polyval(trend, xm), ".", ms=1.5, color="0.6", label="measured")
        ax2.plot(xm, fit.predicted[:, j] - np.polyval(trend, xm), "-", lw=0.8, color="C3", label="model")
        ax2.set_xlabel("elongation x [mm]")
        ax2.set_ylabel("force minus linear trend [N]")
        ax2.set_title("loops without the elastic trend")
        fig.tight_layout()
        name = f"loops_cable{c}.png"
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        names.append(name)
    return names


def _convergence(fit: Any, out: Path) -> str:
    plt = _plt()
    name = "convergence.png"
    if fit.amplitude is not None:
        af = fit.amplitude
        from cablesvc.identify.amplitude_levels import PER_LEVEL
        fig, axes = plt.subplots(2, 3, figsize=(12, 7))
        grid = af.table_amplitudes
        for ax, k in zip(axes.ravel(), PER_LEVEL):
            for j, c in enumerate(af.cables):
                lt = af.level_table(j)
                se = np.where(np.isfinite(lt[k + "_se"]), lt[k + "_se"], 0.0)
                ax.errorbar(lt["A"] * 1e3, lt[k], yerr=se, fmt="o", ms=3, color=f"C{j % 10}", capsize=2)
                ax.plot(grid * 1e3, af.tables[k][j], "-", lw=0.8, color=f"C{j % 10}")
            ax.set_xlabel("amplitude A [mm]")
            ax.set_title(k)
            lo = min(np.min(af.tables[k]), np.min([np.min(af.level_table(j)[k]) for j in range(len(af.cables))]))
            hi = max(np.max(af.tables[k]), np.max([np.max(af.level_table(j)[k]) for j in range(len(af.cables))]))
            span = hi - lo if hi > lo else abs(hi) + 1e-12
            # keep badly determined small-amplitude points from squashing the plot
            ax.set_ylim(np.min(af.tables[k]) - 0.5 * span, np.max(af.tables[k]) + 0.5 * span)
        fig.suptitle("per-level fits (points, +- standard error) and f_A(A) (lines), one colour per cable")
    else:
        fig, ax = plt.subplots(figsize=(6, 4.5))
        if fit.swarm:
            for j, r in enumerate(fit.swarm):
                lab = f"cable {fit.cables[j]}" if not fit.shared else "shared"
                ax.semilogy(np.arange(len(r.history)), np.maximum(r.history, 1e-16), label=lab)
            ax.set_xlabel("PSO iteration")
            ax.set_ylabel("best normalised MSE (000 eq 25)")
            ax.legend(loc="best", fontsize=7)
        else:
            for j, r in enumerate(fit.results):
                h = np.asarray(r.get("history", []))
                if h.size:
                    ax.semilogy(np.arange(h.size), np.maximum(h, 1e-16), label=f"#{j}")
            ax.set_xlabel("residual evaluation")
            ax.set_ylabel("best 1/2 sum r^2 [N^2]")
        ax.set_title(f"convergence ({fit.method})")
    fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def _residuals(fit: Any, out: Path) -> str:
    plt = _plt()
    d = fit.data
    k = len(fit.cables)
    fig, axes = plt.subplots(k, 2, figsize=(10, 1.8 * k + 1), squeeze=False,
                             gridspec_kw={"width_ratios": [3, 1]})
    for j, c in enumerate(fit.cables):
        r = fit.predicted[:, j] - d.force[:, j]
        axes[j, 0].plot(d.t, r, lw=0.4, color=f"C{j % 10}")
        axes[j, 0].set_ylabel(f"cable {c} [N]")
        axes[j, 1].hist(r[np.isfinite(r)], bins=60, color=f"C{j % 10}")
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("model - measured [N]")
    fig.suptitle("residuals: model minus measured force")
    fig.tight_layout()
    name = "residuals.png"
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def _param_table(fit: Any) -> list[str]:
    lines = []
    if fit.amplitude is not None:
        from cablesvc.identify.amplitude_levels import PER_LEVEL, UNITS
        af = fit.amplitude
        for j, c in enumerate(af.cables):
            rng = ("" if af.xi_range is None else
                   f"; backbone identified on xi = {af.xi_range[j][0] * 1e3:.3g} to {af.xi_range[j][1] * 1e3:.3g} mm"
                   " (it continues along its tangent outside)")
            lines += [f"### cable {c}", "", f"x_center = {af.x_center[j]:.6g} m (pretension working point){rng}", "",
                      "| A [mm] | " + " | ".join(f"{k} [{UNITS[k]}]" for k in PER_LEVEL) + " | RMSE [N] |",
                      "|---" * (len(PER_LEVEL) + 2) + "|"]
            lt = af.level_table(j)
            for i, f in enumerate(af.fits):
                cells = [format_value(lt[k][i], lt[k + "_se"][i]) for k in PER_LEVEL]
                lines.append(f"| {lt['A'][i] * 1e3:.4g} | " + " | ".join(cells) + f" | {f.results[j]['rmse']:.4g} |")
            degs = ", ".join(f"{k}: " + (str(af.functions[j][k].degree) if af.functions[j][k].degree >= 0
                                         else "absent (held at 0: the data do not show it)")
                             + (" (log-log)" if af.functions[j][k].log else "") for k in PER_LEVEL)
            lines += ["", f"f_A degrees: {degs}", ""]
        if af.held_out:
            lines += [f"Held out (not fitted): {', '.join(f'{a * 1e3:.4g} mm' for a in af.held_out)}", ""]
        return lines
    header = "| cable | " + " | ".join(f"{n} [{u}]" if u else n for n, u in zip(fit.names, fit.units)) + \
        " | RMSE [N] | cond | |"
    lines += [header, "|---" * (len(fit.names) + 4) + "|"]
    rows = fit.results if not fit.shared else fit.results * 1
    for j, r in enumerate(rows):
        lab = str(fit.cables[j]) if not fit.shared else "all (shared)"
        cells = [format_value(v, s) for v, s in zip(r.x, r.stderr)]
        rm = fit.rmse[j] if not fit.shared else float(np.sqrt(np.mean(fit.rmse ** 2)))
        lines.append(f"| {lab} | " + " | ".join(cells) + f" | {rm:.4g} | {r.get('cond', float('nan')):.3g} | |")
    return lines + [""]


def _identifiability(fit: Any) -> list[str]:
    lines = ["## Identifiability", ""]
    rs = fit.results if fit.amplitude is None else [r for lf in fit.amplitude.fits for r in lf.results]
    any_group = False
    for j, r in enumerate(rs):
        if fit.amplitude is None:
            lab = f"cable {fit.cables[j]}" if not fit.shared else "shared"
        else:
            L = len(fit.amplitude.cables)
            lf = fit.amplitude.fits[j // L]
            lab = f"cable {fit.amplitude.cables[j % L]}, level {lf.amplitude[j % L] * 1e3:.3g} mm"
        corr = np.asarray(r.get("correlation"))
        names = r.get("names") or []
        pairs = []
        if corr.ndim == 2:
            for a in range(corr.shape[0]):
                for b in range(a + 1, corr.shape[0]):
                    if np.isfinite(corr[a, b]) and abs(corr[a, b]) > 0.95:
                        pairs.append(f"{names[a]}/{names[b]} {corr[a, b]:+.3f}")
        groups = r.get("redundant") or []
        if groups:
            any_group = True
        if fit.amplitude is None or groups or pairs:
            lines.append(f"- {lab}: condition number (equilibrated J) {r.get('cond', float('nan')):.3g}"
                         + (f"; |correlation| > 0.95: {', '.join(pairs)}" if pairs else "")
                         + "".join(f"; {g.describe()}" for g in groups))
    if fit.amplitude is not None and not any_group:
        lines.append("- no redundant parameter group in any level fit (condition numbers in the level tables' "
                     "standard errors: a large standard error marks a parameter the level barely determines)")
    return lines + [""]


def write_report(fit: Any, out_dir: str | Path, *, recording: str | None = None, params_file: str | None = None) -> Path:
    """Write the Markdown report and its PNGs for a :class:`~cablesvc.identify.cable.CableFit`
    into ``out_dir`` (created). Returns the path of ``report.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    loops = _loops(fit, out)
    conv = _convergence(fit, out)
    resid = _residuals(fit, out)
    d = fit.data
    lines = [f"# Cable identification: {fit.model} model", "",
             f"- recording: {recording or '(in memory)'}; robot {d.robot}; cables {fit.cables}"
             + (" (one shared parameter set)" if fit.shared else ""),
             f"- data: {d.t.size} ticks, {d.t[-1] - d.t[0]:.1f} s, dt {d.dt * 1e3:.3g} ms; elongation "
             "x = l(pose) - motor_length (inverse kinematics on the recorded pose)",
             f"- method: {fit.method}; run time {fit.seconds:.1f} s",
             "- force RMSE per cable [N]: " + ", ".join(f"{c}: {v:.4g}" for c, v in zip(fit.cables, fit.rmse))]
    if params_file:
        lines.append(f"- parameter file: `{params_file}` (load with `cablesvc run --params {params_file}`)")
    lines += [""]
    if fit.notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in fit.notes] + [""]
    lines += ["## Parameters (value +- standard error)", ""] + _param_table(fit)
    lines += _identifiability(fit)
    lines += ["## Plots", "", "### Measured vs model loops", ""]
    lines += [f"![{n}]({n})" for n in loops] + [""]
    lines += ["### Convergence" if fit.amplitude is None else "### Amplitude functions", "", f"![{conv}]({conv})", "",
              "### Residuals", "", f"![{resid}]({resid})", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
