"""The result object every identification routine returns.

:class:`IdentifyResult` follows :class:`scipy.optimize.OptimizeResult`: a dict whose keys
are also attributes. Fields always present:

``x``        best parameter vector, ``(n,)``, in the units of the parameters
``fun``      objective value at ``x`` (float; for PSO on the eq 25 objective of paper 000
             it is the normalised MSE, dimensionless; for least squares it is
             ``0.5 * sum(residual**2)`` in the squared residual unit)
``nfev``     number of objective evaluations (one per particle per PSO iteration)
``nit``      number of iterations
``success``  whether the method reports convergence
``message``  human-readable reason for stopping
``names``    parameter names (list of str) or None
``history``  best objective after every iteration (``np.ndarray``; element 0 is the
             initial population / start point)

Fields filled when the method computes them: ``jac`` (Jacobian of the residuals at
``x``, ``(N, n)``), ``residual`` (``(N,)``), ``stderr`` (standard errors of ``x``),
``correlation`` (``(n, n)`` parameter correlation matrix), ``cond`` (condition number of
the Jacobian), ``method`` (str), and method-specific extras (``starts_result`` of the
multi-start SQP, ``population`` of PSO ...).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

__all__ = ["IdentifyResult"]


class IdentifyResult(OptimizeResult):
    """Result of an identification: dict with attribute access (see module docstring)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.setdefault("names", None)
        self.setdefault("history", np.empty(0))
        self.setdefault("success", False)
        self.setdefault("message", "")
        self.setdefault("nfev", 0)
        self.setdefault("nit", 0)

    def as_dict(self) -> dict[str, float]:
        """Best parameters as ``{name: value}`` (names ``p0, p1, ...`` when unnamed)."""
        x = np.atleast_1d(np.asarray(self["x"], dtype=float))
        names = self.get("names") or [f"p{i}" for i in range(x.size)]
        return {str(n): float(v) for n, v in zip(names, x)}

    def summary(self) -> str:
        """A few lines: method, objective, and each parameter with its standard error."""
        lines = [f"{self.get('method', 'identify')}: fun={float(self['fun']):.6g} nfev={self['nfev']} "
                 f"nit={self['nit']} success={self['success']} ({self['message']})"]
        se = self.get("stderr")
        for i, (n, v) in enumerate(self.as_dict().items()):
            s = "" if se is None else f" +- {float(np.asarray(se)[i]):.3g}"
            lines.append(f"  {n} = {v:.6g}{s}")
        return "\n".join(lines)
