"""The elastic curve of the twin's base model: what the twin's controller inverts.

The controller of the digital twin (:mod:`cablesvc.simulate.twin`) turns a wanted force
into a commanded elongation with its nominal model: the truth's base model
(:mod:`cablesvc.simulate.truth`) without hysteresis and effects. :class:`ElasticCurve`
is that curve, its stiffness and its inverse. Units: SI (m, N).
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from cablesvc.config.params import ModelParams
from cablesvc.errors import SimulationError
from cablesvc.models import AmplitudeDependent, CableModel

__all__ = ["ElasticCurve"]


class ElasticCurve:
    """The elastic (rate-independent, hysteresis-free) force of a base model, F_el(x) [N].

    This is what the twin's controller uses to turn a wanted force into a commanded
    elongation (its nominal model: the truth base model without hysteresis and effects).

    * Amplitude model (002 eq 8): its backbone ``K0 + K1 xi + K2 xi^2 + K3 xi^3`` with
      ``xi = x - x_center`` (:meth:`~cablesvc.models.amplitude.AmplitudeDependent.backbone_force`,
      the model's own law), with K0..K3 interpolated *linearly* in the raw amplitude tables
      at the amplitude A [m] (clamped to the table range, as the model does). This
      deliberately differs from the model's step, which reads the nearest point of a
      resampled grid: the twin's truth keeps its own interpolation (its numbers must not
      move). Without an amplitude, the amplitude the model assumes at rest
      (``amplitude_init``) is used.
    * Any other model: the model's force at rest at x, averaged over both directions of
      motion (so the friction-like part of the polynomial model cancels; Bouc-Wen starts
      with z = 0). The linear model gets ``l0 = length - x`` when ``length`` is given.

    Arrays broadcast over a leading batch axis; the last axis is the cable axis (m,).
    """

    def __init__(self, params: ModelParams, n_cables: int):
        self.params = params
        self.n_cables = int(n_cables)
        self._model = params.build(self.n_cables, 1)
        self.is_amplitude = isinstance(self._model, AmplitudeDependent)
        if self.is_amplitude:
            mdl = self._model
            self.amplitude_grid = np.array(mdl.amplitude_grid)
            self.rest_amplitude: Optional[np.ndarray] = np.array(mdl.params["amplitude_init"][0])
            self.max_amplitude: Optional[float] = float(self.amplitude_grid[-1])
        else:
            self.amplitude_grid = None
            self.rest_amplitude = None
            self.max_amplitude = None
        self._batch_models: dict[int, CableModel] = {}

    # -- evaluation ----------------------------------------------------------------
    def force(self, x: Any, amplitude: Any = None, length: Any = None) -> np.ndarray:
        """Elastic force [N] at elongation ``x`` [m] (..., m); ``amplitude`` [m] scalar or
        broadcastable to x (amplitude model only); ``length`` [m] the geometric length l, so
        that the unstretched length is ``l0 = l - x`` (linear model only)."""
        x = np.asarray(x, dtype=np.float64)
        if self.is_amplitude:
            A = self.rest_amplitude if amplitude is None else np.asarray(amplitude, dtype=np.float64)
            return self._model.backbone_force(x, A, interpolation="linear")
        return self._force_at_rest(x, length)

    def _force_at_rest(self, x: np.ndarray, length: Any) -> np.ndarray:
        m = self.n_cables
        flat = x.reshape(-1, m)
        l0 = None
        if length is not None:
            l0 = (np.broadcast_to(np.asarray(length, dtype=np.float64), x.shape) - x).reshape(-1, m)
        out = np.empty_like(flat)
        chunk = 4096
        for a in range(0, flat.shape[0], chunk):
            xb = flat[a:a + chunk]
            B = xb.shape[0]
            model = self._batch_models.get(B)
            if model is None:
                model = self.params.build(m, B)
                self._batch_models[B] = model
            lb = None if l0 is None else l0[a:a + chunk]
            acc = np.zeros((B, m))
            for direction in (1.0, -1.0):
                st = model.create_state(xb)
                if hasattr(st, "direction"):
                    st.direction[...] = direction
                acc += model.step(st, xb, 1e-3, lb)
            out[a:a + chunk] = 0.5 * acc
        return out.reshape(x.shape)

    def stiffness(self, x: Any, amplitude: Any = None, length: Any = None, h: float = 1e-7) -> np.ndarray:
        """dF_el/dx [N/m] by central differences of step ``h`` [m]."""
        x = np.asarray(x, dtype=np.float64)
        return (self.force(x + h, amplitude, length) - self.force(x - h, amplitude, length)) / (2 * h)

    def elongation(self, force: Any, amplitude: Any = None, length: Any = None,
                   tol: float = 1e-9, max_iter: int = 60) -> np.ndarray:
        """Elongation x [m] with ``force(x, amplitude, length) == force`` [N] (Newton on a
        monotone curve, vectorised). Raises SimulationError when it does not converge (a
        force the elastic curve cannot reach)."""
        F = np.asarray(force, dtype=np.float64)
        if F.shape[-1] != self.n_cables:
            raise SimulationError(f"elongation(): last axis must be the {self.n_cables} cables, got {F.shape}")
        k0 = self.stiffness(np.zeros(F.shape) + 1e-3, amplitude, length)
        x = np.where(k0 > 0, F / np.where(k0 > 0, k0, 1.0), 1e-3)
        scale = np.maximum(1.0, np.abs(F))
        for _ in range(max_iter):
            r = self.force(x, amplitude, length) - F
            if np.all(np.abs(r) <= tol * scale):
                return x
            k = self.stiffness(x, amplitude, length)
            if np.any(~np.isfinite(k)) or np.any(k <= 0):
                break
            x = x - r / k
        raise SimulationError(
            f"cannot find the elongation for forces {np.min(F):.3g}..{np.max(F):.3g} N on the base "
            f"model's elastic curve ({self.params.model}); is the model's stiffness positive there?")
