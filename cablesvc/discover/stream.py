"""Discovery at the size of real logs: the recording streamed, decimated and sampled by
whole split groups, in memory that does not grow with its length (issue 17 item 1).

:func:`read_reduced` reads a recording piece by piece (:func:`cablesvc.recording.chunks.iter_chunks`)
and hands discovery the same :class:`~cablesvc.models.terms.Signals` that
:func:`~cablesvc.discover.pipeline.build_signals` makes, with three differences:

1. **Decimation to the analysis rate** (default 100 Hz, the rate every discovery bench
   runs at). Every ``D`` = round(rate / analysis rate) consecutive ticks are replaced by
   their mean (time, motor lengths, pose, measured force, temperature): an anti-alias
   block mean, which keeps everything below about 40 Hz and divides the sensor noise by
   sqrt(D). The physics allows it: the platform and the winches move at a few Hz (the
   trajectory's moves last >= 1 s), so the cable lengths, the pulley wrap angle, the
   tension and the temperature change little within 10 ms, and every term's law is
   smooth in them; creep and temperature are slower still. The baseline, its elongation
   x = l(pose) - motor_length and the amplitude tracker then run at the analysis rate, as
   on a 100 Hz recording. What needs the rate is dead time: its grid starts at one
   analysis tick (10 ms) and is refined continuously by interpolation, as at 100 Hz.
2. **The baseline and the amplitude run over every (decimated) tick**, their state
   carried from piece to piece (the cable model's hysteresis state, the reversal
   tracker, the previous tick for the backward rates), so a piece boundary inside a
   hysteresis branch changes nothing.
3. **Whole split groups are kept, evenly spaced.** The split's blocks go train, valid,
   train, test; a group is those four blocks (4 x ``block`` s). At most ``max_groups``
   groups are kept: when more have been seen, every other kept group is dropped and only
   every ``stride``-th group is kept from then on (stride doubling), so the groups kept
   span the whole recording (a slow drift over the hour is seen) and memory is bounded by
   ``max_groups`` groups whatever the length. A recording with no more groups than that
   is analysed whole.

The noise floor is taken from first differences inside the kept groups only (the jump
between two kept groups is not noise). Dead time's delayed signals at the start of a kept
group are held at its first value, as at a recording's start.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from cablesvc.config.params import ModelParams
from cablesvc.config.robot import Robot
from cablesvc.kinematics import inverse_kinematics
from cablesvc.models.reversal import amplitude_stream
from cablesvc.models.terms import Signals

__all__ = ["ReducedRecording", "read_reduced", "discover_stream", "wants_stream", "ANALYSIS_RATE", "MAX_GROUPS"]

#: default analysis rate [Hz]
ANALYSIS_RATE = 100.0
#: default most split groups kept (4 blocks of 2.5 s each: 160 s at 100 Hz)
MAX_GROUPS = 16


@dataclass
class ReducedRecording:
    """What the streamed path keeps: the decimated ticks of the kept groups as a
    recording-like object (``t`` [s] from the recording's first tick, ``position``,
    ``orientation``, ``force``; what :func:`~cablesvc.discover.equilibrium.equilibrium_check`
    reads), their :class:`Signals`, the mask of ticks that start a kept run (``breaks``:
    the first tick after a gap) and ``info`` (ticks read, rates, groups kept, seconds)."""

    t: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    force: np.ndarray
    signals: Signals
    breaks: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


class BlockAccumulator:
    """Keeps the decimated ticks of the kept groups (stride doubling, see the module)."""

    def __init__(self, group_s: float, max_groups: int):
        self.group_s, self.max_groups = group_s, max_groups
        self.stride = 1
        self.groups: dict[int, list[dict[str, np.ndarray]]] = {}
        self.seen = -1

    def add(self, cols: dict[str, np.ndarray]) -> None:
        g = np.floor(cols["t"] / self.group_s).astype(np.int64)
        if g.size:
            self.seen = max(self.seen, int(g[-1]))
        for gi in np.unique(g):
            if gi % self.stride:
                continue
            sel = g == gi
            self.groups.setdefault(int(gi), []).append({k: v[sel] for k, v in cols.items()})
            while len(self.groups) > self.max_groups:
                self.stride *= 2
                self.groups = {k: v for k, v in self.groups.items() if k % self.stride == 0}

    def result(self) -> tuple[dict[str, np.ndarray], np.ndarray, list[int]]:
        keys = sorted(self.groups)
        parts = [p for k in keys for p in self.groups[k]]
        out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}
        starts = np.zeros(out["t"].shape[0] if out else 0, bool)
        i = 0
        prev = None
        for k in keys:
            n = sum(p["t"].shape[0] for p in self.groups[k])
            if prev is None or k != prev + 1:
                starts[i] = True
            i += n
            prev = k
        return out, starts, keys


def _block_means(a: np.ndarray, D: int) -> np.ndarray:
    n = a.shape[0] // D
    return a[: n * D].reshape((n, D) + a.shape[1:]).mean(axis=1)


class _Decimator:
    """The recording at ``path`` read in pieces and decimated to ``rate`` by block means
    (iterate: dicts of the decimated ``t`` [s from the first tick], ``ml``, ``pos``,
    ``ori`` (renormalised), ``y``, ``T``); ``ticks``, ``t0``, ``raw_dt``, ``D`` and
    ``has_temp`` are known once the first piece is read."""

    def __init__(self, path: Any, m: int, rate: float, chunk_ticks: int, fail: Any):
        self.path, self.m, self.rate, self.chunk_ticks, self.fail = path, m, rate, chunk_ticks, fail
        self.ticks = 0
        self.t0: Optional[float] = None
        self.raw_dt = 1.0 / rate
        self.D = 1
        self.has_temp = False

    def __iter__(self):
        from cablesvc.recording.chunks import iter_chunks

        carry: Optional[dict[str, np.ndarray]] = None
        m, D = self.m, self.D
        for rec in iter_chunks(self.path, self.chunk_ticks, robot_cables=m):
            if rec.force is None:
                raise self.fail("the recording has no measured forces (a piece of "
                                f"{rec.t.size} ticks from t = {rec.t[0]:g} s has none)")
            if rec.position is None or rec.orientation is None:
                raise self.fail("the recording has no platform pose (a piece of "
                                f"{rec.t.size} ticks from t = {rec.t[0]:g} s has none)")
            n = rec.t.shape[0]
            self.ticks += n
            if self.t0 is None:
                self.t0 = float(rec.t[0])
                self.raw_dt = float(np.median(np.diff(rec.t))) if n > 1 else 1.0 / self.rate
                if not self.raw_dt > 0:
                    raise self.fail("the recording's time does not advance over its first ticks")
                D = self.D = (max(1, int(round(1.0 / (self.raw_dt * self.rate))))
                              if 1.0 / self.raw_dt > 1.5 * self.rate else 1)
            self.has_temp = self.has_temp or rec.temperature is not None
            cols = {"t": np.asarray(rec.t, float) - self.t0, "ml": np.asarray(rec.motor_length, float),
                    "pos": np.asarray(rec.position, float), "ori": np.asarray(rec.orientation, float),
                    "y": np.asarray(rec.force, float),
                    "T": (np.asarray(rec.temperature, float) if rec.temperature is not None
                          else np.full(n, np.nan))}
            del rec
            if carry is not None:
                cols = {k: np.concatenate([carry[k], v]) for k, v in cols.items()}
            nd = cols["t"].shape[0] // D
            carry = {k: v[nd * D:] for k, v in cols.items()}
            if nd == 0:
                continue
            dec = {k: _block_means(v[: nd * D], D) if D > 1 else v[:nd] for k, v in cols.items()}
            if D > 1:        # a mean of unit quaternions (all close together) is renormalised
                dec["ori"] = dec["ori"] / np.linalg.norm(dec["ori"], axis=1, keepdims=True)
            yield dec


def _reduction_info(src: "_Decimator", acc: BlockAccumulator, groups: list[int], analysis_ticks: int, block: float,
                    max_groups: int, t_start: float) -> dict[str, Any]:
    """What a reduction read and kept (the ``stream`` entry of reports and parameter files)."""
    return {"t0": src.t0, "ticks": src.ticks, "rate_hz": 1.0 / src.raw_dt,
            "analysis_rate_hz": 1.0 / (src.raw_dt * src.D), "decimation": src.D, "analysis_ticks": analysis_ticks,
            "groups_seen": acc.seen + 1, "groups_kept": len(groups), "group_stride": acc.stride,
            "group_s": 4.0 * block, "max_groups": max_groups, "stream_seconds": time.perf_counter() - t_start}


def read_reduced(path: Any, robot: Robot, params: ModelParams, *, rate: float = ANALYSIS_RATE,
                 block: float = 2.5, max_groups: int = MAX_GROUPS, chunk_ticks: int = 200_000) -> ReducedRecording:
    """Stream the recording at ``path`` into the reduced :class:`Signals` (see the module):
    ``rate`` [Hz] the analysis rate (no decimation when the recording is slower than 1.5 x
    that), ``block`` [s] the split block, ``max_groups`` the most split groups kept,
    ``chunk_ticks`` the piece size read at a time."""
    from cablesvc.discover.pipeline import DiscoveryError, backward_rate

    t_start = time.perf_counter()
    geom = robot.geometry()
    m = geom.n_cables
    model = params.build(m, 1)
    state = None
    amp_state = None
    acc = BlockAccumulator(4.0 * block, max_groups)
    last: Optional[dict[str, np.ndarray]] = None      # previous decimated tick: t, x, ml
    src = _Decimator(path, m, rate, chunk_ticks, DiscoveryError)
    for dec in src:
        nd = dec["t"].shape[0]
        ik = inverse_kinematics(geom, dec["pos"], dec["ori"])
        length = np.array(ik.length)
        x = length - dec["ml"]
        # the baseline, tick by tick with its hysteresis state carried across pieces
        t = dec["t"]
        f0 = np.empty_like(x)
        tp = None if last is None else float(last["t"][0])
        for k in range(nd):
            xk = x[k:k + 1]
            if state is None:
                state = model.create_state(xk)
                dtk = 0.0
            else:
                dtk = float(t[k] - (tp if k == 0 else t[k - 1]))
            f0[k] = model.step(state, xk, dtk, dec["ml"][k:k + 1])[0]
        # backward rates, continuing from the previous piece's last tick
        tt = t if last is None else np.r_[last["t"], t]
        xx = x if last is None else np.vstack([last["x"], x])
        mm = dec["ml"] if last is None else np.vstack([last["ml"], dec["ml"]])
        v = backward_rate(xx, tt)
        vs = -backward_rate(mm, tt)
        if last is not None:
            v, vs = v[1:], vs[1:]
        amp, amp_state = amplitude_stream(x, amp_state)
        last = {"t": t[-1:], "x": x[-1:], "ml": dec["ml"][-1:]}
        # the IK object of a batch holds its buffers in reference cycles: free them with
        # the piece, not at the next full collection (some 6 KB per tick would pile up)
        wrap, free = np.array(ik.wrap_angle), np.array(ik.free_length)
        del ik
        gc.collect()
        acc.add({"t": t, "y": dec["y"], "f0": f0, "x": x, "v": v, "v_slide": vs, "wrap": wrap,
                 "free_length": free, "T": dec["T"], "amplitude": amp, "pos": dec["pos"],
                 "ori": dec["ori"]})
    if src.t0 is None:
        raise DiscoveryError("the recording has no ticks")
    raw_dt, D, has_temp = src.raw_dt, src.D, src.has_temp
    kept, breaks, groups = acc.result()
    if not kept or kept["t"].size < 200:
        raise DiscoveryError(f"the recording is too short for a held-out split "
                             f"({0 if not kept else kept['t'].size} analysis ticks, need >= 200)")
    temp = kept["T"] if has_temp and not np.all(np.isnan(kept["T"])) else None
    s = Signals(t=kept["t"], dt=float(raw_dt * D), y=kept["y"], f0=kept["f0"], x=kept["x"], v=kept["v"],
                v_slide=kept["v_slide"], wrap=kept["wrap"], free_length=kept["free_length"], temperature=temp,
                ea=np.asarray(geom.ea, float), has_pulley=np.asarray(geom.has_pulley, bool),
                amplitude=kept["amplitude"], train=np.ones(kept["t"].size, bool),
                cable_names=tuple(geom.cable_names))
    info = _reduction_info(src, acc, groups, int(s.n), block, max_groups, t_start)
    return ReducedRecording(t=kept["t"], position=kept["pos"], orientation=kept["ori"], force=kept["y"],
                            signals=s, breaks=breaks, info=info)


def wants_stream(path: Any, rate: float = ANALYSIS_RATE, block: float = 2.5, max_groups: int = MAX_GROUPS,
                 probe_ticks: int = 4096, min_ticks: Optional[int] = None) -> bool:
    """Whether the streamed path changes anything for the recording at ``path``: its rate
    is above 1.5 x the analysis rate, or it is longer than ``max_groups`` split groups
    (and, with ``min_ticks``, it has more ticks than that). Reads pieces of ``probe_ticks``
    only until the answer is known."""
    from cablesvc.recording.chunks import iter_chunks

    limit = max_groups * 4.0 * block
    n, t_first, fast = 0, None, False
    for piece in iter_chunks(path, probe_ticks):
        if t_first is None:
            t_first = float(piece.t[0])
            if piece.t.size >= 2:
                dt = float(np.median(np.diff(piece.t)))
                fast = dt > 0 and 1.0 / dt > 1.5 * rate
        n += piece.t.size
        long_ = float(piece.t[-1]) - t_first > limit
        if (min_ticks is None or n > min_ticks) and (fast or long_):
            return True
    return False


def discover_stream(path: Any, robot: Any, params: Any = None, *, terms: Optional[list] = None,
                    selector: Any = None, block: float = 2.5, exact_baseline: bool = False,
                    rate: float = ANALYSIS_RATE, max_groups: int = MAX_GROUPS, chunk_ticks: int = 200_000):
    """:func:`cablesvc.discover.discover` on the recording at ``path`` through the streamed
    path (see the module): the same selection, statistics and report, on the decimated
    ticks of at most ``max_groups`` split groups spread over the whole recording. The
    :class:`~cablesvc.discover.pipeline.Discovery`'s ``options["stream"]`` says what was
    read and kept; its fits, held-out scores and parameter file come from the kept ticks."""
    from cablesvc.discover.pipeline import as_robot, baseline_params, discover_signals

    rob = as_robot(robot)
    base = baseline_params(rob, params)
    red = read_reduced(path, rob, base, rate=rate, block=block, max_groups=max_groups, chunk_ticks=chunk_ticks)
    t_an = time.perf_counter()
    d = discover_signals(red, rob, base, red.signals, terms=terms, selector=selector, block=block,
                         exact_baseline=exact_baseline, t_origin=float(red.info["t0"]), breaks=red.breaks)
    red.info["analysis_seconds"] = time.perf_counter() - t_an
    d.options["stream"] = dict(red.info)
    return d


def reduced_recording(path: Any, robot: Robot, *, rate: float = ANALYSIS_RATE, block: float = 2.5,
                      max_groups: int = MAX_GROUPS, chunk_ticks: int = 200_000) -> tuple[Any, dict[str, Any]]:
    """The recording at ``path`` decimated to ``rate`` by block means and sampled by at most
    ``max_groups`` whole groups of 4 ``block`` s spread over it (the streamed path's
    reduction, without the baseline), as a :class:`~cablesvc.recording.Recording` (time from
    the first tick, gaps between the groups) and a description: what ``cablesvc identify``
    fits on for a long or fast recording. Memory is bounded by ``max_groups`` groups."""
    from cablesvc.recording import Recording
    from cablesvc.recording.format import RecordingError

    class _Fail(RecordingError):
        def __init__(self, msg: str):
            super().__init__(path, "inputs", msg)

    t_start = time.perf_counter()
    m = robot.geometry().n_cables
    acc = BlockAccumulator(4.0 * block, max_groups)
    src = _Decimator(path, m, rate, chunk_ticks, _Fail)
    for dec in src:
        acc.add(dec)
    kept, breaks, groups = acc.result()
    if not kept:
        raise _Fail("the recording has no ticks")
    n = kept["t"].size
    temp = kept["T"] if src.has_temp and not np.all(np.isnan(kept["T"])) else None
    rec = Recording(robot=robot.name, metadata={}, t=kept["t"], seq=np.arange(n, dtype=np.int64),
                    motor_length=kept["ml"], position=kept["pos"], orientation=kept["ori"], force=kept["y"],
                    temperature=temp)
    info = _reduction_info(src, acc, groups, int(n), block, max_groups, t_start)
    return rec, {**info, "gaps": int(breaks[1:].sum())}

