"""What the detectors of the residual (measured - predicted force, per cable) share.

:class:`~cablesvc.alarms.drift.DriftDetector` (its mean) and
:class:`~cablesvc.alarms.spread.SpreadDetector` (its spread) weigh every sample by the same
law and run the same way:

- :func:`sample_dt`: the weight of a sample is the time since the cable's previous valid
  sample, at most ``max_dt_s`` (a gap in the measurements does not count as evidence), so
  every sum is an integral over time and the tuning does not depend on the tick rate;
- :func:`ewma_gain`: an EWMA with a time constant in seconds;
- :class:`ResidualDetector`: the per-tick :meth:`~ResidualDetector.update` (one numba call
  for all cables, no allocation unless an event happens), the block-wise
  :meth:`~ResidualDetector.update_batch` running the same compiled per-sample code (so both
  give bit-identical states and events), and the snapshot of the state.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from cablesvc.alarms import ALARM_CODES, AlarmEvent, jit_inline

__all__ = ["RUN_SIGNATURE", "STEP_SIGNATURE", "ResidualDetector", "block_samples", "tick_samples"]

# event record columns every residual detector starts its records with
E_ROW, E_CABLE = 0, 1


@jit_inline
def sample_dt(t, t_last, max_dt):
    """Weight [s] of a sample at time t after the cable's previous valid one at t_last: the
    time between them, 0 when time stands still or goes back (or t_last is NaN), at most
    max_dt."""
    dt = t - t_last
    if not dt > 0.0:
        dt = 0.0
    if dt > max_dt:
        dt = max_dt
    return dt


@jit_inline
def ewma_gain(dt, tau):
    """Gain of one sample of weight dt [s] in an EWMA of time constant tau [s]:
    e += dt / (tau + dt) * (x - e), the exact implicit discretisation (no transcendental
    function, so the tick-by-tick and batch paths round identically)."""
    return dt / (tau + dt)


# Each detector module writes its own two-line wrappers (``_drift_step``/``_drift_run``,
# ``_spread_step``/``_spread_run``) around tick_samples/block_samples on purpose: numba needs
# one concrete, module-level function per detector to compile it at import with an explicit
# signature and to cache it on disk (cache=True keys the cache by the function's module and
# name; one factory here would give both detectors' closures the same cache name).
#: numba signatures of a detector's per-tick kernel (S, P, t, r, E) -> records and per-block
#: kernel (S, P, T, R, E, row0) -> (records, next row); see :func:`tick_samples`, :func:`block_samples`
STEP_SIGNATURE = "int64(float64[:, ::1], float64[::1], float64, float64[::1], float64[:, ::1])"
RUN_SIGNATURE = ("UniTuple(int64, 2)(float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], "
                 "float64[:, ::1], int64)")


@jit_inline
def tick_samples(sample, S, P, t, r, E):
    """One tick: ``sample`` (S, P, t, r, i, E, ne, row) -> records (a detector's inline
    per-sample kernel, which appends cable i's raise/clear records to E[ne:]) on sample
    r[i] of every cable at time t. Returns the number of event records."""
    ne = 0
    for i in range(S.shape[1]):
        ne = sample(S, P, t, r[i], i, E, ne, 0)
    return ne


@jit_inline
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
    (records, next row) as staticmethods, :meth:`_event` (one record -> AlarmEvent), and
    the layout of its state rows that :meth:`reset`, :meth:`deactivate`,
    :meth:`rebase_time`, :attr:`ready`, :attr:`active` and :meth:`describe_state` read:
    ``state_names``, ``rest_nan_rows``, ``time_rows``, ``alarm_zero_rows``,
    ``alarm_nan_rows``, ``ready_row`` and ``active_row``.
    ``config`` must have ``as_array()`` (the kernel's parameter vector).
    """

    code = ""
    config_class: Any = None
    n_state = 0
    n_record = 2
    _step: Any = None
    _run: Any = None
    #: name of every state row, in row order
    state_names: tuple[str, ...] = ()
    #: rows that are NaN in a cable's state at rest (times and values not known yet); the others are 0
    rest_nan_rows: tuple[int, ...] = ()
    #: rows that hold controller times [s]
    time_rows: tuple[int, ...] = ()
    #: rows of the raised alarm and its pending raise/clear: set to 0 / NaN by :meth:`deactivate`
    alarm_zero_rows: tuple[int, ...] = ()
    alarm_nan_rows: tuple[int, ...] = ()
    #: row that is 1 once the cable's warm-up is over, and row that is 1 while its alarm is raised
    ready_row = 0
    active_row = 0
    #: row counts of this detector's older state layouts, each the head of the current one
    #: (rows were only ever appended): such a snapshot loads, the rows it lacks at rest
    older_n_states: tuple[int, ...] = ()

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

    def reset(self, cables: Sequence[int] | None = None) -> None:
        """Forget everything of these cables (default: all), active alarms included: their
        state goes back to rest and the warm-up starts again with the next sample (the drift
        detector learns its baseline again, e.g. after re-identifying the cable model).
        Raises no clear event: the caller knows what it reset."""
        idx = slice(None) if cables is None else np.asarray(list(cables), dtype=int)
        S = self._S
        S[:, idx] = 0.0
        for row in self.rest_nan_rows:
            S[row, idx] = np.nan

    def deactivate(self) -> None:
        """Drop every cable's active alarm and pending raise/clear, keeping the warm-up and
        the statistics (for a restored state whose detector is disabled in this config).
        Raises no clear event."""
        S = self._S
        for row in self.alarm_zero_rows:
            S[row] = 0.0
        for row in self.alarm_nan_rows:
            S[row] = np.nan

    def rebase_time(self, delta: float) -> None:
        """Move the restored times (warm-up, hold and CUSUM timers, last samples) by
        ``delta`` [s] into this session's time base (see AlarmManager.rebase_time); NaN stays NaN."""
        self._S[list(self.time_rows)] += delta

    @property
    def ready(self) -> np.ndarray:
        """(m,) bool: the cable's warm-up is over (decisions are made)."""
        return self._S[self.ready_row] > 0

    @property
    def active(self) -> np.ndarray:
        """(m,) bool: the detector's alarm is raised on the cable."""
        return self._S[self.active_row] > 0

    def describe_state(self) -> dict[str, list[float]]:
        """Named rows of the state (for debugging and tests)."""
        return {name: self._S[k].tolist() for k, name in enumerate(self.state_names)}

    def state_dict(self) -> dict[str, np.ndarray]:
        """The detector's complete state (numeric arrays only; for the daemon's snapshots)."""
        return {"state": self._S.copy(), "params": self._P.copy()}

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state_dict`. The state must be of the same cable count; the
        tuning stays this detector's own config. A state of an older layout
        (``older_n_states``) fills the head of this one; the rows it lacks start at rest."""
        S = np.asarray(d["state"], dtype=np.float64)
        older = S.ndim == 2 and S.shape[1] == self.n_cables and S.shape[0] in self.older_n_states
        if S.shape != self._S.shape and not older:
            raise ValueError(f"{self.code} state of shape {S.shape} does not fit {self.n_cables} cables")
        if older:
            k = S.shape[0]
            self.reset()                      # the rows the older layout lacks: at rest
            self._S[:k] = S
            return
        self._S[...] = S
