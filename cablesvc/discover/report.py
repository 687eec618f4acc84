"""Discovery report: JSON, PNG figures and one HTML page.

:func:`write_report` writes into a directory

* ``discovery.json``: :meth:`Discovery.to_json`;
* ``rmse.png``: held-out (test) RMSE per cable before and after, with the noise floor;
* ``term_<name>.png`` per finding: the residual left for the term against the variable
  that explains it, before (residual) and after (residual minus the term), test ticks;
* ``overlay.png``: measured force, baseline and augmented model on the most improved cable;
* ``limits.png`` (identified baseline): per candidate term and cable, the least effect the
  recording could show beside the recalibration, with a perfect baseline (floor) and with
  this one's model form (limit), against the sensor noise
  (:mod:`cablesvc.discover.detectability`);
* ``unexplained_travel.png`` (a residual that repeats with a cable's travel,
  :mod:`cablesvc.discover.periodic`): per such cable, what the model leaves on the test
  ticks against the travel folded on the period found, with its mean per twentieth of a
  period: the shape a turning part leaves once per turn;
* ``params.toml``: the augmented parameter file;
* ``index.html``: the summary sentences, the tables and the figures.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["write_report"]


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _fig_rmse(d, path: Path) -> None:
    plt = _plt()
    m = d.residual.shape[1]
    fig, ax = plt.subplots(figsize=(7, 3.2))
    i = np.arange(m)
    ax.bar(i - 0.2, d.rmse_before, 0.4, label="baseline")
    ax.bar(i + 0.2, d.rmse_after, 0.4, label="with discovered terms")
    ax.plot(i, d.noise, "k_", ms=18, mew=2, label="sensor-noise floor")
    ax.set_xticks(i)
    ax.set_xlabel("cable")
    ax.set_ylabel("held-out RMSE [N]")
    ax.legend(fontsize=8)
    ax.set_title("test blocks (never used for fitting or selection)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fig_term(d, f, path: Path) -> None:
    plt = _plt()
    s = d.signals
    test = d.masks["test"]
    n = len(f.cables)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n + 0.5, 3.2), squeeze=False)
    from cablesvc.models.terms import LIBRARY
    term = LIBRARY.get(f.term)
    for ax, c in zip(axes[0], f.cables):
        fit = d.final[c]
        left = d.residual[:, c] - (fit.pred - fit.contrib[f.term])
        var = term.evidence(s, c, fit.hyper[f.term]) if term is not None else fit.contrib[f.term]
        k = np.flatnonzero(test)[:: max(1, test.sum() // 1500)]
        ax.plot(var[k], left[k], ".", ms=2, alpha=0.5, label="before")
        ax.plot(var[k], left[k] - fit.contrib[f.term][k], ".", ms=2, alpha=0.5, label="after")
        ax.set_title(f"cable {c}: r = {f.r[c]:.2f}", fontsize=9)
        ax.set_xlabel(f.variable, fontsize=7)
        ax.set_ylabel("residual [N]")
        ax.legend(fontsize=7, markerscale=4)
    fig.suptitle(f.label, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fig_overlay(d, path: Path) -> None:
    plt = _plt()
    s = d.signals
    c = int(np.argmax(d.rmse_before - d.rmse_after))
    aug = d.signals.f0[:, c] + (d.final[c].pred if c in d.final else 0.0)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    a1.plot(s.t, s.y[:, c], lw=0.6, label="measured")
    a1.plot(s.t, s.f0[:, c], lw=0.8, label="baseline")
    a1.plot(s.t, aug, lw=0.8, ls="--", label="augmented")
    a1.set_ylabel(f"force cable {c} [N]")
    a1.legend(fontsize=8)
    a2.plot(s.t, s.y[:, c] - s.f0[:, c], lw=0.5, label="residual before")
    a2.plot(s.t, s.y[:, c] - aug, lw=0.5, label="residual after")
    test = d.masks["test"]
    a2.fill_between(s.t, 0, 1, where=test, transform=a2.get_xaxis_transform(), color="0.9", label="test blocks")
    a2.set_xlabel("t [s]")
    a2.set_ylabel("residual [N]")
    a2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fig_limits(d, path: Path) -> bool:
    """Floor and limit per term and cable (log scale); False when there are none."""
    lim = d.options.get("limits") or {}
    terms = sorted({k.split("@")[0] for k in lim})
    if not terms:
        return False
    plt = _plt()
    from matplotlib.ticker import FuncFormatter
    m = d.residual.shape[1]
    fig, axes = plt.subplots(len(terms), 1, figsize=(7, 1.5 * len(terms) + 1.2), sharex=True, squeeze=False)
    i = np.arange(m)
    named = {f.term for f in d.findings}
    for ax, t in zip(axes[:, 0], terms):
        fl = np.array([lim.get(f"{t}@{c}", {}).get("floor_rms_N", np.nan) for c in range(m)], float)
        li = np.array([lim.get(f"{t}@{c}", {}).get("limit_rms_N", np.nan) for c in range(m)], float)
        top = np.nanmax(np.where(np.isfinite(li), li, np.nan)) if np.any(np.isfinite(li)) else 1.0
        ax.bar(i - 0.2, np.where(np.isfinite(fl), fl, 3 * top), 0.4, label="perfect baseline (floor)")
        ax.bar(i + 0.2, np.where(np.isfinite(li), li, 3 * top), 0.4, label="this baseline's model form")
        ax.plot(i, d.noise, "k_", ms=14, mew=2, label="sensor noise")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(FuncFormatter(
            lambda v, _: f"{v:g}" if v > 0 and f"{v:.0e}"[0] in "25" else ""))
        ax.set_ylabel(f"{t}{' (named)' if t in named else ''}\n[N RMS]", fontsize=8)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, 0.965))
    axes[-1, 0].set_xticks(i)
    axes[-1, 0].set_xlabel("cable")
    fig.suptitle("least effect the recording could show beside the baseline's recalibration", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def _unexplained_words(d) -> str:
    return " ".join(f"Cable {', '.join(map(str, u['cables']))}: {u['variable']}." for u in d.unexplained)


def _fig_travel(d, path: Path) -> bool:
    """Held-out residual after the model against the travel folded on the period, per cable
    reported as repeating with its travel; False when there is none."""
    from cablesvc.discover.periodic import travel
    rep = [u for u in d.unexplained if "period_m" in u]
    if not rep:
        return False
    plt = _plt()
    s = d.signals
    test = d.masks["test"]
    fig, axes = plt.subplots(1, len(rep), figsize=(max(6.0, 4.2 * len(rep) + 0.5), 3.3), squeeze=False)
    for ax, u in zip(axes[0], rep):
        c, P = u["cables"][0], u["period_m"]
        fit = d.full[c]
        left = (d.residual[:, c] - fit.pred)[test]
        L = travel(s, c)
        ph = np.mod(L - L[0], P)[test]
        ax.plot(1e3 * ph, left, ".", ms=2, alpha=0.4, label="test ticks")
        edges = np.linspace(0.0, P, 21)
        k = np.clip(np.digitize(ph, edges) - 1, 0, 19)
        mean = np.array([left[k == j].mean() if np.any(k == j) else np.nan for j in range(20)])
        ax.plot(1e3 * 0.5 * (edges[1:] + edges[:-1]), mean, "k-", lw=1.5, label="mean per 1/20 period")
        ax.set_xlabel(f"travel within one period of {1e3 * P:.0f} mm [mm]", fontsize=8)
        ax.set_ylabel("residual after the model [N]")
        ax.set_title(f"cable {c}: {u['amplitude_N']:.2g} N, {u['turns']:.3g} periods seen", fontsize=9)
        ax.legend(fontsize=7, markerscale=4)
    fig.suptitle("unexplained: repeats with the cable's travel (a turning part?)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def write_report(d, directory: str | os.PathLike) -> dict[str, str]:
    """Write the report of discovery ``d`` into ``directory``; returns name -> path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, str] = {}
    doc = d.to_json()
    (out / "discovery.json").write_text(json.dumps(doc, indent=1, default=float))
    files["json"] = str(out / "discovery.json")
    d.augmented_params().save(out / "params.toml")
    files["params"] = str(out / "params.toml")
    _fig_rmse(d, out / "rmse.png")
    files["rmse"] = str(out / "rmse.png")
    _fig_overlay(d, out / "overlay.png")
    files["overlay"] = str(out / "overlay.png")
    if _fig_limits(d, out / "limits.png"):
        files["limits"] = str(out / "limits.png")
    if _fig_travel(d, out / "unexplained_travel.png"):
        files["unexplained_travel"] = str(out / "unexplained_travel.png")
    for f in d.findings:
        if not all(c in d.final and f.term in d.final[c].contrib for c in f.cables):
            continue        # named from the wrench balance (sensor error), not a force term
        p = out / f"term_{f.term}.png"
        _fig_term(d, f, p)
        files[f"term_{f.term}"] = str(p)
    e = html.escape
    rows = "".join(f"<tr><td>{c}</td><td>{d.rmse_before[c]:.4g}</td><td>{d.rmse_after[c]:.4g}</td>"
                   f"<td>{d.noise[c]:.3g}</td></tr>" for c in range(d.residual.shape[1]))
    finds = "".join(
        f"<h3>{e(f.label)} ({e(f.term)})</h3><p>{e(f.sentence())}</p><pre>{e(json.dumps(f.params, indent=1, default=float))}</pre>"
        + (f"<img src='term_{e(f.term)}.png'>" if f"term_{f.term}" in files else "") for f in d.findings) or "<p>Nothing significant remains; no term added.</p>"
    loc = d.location
    def _regions(c: int) -> str:
        return ", ".join("%s (eta2 %.2f)" % (r["variable"], r["eta2"]) for r in loc["state_regions"].get(str(c), []))

    locs = "".join("<li>cable %d: change points at %s s; state: %s</li>"
                   % (c, e(str([round(v, 1) for v in loc["change_points"].get(str(c), [])])), e(_regions(c)))
                   for c in loc["flagged"])
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>cablesvc discovery: {e(d.robot)}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:auto}}td,th{{padding:2px 8px;text-align:right}}img{{max-width:100%}}</style>
</head><body><h1>Discovery report: {e(d.robot)}</h1>
<p>Baseline: {e(d.baseline.model)} ({e(d.baseline.source)}). Split: {e(str(doc['split']))}.</p>
<h2>Summary</h2><ul>{''.join(f'<li>{e(x)}</li>' for x in d.summary())}</ul>
<h2>Where</h2><ul>{locs or '<li>no cable above the noise floor</li>'}</ul>
<h2>Findings</h2>{finds}
{'<h2>Unexplained</h2><p>' + e(_unexplained_words(d)) + '</p><img src="unexplained_travel.png">' if "unexplained_travel" in files else ''}
<h2>Held-out RMSE</h2><table><tr><th>cable</th><th>before [N]</th><th>after [N]</th><th>noise floor [N]</th></tr>{rows}</table>
<img src="rmse.png"><img src="overlay.png">
{'<h2>What the recording cannot show</h2><img src="limits.png">' if "limits" in files else ''}
<p>Files: discovery.json, params.toml (baseline with the discovered terms in [identification]).</p>
</body></html>"""
    (out / "index.html").write_text(page)
    files["html"] = str(out / "index.html")
    return files
