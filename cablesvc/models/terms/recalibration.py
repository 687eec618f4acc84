"""The baseline's own recalibration (:class:`Recalibration`): the nuisance every named term
must beat in identified-baseline discovery (background: :mod:`cablesvc.discover.nuisance`),
and the baseline's hysteretic part it is built on (:func:`hysteretic_part`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cablesvc.models.terms.base import LiveTerm, Term
from cablesvc.models.terms.material import (AmplitudeStiffness, AsymmetricHardening, amplitude_varies,
                                            elongation_centre_scale)
from cablesvc.models.play import LiveStops, initial_state_columns, stop_columns
from cablesvc.models.relaxation import relaxation_columns
from cablesvc.models.terms.signals import Signals, cable_view

__all__ = ["Recalibration", "hysteretic_part"]


def _backbone_refs(s: Signals, c: int) -> dict[str, float]:
    x = s.x[:, c]
    xm, sx = elongation_centre_scale(s, c)
    u = (x - xm) / sx
    V = np.column_stack([np.ones_like(u), u, u ** 2, u ** 3])
    coef, *_ = np.linalg.lstsq(V[s.train], s.f0[s.train, c], rcond=None)
    return {"x_mean": xm, "x_scale": sx, "h0": float(coef[0]), "h1": float(coef[1]), "h2": float(coef[2]),
            "h3": float(coef[3])}


def _hysteretic_part(f0, x, R, out, tmp) -> None:
    """h = f0 - (h0 + h1 u + h2 u^2 + h3 u^3), u = (x - x_mean) / x_scale, into ``out``."""
    np.subtract(x, R["x_mean"], out=tmp)
    np.divide(tmp, R["x_scale"], out=tmp)
    np.multiply(tmp, R["h3"], out=out)
    np.add(out, R["h2"], out=out)
    np.multiply(out, tmp, out=out)
    np.add(out, R["h1"], out=out)
    np.multiply(out, tmp, out=out)
    np.add(out, R["h0"], out=out)
    np.subtract(f0, out, out=out)


def hysteretic_part(s: Signals, c: int) -> np.ndarray:
    """The baseline's hysteretic part h (N,) [N] of cable ``c``: f0 minus the cubic in the
    elongation that fits f0 best on the training ticks (the backbone)."""
    out, tmp = np.empty(s.n), np.empty(s.n)
    _hysteretic_part(s.f0[:, c], s.x[:, c], _backbone_refs(s, c), out, tmp)
    return out


#: m/s: the speed the damping columns are scaled at (their coefficient is the force at it)
V_REF = 1e-3
#: m/s: below this speed the damping columns are linear in v (sgn(v) |v|^alpha regularised)
V_LIN = 1e-5
#: the rate exponents alpha of the damping columns (002 eq 8: alpha = 0 is dry friction):
#: well below a viscous force's 1, so that a Kelvin-Voigt damper keeps a part of its own
RATE_EXPONENTS = (0.0, 0.25)
#: the damping columns: per exponent, the rate law with a free level [N at V_REF] ...
DAMPING_LEVELS = tuple(f"c_r{int(100 * a)}" for a in RATE_EXPONENTS)
#: ... then the same with a level that grows with the elongation's envelope [N/mm]
DAMPING_PER_MM = tuple(f"{n}_e" for n in DAMPING_LEVELS)
_RATE = DAMPING_LEVELS + DAMPING_PER_MM
#: m: the widths of the rate-independent loop's stops (:mod:`cablesvc.models.play`), a
#: decade of yield elongations about a rope's strand slip (0.1-few mm), log-spaced
STOP_WIDTHS = (3e-4, 1e-3, 3e-3)
#: ... and their parameters, the force of each stop at full yield [N] (``c_s03``: 0.3 mm)
STOPS = tuple(f"c_s{round(w * 1e4):02d}" for w in STOP_WIDTHS)
#: ... and the force their unknown state at the recording's start leaves, per width [N]
#: (``c_i03``: 0.3 mm), on the initial-state columns d_r (:func:`~cablesvc.models.play.initial_state_columns`)
INITIAL = tuple(f"c_i{round(w * 1e4):02d}" for w in STOP_WIDTHS)
#: the loop's parameters: its stops and their initial state, used together or not at all
LOOP = STOPS + INITIAL
#: the loop's stops scaled by the force (offline only: a model-form alternative)
FORCE_LOOP = tuple(f"c_f{round(w * 1e4):02d}" for w in STOP_WIDTHS)
#: s: the relaxation times of the rope's own viscoelastic relaxation (Maxwell branches,
#: :mod:`cablesvc.models.relaxation`; offline only: a model-form alternative), well inside
#: a recording of tens of seconds: a branch that relaxes over the whole recording is a slow
#: course in time, which a temperature drift draws too
RELAX_TAUS = (2.0, 8.0)
#: ... and their parameters, the force of each per training std of the elongation [N]
RELAX = tuple(f"c_m{round(t):d}" for t in RELAX_TAUS)
_N_BASE = 7 + 2 * len(RATE_EXPONENTS)               # the columns before the stops


def rate_power(v: np.ndarray, alpha: Any, out: np.ndarray) -> np.ndarray:
    """sgn(v) (|v| / V_REF)^alpha, linear in v below V_LIN (into ``out``) [-]: the rate law
    of 002 eq 8's damping with its amplitude normalisation left out."""
    np.abs(v, out=out)
    np.maximum(out, V_LIN, out=out)
    np.divide(out, V_REF, out=out)
    np.power(out, alpha - 1.0, out=out)
    np.multiply(out, v, out=out)
    np.divide(out, V_REF, out=out)
    return out


def envelope(x: np.ndarray) -> np.ndarray:
    """The elongation's envelope [mm] (N, ...): half the range x has covered from the first
    tick to each tick (the running peak-to-peak / 2), another estimate of the excitation
    amplitude than 002's last reversal points. A non-finite elongation is passed over (as
    live: one bad reading does not end the envelope)."""
    return 0.5e3 * (np.fmax.accumulate(x, axis=0) - np.fmin.accumulate(x, axis=0))


def _largest(a: np.ndarray, mask: np.ndarray) -> float:
    """The largest finite value of ``a`` on ``mask`` (of all of ``a`` when the mask is
    empty; 0 when none is finite)."""
    v = a[mask] if np.any(mask) else a
    v = v[np.isfinite(v)]
    return float(v.max()) if v.size else 0.0


#: the discrepancy's amplitude columns (the law of the amplitude term, columns 5 and 6 of
#: this one), held within their training range
_HELD = ("K1_A", "d_A")


class Recalibration(Term):
    """Recalibration of the baseline's own parameters plus a smooth discrepancy in its own
    state (the nuisance every named term must beat with an identified baseline):

        delta_f = o + k_s f0 + a_h h + c2 xi^2 / s + c3 xi^3 / s^2 + K1_A (A - mean A) xi + d_A A tanh(v / v_s)
                  + sum_a (c_ra + c_ra_e E) sgn(v) (|v| / v_ref)^a,   a in RATE_EXPONENTS = (0, 0.25)
                  [+ sum_r (c_sr s_r(x) + c_ir d_r(x)),   r in STOP_WIDTHS = (0.3, 1, 3) mm]

    f0 the baseline force [N], xi = x - mean x [m], s its training std [m], h = f0 - P3(x)
    the baseline's hysteretic part (f0 minus its least-squares cubic backbone in x on the
    training ticks) [N], A the reversal amplitude [m] (002 eq 8), v_s = 1e-4 m/s. o [N],
    k_s [-], a_h [-], c2, c3 [N], K1_A [N/m^2], d_A [N/m] (the last two only when A varies).
    The last columns are 002 eq 8's damping rate law sgn(v) |v|^a (:func:`rate_power`,
    v_ref = 1 mm/s) with its level free instead of S_a / (A (A w)^a l pi): c_ra [N at
    v_ref], and a level growing with the elongation's envelope E [mm] (:func:`envelope`:
    another amplitude estimate than the last reversal points), c_ra_e [N/mm], E held at the
    largest value it took on the training ticks (reference ``E_hi``; offline and live: a
    level fitted on 2 mm of envelope does not grow without limit when the robot later
    covers 20 mm). The exponents span dry friction (a = 0) to a weak rate dependence;
    together they stand for an exponent up to about 0.5 over a trajectory's speeds, and
    stay well below a viscous force's 1, which keeps a part of its own.
    The last, optional, columns are a rate-independent loop: Prandtl-Ishlinskii stops s_r of
    widths r (:mod:`cablesvc.models.play`; s_r in [-1, 1], c_sr [N] the force of each at full
    yield), started relaxed, and the loop's unknown state at the recording's start: d_r in
    [0, 1], half the difference between the stop started at full yield either way, 1 on the
    first tick and 0 once the elongation has moved 2 r one way (c_ir [N]). A recording starts
    wherever the rope's loop happens to be; with the stops alone, the first seconds of a
    recording whose loop did not start relaxed were a misfit that a creep's settling or a
    pulley's friction "explained" (measured: docs/discovery.md, "The loop's state at the
    recording's start"). A rope whose strands slip (a Bouc-Wen-like loop, which the realistic
    bench's ``--truth-hysteresis boucwen`` draws) is a loop 002 eq 8's damping cannot draw: its force
    turns over a yield elongation after each reversal, whatever the speed. The stops are used
    only where discovery finds that most of the robot's cables show such a loop
    (:func:`cablesvc.discover.nuisance.loop_gate`, then ``Recalibration(stops=True)``; by
    default they are held at 0): on a robot without one they would take part of a creep, a sag or a viscous force
    (measured: docs/discovery.md, "A rate-independent loop"). The live form runs the loop
    with the coefficients the file gives, and not at all where they are 0 (unused, or a file
    written before them).
    An identified baseline's damping is the loop
    area of millimetre sines at one working point; along a trajectory its amplitude
    normalisation is the least reliable part of its law (issue 15 lists "another amplitude
    estimator" among the model-form errors of a real cable).
    Background and references: :mod:`cablesvc.discover.nuisance`.

    The two amplitude columns of the discrepancy (K1_A, d_A) are held within the range they
    took on the training ticks (references ``lo_<name>``, ``hi_<name>``), offline and live.
    They are an empirical correction, fitted where the recording went; outside that support
    they extrapolated without limit (measured on the realistic bench's development seed 7: a
    held-out stretch after a long dwell, whose reversal amplitude the training ticks never
    reached with that sign of speed, left 184 x the noise instead of 22 x). Held at its edge,
    the correction there is the one at the nearest state it was fitted on, as a discrepancy
    with a prior reverts to it away from its data (Kennedy & O'Hagan 2001). The backbone
    columns (c2, c3) are not held (holding them too added a false finding on the development
    cases), nor are the baseline's own parameters (o, k_s, a_h), which are physical. A file
    written without these references runs unclamped. The two columns are the term's
    ``held`` ones (``Design.held``), so that a leave-one-block-out fit holds them within
    the support of its own fitted ticks too (:func:`cablesvc.discover.evidence.loo_errors`)."""

    name = "baseline"
    label = "baseline recalibration (its own parameters and a smooth discrepancy in its own state)"
    equation = ("o + k_s f0 + a_h h + c2 xi^2/s + c3 xi^3/s^2 + K1_A (A - mean A) xi + d_A A tanh(v/v_s)"
                " + sum_a (c_ra + c_ra_e E) sgn(v) |v/v_ref|^a [+ sum_r (c_sr s_r(x) + c_ir d_r(x))]  (002 eq 8, 001 Ch 4; "
                "Prandtl-Ishlinskii stops; Kennedy & O'Hagan 2001)")
    variable = "baseline force f0 [N]"
    params = ("o", "k_s", "a_h", "c2", "c3", "K1_A", "d_A", *_RATE, *LOOP)
    units = ("N", "-", "-", "N", "N", "N/m^2", "N/m", *("N" for _ in RATE_EXPONENTS),
             *("N/mm" for _ in RATE_EXPONENTS), *("N" for _ in LOOP))
    ref_names = ("x_mean", "x_scale", "h0", "h1", "h2", "h3", "A_mean", "E_hi",
                 *(f"{side}_{n}" for n in _HELD for side in ("lo", "hi")))
    owns_nuisance = True
    #: the amplitude columns, held offline and live within their training range; and the
    #: loop's initial state, 1 on the first tick and 0 once it is forgotten, which lies in
    #: [0, 1] anyway: held too, so that a fold which leaves out the recording's start does not
    #: extrapolate a coefficient fitted where the column is all but 0 (a leave-one-block-out
    #: fit holds a held column within its own fitted ticks' range: Design.held)
    held = _HELD + INITIAL

    def __init__(self, stops: bool = False, initial: bool = True, rate_exponents: tuple = RATE_EXPONENTS,
                 force_loop: bool = False, relax: bool = False, spare_time: bool = False):
        #: whether the fit uses the loop, its stops and their state at the recording's start
        #: (False, the default: their columns are dropped, held at 0); the live form runs
        #: the loop wherever the file gives it a coefficient
        self.stops = bool(stops)
        #: with the stops, whether the loop's state at the recording's start is fitted too
        #: (offline only: the loop alone is the model-form alternative a term named where the
        #: gate left the loop out must also beat, :class:`cablesvc.discover.screen.BlockScreen`)
        self.initial = bool(initial)
        #: the damping columns' rate exponents (offline only: the baseline's own damping law
        #: with another exponent is a model-form alternative a named term must also beat;
        #: the file's law and the live form keep RATE_EXPONENTS)
        self.rate_exponents = tuple(float(a) for a in rate_exponents)
        if len(self.rate_exponents) != len(RATE_EXPONENTS):
            raise ValueError(f"rate_exponents: {len(RATE_EXPONENTS)} exponents, got {rate_exponents!r}")
        #: with the stops, whether the loop also has a part whose height grows with the force
        #: (the stops times f0 / mean f0 on the training ticks, c_fr [N at the mean force]):
        #: the friction between a rope's strands grows with the contact pressure, that is
        #: with the tension. Offline only, as a model-form alternative a named term must also
        #: beat (:class:`cablesvc.discover.screen.BlockScreen`, step 4): a pulley's bearing
        #: friction is a force-proportional loop too, and on the Bouc-Wen truth the
        #: recalibration's stops left one for it to fit on controls. The file and the live
        #: form have no such columns
        self.force_loop = bool(force_loop)
        if self.force_loop and not self.stops:
            raise ValueError("force_loop needs stops=True (it scales the loop's stops)")
        #: whether the fit also has the rope's own viscoelastic relaxation, Maxwell branches
        #: of RELAX_TAUS (:mod:`cablesvc.models.relaxation`; c_m<tau> [N per training std
        #: of the elongation]). Offline only, as a model-form alternative a term whose force
        #: is the force times a slow course (temperature) must also beat
        #: (:class:`cablesvc.discover.screen.BlockScreen`, step 4): on the Bouc-Wen truth the
        #: rope's loop left a slow force that the temperature's slow swing followed. The
        #: file and the live form have no such columns
        self.relax = bool(relax)
        #: as a model-form alternative, whether it spares the terms whose force follows time:
        #: a settling from the recording's start (``Term.settles``: creep) or a slow course
        #: (``Term.follows_slow_course``: temperature). Used for the rope's whole loop, its
        #: state at the start included, where the gate left the loop out: that state fades
        #: over the recording's first moves, as a settling does by construction and a slow
        #: drift can (it took true temperature cables on the default truth; docs/discovery.md,
        #: "A loop the gate left out"). The design is the same (the key too)
        self.spare_time = bool(spare_time)
        self.params, self.units = Recalibration.params, Recalibration.units
        if self.force_loop:
            self.params = self.params + FORCE_LOOP
            self.units = self.units + tuple("N" for _ in FORCE_LOOP)
        if self.relax:
            self.params = self.params + RELAX
            self.units = self.units + tuple("N" for _ in RELAX)

    @property
    def design_key(self) -> str:
        key = self.name
        if self.stops:
            key += "+loop" if self.initial else "+stops"
        if self.rate_exponents != RATE_EXPONENTS:
            key += "+rate" + ",".join(f"{a:g}" for a in self.rate_exponents)
        if self.force_loop:
            key += "+force"
        if self.relax:
            key += "+relax"
        return key

    def confronts(self, term: Term) -> bool:
        """Whether this recalibration, as a model-form alternative, is tried in the place of
        ``term`` (:class:`cablesvc.discover.screen.BlockScreen`, step 4): every term, except
        that each offline-only part narrows it. The loop growing with the force only
        confronts the terms whose force follows the direction of motion
        (``Term.follows_direction``: a loop, as it is). Tried on
        every term, it refused a true creep of the twin (a 20 s recording, cable 2: the term
        better by 5.6 noise variances, p = 0.09; its 3 mm stop times the force is nearly the
        elongation times the force, which follows a slow drift too; docs/discovery.md, "A
        loop that grows with the force"). The viscoelastic relaxation confronts only the
        terms whose force is the force times a slow course (``Term.follows_slow_course``:
        the temperature drift). With ``spare_time`` the terms whose force follows time (a
        settling or a slow course: creep, temperature) are spared."""
        return ((not self.force_loop or term.follows_direction)
                and (not self.relax or term.follows_slow_course)
                and not (self.spare_time and (term.settles or term.follows_slow_course)))

    def describe_alternative(self) -> str:
        """What this recalibration holds beyond the nuisance's default, in words (a model-form
        alternative's, :meth:`cablesvc.discover.screen.BlockScreen.select`)."""
        parts = []
        if self.stops:
            parts.append("the rope's own rate-independent loop (Prandtl-Ishlinskii stops"
                         + (" and their state at the start" if self.initial else "")
                         + (", with a part growing with the force)" if self.force_loop else ")"))
        if self.relax:
            parts.append("the rope's own viscoelastic relaxation (Maxwell branches of "
                         + " and ".join(f"{t:g}" for t in RELAX_TAUS) + " s)")
        if self.rate_exponents != RATE_EXPONENTS:
            parts.append("the baseline's own damping law (002 eq 8) with rate exponents "
                         + ", ".join(f"{a:g}" for a in self.rate_exponents))
        return " and ".join(parts) or "the baseline's recalibration"

    def refs(self, s, c, h):
        R = {**_backbone_refs(s, c), "A_mean": s.train_mean(s.amplitude[:, c]),
             "has_A": float(amplitude_varies(s, c)), "E_hi": _largest(envelope(s.x[:, c]), s.train)}
        if self.force_loop:
            R["f_mean"] = max(abs(s.train_mean(s.f0[:, c])), 1.0)
        amp = np.empty((len(_HELD), s.n))
        _AMPLITUDE.columns(cable_view(s, c), R, h, amp)
        for n, v in zip(_HELD, amp):
            R[f"lo_{n}"], R[f"hi_{n}"] = float(v[s.train].min()), float(v[s.train].max())
        return R

    def columns(self, g, R, h, out):
        self.law(g, R, h, envelope(g.x), out, self.rate_exponents)
        k = len(STOP_WIDTHS)
        stop_columns(g.x, np.asarray(STOP_WIDTHS), out[_N_BASE:_N_BASE + k])
        initial_state_columns(g.x, np.asarray(STOP_WIDTHS), out[_N_BASE + k:_N_BASE + 2 * k])
        j = _N_BASE + 2 * k
        if self.force_loop:                              # the stops times f0 / mean f0
            np.multiply(out[_N_BASE:_N_BASE + k], g.f0 / R["f_mean"], out=out[j:j + k])
            j += k
        if self.relax:                                   # Maxwell branches, per std of x
            relaxation_columns(g.t, g.x, np.asarray(RELAX_TAUS), out[j:j + len(RELAX_TAUS)])
            np.divide(out[j:j + len(RELAX_TAUS)], R["x_scale"], out=out[j:j + len(RELAX_TAUS)])

    @staticmethod
    def law(g, R, h, env, out, rate_exponents=RATE_EXPONENTS):
        """The columns before the stops (the first ``_N_BASE`` of ``out``) from the signals
        ``g`` and the elongation's envelope ``env`` [mm] (:func:`envelope` offline,
        :class:`_RecalibrationLive` live), which is clamped at ``E_hi`` in place: callers pass
        an array of their own. The loop's columns, which carry a state, are written by the
        caller (:func:`~cablesvc.models.play.stop_columns` and
        :func:`~cablesvc.models.play.initial_state_columns` offline,
        :class:`~cablesvc.models.play.LiveStops` live). ``rate_exponents``: the damping
        columns' exponents (another pair only for an offline model-form alternative)."""
        o, ks, ah, c2 = out[:4]
        o.fill(1.0)
        np.copyto(ks, g.f0)
        _hysteretic_part(g.f0, g.x, R, ah, c2)
        # the backbone curvature and the amplitude dependence are the laws of those terms
        _ASYMMETRIC.columns(g, R, h, out[3:5])           # xi^2 / s, xi^3 / s^2
        _AMPLITUDE.columns(g, R, h, out[5:7])            # (A - mean A) xi, A tanh(v / v_s)
        for n, col in zip(_HELD, out[5:7]):              # ... held within their support
            np.maximum(col, R[f"lo_{n}"], out=col)
            np.minimum(col, R[f"hi_{n}"], out=col)
        np.minimum(env, R["E_hi"], out=env)              # the level grows no further than fitted
        k = len(RATE_EXPONENTS)
        for a, col, col_e in zip(rate_exponents, out[7:7 + k], out[7 + k:_N_BASE]):
            rate_power(g.v, a, col)                      # 002 eq 8's damping rate law, its level free
            np.multiply(col, env, out=col_e)             # ... and its level growing with the envelope

    def live(self, table, lanes, m):
        lt = _RecalibrationLive(self, table, lanes, m)
        if "E_hi" not in table:                          # a file without it: the envelope unheld
            lt.R["E_hi"].fill(np.inf)
        for n in _HELD:                                  # a file without the bounds: unclamped
            for side, unbounded in (("lo", -np.inf), ("hi", np.inf)):
                if f"{side}_{n}" not in table:
                    lt.R[f"{side}_{n}"].fill(unbounded)
        return lt

    def design(self, s, c, h):
        d = super().design(s, c, h)
        if not self.stops:
            d = d.without(LOOP)
        elif not self.initial:
            d = d.without(INITIAL)
        return d if d.refs.get("has_A", 1.0) else d.without(_HELD)

    def evidence(self, s, c, h):
        return s.f0[:, c]

    def physical(self, params, h, s, c):
        f0 = s.f0[:, c]
        return {**params, "mean_f0_N": float(np.mean(f0)),
                "offset_at_mean_N": float(params.get("o", 0.0) + params.get("k_s", 0.0) * np.mean(f0))}


class _RecalibrationLive(LiveTerm):
    """The live form: the envelope's running extremes of the elongation per (lane, cable),
    from the first tick this term sees (as :func:`envelope` from the signals' first tick)."""

    def __init__(self, term, table, lanes, m):
        super().__init__(term, table, lanes, m)
        self.hi = np.zeros((lanes, m))
        self.lo = np.zeros((lanes, m))
        self.env = np.zeros((lanes, m))
        self.started = np.zeros(1, bool)
        # the stops from a relaxed start, then from full yield either way (their half
        # difference is the initial state's column)
        k = len(STOP_WIDTHS)
        self.stops = LiveStops(STOP_WIDTHS * 3, lanes, m, starts=[0.0] * k + [1.0] * k + [-1.0] * k)
        self.s = np.zeros((3 * k, lanes, m))
        self._bind_views(self.cols)
        # a file whose loop is all 0 (not taken, or written before it) leaves its rows at 0
        # and does not run it each tick
        self.loop = bool(np.any(self.P[_N_BASE:] != 0.0))

    def write(self, g):
        if not self.started[0]:
            np.copyto(self.hi, g.x)
            np.copyto(self.lo, g.x)
            self.started[0] = True
        np.fmax(self.hi, g.x, out=self.hi)               # a non-finite reading is passed over
        np.fmin(self.lo, g.x, out=self.lo)
        np.subtract(self.hi, self.lo, out=self.env)
        np.multiply(self.env, 0.5e3, out=self.env)
        self.term.law(g, self.R, self.H, self.env, self.cols)
        if self.loop:
            relaxed, up, down, stops, init = self._views
            self.stops.step(g.x, self.s)
            np.copyto(stops, relaxed)
            np.subtract(up, down, out=init)
            np.multiply(init, 0.5, out=init)

    def bind(self, cols, coef):
        super().bind(cols, coef)
        self._bind_views(cols)

    def _bind_views(self, cols):
        # the views the loop reads and writes through, made once per buffer (a slice per tick
        # would allocate): the relaxed, +1 and -1 stops, and the loop's rows of ``cols``
        k = len(STOP_WIDTHS)
        self._views = (self.s[:k], self.s[k:2 * k], self.s[2 * k:], cols[_N_BASE:_N_BASE + k], cols[_N_BASE + k:])

    def state_dict(self):
        return {"hi": self.hi.copy(), "lo": self.lo.copy(), "started": self.started.copy(),
                "play": self.stops.p.copy(), "play_started": self.stops.started.copy()}

    def load_state_dict(self, d):
        if "hi" not in d or np.shape(d["hi"]) != self.hi.shape:     # a state saved without it
            return
        np.copyto(self.hi, d["hi"])
        np.copyto(self.lo, d["lo"])
        np.copyto(self.started, d["started"])
        if "play" in d and np.shape(d["play"]) == self.stops.p.shape:  # saved before the loop: relaxed
            np.copyto(self.stops.p, d["play"])
            np.copyto(self.stops.started, d["play_started"])


_ASYMMETRIC = AsymmetricHardening()
_AMPLITUDE = AmplitudeStiffness()
