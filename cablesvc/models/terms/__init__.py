"""Physics terms: the library discovery chooses from and the kernel runs live, one class each.

A term is a small parameterised physical model of the force a baseline cable model leaves
out. It adds, to the baseline prediction ``f0`` of one cable, a correction

    delta_f(t) = fixed(t; h) + X(t; h) @ p          [N]

where ``p`` are the term's *linear* parameters (fitted by bounded linear least squares,
fast and stable) and ``h`` its few *nonlinear* hyper-parameters (a time constant, a dead
time, a regularisation speed, the shape of a Bouc-Wen loop), searched on a short grid
(:meth:`Term.grid`) and, for dead time, refined by a bounded scalar search. Every term
names its paper equation and the units of its parameters; :meth:`Term.physical` turns the
fitted numbers into the physical ones the report prints.

The library (:data:`LIBRARY`) is open: a new term is one subclass with ``name``,
``label``, ``equation``, its parameter spec (``params``, ``units``, ``lower``, ``hypers``,
``ref_names``), ``applies``, ``grid``, ``refs`` and its law in ``columns`` / ``fixed_part``
(and optionally ``physical``/``evidence``), registered with :func:`register`. The same
law gives the offline form (:meth:`Term.design`, the columns discovery fits over a
recording) and the live form (:meth:`Term.live`, run every tick by the kernel through
:class:`TermStack` over (lanes, cables), in fixed time), so a new term runs live without
touching the kernel. Terms with state (Bouc-Wen z, the dead-time line, the amplitude
tracker, the creep clock) keep it in the stack's :meth:`TermStack.state_dict`. Terms only
see the :class:`Signals` of a recording (what a controller logs, the kinematics and the
baseline's prediction), never any simulation ground truth.

Units: SI throughout (m, s, N, K, rad).

The package, one purpose a module:

* :mod:`~cablesvc.models.terms.signals`: what a term sees (:class:`Signals`,
  :class:`CableView`) and what it contributes to a fit (:class:`Design`);
* :mod:`~cablesvc.models.terms.base`: the protocol (:class:`Term`), the library's registry
  (:data:`LIBRARY`, :func:`register`, :func:`library`) and the generic live form
  (:class:`LiveTerm`);
* the library's terms by family, each term with its own live form beside it:
  :mod:`~cablesvc.models.terms.path` (pulley, sag), :mod:`~cablesvc.models.terms.drift`
  (creep, temperature), :mod:`~cablesvc.models.terms.material` (viscous, amplitude,
  asymmetric), :mod:`~cablesvc.models.terms.sensor` (dead time, offset and gain) and
  :mod:`~cablesvc.models.terms.hysteresis` (Bouc-Wen);
* :mod:`~cablesvc.models.terms.recalibration`: the baseline's own recalibration;
* :mod:`~cablesvc.models.terms.catalogue`: the registration in the library's order (a new
  term of the default library is registered there) and :func:`term_class`;
* :mod:`~cablesvc.models.terms.live`: the stack that runs a parameter file's terms in the
  kernel (:class:`TermStack`, the dead-time delay line); the amplitude tracker it runs is
  :class:`cablesvc.models.reversal.LiveReversalAmplitude`.
"""

from __future__ import annotations

from cablesvc.models.terms.base import LIBRARY, LiveTerm, Term, library, register
from cablesvc.models.terms.catalogue import term_class
from cablesvc.models.terms.drift import Creep, TemperatureStiffness
from cablesvc.models.terms.hysteresis import BoucWenHysteresis, bouc_wen_z
from cablesvc.models.terms.live import DELAY_WINDOW_S, TermStack
from cablesvc.models.terms.material import AmplitudeStiffness, AsymmetricHardening, Viscous
from cablesvc.models.terms.path import PulleyFriction, Sag
from cablesvc.models.terms.recalibration import Recalibration, hysteretic_part
from cablesvc.models.terms.sensor import DeadTime, OffsetGain
from cablesvc.models.terms.signals import CableView, Design, Signals, cable_view, make_design, smooth_sign

__all__ = [
    "LIBRARY", "Signals", "Term", "Design", "make_design", "register", "library", "PulleyFriction", "Creep",
    "TemperatureStiffness", "Viscous", "AmplitudeStiffness", "AsymmetricHardening", "Sag", "DeadTime",
    "OffsetGain", "BoucWenHysteresis", "Recalibration", "bouc_wen_z", "hysteretic_part",
    "smooth_sign", "CableView", "cable_view", "LiveTerm", "TermStack", "term_class", "DELAY_WINDOW_S",
]
