"""Discovery pipeline: baseline, split, locate, explain, model, show.

:func:`discover` takes a recording (measured forces required), the robot and optionally a
baseline parameter file and

1. runs the baseline model (the parameter file, or the robot's nominal amplitude model
   that the kernel uses without one) on the recording's elongations x = l(pose) -
   motor_length, and splits the time axis into blocks of ``block`` seconds assigned in
   turn to training, training, validation and test (train 50 %, validation 25 %, test
   25 %): term parameters are fitted on training blocks only, terms are chosen on the
   validation blocks, and the before/after RMSE is reported on the test blocks, which
   nothing else touches. The designs use only inputs (elongation, pose, temperature,
   baseline prediction), never the measured force, so no residual crosses the split;
2. locates the residual (:mod:`cablesvc.discover.locate`);
3. explains it with the term library (:mod:`cablesvc.discover.terms`) and the selector
   (:mod:`cablesvc.discover.select`), stating the evidence per term;
4. refits the chosen terms (training + validation for the test score, all ticks for the
   parameter file) and writes them into a parameter file;
5. reports held-out RMSE per cable before and after (:mod:`cablesvc.discover.report`
   writes the JSON, HTML and figures).

It never reads a recording's metadata (a simulated recording's ``truth`` key is the
benchmark's answer key).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Optional, Union

import numpy as np

from cablesvc.config.params import ModelParams, default_params, load_params
from cablesvc.config.robot import Robot, load_robot
from cablesvc.discover.locate import locate
from cablesvc.discover.select import Fit, ForwardSelector, Selection, fit_terms
from cablesvc.discover.terms import Signals, Term, library, reversal_amplitude
from cablesvc.kinematics import inverse_kinematics
from cablesvc.models import simulate

__all__ = ["Discovery", "Finding", "DiscoveryError", "baseline_params", "build_signals", "split_blocks", "discover"]


class DiscoveryError(ValueError):
    """Discovery cannot run on these inputs (no forces, too short...)."""


def _robot(robot: Union[Robot, str, "os.PathLike[str]"]) -> Robot:
    return robot if isinstance(robot, Robot) else load_robot(robot)


def baseline_params(robot: Robot, params: Union[None, str, "os.PathLike[str]", ModelParams] = None) -> ModelParams:
    """The baseline: a :class:`ModelParams`, a parameter file, or (None) the nominal
    amplitude model from the robot's E*A and its cable lengths at the home pose."""
    if isinstance(params, ModelParams):
        return params
    if params is not None:
        return load_params(params)
    geom = robot.geometry()
    home = inverse_kinematics(geom, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])).length[0]
    return default_params(geom.ea, home, "amplitude")


def build_signals(rec: Any, robot: Robot, params: ModelParams) -> Signals:
    """Signals of a recording: IK, elongation and rates, the baseline's prediction."""
    if rec.force is None:
        raise DiscoveryError("the recording has no measured forces; discovery compares the model with them")
    if rec.position is None or rec.orientation is None:
        raise DiscoveryError("the recording has no platform pose; discovery needs it for the cable lengths")
    geom = robot.geometry()
    m = geom.n_cables
    if rec.force.shape[1] != m:
        raise DiscoveryError(f"the recording has {rec.force.shape[1]} cables, robot {robot.name} has {m}")
    t = np.asarray(rec.t, float) - float(rec.t[0])
    if t.size < 200:
        raise DiscoveryError(f"the recording is too short for a held-out split ({t.size} ticks, need >= 200)")
    dt = float(np.median(np.diff(t)))
    ik = inverse_kinematics(geom, np.asarray(rec.position, float), np.asarray(rec.orientation, float))
    length = np.array(ik.length)
    ml = np.asarray(rec.motor_length, float)
    x = length - ml
    model = params.build(m, 1)
    f0 = simulate(model, x, np.r_[dt, np.diff(t)], l0=ml)
    return Signals(t=t, dt=dt, y=np.asarray(rec.force, float), f0=f0, x=x, v=np.gradient(x, t, axis=0),
                   v_slide=-np.gradient(ml, t, axis=0), wrap=np.array(ik.wrap_angle),
                   free_length=np.array(ik.free_length),
                   temperature=None if rec.temperature is None else np.asarray(rec.temperature, float),
                   ea=np.asarray(geom.ea, float), has_pulley=np.asarray(geom.has_pulley, bool),
                   amplitude=reversal_amplitude(x), train=np.ones(t.size, bool),
                   cable_names=tuple(geom.cable_names))


def split_blocks(t: np.ndarray, block: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks (train, valid, test) of blocks of ``block`` s taken in turn as train, valid,
    train, test (so every part spans the whole recording)."""
    k = np.floor((t - t[0]) / block).astype(int)
    role = np.array([0, 1, 0, 2])[k % 4]
    train, valid, test = role == 0, role == 1, role == 2
    if valid.sum() < 20 or test.sum() < 20:
        raise DiscoveryError(f"blocks of {block} s leave too few validation/test ticks; use a shorter block")
    return train, valid, test


@dataclass
class Finding:
    """A term discovery keeps: ``term`` (name), ``label`` (plain words), ``equation``,
    ``cables`` (0-based), the explaining ``variable`` and the held-out correlation ``r``
    per cable between the residual left for this term and the term's fitted correction
    (uncentred, so an offset counts: <a, b> / (|a| |b|)),
    ``raw_r`` between that residual and the raw variable, and the physical parameters per
    cable."""

    term: str
    label: str
    equation: str
    variable: str
    cables: list[int]
    r: dict[int, float]
    raw_r: dict[int, float]
    params: dict[int, dict[str, Any]]

    def sentence(self, names: tuple[str, ...] = ()) -> str:
        cs = ", ".join(str(c) for c in self.cables)
        rr = np.median(list(self.r.values())) if self.r else float("nan")
        return (f"{self.label}: the residual follows {self.variable} on cable{'s' if len(self.cables) > 1 else ''} "
                f"{cs} (held-out r = {rr:.2f}, model: {self.equation})")


@dataclass
class Discovery:
    """Result of :func:`discover` (see the module docstring); :meth:`to_json` is the report's JSON."""

    robot: str
    baseline: ModelParams
    signals: Signals
    residual: np.ndarray
    masks: dict[str, np.ndarray]
    location: dict[str, Any]
    selection: Selection
    final: dict[int, Fit]
    full: dict[int, Fit]
    findings: list[Finding]
    rmse_before: np.ndarray
    rmse_after: np.ndarray
    noise: np.ndarray
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def named(self) -> list[str]:
        return [f.term for f in self.findings]

    @property
    def significant(self) -> bool:
        return bool(self.findings)

    def reduction(self, cables: Optional[list[int]] = None) -> float:
        """Relative drop of the test RMS residual over ``cables`` (default: all), 0..1."""
        cs = list(range(self.residual.shape[1])) if cables is None else cables
        b = math.sqrt(float(np.mean(self.rmse_before[cs] ** 2)))
        a = math.sqrt(float(np.mean(self.rmse_after[cs] ** 2)))
        return 1.0 - a / b if b > 0 else 0.0

    def summary(self) -> list[str]:
        lines = []
        loc = self.location
        if loc["flagged"]:
            lines.append("cables whose residual exceeds the sensor-noise floor: "
                         + ", ".join(str(c) for c in loc["flagged"]))
        else:
            lines.append("no cable's residual exceeds the sensor-noise floor by 30 %")
        if not self.findings:
            lines.append("nothing significant remains: no term improves the held-out fit enough to pay for its "
                         "parameters; the model is left as it is")
        for f in self.findings:
            lines.append(f.sentence())
        m = self.residual.shape[1]
        lines.append("held-out (test) RMSE per cable [N], before -> after: " + "; ".join(
            f"{c}: {self.rmse_before[c]:.3g} -> {self.rmse_after[c]:.3g}" for c in range(m)))
        return lines

    def augmented_params(self) -> ModelParams:
        """The baseline parameter file with the discovered terms (fitted on all ticks) in
        its ``[identification]`` section (``discovered_terms``, and per term a table of
        parameters per cable: cables without the term get 0)."""
        p = self.baseline
        ident = dict(p.identification)
        m = self.residual.shape[1]
        ident["discovered_terms"] = self.named
        for f in self.findings:
            table: dict[str, list[float]] = {}
            for c in f.cables:
                fit = self.full[c]
                for k, v in {**fit.params.get(f.term, {}), **fit.hyper.get(f.term, {})}.items():
                    table.setdefault(k, [0.0] * m)[c] = float(v)
            ident[f"term_{f.term}"] = table
        ident["discovery_rmse_before"] = [float(v) for v in self.rmse_before]
        ident["discovery_rmse_after"] = [float(v) for v in self.rmse_after]
        return ModelParams(model=p.model, params=dict(p.params), options=dict(p.options), tables=dict(p.tables),
                           robot=self.robot, identification=ident, source="<discovery>")

    def predict(self) -> np.ndarray:
        """Augmented model's force on this recording (N, m) [N] (terms fitted on all ticks)."""
        out = self.signals.f0.copy()
        for c, f in self.full.items():
            out[:, c] += f.pred
        return out

    def to_json(self) -> dict[str, Any]:
        m = self.residual.shape[1]
        return {
            "robot": self.robot,
            "baseline": {"model": self.baseline.model, "source": self.baseline.source},
            "split": {k: int(v.sum()) for k, v in self.masks.items()} | {"block_s": self.options.get("block")},
            "locate": self.location,
            "significant": self.significant,
            "findings": [{"term": f.term, "label": f.label, "equation": f.equation, "variable": f.variable,
                          "cables": f.cables, "r": {str(k): v for k, v in f.r.items()},
                          "raw_r": {str(k): v for k, v in f.raw_r.items()},
                          "params": {str(k): v for k, v in f.params.items()}, "sentence": f.sentence()}
                         for f in self.findings],
            "steps": [{"term": st.term, "cables": st.cables,
                       "valid_mse_before": {str(k): v for k, v in st.mse_before.items()},
                       "valid_mse_after": {str(k): v for k, v in st.mse_after.items()},
                       "candidate_scores": st.candidates, "pruned": [list(p) for p in st.pruned],
                       "swapped": [list(p) for p in getattr(st, "swapped", [])]}
                      for st in self.selection.steps],
            "rmse_test_before": [float(v) for v in self.rmse_before],
            "rmse_test_after": [float(v) for v in self.rmse_after],
            "noise_floor": [float(v) for v in self.noise],
            "rmse_reduction": self.reduction(),
            "summary": self.summary(),
            "cables": m,
        }


def _corr(a: np.ndarray, b: np.ndarray, centred: bool = True) -> float:
    if centred:
        a = a - a.mean()
        b = b - b.mean()
    d = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / d) if d > 0 else 0.0


def discover(recording: Any, robot: Union[Robot, str, "os.PathLike[str]"],
             params: Union[None, str, "os.PathLike[str]", ModelParams] = None, *,
             terms: Optional[list[Term]] = None, selector: Any = None, block: float = 2.5) -> Discovery:
    """Run discovery on ``recording`` (a :class:`~cablesvc.recording.Recording` or a path)
    of ``robot``; ``params`` the baseline (None: nominal); ``terms`` the library (default
    :func:`~cablesvc.discover.terms.library`); ``selector`` (default
    :class:`~cablesvc.discover.select.ForwardSelector`); ``block`` [s] the split's block."""
    from cablesvc.recording import read_recording
    rob = _robot(robot)
    rec = recording if not isinstance(recording, (str, os.PathLike)) else read_recording(recording)
    base = baseline_params(rob, params)
    s = build_signals(rec, rob, base)
    train, valid, test = split_blocks(s.t, block)
    s.train = train
    terms = library() if terms is None else terms
    selector = selector or ForwardSelector()
    r = s.y - s.f0
    loc = locate(s, r)
    noise = np.array([d["noise"] for d in loc["cables"]])
    sel = selector.select(s, r, terms, train, valid, noise=noise)

    m = s.m
    fitmask = train | valid
    final: dict[int, Fit] = {}
    full: dict[int, Fit] = {}
    rmse_b = np.sqrt(np.mean(r[test] ** 2, axis=0))
    rmse_a = rmse_b.copy()
    for c in range(m):
        f_sel = sel.fits[c]
        if not f_sel.terms:
            continue
        hyp = [f_sel.hyper[t.name] for t in f_sel.terms]
        final[c] = fit_terms(s, c, r[:, c], f_sel.terms, fitmask, hypers=hyp)
        rmse_a[c] = math.sqrt(float(np.mean((r[test, c] - final[c].pred[test]) ** 2)))
        full[c] = fit_terms(s, c, r[:, c], f_sel.terms, np.ones(s.n, bool), hypers=hyp)

    findings: list[Finding] = []
    for name, cables in sel.named().items():
        t = next(u for u in terms if u.name == name)
        rr, raw, phys = {}, {}, {}
        for c in cables:
            fit = final[c]
            others = fit.pred - fit.contrib[name]
            left = (r[:, c] - others)[test]
            rr[c] = _corr(left, fit.contrib[name][test], centred=False)
            raw[c] = _corr(left, t.evidence(s, c, fit.hyper[name])[test])
            phys[c] = t.physical(full[c].params[name], full[c].hyper[name], s, c)
        findings.append(Finding(term=name, label=t.label, equation=t.equation, variable=t.variable,
                                cables=list(cables), r=rr, raw_r=raw, params=phys))
    return Discovery(robot=rob.name, baseline=base, signals=s, residual=r,
                     masks={"train": train, "valid": valid, "test": test}, location=loc, selection=sel,
                     final=final, full=full, findings=findings, rmse_before=rmse_b, rmse_after=rmse_a,
                     noise=np.array([d["noise"] for d in loc["cables"]]), options={"block": block})
