"""``cablesvc bench cable-experiment``: the experiment of paper 002 Sec 4, simulated, and the
amplitude model of 002 Sec 3 identified from it.

Set-up (what 002 Sec 4 describes): the platform is held fixed at the home pose, every
winch stretches its cable around a 60 N pretension with x = x_pre - A cos(w t) (eq 15), at
amplitude levels from 0.1 mm to 1.5 mm, 1 kHz sampling, force sensors with 0.1 N Gaussian
noise (``hold-sine`` scenario of the twin). Our design: 15 periods per level at 0.5 Hz
(30 s per level, 6 levels, 1 s ramps, 1 s rest at both ends: a 189 s recording). alpha at
0.1 mm limits it: its error is about 7 % with 3 periods and 1.4-2.0 % (seeds 0, 1) with 10.

Truth (defined here, per cable i with k_i = EA_i / L_i at home and a = A / 1.5 mm)::

    K0 = 60 N                       x_center = 60 N / k_i  (the pretension working point)
    K1(A) = k_i (1 - 0.2 a)         [N/m]   secant stiffness softening with amplitude
    K2 = 0.05 k_i / 1.5 mm          [N/m^2] (1.1 N at xi = 1.5 mm for k = 15 kN/m)
    K3 = 0.05 k_i / (1.5 mm)^2      [N/m^3] (1.1 N at xi = 1.5 mm)
    S_a(A) = pi (0.08 + 0.04 a) K1(A) A^2   [J]  (loss factor 0.08..0.12)
    alpha(A) = 0.2 + 0.2 a          [-]

tabulated on 57 amplitudes from 0.1 to 1.5 mm (the kernel model interpolates them).
Because K0 = 60 N at xi = 0, the pretension elongation is x_center at every level.

Identification (:func:`cablesvc.identify.amplitude_fit.fit_amplitude_model`) sees only
the recording (pose, motor lengths, forces), never the truth. Levels 0.1, 0.25, 0.5, 1.0,
1.5 mm are fitted; the 0.75 mm level is held out and predicted by the identified
amplitude model (run as the kernel runs it, over the whole recording).

Scores:

* parameter recovery, target 2 %, relative error, every parameter (K0, K1, K2, K3, S_a,
  alpha) and x_center, max over cables:
  (a) at each fitted level, the identified f_A at the level's measured amplitude AND the
  identified table as the kernel reads it, against the truth value the recording applied
  there (the truth's table read the way the kernel reads it);
  (b) over the tested range, the identified f_A against the truth at its table amplitudes
  between the smallest and largest fitted level (0.1 .. 1.5 mm, 57 amplitudes) (the held-out 0.75 mm and the amplitudes between levels
  included: a constant truth K2 must come out constant over the whole range);
  both (a) and (b) must be within 2 % for "params_within_2pct". The per-level fits (the
  joint fit's start) are reported with their standard errors, and the (level, parameter)
  pairs whose per-level relative standard error is <= 1 % separately;
* held-out force RMSE on the 0.75 mm level against the measured force, target
  <= 1.1 x 0.1 N (10 % above the sensor noise);
* the sensitivities of Table 1 of 002 (eq 11) for the truth model at each level.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from cablesvc.config import load_robot

if TYPE_CHECKING:     # identification and the models load scipy and numba: imported where the
    # bench runs, so that building the CLI (every ``cablesvc`` command) does not pay for them
    from cablesvc.config.params import ModelParams

__all__ = ["experiment_truth", "run_cable_experiment", "effective_values", "table1_sensitivity", "add_parser"]

A_MAX = 1.5e-3
FIT_LEVELS = (1e-4, 2.5e-4, 5e-4, 1e-3, 1.5e-3)
HELD_OUT = 7.5e-4
NOISE = 0.1
TARGET_REL = 0.02
#: sine periods per amplitude level (our experiment design, see the module docstring)
CYCLES = 15
TARGET_RMSE = 1.1 * NOISE
#: a parameter counts as determined by one level's data when its standard error is at most this fraction of it
DETERMINED_RSE = 0.01


def experiment_truth(robot: str = "ipanema3", points: int = 57) -> ModelParams:
    """The truth amplitude model of the experiment (see module docstring)."""
    from cablesvc.config.params import ModelParams
    from cablesvc.config.params import home_lengths

    rob = load_robot(robot)
    geom = rob.geometry()
    L = home_lengths(geom)
    k = np.asarray(geom.ea, float) / L
    A = np.linspace(1e-4, A_MAX, points)
    a = A / A_MAX
    K1 = k[:, None] * (1.0 - 0.2 * a)[None, :]
    tables = {
        "amplitudes": A.tolist(),
        "K0": [60.0] * points,
        "K1": K1.tolist(),
        "K2": np.repeat((0.05 * k / A_MAX)[:, None], points, axis=1).tolist(),
        "K3": np.repeat((0.05 * k / A_MAX ** 2)[:, None], points, axis=1).tolist(),
        "S_a": (np.pi * (0.08 + 0.04 * a)[None, :] * K1 * A[None, :] ** 2).tolist(),
        "alpha": (0.2 + 0.2 * a).tolist(),
    }
    return ModelParams(model="amplitude", params={"x_center": (60.0 / k).tolist(), "amplitude_init": 5e-4},
                       tables=tables, robot=rob.name, source="cable-experiment truth")


def effective_values(params: ModelParams, n_cables: int, A: float) -> dict[str, np.ndarray]:
    """Table values (per cable, (m,)) the kernel's amplitude model applies at amplitude
    ``A`` [m]: the tables are resampled on GRID_POINTS uniform amplitudes and read at the
    nearest point, clamped to the table range (see :class:`AmplitudeDependent`)."""
    from cablesvc.identify.amplitude_levels import PER_LEVEL
    from cablesvc.models.amplitude import GRID_POINTS

    grid = np.asarray(params.tables["amplitudes"], float)
    lo, hi = grid[0], grid[-1]
    if grid.size > 1:
        G = GRID_POINTS
        u = min(max(A, lo) * (G - 1) / (hi - lo) - (lo * (G - 1) / (hi - lo) - 0.5), (G - 1) + 0.25)
        idx = int(np.floor(u))
        Aeff = lo + idx * (hi - lo) / (G - 1)
    else:
        Aeff = lo
    out = {}
    for k in PER_LEVEL:
        tab = np.broadcast_to(np.asarray(params.tables[k], float), (n_cables, grid.size))
        out[k] = np.array([np.interp(Aeff, grid, tab[c]) for c in range(n_cables)])
    return out


def table1_sensitivity(params: ModelParams, n_cables: int, A: float, *, cable: int = 0, frequency: float = 0.5,
                       samples: int = 400, rel_step: float = 0.1) -> dict[str, float]:
    """Sensitivities of eq 11 of 002 (Table 1: K1, K2, K3, S_a; alpha added) of the
    amplitude model at amplitude ``A`` [m] for one cable.

    Output O: the RMS over one steady period of x = x_center - A cos(w t) of the force
    variation F - K0 [N] (the model's response to the excitation, without the constant
    pretension that no parameter of p_M acts on). Input I: one parameter, perturbed by
    +-``rel_step`` around its value; the perturbed sets are the lanes of one model run."""
    from cablesvc.identify.identifiability import sensitivity
    from cablesvc.models import AmplitudeDependent

    vals = effective_values(params, n_cables, A)
    p = np.array([vals[k][cable] for k in ("K1", "K2", "K3", "S_a", "alpha")])
    xc = float(np.broadcast_to(np.asarray(params.params["x_center"], float), (n_cables,))[cable])
    K0 = float(vals["K0"][cable])
    w = 2 * np.pi * frequency
    t = np.arange(3 * samples + 1) / (samples * frequency)
    x = xc - A * np.cos(w * t)

    def output(P):
        L = P.shape[0]
        model = AmplitudeDependent((L, 1), amplitudes=[1e-12], K0=np.full((L, 1, 1), K0),
                                   K1=P[:, 0, None, None], K2=P[:, 1, None, None], K3=P[:, 2, None, None],
                                   S_a=P[:, 3, None, None], alpha=P[:, 4, None, None], x_center=xc,
                                   amplitude_init=A, omega_init=w)
        st = model.create_state(np.full((L, 1), x[0]))
        st.memory[0] = x[0]
        st.direction[...] = 1.0
        F = np.empty((t.size, L))
        dt = t[1] - t[0]
        for i in range(t.size):
            F[i] = model.step(st, np.full((L, 1), x[i]), dt if i else 0.0)[:, 0]
        steady = F[-samples:] - K0
        return np.sqrt(np.mean(steady ** 2, axis=0))

    s = sensitivity(output, p, rel_step=rel_step, names=["K1", "K2", "K3", "S_a", "alpha"])
    return {n: float(v) for n, v in zip(s["names"], s["S"])}


def run_cable_experiment(robot: str = "ipanema3", *, seed: int = 0, rate: float = 1000.0, frequency: float = 0.5,
                         cycles: int = CYCLES, noise: float = NOISE, fit_levels: Sequence[float] = FIT_LEVELS,
                         held_out: float = HELD_OUT, cables: Sequence[int] | None = None,
                         progress: Any = None) -> dict[str, Any]:
    """Simulate the experiment, identify, score. Returns a JSON-able dict (see module docstring)."""
    from cablesvc.identify.amplitude_fit import fit_amplitude_model
    from cablesvc.identify.amplitude_levels import PER_LEVEL
    from cablesvc.identify.cable import amplitude_params, cable_data

    from cablesvc.simulate import TruthConfig, simulate_recording
    t0 = time.perf_counter()
    rob = load_robot(robot)
    m = rob.n_cables
    truth = experiment_truth(robot)
    levels = sorted(list(fit_levels) + [held_out])
    rec = simulate_recording(rob, "hold-sine", truth=TruthConfig(base=truth, noise_std=noise), seed=seed, rate=rate,
                             frequency=frequency, cycles=cycles, amplitudes=levels)
    t_sim = time.perf_counter() - t0
    data = cable_data(rec, rob, cables)
    K = len(data.cables)
    fit = fit_amplitude_model(data.t, data.x, data.force, cables=data.cables, hold_out=[held_out],
                              progress=progress)
    params = amplitude_params(fit, rob, data, seed)
    t_fit = time.perf_counter() - t0 - t_sim

    # parameter recovery at the fitted levels: identified model vs truth, as the kernel applies them
    rec_rows = []
    worst: dict[str, float] = {k: 0.0 for k in PER_LEVEL}
    worst_raw: dict[str, float] = {k: 0.0 for k in PER_LEVEL}
    worst_det: dict[str, float] = {k: 0.0 for k in PER_LEVEL}
    undetermined: list[str] = []
    worst_fn: dict[str, float] = {k: 0.0 for k in PER_LEVEL}
    worst_table: dict[str, float] = {k: 0.0 for k in PER_LEVEL}
    for lf in fit.fits:
        A = float(np.median(lf.amplitude))
        tv = effective_values(truth, m, A)
        iv = effective_values(params, m, A)
        row: dict[str, Any] = {"amplitude_mm": A * 1e3}
        for j, k in enumerate(PER_LEVEL):
            tru = tv[k][data.cables]
            ide = iv[k][data.cables]
            # the identified f_A at the level's measured amplitude (what the fit claims for the level)
            fa = np.array([fit.functions[c][k](float(lf.amplitude[c])) for c in range(K)])
            raw = np.array([r.x[j] for r in lf.results])
            se = np.array([r.stderr[j] for r in lf.results])
            rel_tab = np.abs(ide - tru) / np.abs(tru)
            rel_fn = np.abs(fa - tru) / np.abs(tru)
            rel = np.maximum(rel_tab, rel_fn)
            rel_raw = np.abs(raw - tru) / np.abs(tru)
            worst_fn[k] = max(worst_fn[k], float(rel_fn.max()))
            worst_table[k] = max(worst_table[k], float(rel_tab.max()))
            worst[k] = max(worst[k], float(rel.max()))
            worst_raw[k] = max(worst_raw[k], float(rel_raw.max()))
            # determined by the data at this level: per-level relative standard error <= 1 %
            det = se / np.abs(raw) <= DETERMINED_RSE
            if np.any(det):
                worst_det[k] = max(worst_det[k], float(rel[det].max()))
            if not np.all(det):
                undetermined.append(f"{k}@{A * 1e3:.3g}mm")
            row[k] = {"truth_cable0": float(tru[0]), "model_cable0": float(ide[0]), "f_A_cable0": float(fa[0]),
                      "max_rel_err": float(rel.max()), "f_A_max_rel_err": float(rel_fn.max()),
                      "table_max_rel_err": float(rel_tab.max()),
                      "level_fit_cable0": float(raw[0]), "level_fit_stderr_cable0": float(se[0]),
                      "level_fit_max_rel_err": float(rel_raw.max()),
                      "level_fit_max_err_in_stderr": float(np.max(np.abs(raw - tru) / se))}
        rec_rows.append(row)
    # the amplitude functions over the tested range (the truth's table amplitudes between the
    # smallest and the largest fitted level: 0.1 .. 1.5 mm in the default run, where its tables are the defining formulas; includes the held-out 0.75 mm
    # and the amplitudes between levels): identified f_A vs truth, relative error
    A_tab = np.asarray(truth.tables["amplitudes"], float)
    lo_fit, hi_fit = float(fit.table_amplitudes[0]), float(fit.table_amplitudes[-1])
    sel = (A_tab >= lo_fit * (1 - 1e-3)) & (A_tab <= hi_fit * (1 + 1e-3))          # the tested (fitted) range
    A_tab = A_tab[sel]
    range_err: dict[str, float] = {}
    range_at: dict[str, float] = {}
    for k in PER_LEVEL:
        tru = np.broadcast_to(np.asarray(truth.tables[k], float), (m, sel.size))[data.cables][:, sel]
        ide = np.stack([fit.functions[c][k](A_tab) for c in range(K)])
        rel = np.abs(ide - tru) / np.abs(tru)
        i = np.unravel_index(int(np.argmax(rel)), rel.shape)
        range_err[k], range_at[k] = float(rel[i]), float(A_tab[i[1]] * 1e3)
    xc_truth = np.asarray(truth.params["x_center"], float)[data.cables]
    xc_err = float(np.max(np.abs(fit.x_center - xc_truth) / xc_truth))

    # held-out level: run the identified parameters as the kernel does, over the whole recording
    model = params.build(m, 1)
    x_all = np.zeros((data.t.size, m))
    l0_all = np.ones((data.t.size, m))
    x_all[:, data.cables] = data.x
    l0_all[:, data.cables] = data.l0
    st = model.create_state(x_all[0][None])
    pred = np.empty_like(x_all)
    dts = np.diff(data.t, prepend=data.t[0])
    for i in range(data.t.size):
        pred[i] = model.step(st, x_all[i][None], float(dts[i]), l0_all[i][None])[0]
    pred = pred[:, data.cables]
    from cablesvc.identify.amplitude_levels import segment_levels
    held_rmse = []
    held_rmse_truthfree = []
    for c in range(K):
        lvs = [lv for lv in segment_levels(data.x[:, c], data.t) if abs(lv.amplitude - held_out) <= 0.05 * held_out]
        if not lvs:
            continue
        lv = lvs[0]
        a, b = int(lv.reversals[1]), int(lv.stop) + 1
        held_rmse.append(float(np.sqrt(np.mean((pred[a:b, c] - data.force[a:b, c]) ** 2))))
        held_rmse_truthfree.append(float(np.sqrt(np.mean((pred[lv.start:b, c] - data.force[lv.start:b, c]) ** 2))))
    # sensitivities of Table 1 for the truth model, cable 0, every level
    sens = {f"{A * 1e3:g} mm": table1_sensitivity(truth, m, A, cable=data.cables[0]) for A in levels}
    t_total = time.perf_counter() - t0
    out = {
        "bench": "cable-experiment", "robot": rob.name, "cables": data.cables, "seed": seed, "rate_hz": rate,
        "frequency_hz": frequency, "cycles": cycles, "noise_std_n": noise,
        "fit_levels_mm": [a * 1e3 for a in fit_levels], "held_out_mm": held_out * 1e3,
        "levels_found_mm": [float(np.median(lf.amplitude) * 1e3) for lf in fit.fits],
        "recovery": rec_rows,
        "max_rel_err": worst, "f_A_at_levels_max_rel_err": worst_fn, "table_at_levels_max_rel_err": worst_table,
        "f_A_range_max_rel_err": range_err, "f_A_range_worst_at_mm": range_at,
        "level_fit_max_rel_err": worst_raw, "x_center_max_rel_err": xc_err,
        "max_rel_err_determined": worst_det, "undetermined": undetermined,
        "f_A_degrees_cable0": {k: fit.functions[0][k].degree for k in PER_LEVEL},
        "f_A_degrees_all": [{k: fit.functions[c][k].degree for k in PER_LEVEL} for c in range(K)],
        "duration_s": float(data.t[-1] - data.t[0]),
        "fit_rmse_n": [float(np.sqrt(np.nanmean((lf.model - lf.force) ** 2))) for lf in fit.fits],
        "held_out_rmse_n": held_rmse, "held_out_rmse_max_n": max(held_rmse) if held_rmse else None,
        "held_out_rmse_incl_first_half_cycle_n": held_rmse_truthfree,
        "sensitivity_table1_truth_cable0": sens,
        "targets": {"param_rel_err": TARGET_REL, "held_out_rmse_n": TARGET_RMSE * noise / NOISE},
        "met": {"params_within_2pct": bool(max(worst.values()) <= TARGET_REL and max(range_err.values()) <= TARGET_REL
                                           and xc_err <= TARGET_REL),
                "determined_params_within_2pct": bool(max(worst_det.values()) <= TARGET_REL
                                                      and xc_err <= TARGET_REL),
                "held_out_rmse": bool(held_rmse and max(held_rmse) <= TARGET_RMSE * noise / NOISE)},
        "seconds": {"simulate": t_sim, "identify": t_fit, "total": t_total},
    }
    return out


def _print_human(res: dict[str, Any]) -> None:
    from cablesvc.identify.amplitude_levels import PER_LEVEL

    from rich.console import Console
    from rich.table import Table
    con = Console()
    con.print(f"[bold]002 Sec 4 experiment[/], robot {res['robot']}, cables {res['cables']}, "
              f"{res['rate_hz']:g} Hz, {res['frequency_hz']:g} Hz sine, {res['cycles']} cycles/level, "
              f"noise {res['noise_std_n']} N; fitted levels {res['levels_found_mm']} mm, held out "
              f"{res['held_out_mm']:g} mm")
    tb = Table(title="identified amplitude model vs truth at the fitted levels: max relative error over cables of "
                     "f_A and of the kernel table (in brackets: the per-level fit, the joint fit's start)")
    tb.add_column("A [mm]", justify="right")
    for k in PER_LEVEL:
        tb.add_column(k, justify="right")
    for row in res["recovery"]:
        tb.add_row(f"{row['amplitude_mm']:.3g}", *[f"{row[k]['max_rel_err'] * 100:.3f} % "
                                                   f"({row[k]['level_fit_max_rel_err'] * 100:.2g} %)" for k in PER_LEVEL])
    con.print(tb)
    con.print(f"x_center max rel. error {res['x_center_max_rel_err'] * 100:.4f} %; "
              f"f_A degrees (cable {res['cables'][0]}): {res['f_A_degrees_cable0']}")
    con.print("f_A over the tested (fitted) amplitude range vs truth, max rel. error over cables: "
              + ", ".join(f"{k} {v * 100:.3f} % (at {res['f_A_range_worst_at_mm'][k]:.3g} mm)"
                          for k, v in res["f_A_range_max_rel_err"].items()))
    ok = res["met"]
    con.print(f"parameters within 2 %: {'[green]yes' if ok['params_within_2pct'] else '[red]NO'}[/] "
              f"(worst at the levels {max(res['max_rel_err'].values()) * 100:.3f} %, over the range "
              f"{max(res['f_A_range_max_rel_err'].values()) * 100:.3f} %)")
    hr = res["held_out_rmse_max_n"]
    wd = res["max_rel_err_determined"]
    con.print(f"parameters the data determine (per-level relative standard error <= 1 %) within 2 %: "
              f"{'[green]yes' if ok['determined_params_within_2pct'] else '[red]NO'}[/] "
              f"(worst {max(wd.values()) * 100:.3f} %: " + ", ".join(f"{k} {v * 100:.2f} %" for k, v in wd.items())
              + f"); not determined at their level: {', '.join(res['undetermined']) or 'none'}")
    con.print(f"held-out {res['held_out_mm']:g} mm level force RMSE: max over cables {hr:.4f} N "
              f"(target <= {res['targets']['held_out_rmse_n']:.3f} N): "
              f"{'[green]met' if ok['held_out_rmse'] else '[red]NOT met'}[/]; per cable "
              f"{[round(v, 4) for v in res['held_out_rmse_n']]}")
    st = Table(title="Table 1 of 002 for the truth model (eq 11, O = RMS of F - K0 over a period, +-10 % steps)")
    st.add_column("A")
    names = ["K1", "K2", "K3", "S_a", "alpha"]
    for n in names:
        st.add_column(n, justify="right")
    for lvl, s in res["sensitivity_table1_truth_cable0"].items():
        st.add_row(lvl, *[f"{s[n]:.3g}" for n in names])
    con.print(st)
    sec = res["seconds"]
    con.print(f"recording {res['duration_s']:.0f} s; time: simulate {sec['simulate']:.1f} s, identify "
              f"{sec['identify']:.1f} s, total {sec['total']:.1f} s")


def cmd_cable_experiment(args: argparse.Namespace) -> int:
    cables = None if not args.cables else [int(c) for c in args.cables.split(",")]
    if args.json:
        res = run_cable_experiment(args.robot, seed=args.seed, cables=cables, cycles=args.cycles)
        print(json.dumps(res))
    else:
        from rich.progress import Progress
        with Progress(transient=True) as prog:
            task = prog.add_task("identify", total=1)

            def cb(done, total, text):
                prog.update(task, total=total, completed=done, description=text)
            res = run_cable_experiment(args.robot, seed=args.seed, cables=cables, cycles=args.cycles, progress=cb)
        _print_human(res)
    return 0 if res["met"]["params_within_2pct"] and res["met"]["held_out_rmse"] else 1


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``cable-experiment`` on the ``cablesvc bench`` sub-parsers."""
    p = subparsers.add_parser(
        "cable-experiment", help="002 Sec 4 experiment simulated; amplitude model identified and scored",
        description="Simulates the hold experiment of 002 Sec 4 (platform fixed, 60 N pretension, amplitudes "
                    "0.1-1.5 mm, 0.1 N noise) with a known amplitude model, identifies the model of 002 Sec 3 "
                    "from the recording, and reports parameter errors, the held-out-level force RMSE and the "
                    "Table 1 sensitivities. Exit code 1 when a target is missed.")
    p.add_argument("--robot", default="ipanema3")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cables", help="comma-separated cable indices (default all)")
    p.add_argument("--cycles", type=int, default=CYCLES, help=f"sine periods per amplitude level (default {CYCLES})")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_cable_experiment)
    return p
