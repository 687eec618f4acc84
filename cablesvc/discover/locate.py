"""Where the residual lives: which cables, which time segments, which regions of state.

* :func:`noise_floor`: the sensor-noise level of a residual from its differences (smooth
  model errors cancel in a difference, sensor noise does not): sigma = std(diff r) /
  sqrt(2) [N] for white noise, from second differences at 0.1 s where the noise's ticks
  are correlated (a filtered force channel).
* :func:`cable_excess`: per cable, residual RMS against that floor; a cable "carries" the
  residual when RMS > ``ratio`` x floor.
* :func:`change_points`: binary segmentation of the residual's mean (averaged in windows of
  ``window`` s) with a BIC penalty: the times at which the mismatch changes level.
* :func:`state_regions`: for each state variable (tension, wrap angle, direction of
  motion, amplitude, temperature, time since start, pose, elongation rate), the share of
  the residual's variance explained by its quantile bins (the correlation ratio eta^2);
  plus the residual's spectrum in frequency bands against white noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from cablesvc.noise import NOISE_LAG_S, NOISE_RATIO
from cablesvc.robust import robust_std

__all__ = ["noise_floor", "cable_excess", "change_points", "state_variables", "state_regions", "frequency_bands",
           "locate"]


#: a lagged estimate is taken only where it stands this many of its standard errors above the
#: first-difference one: a recording with readings missing here and there keeps few
#: triplets whole (2 % per force channel leaves a few hundred of 3000), and on those the
#: 1.2 x of NOISE_RATIO alone is within two standard errors
NOISE_LAG_SE = 4.0
#: efficiency of the MAD-based std against the sample std on Gaussian data (0.37): its
#: relative standard error on n values is 1 / sqrt(2 x 0.37 n)
_MAD_EFFICIENCY = 0.37


def _grid_ticks(t: Optional[np.ndarray], dt: Optional[float]) -> Optional[np.ndarray]:
    """Each tick's index on the recording's time grid, round((t - t0) / dt), where ``t`` lies
    on such a grid (within a quarter tick, strictly increasing); None otherwise."""
    if t is None or dt is None or not dt > 0:
        return None
    t = np.asarray(t, float)
    if t.size < 2 or not np.all(np.isfinite(t)):
        return None
    u = (t - t[0]) / dt
    n = np.rint(u).astype(np.int64)
    if np.max(np.abs(u - n)) > 0.25 or np.any(np.diff(n) <= 0):
        return None
    return n


def noise_floor(r: np.ndarray, breaks: Optional[np.ndarray] = None, dt: Optional[float] = None,
                detail: bool = False, t: Optional[np.ndarray] = None) -> Any:
    """Sensor-noise std [N] per column of r (N, m). Smooth model errors cancel in a
    difference, sensor noise does not: sigma = std(diff r) / sqrt(2) for white noise. A
    force channel behind a low-pass filter (a load-cell amplifier) has noise whose ticks
    are correlated, and its first differences see only the part above the filter: a 5 Hz
    first-order filter at 100 Hz halves sigma so measured, and every gain in noise
    variances, every floor and the forces' balance would be read four times too large.
    With ``dt`` [s], sigma is also measured from second differences at a lag of
    :data:`~cablesvc.noise.NOISE_LAG_S` (r(t + k) - 2 r(t) + r(t - k), robust std / sqrt 6: a
    trajectory's smooth part cancels to second order, the kinks at reversals are outliers)
    and taken where it is more than :data:`~cablesvc.noise.NOISE_RATIO` x the
    first-difference one (the live ``spread`` alarm does the same, :mod:`cablesvc.noise`)
    and more than NOISE_LAG_SE of its standard errors above it; elsewhere the white-noise
    estimate stands unchanged. ``t`` (N,) [s], the ticks' times on a grid of ``dt`` with the
    ticks that missed a reading left out: differences and triplets are taken between ticks
    1 and k grid steps apart, whatever was left out between other ticks. Without ``t``,
    ``breaks`` (N,) bool marks the first tick after a gap in time (the kept groups of a
    streamed long recording): the jumps across gaps are not noise and are left out.
    ``detail``: also return, per column, whether the lagged estimate was taken (the noise
    is correlated)."""
    r = np.asarray(r, float)
    grid = _grid_ticks(t, dt)
    d = np.diff(r, axis=0)
    if grid is not None:
        d = d[np.diff(grid) == 1]
    elif breaks is not None:
        d = d[~breaks[1:]]
    white = np.std(d, axis=0) / math.sqrt(2.0)
    corr = np.zeros(white.shape, bool)
    k = int(round(NOISE_LAG_S / dt)) if dt is not None and dt > 0 else 0
    if k >= 2 and r.shape[0] > 8 * k:
        if grid is not None:                # triplets k and 2 k grid steps apart, all three kept
            j = np.searchsorted(grid, grid + k)
            j2 = np.searchsorted(grid, grid + 2 * k)
            j, j2 = np.minimum(j, grid.size - 1), np.minimum(j2, grid.size - 1)
            whole = (grid[j] == grid + k) & (grid[j2] == grid + 2 * k)
            i = np.flatnonzero(whole)
            d2 = r[j2[i]] - 2.0 * r[j[i]] + r[i]
        else:
            d2 = r[2 * k:] - 2.0 * r[k:-k] + r[:-2 * k]
            if breaks is not None:          # a triplet that straddles a gap is no difference
                cs = np.concatenate([[0], np.cumsum(np.asarray(breaks, bool)[1:])])
                d2 = d2[cs[2 * k:] - cs[:-2 * k] == 0]
        if d2.shape[0] > 8:
            lagged = robust_std(d2) / math.sqrt(6.0)      # a reversal's kink does not count
            se = 1.0 / math.sqrt(2.0 * _MAD_EFFICIENCY * d2.shape[0])
            corr = lagged > max(NOISE_RATIO, 1.0 + NOISE_LAG_SE * se) * white
            white = np.where(corr, lagged, white)
    return (white, corr) if detail else white


def cable_excess(r: np.ndarray, ratio: float = 1.3, breaks: Optional[np.ndarray] = None,
                 dt: Optional[float] = None, t: Optional[np.ndarray] = None) -> list[dict[str, Any]]:
    """Per cable: RMS, noise floor (:func:`noise_floor`; ``noise_correlated`` where the
    lagged estimate was taken), their ratio and whether it exceeds ``ratio``."""
    rms = np.sqrt(np.mean(r ** 2, axis=0))
    fl, corr = noise_floor(r, breaks, dt, detail=True, t=t)
    return [{"cable": c, "rms": float(rms[c]), "noise": float(fl[c]), "noise_correlated": bool(corr[c]),
             "ratio": float(rms[c] / fl[c]) if fl[c] > 0 else float("inf"),
             "carries_residual": bool(rms[c] > ratio * fl[c])} for c in range(r.shape[1])]


def _seg_cost(cs: np.ndarray, cs2: np.ndarray, a: int, b: int) -> float:
    n = b - a
    s = cs[b] - cs[a]
    return float(cs2[b] - cs2[a] - s * s / n)


def change_points(t: np.ndarray, r: np.ndarray, window: float = 0.5, max_points: int = 8,
                  noise: Optional[float] = None) -> list[float]:
    """Times [s] where the mean of the residual r (N,) changes (binary segmentation on
    window means, BIC penalty with the window-mean noise variance)."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    w = max(1, int(round(window / dt)))
    nb = r.size // w
    if nb < 4:
        return []
    mb = r[:nb * w].reshape(nb, w).mean(axis=1)
    tb = t[:nb * w].reshape(nb, w)[:, 0]
    sig2 = (noise ** 2 / w) if noise is not None else float(np.var(np.diff(mb)) / 2.0)
    sig2 = max(sig2, 1e-18)
    pen = 2.0 * math.log(nb) * sig2 * 2.0
    cs = np.r_[0.0, np.cumsum(mb)]
    cs2 = np.r_[0.0, np.cumsum(mb * mb)]
    segs = [(0, nb)]
    cps: list[int] = []
    while len(cps) < max_points:
        best = None
        for (a, b) in segs:
            if b - a < 4:
                continue
            full = _seg_cost(cs, cs2, a, b)
            for k in range(a + 2, b - 1):
                gain = full - _seg_cost(cs, cs2, a, k) - _seg_cost(cs, cs2, k, b)
                if best is None or gain > best[0]:
                    best = (gain, k, (a, b))
        if best is None or best[0] < pen:
            break
        _, k, (a, b) = best
        segs.remove((a, b))
        segs += [(a, k), (k, b)]
        cps.append(k)
    return sorted(float(tb[k]) for k in cps)


def state_variables(s) -> dict[str, np.ndarray]:
    """The state variables the residual is checked against, each (N, m) (or (N,))."""
    out: dict[str, np.ndarray] = {
        "tension f [N]": s.f0,
        "wrap angle [rad]": s.wrap,
        "direction of motion sgn(dx/dt)": np.sign(s.v),
        "wrap angle x direction of sliding": np.sin(0.5 * s.wrap) * np.sign(s.v_slide),
        "amplitude A [m]": s.amplitude,
        "elongation rate dx/dt [m/s]": s.v,
        "time since start [s]": s.t - s.t[0],
        "free length (pose) [m]": s.free_length,
    }
    if s.temperature is not None:
        out["temperature [deg C]"] = s.temperature
    return out


def _eta2(v: np.ndarray, r: np.ndarray, bins: int = 10) -> float:
    if np.ptp(v) <= 1e-12 * max(1.0, float(np.max(np.abs(v)))):
        return 0.0
    uniq = np.unique(v)
    if uniq.size <= bins:
        idx = np.searchsorted(uniq, v)
    else:
        edges = np.quantile(v, np.linspace(0, 1, bins + 1)[1:-1])
        idx = np.searchsorted(edges, v)
    tot = float(np.sum((r - r.mean()) ** 2))
    if tot <= 0:
        return 0.0
    between = 0.0
    for b in np.unique(idx):
        sel = idx == b
        between += sel.sum() * (r[sel].mean() - r.mean()) ** 2
    return float(between / tot)


def state_regions(s, r: np.ndarray, cables: list[int], top: int = 3) -> dict[int, list[dict[str, Any]]]:
    """Per cable in ``cables``: the state variables ranked by eta^2 (share of residual
    variance their bins explain), the ``top`` ones with the bin of largest mean residual."""
    vars_ = state_variables(s)
    out = {}
    for c in cables:
        ranked = []
        for name, a in vars_.items():
            v = a[:, c] if a.ndim == 2 else a
            ranked.append({"variable": name, "eta2": _eta2(v, r[:, c])})
        ranked.sort(key=lambda d: -d["eta2"])
        out[c] = ranked[:top]
    return out


def frequency_bands(r: np.ndarray, dt: float, edges=(0.0, 0.1, 1.0, 10.0)) -> list[dict[str, Any]]:
    """Share of the residual's power (N,) per frequency band [Hz] against the share white
    noise would have (bandwidth / Nyquist): > 1 means the band carries structure."""
    n = r.size
    P = np.abs(np.fft.rfft(r - r.mean())) ** 2
    f = np.fft.rfftfreq(n, dt)
    tot = float(P.sum()) or 1.0
    nyq = 0.5 / dt
    es = list(edges) + [nyq]
    out = []
    for a, b in zip(es[:-1], es[1:]):
        if a >= nyq:
            break
        sel = (f >= a) & (f < b)
        share = float(P[sel].sum() / tot)
        white = (min(b, nyq) - a) / nyq
        out.append({"band_hz": [a, min(b, nyq)], "power_share": share, "vs_white": share / white if white else 0.0})
    return out


def locate(s, r: np.ndarray, breaks: Optional[np.ndarray] = None) -> dict[str, Any]:
    """Everything above for the residual r (N, m): JSON-able. ``breaks``: see
    :func:`noise_floor`."""
    cab = cable_excess(r, breaks=breaks, dt=s.dt, t=s.t)
    flagged = [d["cable"] for d in cab if d["carries_residual"]]
    cps = {c: change_points(s.t, r[:, c], noise=cab[c]["noise"]) for c in flagged}
    regions = state_regions(s, r, flagged)
    freq = {c: frequency_bands(r[:, c], s.dt) for c in flagged}
    return {"cables": cab, "flagged": flagged, "change_points": {str(c): v for c, v in cps.items()},
            "state_regions": {str(c): v for c, v in regions.items()},
            "frequency": {str(c): v for c, v in freq.items()}}
