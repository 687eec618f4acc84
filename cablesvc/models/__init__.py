"""Cable force models. Pure numpy, no I/O. See :mod:`cablesvc.models.base` for the protocol."""

from cablesvc.models.amplitude import AmplitudeDependent
from cablesvc.models.asymmetric import AsymmetricBoucWen
from cablesvc.models.base import CableModel, ModelParameterError, ModelState, loop_area, simulate
from cablesvc.models.boucwen import BoucWen, bouc_wen_bound, from_benchmark, to_benchmark
from cablesvc.models.linear import LinearElastic
from cablesvc.models.polynomial import PolynomialHysteresis

#: model name -> class, as used in parameter files and on the command line (the default,
#: amplitude, first: identification lists them in this order)
MODELS = {cls.name: cls for cls in (AmplitudeDependent, LinearElastic, PolynomialHysteresis, BoucWen, AsymmetricBoucWen)}

__all__ = [
    "MODELS", "CableModel", "ModelState", "ModelParameterError", "simulate", "loop_area",
    "LinearElastic", "PolynomialHysteresis", "AmplitudeDependent", "BoucWen", "AsymmetricBoucWen",
    "bouc_wen_bound", "from_benchmark", "to_benchmark",
]
