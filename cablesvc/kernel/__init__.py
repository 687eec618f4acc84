"""The fixed-time per-tick kernel the live service calls."""

from cablesvc.kernel.predictor import Predictor, TickOutput

__all__ = ["Predictor", "TickOutput"]
