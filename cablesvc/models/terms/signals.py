"""What a term sees: the signals of a recording (:class:`Signals`), one cable's view of them
or of the live buffers (:class:`CableView`), and the design a term contributes to a fit
(:class:`Design`), with the smoothed sign the friction-like laws share (:func:`smooth_sign`).

Units: SI throughout (m, s, N, K, rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

__all__ = ["Signals", "Design", "make_design", "smooth_sign", "CableView", "cable_view"]


@dataclass
class Signals:
    """Per-tick signals of one recording, arrays (N,) or (N, m), SI units.

    ``t`` time from the start [s]; ``dt`` tick period [s]; ``y`` measured force [N];
    ``f0`` the baseline model's predicted force [N]; ``x`` elongation l(pose) -
    motor_length [m]; ``v`` its rate dx/dt [m/s]; ``v_slide`` haul-in speed over the pulley
    -d(motor_length)/dt [m/s]; ``wrap`` pulley wrap angle [rad] (0 without pulley);
    ``free_length`` free cable length [m]; ``temperature`` [deg C] (None when not recorded);
    ``ea`` nominal E*A per cable [N]; ``has_pulley`` (m,) bool; ``amplitude`` elongation
    amplitude from the last reversal points [m]
    (:func:`cablesvc.models.reversal.reversal_amplitude`);
    ``train`` (N,) bool: the ticks a term may use to fix data-dependent references (means)
    so nothing of the held-out blocks leaks into the design; ``travel`` the motor length,
    the cable the winch has paid out [m] (None where a caller did not give it: the free
    length stands in for it).
    """

    t: np.ndarray
    dt: float
    y: np.ndarray
    f0: np.ndarray
    x: np.ndarray
    v: np.ndarray
    v_slide: np.ndarray
    wrap: np.ndarray
    free_length: np.ndarray
    temperature: Optional[np.ndarray]
    ea: np.ndarray
    has_pulley: np.ndarray
    amplitude: np.ndarray
    train: np.ndarray
    cable_names: tuple[str, ...] = ()
    travel: Optional[np.ndarray] = None

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def m(self) -> int:
        return int(self.y.shape[1])

    def train_mean(self, a: np.ndarray) -> float:
        return float(np.mean(a[self.train]))

    def delayed(self, tau: float) -> "Signals":
        """These signals with the elongation and what follows from it (x, v, amplitude and
        the baseline force f0) delayed by ``tau`` [s] (held at the first value before
        t0 + tau): what the force-stage terms see when the force follows the elongation
        of tau seconds ago (dead time). Pose-side signals (wrap, v_slide, free length,
        temperature) are not delayed."""
        if tau <= 0:
            return self
        import copy as _copy

        def sh(a):
            a2 = a.reshape(a.shape[0], -1)
            out = np.column_stack([np.interp(self.t - tau, self.t, a2[:, j]) for j in range(a2.shape[1])])
            return out.reshape(a.shape)

        d = _copy.copy(self)
        d.f0, d.x, d.v, d.amplitude = sh(self.f0), sh(self.x), sh(self.v), sh(self.amplitude)
        return d


@dataclass
class Design:
    """What a term contributes to one cable's fit: ``fixed`` (N,) [N] a column with no free
    coefficient (or None), ``X`` (N, p) the columns of the linear parameters, their
    ``names``, ``units`` and bounds ``lower``/``upper``."""

    fixed: Optional[np.ndarray]
    X: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    #: linear parameters left out of the fit (held at 0), e.g. a nuisance gain owned by
    #: another term on the same cable
    dropped: tuple[str, ...] = ()
    #: reference values the columns took from the training ticks (:meth:`Term.refs`)
    refs: dict = field(default_factory=dict)
    #: columns held within the range they took on the ticks they were fitted on (an
    #: empirical correction with no law outside its support); a leave-one-block-out fit
    #: holds them within the range of its own fitted ticks (:func:`cablesvc.discover.evidence.loo_errors`)
    held: tuple[str, ...] = ()

    @property
    def p(self) -> int:
        return int(self.X.shape[1])

    def without(self, names: tuple[str, ...]) -> "Design":
        """This design with the columns ``names`` left out (held at 0)."""
        keep = [i for i, n in enumerate(self.names) if n not in names]
        gone = tuple(n for n in self.names if n in names)
        if not gone:
            return self
        return Design(fixed=self.fixed, X=self.X[:, keep], names=tuple(self.names[i] for i in keep),
                      units=tuple(self.units[i] for i in keep), lower=self.lower[keep], upper=self.upper[keep],
                      dropped=self.dropped + gone, refs=self.refs, held=tuple(n for n in self.held if n not in gone))

    def only(self, names: tuple[str, ...]) -> "Design":
        """Only the columns ``names`` (no fixed part)."""
        keep = [i for i, n in enumerate(self.names) if n in names]
        return Design(fixed=None, X=self.X[:, keep], names=tuple(self.names[i] for i in keep),
                      units=tuple(self.units[i] for i in keep), lower=self.lower[keep], upper=self.upper[keep],
                      refs=self.refs, held=tuple(n for n in self.held if n in names))


def make_design(cols: list[np.ndarray], names, units, lower=None, upper=None, fixed=None,
            refs: Optional[dict[str, float]] = None, held: tuple[str, ...] = ()) -> Design:
    n = len(cols)
    X = np.column_stack(cols) if cols else np.zeros((0, 0))
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, float)
    return Design(fixed=fixed, X=X, names=tuple(names), units=tuple(units), lower=lo, upper=hi,
                  refs=dict(refs or {}), held=tuple(n for n in held if n in names))


def smooth_sign(v: np.ndarray, v_s: Any, out: Optional[np.ndarray] = None) -> np.ndarray:
    """tanh(v / v_s): the sign of v, smoothed over the speed ``v_s`` [m/s] (into ``out``
    when given: the live form's buffers)."""
    out = np.divide(v, v_s, out=out)
    return np.tanh(out, out=out)


@dataclass
class CableView:
    """One cable's signals (N,) for the offline form of a term (see :class:`Signals`), or
    the live signals (lanes, m): terms write their law once over whatever shape this has."""

    t: Any
    f0: np.ndarray
    x: np.ndarray
    v: np.ndarray
    v_slide: np.ndarray
    wrap: np.ndarray
    free_length: np.ndarray
    temperature: Any
    amplitude: np.ndarray


def cable_view(s: Signals, c: int) -> CableView:
    return CableView(t=s.t - s.t[0], f0=s.f0[:, c], x=s.x[:, c], v=s.v[:, c], v_slide=s.v_slide[:, c],
                     wrap=s.wrap[:, c], free_length=s.free_length[:, c], temperature=s.temperature,
                     amplitude=s.amplitude[:, c])
