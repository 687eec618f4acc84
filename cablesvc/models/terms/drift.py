"""Slow drifts of the force: creep and settling over time (:class:`Creep`) and the
temperature dependence of the stiffness (:class:`TemperatureStiffness`).
"""

from __future__ import annotations

import numpy as np

from cablesvc.models.terms.base import Term

__all__ = ["Creep", "TemperatureStiffness"]


class Creep(Term):
    """Creep and settling (002 Fig 6: the force drifts away from the identified model over
    time). The unstretched length grows by a settling part and a steady creep,

        delta_l(t) = d0 + a (1 - exp(-t / tau)) + b t,        delta_f = -k delta_l(t)

    with k = EA / L the nominal stiffness at the mean free length. a [m] >= 0, b [m/s] >= 0,
    tau [s] on a grid of fractions of the analysed span, then refined by a bounded scalar
    search. t is the time since the analysis' start offline (the recording's start, or
    ``discover --since``), and since the creep clock's start live (``terms_clock_origin``
    of the file, kept in the daemon's snapshot across restarts). d0 [m] is the creep the
    cable already had when the clock started (a cable found creeping after an alarm has
    crept since before it): a constant, so it is a nuisance column, held at 0 where the
    sensor offset (``offset_gain``) already carries the constant, and the creep term must
    explain more than it alone."""

    name = "creep"
    label = "creep and settling drift"
    equation = "-k (d0 + a (1 - exp(-t/tau)) + b t), k = EA/L  (002 Fig 6)"
    variable = "time since start [s]"
    params = ("a", "b", "d0")
    units = ("m", "m/s", "m")
    lower = (0.0, 0.0, -np.inf)
    nuisance = ("d0",)
    hypers = ("tau",)
    ref_names = ("k",)
    n_hyper = 1
    settles = True
    refine_hyper = "tau"
    refine_bounds = (0.1, 1e6)

    def grid(self, s):
        T = float(s.t[-1] - s.t[0]) or 1.0
        return [{"tau": fr * T} for fr in (0.03, 0.1, 0.25, 0.5, 1.0, 2.0)]

    def refs(self, s, c, h):
        return {"k": float(s.ea[c] / s.train_mean(s.free_length[:, c]))}

    def columns(self, g, R, h, out):
        o0, o1, o2 = out
        np.negative(R["k"], out=o2)                    # -k (the creep before the clock's start)
        np.divide(g.t, h["tau"], out=o0)
        np.negative(o0, out=o0)
        np.expm1(o0, out=o0)
        np.multiply(o0, R["k"], out=o0)                # -k (1 - exp(-t/tau)) = k expm1(-t/tau)
        np.multiply(g.t, R["k"], out=o1)
        np.negative(o1, out=o1)                        # -k t

    def evidence(self, s, c, h):
        return s.t - s.t[0]


class TemperatureStiffness(Term):
    """Temperature-dependent stiffness: the cable's modulus scales as
    k(T) = k (1 + c_T (T - T_ref)), so the force becomes f (1 + c_T (T - T_ref)):

        delta_f = f (c_T (T - T_mean) + g),   g = c_T (T_mean - T_ref)

    c_T [1/K], g [-]; needs the recording's temperature channel. Live, a tick without a
    temperature on the bus takes T = T_mean (the temperature part is 0, the gain g stays)."""

    name = "temperature"
    label = "temperature-dependent stiffness"
    equation = "f (c_T (T - T_mean) + g)"
    variable = "temperature x force, (T - T_mean) f [K N]"
    params = ("c_T", "g")
    units = ("1/K", "-")
    ref_names = ("T_mean",)
    nuisance = ("g",)
    follows_slow_course = True

    def applies(self, s, c):
        return s.temperature is not None and float(np.ptp(s.temperature)) > 0.05

    def refs(self, s, c, h):
        return {"T_mean": s.train_mean(s.temperature)}

    def columns(self, g, R, h, out):
        o0, o1 = out
        np.subtract(g.temperature, R["T_mean"], out=o0)
        # no temperature (NaN): T = T_mean. min(y, 0) + max(y, 0) is y exactly, and fmin/fmax
        # take 0 for NaN (three ufuncs, no allocation; np.nan_to_num costs ~15 us a tick)
        np.fmin(o0, 0.0, out=o1)
        np.fmax(o0, 0.0, out=o0)
        np.add(o0, o1, out=o0)
        np.multiply(o0, g.f0, out=o0)
        np.copyto(o1, g.f0)

    def evidence(self, s, c, h):
        return (s.temperature - np.mean(s.temperature)) * s.f0[:, c]
