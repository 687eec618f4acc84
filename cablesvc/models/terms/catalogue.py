"""The default library in its order, and the terms a parameter file may name.

The order of registration is the order of :data:`~cablesvc.models.terms.base.LIBRARY` and
of :func:`~cablesvc.models.terms.base.library`: discovery fits and reports the terms in it,
and its results depend on it.
"""

from __future__ import annotations

from cablesvc.models.terms.base import LIBRARY, Term, register
from cablesvc.models.terms.drift import Creep, TemperatureStiffness
from cablesvc.models.terms.hysteresis import BoucWenHysteresis
from cablesvc.models.terms.material import AmplitudeStiffness, AsymmetricHardening, Viscous
from cablesvc.models.terms.path import PulleyFriction, Sag
from cablesvc.models.terms.recalibration import Recalibration
from cablesvc.models.terms.sensor import DeadTime, OffsetGain

__all__ = ["term_class"]


for _t in (PulleyFriction(), Creep(), TemperatureStiffness(), Viscous(), AmplitudeStiffness(),
           AsymmetricHardening(), Sag(), DeadTime(), OffsetGain(), BoucWenHysteresis()):
    register(_t)


def term_class(name: str) -> Term:
    """The term a parameter file names ``name``: one of the library or the baseline's
    recalibration."""
    if name == Recalibration.name:
        return Recalibration()
    if name not in LIBRARY:
        raise KeyError(f"unknown term {name!r}; known: {', '.join([Recalibration.name, *LIBRARY])}")
    return LIBRARY[name]
