"""What the detectors of the residual (measured - predicted force, per cable) share.

:class:`~cablesvc.alarms.drift.DriftDetector` (its mean) and
:class:`~cablesvc.alarms.spread.SpreadDetector` (its spread) weigh every sample by the same
law and run the same way:

- :func:`_sample_dt`: the weight of a sample is the time since the cable's previous valid
  sample, at most ``max_dt_s`` (a gap in the measurements does not count as evidence), so
  every sum is an integral over time and the tuning does not depend on the tick rate;
- :func:`_ewma_gain`: an EWMA with a time constant in seconds;
- :class:`ResidualDetector`: the per-tick :meth:`~ResidualDetector.update` (one numba call
  for all cables, no allocation unless an event happens), the block-wise
  :meth:`~ResidualDetector.update_batch` running the same compiled per-sample code (so both
  give bit-identical states and events), and the snapshot of the state.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from cablesvc.alarms import ALARM_CODES, AlarmEvent, _jit_inline

__all__ = ["RUN_SIGNATURE", "STEP_SIGNATURE", "ResidualDetector", "block_samples", "tick_samples"]

# event record columns every residual detector starts its records with
E_ROW, E_CABLE = 0, 1


@_jit_inline
def _sample_dt(t, t_last, max_dt):
    """Weight [s] of a sample at time t after the cable's previous valid one at t_last: the
    time between them, 0 when time stands still or goes back (or t_last is NaN), at most
    max_dt."""
    dt = t - t_last
    if not dt > 0.0:
        dt = 0.0
    if dt > max_dt:
        dt = max_dt
    return dt


@_jit_inline
def _ewma_gain(dt, tau):
    """Gain of one sample of weight dt [s] in an EWMA of time constant tau [s]:
    e += dt / (tau + dt) * (x - e), the exact implicit discretisation (no transcendental
    function, so the tick-by-tick and batch paths round identically)."""
    return dt / (tau + dt)


#: numba signatures of a detector's per-tick kernel (S, P, t, r, E) -> records and per-block
#: kernel (S, P, T, R, E, row0) -> (records, next row); see :func:`tick_samples`, :func:`block_samples`
STEP_SIGNATURE = "int64(float64[:, ::1], float64[::1], float64, float64[::1], float64[:, ::1])"
RUN_SIGNATURE = ("UniTuple(int64, 2)(float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], "
                 "float64[:, ::1], int64)")


@_jit_inline
def tick_samples(sample, S, P, t, r, E):
    """One tick: ``sample`` (S, P, t, r, i, E, ne, row) -> records (a detector's inline
    per-sample kernel, which appends cable i's raise/clear records to E[ne:]) on sample
    r[i] of every cable at time t. Returns the number of event records."""
    ne = 0
    for i in range(S.shape[1]):
        ne = sample(S, P, t, r[i], i, E, ne, 0)
    return ne


@_jit_inline
def block_samples(sample, S, P, T, R, E, row0):
    """Ticks row0.. of a block (T (n,) [s], R (n, m) [N]) through ``sample`` (as
    :func:`tick_samples`), until the end of the block or until E cannot hold one more
    tick's records. Returns (records, next row). The same per-sample code as the per-tick
    path, so both give bit-identical states and events."""
    m = S.shape[1]
    cap = E.shape[0]
    ne = 0
    row = row0
    n = T.shape[0]
    while row < n and ne + m <= cap:
        t = T[row]
        for i in range(m):
            ne = sample(S, P, t, R[row, i], i, E, ne, row)
        row += 1
    return ne, row

class ResidualDetector:
    """Shell of a per-cable detector of the residual [N].

    ``n_cables`` m; ``config`` the subclass's ``config_class`` (default: its defaults);
    ``cable_names`` for the messages. A subclass sets ``code`` (its alarm code),
    ``config_class``, ``n_state`` (rows of its (n_state, m) state),
    ``n_record`` (columns of its event records, starting with row and cable), the numba
    kernels ``_step`` (S, P, t, r, E) -> records and ``_run`` (S, P, T, R, E, row0) ->
    (records, next row) as staticmethods, :meth:`reset` (cables -> their state at rest;
    called here for all) and :meth:`_event` (one record -> AlarmEvent).
    ``config`` must have ``as_array()`` (the kernel's parameter vector).
    """

    code = ""
    config_class: Any = None
    n_state = 0
    n_record = 2
    _step: Any = None
    _run: Any = None

    def __init__(self, n_cables: int, config=None, cable_names: Sequence[str] | None = None):
        self.n_cables = m = int(n_cables)
        if m < 1:
            raise ValueError("n_cables must be >= 1")
        self.config = config if config is not None else self.config_class()
        self.cable_names = tuple(cable_names) if cable_names is not None else tuple(f"cable{i}" for i in range(m))
        if len(self.cable_names) != m:
            raise ValueError(f"{len(self.cable_names)} cable names for {m} cables")
        self._P = self.config.as_array()
        self._S = np.zeros((self.n_state, m))
        self._E = np.zeros((m, self.n_record))                    # one tick: at most one record per cable
        self._Eb = np.zeros((max(4096, 4 * m), self.n_record))   # batch
        self._shape = (m,)
        self._severity = ALARM_CODES[self.code][0]
        self.reset()

    def update(self, t: float, seq: int | None, residual: np.ndarray) -> list[AlarmEvent]:
        """One tick: ``residual`` (m,) measured - predicted [N], NaN where a cable has no
        measurement (skipped). ``t`` controller time [s]. Returns the events of this tick."""
        if type(residual) is not np.ndarray or residual.shape != self._shape:
            residual = self._coerce(residual)
        try:
            n = self._step(self._S, self._P, t, residual, self._E)
        except TypeError:                      # int t, other dtype, read-only or strided array
            n = self._step(self._S, self._P, float(t), self._coerce(residual), self._E)
        if n == 0:
            return []
        return [self._event(self._E[j], float(t), seq) for j in range(n)]

    def update_batch(self, t, residual_block, seq=None) -> list[AlarmEvent]:
        """A block of ticks at once: ``t`` (n,) [s], ``residual_block`` (n, m) [N]. ``seq``:
        None, the seq of the first row (then +1 per row) or an (n,) array. Returns the same
        events, in the same order, with the same state afterwards, as n calls of :meth:`update`."""
        T = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        R = np.ascontiguousarray(residual_block, dtype=np.float64)
        if R.ndim != 2 or R.shape[1] != self.n_cables or R.shape[0] != T.shape[0]:
            raise ValueError(f"residual_block must be (n, {self.n_cables}) with n = len(t) = {T.shape[0]}, "
                             f"got {R.shape}")
        if not R.flags.writeable:                     # numba signature wants writable arrays
            R = R.copy()
        if not T.flags.writeable:
            T = T.copy()
        seqs = None if seq is None or np.ndim(seq) == 0 else np.asarray(seq).reshape(-1)
        events: list[AlarmEvent] = []
        row = 0
        n = T.shape[0]
        E = self._Eb
        while row < n:
            ne, row = self._run(self._S, self._P, T, R, E, row)
            for j in range(ne):
                r = int(E[j, E_ROW])
                if seq is None:
                    s = None
                elif seqs is None:
                    s = int(seq) + r
                else:
                    s = int(seqs[r])
                events.append(self._event(E[j], float(T[r]), s))
        return events

    def _coerce(self, residual) -> np.ndarray:
        r = np.array(residual, dtype=np.float64, order="C", copy=True).reshape(-1)
        if r.shape != self._shape:
            raise ValueError(f"residual must have {self.n_cables} values (one per cable), got shape {np.shape(residual)}")
        return r

    def state_dict(self) -> dict[str, np.ndarray]:
        """The detector's complete state (numeric arrays only; for the daemon's snapshots)."""
        return {"state": self._S.copy(), "params": self._P.copy()}

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state_dict`. The state must be of the same cable count; the
        tuning stays this detector's own config."""
        S = np.asarray(d["state"], dtype=np.float64)
        if S.shape != self._S.shape:
            raise ValueError(f"{self.code} state of shape {S.shape} does not fit {self.n_cables} cables")
        self._S[...] = S
