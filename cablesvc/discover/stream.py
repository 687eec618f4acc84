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
import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from cablesvc.config.params import ModelParams
from cablesvc.config.robot import Robot
from cablesvc.kinematics import inverse_kinematics
from cablesvc.models.reversal import amplitude_stream
from cablesvc.models.terms import Signals

__all__ = ["ReducedRecording", "read_reduced", "discover_stream", "wants_stream", "reduced_recording",
           "group_excitation", "select_groups", "ANALYSIS_RATE", "MAX_GROUPS", "COVER", "HELD_SPAN"]

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
    """Keeps the decimated ticks of the kept groups: stride doubling (see the module), or,
    with ``keep``, exactly the groups of that set (chosen beforehand, :func:`select_groups`)."""

    def __init__(self, group_s: float, max_groups: int, keep: Optional[set[int]] = None):
        self.group_s, self.max_groups = group_s, max_groups
        self.keep = keep
        self.stride = 1
        self.groups: dict[int, list[dict[str, np.ndarray]]] = {}
        self.seen = -1

    def add(self, cols: dict[str, np.ndarray]) -> None:
        g = np.floor(cols["t"] / self.group_s).astype(np.int64)
        if g.size:
            self.seen = max(self.seen, int(g[-1]))
        for gi in np.unique(g):
            if (int(gi) not in self.keep) if self.keep is not None else gi % self.stride:
                continue
            sel = g == gi
            self.groups.setdefault(int(gi), []).append({k: v[sel] for k, v in cols.items()})
            while self.keep is None and len(self.groups) > self.max_groups:
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
    """Means of every ``D`` consecutive rows; a reading that is not finite (a dropout
    written as null) is left out of its mean, and a mean of none is NaN."""
    n = a.shape[0] // D
    b = a[: n * D].reshape((n, D) + a.shape[1:])
    ok = np.isfinite(b)
    if ok.all():
        return b.mean(axis=1)
    cnt = ok.sum(axis=1)
    return np.where(cnt > 0, np.where(ok, b, 0.0).sum(axis=1) / np.maximum(cnt, 1), np.nan)


#: the decimated columns a tick cannot do without (the temperature may be missing)
_NEEDED = ("t", "ml", "pos", "ori", "y")


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
        self.dropped = 0        # analysis ticks left out: a reading missing or not finite

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
            ok = np.ones(nd, bool)
            for k in _NEEDED:
                ok &= np.isfinite(dec[k]).reshape(nd, -1).all(axis=1)
            if not ok.all():     # a reading missing on every tick of a mean: the tick is left out
                self.dropped += int((~ok).sum())
                dec = {k: v[ok] for k, v in dec.items()}
                if not ok.any():
                    continue
            yield dec


def _reduction_info(src: "_Decimator", acc: BlockAccumulator, groups: list[int], analysis_ticks: int, block: float,
                    max_groups: int, t_start: float) -> dict[str, Any]:
    """What a reduction read and kept (the ``stream`` entry of reports and parameter files)."""
    return {"t0": src.t0, "ticks": src.ticks, "rate_hz": 1.0 / src.raw_dt,
            "analysis_rate_hz": 1.0 / (src.raw_dt * src.D), "decimation": src.D, "analysis_ticks": analysis_ticks,
            "groups_seen": acc.seen + 1, "groups_kept": len(groups), "group_stride": acc.stride,
            "group_s": 4.0 * block, "max_groups": max_groups, "dropped_ticks": int(src.dropped),
            "stream_seconds": time.perf_counter() - t_start}


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
                 "free_length": free, "travel": dec["ml"], "T": dec["T"], "amplitude": amp, "pos": dec["pos"],
                 "ori": dec["ori"]})
    if src.t0 is None:
        raise DiscoveryError("the recording has no ticks")
    raw_dt, D, has_temp = src.raw_dt, src.D, src.has_temp
    kept, breaks, groups = acc.result()
    if not kept or kept["t"].size < 200:
        raise DiscoveryError(f"the recording is too short for a held-out split "
                             f"({0 if not kept else kept['t'].size} analysis ticks, need >= 200)")
    temp = None
    if has_temp:
        from cablesvc.discover.pipeline import fill_slow
        temp, _ = fill_slow(kept["t"], kept["T"])      # all finite: a copy; mostly missing: None
    s = Signals(t=kept["t"], dt=float(raw_dt * D), y=kept["y"], f0=kept["f0"], x=kept["x"], v=kept["v"],
                v_slide=kept["v_slide"], wrap=kept["wrap"], free_length=kept["free_length"], temperature=temp,
                ea=np.asarray(geom.ea, float), has_pulley=np.asarray(geom.has_pulley, bool),
                amplitude=kept["amplitude"], train=np.ones(kept["t"].size, bool),
                cable_names=tuple(geom.cable_names), travel=kept["travel"])
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
    red = drop_glitches(read_reduced(path, rob, base, rate=rate, block=block, max_groups=max_groups,
                                     chunk_ticks=chunk_ticks))
    t_an = time.perf_counter()
    d = discover_signals(red, rob, base, red.signals, terms=terms, selector=selector, block=block,
                         exact_baseline=exact_baseline, t_origin=float(red.info["t0"]), breaks=red.breaks)
    red.info["analysis_seconds"] = time.perf_counter() - t_an
    d.options["stream"] = dict(red.info)
    return d


def drop_glitches(red: ReducedRecording) -> ReducedRecording:
    """``red`` without its analysis ticks whose decimated force is a glitch
    (:func:`~cablesvc.discover.pipeline.reading_glitches` on the baseline's residual, the
    threshold counted in a raw reading's noise, sqrt(D) x a D-tick mean's: a spike of tens
    of newtons in one raw reading still stands far off its neighbours in its mean, while a
    fast force step that one mean straddles does not), counted in ``info``
    (``glitch_ticks``, ``glitches_per_cable``)."""
    import dataclasses as _dc

    from cablesvc.discover.pipeline import cut_signals, reading_glitches

    s = red.signals
    gf, ge = reading_glitches(s.y, s.f0, math.sqrt(max(int(red.info.get("decimation", 1)), 1)))
    g = gf | ge
    if not g.any():
        return red
    keep = np.flatnonzero(~g.any(axis=1))
    breaks = red.breaks[keep].copy()
    breaks[1:] |= np.diff(keep) > 1
    if breaks.size:
        breaks[0] = True
    info = {**red.info, "glitch_ticks": int(g.any(axis=1).sum()),
            "glitches_per_cable": {int(c): int(k) for c, k in enumerate(g.sum(axis=0)) if k}}
    info["analysis_ticks"] = int(keep.size)
    return _dc.replace(red, t=red.t[keep], position=red.position[keep], orientation=red.orientation[keep],
                       force=red.force[keep], signals=cut_signals(s, keep), breaks=breaks, info=info)


def group_excitation(src: "_Decimator", group_s: float) -> tuple[np.ndarray, float]:
    """(G, m) standard deviation [N] of the measured force of each cable within each group
    of ``group_s`` s of the decimated recording ``src`` (one pass; memory per group, not
    per tick; non-finite readings are left out, a group without any counts 0), and the
    largest standard deviation of a platform position coordinate over the whole recording
    [m] (about 0 for a platform held still, a calibration (002 Sec 4), whatever noise a
    measured pose carries; decimetres for a trajectory)."""
    n: dict[int, np.ndarray] = {}
    s1: dict[int, np.ndarray] = {}
    s2: dict[int, np.ndarray] = {}
    pn, p1, p2, p0 = 0, np.zeros(3), np.zeros(3), None
    for dec in src:
        if dec["pos"].size:
            p0 = dec["pos"][0] if p0 is None else p0          # shifted sums: no cancellation
            dp = dec["pos"] - p0
            pn, p1, p2 = pn + dp.shape[0], p1 + dp.sum(axis=0), p2 + (dp ** 2).sum(axis=0)
        g = np.floor(dec["t"] / group_s).astype(np.int64)
        y = dec["y"]
        ok = np.isfinite(y)
        y0 = np.where(ok, y, 0.0)
        for gi in np.unique(g):
            sel = g == gi
            k = int(gi)
            if k not in n:
                n[k], s1[k], s2[k] = np.zeros(y.shape[1]), np.zeros(y.shape[1]), np.zeros(y.shape[1])
            n[k] += ok[sel].sum(axis=0)
            s1[k] += y0[sel].sum(axis=0)
            s2[k] += (y0[sel] ** 2).sum(axis=0)
    pos_std = float(np.sqrt(np.max(np.maximum(p2 / pn - (p1 / pn) ** 2, 0.0)))) if pn else 0.0
    if not n:
        return np.zeros((0, 0)), pos_std
    G = max(n) + 1
    m = next(iter(n.values())).size
    out = np.zeros((G, m))
    for k in n:
        cnt = np.maximum(n[k], 1.0)
        mean = s1[k] / cnt
        out[k] = np.where(n[k] > 1, np.sqrt(np.maximum(s2[k] / cnt - mean ** 2, 0.0)), 0.0)
    return out, pos_std


#: the platform counts as held still (a calibration) when no coordinate of its position
#: varies by more than this standard deviation over the recording [m]
HELD_SPAN = 1e-3


#: a cable counts as covered by the groups kept when they hold a group with at least this
#: fraction of its largest within-group force variation
COVER = 0.5


def select_groups(score: np.ndarray, k: int) -> tuple[list[int], int]:
    """Which of G groups to keep, given ``score`` (G, m) (:func:`group_excitation`):
    ``(sorted group indices, groups it took to cover every cable)``; at least ``k`` groups
    (all of them when G <= k).

    A recording that excites the cables one at a time (002 Sec 4's calibration: each
    winch in turn) has each cable's information in a few groups only, and groups evenly
    spaced in time miss most cables. So the groups are first chosen to cover every cable:
    each cable's score is scaled by its largest (every cable weighs the same, whatever its
    tension), and the group that adds most to the sum over cables of min(COVER, best so
    far) is taken next, until every cable holds a group with at least :data:`COVER` of its
    largest variation, even beyond ``k``. The rest of ``k`` is spread evenly over the
    recording, as the one-pass sampling does (a slow drift is seen)."""
    G = score.shape[0]
    if G <= k:
        return list(range(G)), 0
    top = score.max(axis=0)
    s = np.where(top > 0, score / np.where(top > 0, top, 1.0), 0.0)
    cov = np.where(top > 0, 0.0, COVER)        # a cable whose force never varies has nothing to cover
    free = np.ones(G, bool)
    chosen: list[int] = []
    while np.any(cov < COVER) and free.any():
        gain = (np.minimum(COVER, np.maximum(cov, s)) - np.minimum(COVER, cov)).sum(axis=1)
        g = int(np.argmax(np.where(free, gain, -1.0)))
        chosen.append(g)
        free[g] = False
        cov = np.maximum(cov, s[g])
    needed = len(chosen)
    need = k - needed
    if need > 0:
        rest = np.flatnonzero(free)
        pick = rest[np.unique(np.linspace(0, rest.size - 1, min(need, rest.size)).round().astype(int))]
        chosen.extend(int(x) for x in pick)
    return sorted(chosen), needed


def reduced_recording(path: Any, robot: Robot, *, rate: float = ANALYSIS_RATE, block: float = 2.5,
                      max_groups: int = MAX_GROUPS, chunk_ticks: int = 200_000,
                      select: str = "spread", held_groups: Optional[int] = None) -> tuple[Any, dict[str, Any]]:
    """The recording at ``path`` decimated to ``rate`` by block means and sampled by whole
    groups of 4 ``block`` s, as a :class:`~cablesvc.recording.Recording` (time from the first
    tick, gaps between the groups) and a description: what ``cablesvc identify`` fits on
    for a long or fast recording (the streamed path's reduction, without the baseline).

    ``select="spread"``: at most ``max_groups`` groups evenly spread over the recording
    (stride doubling, one pass). ``select="excitation"`` (what ``cablesvc identify`` uses):
    a first pass measures each cable's force variation per group and
    :func:`select_groups` keeps at least ``max_groups`` groups, and as many more as it takes
    for every cable to be excited in them (a calibration that moves one winch at a time);
    a second pass keeps those. With ``held_groups``, a recording whose platform is held
    still (position std < :data:`HELD_SPAN`: 002 Sec 4's calibration, every segment of it
    a level of some winch) and that has no more groups than that is kept whole. Memory is
    bounded by the groups kept."""
    from cablesvc.recording import Recording
    from cablesvc.recording.format import RecordingError

    class _Fail(RecordingError):
        def __init__(self, msg: str):
            super().__init__(path, "inputs", msg)

    if select not in ("spread", "excitation"):
        raise ValueError(f"select must be 'spread' or 'excitation', not {select!r}")
    t_start = time.perf_counter()
    m = robot.geometry().n_cables
    extra: dict[str, Any] = {"selection": select}
    keep = None
    if select == "excitation":
        score, pos_std = group_excitation(_Decimator(path, m, rate, chunk_ticks, _Fail), 4.0 * block)
        held = pos_std < HELD_SPAN
        if held and held_groups is not None and score.shape[0] <= held_groups:
            chosen, needed = list(range(score.shape[0])), 0
            extra["held_calibration"] = True
        else:
            chosen, needed = select_groups(score, max_groups)
        keep = set(chosen)
        extra["groups_to_cover_every_cable"] = int(needed)
        extra["position_std_m"] = pos_std
    acc = BlockAccumulator(4.0 * block, max_groups, keep=keep)
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
    return rec, {**info, **extra, "gaps": int(breaks[1:].sum())}

