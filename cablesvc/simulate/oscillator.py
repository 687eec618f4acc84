"""Force-driven mass-spring-damper with a Bouc-Wen hysteretic spring, simulated the way the
Bouc-Wen identification benchmark was synthesised (Noel & Schoukens, "Hysteretic benchmark
with a dynamic nonlinearity", Workshop on Nonlinear System Identification Benchmarks 2016).

Model (benchmark eqs 1-2, SI units)::

    mL y'' + cL y' + kL y + z = u                                  u [N], y [m], z [N]
    z' = alpha y' - beta (gamma |y'| |z|^(nu-1) z + delta y' |z|^nu)

Only the products ``beta*gamma`` and ``beta*delta`` are identifiable, so a parameter set is
the 7-vector :data:`PARAM_NAMES` = ``(mL, cL, kL, alpha, beta_gamma, beta_delta, nu)`` in
kg, N s/m, N/m, N/m, 1/(m N^(nu-1)), 1/(m N^(nu-1)), dimensionless. In the convention of
:mod:`cablesvc.models.boucwen` (eq 1 of paper 000) ``k_d = alpha``, ``beta_000 =
beta_gamma``, ``gamma_000 = beta_delta``, ``n = nu``, ``k_e = kL``
(:func:`cablesvc.models.boucwen.from_benchmark`).

What this module reproduces (found by comparing with the benchmark's noiseless test
outputs at the published true parameters; docs/boucwen-benchmark.md has the figures):

* time integration: Newmark, constant average acceleration (gamma_N = 1/2, beta_N = 1/4)
  for y, the trapezoidal rule for z, both implicit and solved together by Newton-Raphson
  at every step (:func:`simulate_fine`), at 15 kHz (20 x 750 Hz), from rest;
* input between the 750 Hz samples: band-limited reconstruction
  (:func:`bandlimited_upsample`): FFT zero padding for a periodic record (exact for the
  multisine, whose lines stop at 150 Hz), a Kaiser-windowed sinc on a point-reflected
  extension otherwise (sine sweep);
* output: MATLAB's ``decimate(y, r, 'fir')`` (30th order Hamming-window FIR with
  ``fir1(30, 1/r)``, point-reflected ends, group delay removed), applied as ``r = 2, 2, 5``
  for the multisines and as one ``r = 20`` for the sine sweep (:func:`decimate_fir`,
  :func:`decimate`).

Everything is vectorised over lanes: ``theta`` is ``(lanes, 7)`` and the numba inner loop
runs the lanes in parallel threads (serially when there are fewer than two per thread),
so a particle swarm evaluates all particles in one call. Forward sensitivities ``d y / d theta`` of the discrete scheme come out of the same
pass when asked for (exact derivatives of the discrete simulator, for least squares).
"""

from __future__ import annotations

import math
from typing import Optional

import numba
import numpy as np
from scipy import fft as sfft
from scipy.signal import firwin, upfirdn

from cablesvc.errors import SimulationError
from cablesvc.lanes import run_lanes
from cablesvc.models.boucwen import bouc_wen_rate

__all__ = [
    "PARAM_NAMES", "PARAM_UNITS", "BENCHMARK_TRUTH", "FS", "UPSAMPLE",
    "bandlimited_upsample", "decimate_fir", "decimate", "fine_input", "coarse_output", "simulate_fine", "simulate",
    "as_theta",
]

PARAM_NAMES = ("mL", "cL", "kL", "alpha", "beta_gamma", "beta_delta", "nu")
PARAM_UNITS = {"mL": "kg", "cL": "N s/m", "kL": "N/m", "alpha": "N/m", "beta_gamma": "1/(m N^(nu-1))",
               "beta_delta": "1/(m N^(nu-1))", "nu": "-"}
#: published true parameters of the benchmark (README of the data; beta*gamma = 1e3*0.8,
#: beta*delta = 1e3*(-1.1)); used only to check the simulator, never as a starting point.
BENCHMARK_TRUTH = {"mL": 2.0, "cL": 10.0, "kL": 5e4, "alpha": 5e4, "beta_gamma": 800.0, "beta_delta": -1100.0,
                   "nu": 1.0}
FS = 750.0          # benchmark sampling frequency [Hz]
UPSAMPLE = 20       # integration at FS * UPSAMPLE = 15 kHz
DECIMATION_NFILT = 30


def as_theta(params) -> np.ndarray:
    """``(lanes, 7)`` float array from a dict (names of :data:`PARAM_NAMES`), a ``(7,)`` or a
    ``(lanes, 7)`` array."""
    if isinstance(params, dict):
        return np.array([[float(params[n]) for n in PARAM_NAMES]])
    th = np.atleast_2d(np.asarray(params, dtype=np.float64))
    if th.shape[-1] != len(PARAM_NAMES) or th.ndim != 2:
        raise SimulationError(f"theta must be (lanes, {len(PARAM_NAMES)}), got {th.shape}")
    return np.ascontiguousarray(th)


def with_extras(theta: np.ndarray, extras: Optional[np.ndarray] = None) -> np.ndarray:
    """``(lanes, 11)``: the ``(lanes, 7)`` parameters followed by :data:`EXTRA_NAMES`
    (``extras`` (lanes, 4); None: no extra force, v_s = 1)."""
    th = np.atleast_2d(np.asarray(theta, dtype=np.float64))
    ex = np.tile([0.0, 0.0, 0.0, 1.0], (th.shape[0], 1)) if extras is None else np.atleast_2d(extras)
    return np.ascontiguousarray(np.concatenate([th, ex], axis=1), dtype=np.float64)


def integrate_lanes(u_fine: np.ndarray, h: float, P: np.ndarray, *, ycap: float = 1e3):
    """The lanes ``P`` (lanes, 11) (:func:`with_extras`) from rest, without sensitivities:
    ``(y (lanes, n) [m], ok (lanes,))``. The one integrator of the oscillator, with or
    without the extra restoring forces."""
    P = np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64)
    u = np.ascontiguousarray(u_fine, dtype=np.float64)
    out_y = np.empty((P.shape[0], u.size))
    status = np.zeros(P.shape[0], dtype=np.int64)
    _run_lanes(u, float(h), P, 0.0, 0.0, 0.0, float(ycap), out_y, np.empty((1, 7, 1)), False, status)
    return out_y, status == 0


# ---- input reconstruction --------------------------------------------------------------

def _sinc_kernel(r: int, half_width: int, beta: float) -> np.ndarray:
    """Kaiser-windowed ideal interpolator ``sinc(n / r)`` for n = -half_width*r..half_width*r."""
    n = np.arange(-half_width * r, half_width * r + 1)
    return np.sinc(n / r) * np.kaiser(n.size, beta)


def bandlimited_upsample(u: np.ndarray, r: int, periodic: bool = True, half_width: int = 64,
                         beta: float = 10.0) -> np.ndarray:
    """Band-limited reconstruction of the input between its samples, ``r`` values per sample.

    ``periodic=True``: ``u`` is one or more whole periods; the spectrum is zero padded
    (ideal interpolation of a periodic signal: exact when the signal has no content at the
    Nyquist frequency, as the benchmark multisines, 5-150 Hz at 750 Hz). Returns
    ``len(u) * r`` samples, sample ``k r`` equal to ``u[k]``.

    ``periodic=False`` (a sine sweep, any record that does not wrap around): the record is
    extended at both ends by point reflection (``2 u[0] - u[k]``, continuous value and
    slope), then interpolated with a Kaiser-windowed sinc of ``half_width`` samples each
    side (``beta`` sets the window; 64 and 10 give ~2e-6 relative error inside the record
    for content below 0.07 fs, the benchmark sweep). Returns ``len(u) * r`` samples like the
    periodic case: the last ``r - 1`` lie after the last input sample, on the reflected
    extension (the benchmark integrated ``len(u) * r`` fine steps, and its decimation filter
    reads them).
    """
    u = np.asarray(u, dtype=np.float64)
    n = u.size
    r = int(r)
    if r == 1:
        return u.copy()
    if periodic:
        U = sfft.rfft(u)
        m = n * r
        Uf = np.zeros(m // 2 + 1, dtype=complex)
        Uf[: U.size] = U
        if n % 2 == 0:
            Uf[n // 2] *= 0.5          # the Nyquist line is shared by +-fs/2 after padding
        return sfft.irfft(Uf, m) * r
    pad = half_width + 1
    if n < pad + 1:
        raise SimulationError(f"bandlimited_upsample: non-periodic record needs > {pad} samples")
    left = 2.0 * u[0] - u[pad:0:-1]
    right = 2.0 * u[-1] - u[-2:-2 - pad:-1]
    ext = np.concatenate([left, u, right])
    ker = _sinc_kernel(r, half_width, beta)
    full = upfirdn(ker, ext, up=r)
    start = pad * r + half_width * r          # delay of the kernel + the left extension
    return full[start: start + n * r]


# ---- decimation as the benchmark did it ------------------------------------------------

def decimate_fir(x: np.ndarray, r: int, nfilt: int = DECIMATION_NFILT) -> np.ndarray:
    """MATLAB ``decimate(x, r, 'fir')`` (the version of the 2015-16 benchmark scripts) along
    the last axis: low-pass ``b = fir1(nfilt, 1/r)`` (Hamming window, unit DC gain =
    ``scipy.signal.firwin(nfilt + 1, 1/r)``) run causally over the record extended with
    ``nfilt + 1`` point-reflected samples before it and ``2 (nfilt + 1)`` after it; the
    output is read every ``r`` samples with the group delay ``nfilt / 2`` removed, so output
    ``k`` is centred on input ``k r``. Returns ``ceil(n / r)`` samples."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[-1]
    r = int(r)
    if r == 1:
        return x.copy()
    nf = nfilt + 1
    if n < 2 * nf + 2:
        raise SimulationError(f"decimate_fir: record of {n} samples too short for a {nf}-tap filter")
    b = firwin(nf, 1.0 / r)
    left = 2.0 * x[..., :1] - x[..., nf:0:-1]
    right = 2.0 * x[..., -1:] - x[..., n - 2:n - 2 - 2 * nf:-1]
    ext = np.concatenate([left, x, right], axis=-1)
    # causal filter output at extended index j is sum_i b_i ext[j - i]; output k needs
    # j = nf + k r + nfilt/2. upfirdn(b, ext, 1, r)[q] = causal output at j = q r.
    gd = nfilt // 2
    off = nf + gd
    out_n = -(-n // r)
    # make the wanted indices fall on multiples of r: drop the first s0 extended samples
    # when the filter still sees its whole history after that, else prepend zeros
    s0 = off % r
    if off - s0 >= nfilt:
        ext = ext[..., s0:]
        q0 = (off - s0) // r
    else:
        pad = (-off) % r
        ext = np.concatenate([np.zeros(ext.shape[:-1] + (pad,)), ext], axis=-1)
        q0 = (off + pad) // r
    y = upfirdn(b, ext, up=1, down=r, axis=-1)
    return np.ascontiguousarray(y[..., q0:q0 + out_n])


def decimate(x: np.ndarray, factors=(2, 2, 5)) -> np.ndarray:
    """Cascade of :func:`decimate_fir` stages (the benchmark multisines: ``factor(20) =
    [2 2 5]``; the benchmark sine sweep: ``(20,)``)."""
    for r in factors:
        x = decimate_fir(x, r)
    return x


# ---- the integrator --------------------------------------------------------------------

#: extra restoring forces beyond the benchmark's equation, after the 7 parameters of
#: :data:`PARAM_NAMES` in a lane's parameter vector: k3 y^3 [N/m^3], c2 v|v| [N s^2/m^2],
#: Fc tanh(v / v_s) [N], [m/s] (``cablesvc.discover.oscillator_case`` fits them; 0 = the
#: benchmark's model)
EXTRA_NAMES = ("k3", "c2", "Fc", "v_s")


@numba.njit(cache=True, inline="always")
def _extra_force(y, v, k3, c2, fc, vs):
    """f = k3 y^3 + c2 v|v| + Fc tanh(v / v_s) [N] and its derivatives df/dy, df/dv."""
    t = math.tanh(v / vs) if fc != 0.0 else 0.0
    f = k3 * y * y * y + c2 * v * abs(v) + fc * t
    fy = 3.0 * k3 * y * y
    fv = 2.0 * c2 * abs(v) + (fc / vs * (1.0 - t * t) if fc != 0.0 else 0.0)
    return f, fy, fv


@numba.njit(cache=True, inline="always")
def _trial(m, c, k, A, B, D, nu, k3, c2, fc, vs, h, hh, y, v, a, z, g, ui, y1, z1):
    """At the trial end-of-step state (y1, z1): the Newmark (1/4, 1/2) velocity v1 and
    acceleration a1, the Bouc-Wen law there (g1, dg/dv, dg/dz, |z|^(nu-1) from
    :func:`cablesvc.models.boucwen.bouc_wen_rate`: the benchmark's eq 2 is eq 1 of 000 with
    k = alpha, beta = beta_gamma, gamma = beta_delta), the extra force's derivatives df/dy,
    df/dv, and the residuals of the equation of motion (r1) and of the trapezoidal z update
    (r2)."""
    v1 = 2.0 / h * (y1 - y) - v
    a1 = 4.0 / hh * (y1 - y) - 4.0 / h * v - a
    g1, gv1, gz1, p1 = bouc_wen_rate(A, B, D, nu, v1, z1)
    f1, fy1, fv1 = _extra_force(y1, v1, k3, c2, fc, vs)
    r1 = m * a1 + c * v1 + k * y1 + z1 + f1 - ui
    r2 = z1 - z - 0.5 * h * (g + g1)
    return v1, a1, g1, gv1, gz1, p1, fy1, fv1, r1, r2


@numba.njit(cache=True)
def _run_lane(u, h, th, y0, v0, z0, ycap, out_y, out_s, sens):
    """One lane: Newmark (1/4, 1/2) for y, trapezoidal rule for z, Newton on (y, z).

    ``th`` (11,): the 7 parameters of :data:`PARAM_NAMES`, then :data:`EXTRA_NAMES` (0:
    the benchmark's model, whose floating-point results the extra terms then leave as they
    were). Writes y at every step into out_y (n,) and, when sens, dy/dtheta (the 7) into
    out_s (7, n). Returns 0 on success, the (1-based) step index where the lane failed
    otherwise (the rest of out_y is then NaN)."""
    m, c, k, A, B, D, nu = th[0], th[1], th[2], th[3], th[4], th[5], th[6]
    k3, c2, fc, vs = th[7], th[8], th[9], th[10]
    n = u.size
    hh = h * h
    keff = 4.0 * m / hh + 2.0 * c / h + k
    y = y0
    v = v0
    z = z0
    f0 = _extra_force(y, v, k3, c2, fc, vs)[0]
    a = (u[0] - c * v - k * y - z - f0) / m
    g, gv, gz, p = bouc_wen_rate(A, B, D, nu, v, z)
    out_y[0] = y
    # sensitivities of the state (y, v, a, z, g) to the 7 parameters
    sy = np.zeros(7)
    sv_ = np.zeros(7)
    sa = np.zeros(7)
    sz = np.zeros(7)
    sg = np.zeros(7)
    if sens:
        # a0 = (u0 - c v0 - k y0 - z0) / m with fixed initial state
        sa[0] = -a / m
        sa[1] = -v / m
        sa[2] = -y / m
        # g0 depends on theta directly
        az = abs(z)
        sg[3] = v
        sg[4] = -abs(v) * p * z
        sg[5] = -v * p * az
        if az > 0.0:
            sg[6] = -(B * abs(v) * p * z + D * v * p * az) * math.log(az)
        for j in range(7):
            out_s[j, 0] = 0.0
    for i in range(1, n):
        ui = u[i]
        # predictor: constant acceleration, explicit z
        y1 = y + h * v + 0.5 * hh * a
        z1 = z + h * g
        conv = False
        for it in range(40):
            v1, a1, g1, gv1, gz1, p1, fy1, fv1, r1, r2 = _trial(m, c, k, A, B, D, nu, k3, c2, fc, vs, h, hh, y, v,
                                                                a, z, g, ui, y1, z1)
            j11 = keff + fy1 + 2.0 / h * fv1
            j21 = -gv1                 # d r2 / d y1 = -h/2 * gv * 2/h
            j22 = 1.0 - 0.5 * h * gz1
            det = j11 * j22 - j21
            dy = (r1 * j22 - r2) / det
            dz = (j11 * r2 - j21 * r1) / det
            y1 -= dy
            z1 -= dz
            if not (abs(y1) < ycap):
                break
            if abs(dy) <= 1e-13 * (abs(y1) + abs(y)) + 1e-300 and abs(dz) <= 1e-13 * (abs(z1) + abs(z)) + 1e-300:
                conv = True
                break
        if not conv:
            # accept a stalled iteration only if the residuals are at rounding level
            v1, a1, g1, gv1, gz1, p1, fy1, fv1, r1, r2 = _trial(m, c, k, A, B, D, nu, k3, c2, fc, vs, h, hh, y, v,
                                                                a, z, g, ui, y1, z1)
            scale_f = abs(ui) + abs(k * y1) + abs(z1) + 1e-12
            if not (abs(y1) < ycap and abs(r1) <= 1e-9 * scale_f and abs(r2) <= 1e-9 * (abs(z1) + abs(z) + 1e-12)):
                for q in range(i, n):
                    out_y[q] = np.nan
                return i
        v1, a1, g1, gv1, gz1, p1, fy1, fv1, r1, r2 = _trial(m, c, k, A, B, D, nu, k3, c2, fc, vs, h, hh, y, v, a,
                                                            z, g, ui, y1, z1)
        if sens:
            j11 = keff + fy1 + 2.0 / h * fv1
            j22 = 1.0 - 0.5 * h * gz1
            det = j11 * j22 + gv1
            az1 = abs(z1)
            lnz = math.log(az1) if az1 > 0.0 else 0.0
            for j in range(7):
                # parts of d v1, d a1 that do not depend on d y1
                dv_part = -2.0 / h * sy[j] - sv_[j]
                da_part = -4.0 / hh * sy[j] - 4.0 / h * sv_[j] - sa[j]
                # explicit parameter derivative of g1
                gth = 0.0
                if j == 3:
                    gth = v1
                elif j == 4:
                    gth = -abs(v1) * p1 * z1
                elif j == 5:
                    gth = -v1 * p1 * az1
                elif j == 6:
                    gth = -(B * abs(v1) * p1 * z1 + D * v1 * p1 * az1) * lnz
                # R1: m da1 + (c + fv) dv1 + (k + fy) dy1 + dz1 + a1 dm + v1 dc + y1 dk = 0
                rhs1 = -(m * da_part + (c + fv1) * dv_part)
                if j == 0:
                    rhs1 -= a1
                elif j == 1:
                    rhs1 -= v1
                elif j == 2:
                    rhs1 -= y1
                # R2: dz1 - dz0 - h/2 (dg0 + gv1 dv1 + gz1 dz1 + gth) = 0
                rhs2 = sz[j] + 0.5 * h * (sg[j] + gv1 * dv_part + gth)
                # [j11, 1; -gv1, j22] [dy1; dz1] = [rhs1; rhs2]
                dy1 = (rhs1 * j22 - rhs2) / det
                dz1 = (j11 * rhs2 + gv1 * rhs1) / det
                dv1 = 2.0 / h * dy1 + dv_part
                da1 = 4.0 / hh * dy1 + da_part
                sg[j] = gv1 * dv1 + gz1 * dz1 + gth
                sy[j] = dy1
                sv_[j] = dv1
                sa[j] = da1
                sz[j] = dz1
                out_s[j, i] = dy1
        y = y1
        v = v1
        a = a1
        z = z1
        g = g1
        out_y[i] = y
    return 0


@numba.njit(cache=True, parallel=True)
def _run_lanes_parallel(u, h, theta, y0, v0, z0, ycap, out_y, out_s, sens, status):
    for lane in numba.prange(theta.shape[0]):
        status[lane] = _run_lane(u, h, theta[lane], y0, v0, z0, ycap, out_y[lane],
                                 out_s[lane] if sens else out_s[0], sens)


@numba.njit(cache=True)
def _run_lanes_serial(u, h, theta, y0, v0, z0, ycap, out_y, out_s, sens, status):
    for lane in range(theta.shape[0]):
        status[lane] = _run_lane(u, h, theta[lane], y0, v0, z0, ycap, out_y[lane],
                                 out_s[lane] if sens else out_s[0], sens)


def _run_lanes(u, h, theta, y0, v0, z0, ycap, out_y, out_s, sens, status):
    """Lanes in numba threads when there are at least two per thread, serially otherwise
    (:func:`cablesvc.lanes.run_lanes`)."""
    run_lanes(_run_lanes_parallel, _run_lanes_serial, theta.shape[0], u, h, theta, y0, v0, z0, ycap, out_y, out_s,
              sens, status, min_per_thread=2)


def simulate_fine(u_fine: np.ndarray, h: float, theta, *, y0: float = 0.0, v0: float = 0.0, z0: float = 0.0,
                  sensitivities: bool = False, ycap: float = 1e3):
    """Integrate the oscillator over the fine input ``u_fine`` [N] with step ``h`` [s].

    Newmark constant-average-acceleration (gamma_N = 1/2, beta_N = 1/4) for the mechanical
    equation (benchmark eq 1), the trapezoidal rule ``z1 = z0 + h/2 (z'0 + z'1)`` for eq 2,
    both implicit: at every step a 2x2 Newton-Raphson iteration on (y1, z1) to rounding
    level, starting from a constant-acceleration / explicit-Euler predictor. Initial state
    (y0 [m], v0 [m/s], z0 [N]); the initial acceleration satisfies eq 1.

    ``theta``: ``(lanes, 7)`` (see :func:`as_theta`); lanes run in parallel threads.
    Returns ``(y, dy, ok)``: ``y`` ``(lanes, n)`` [m]; ``dy`` ``(lanes, 7, n)`` = dy/dtheta
    of the discrete scheme when ``sensitivities`` (else None); ``ok`` ``(lanes,)`` False
    where a lane diverged (|y| > ``ycap`` [m] or Newton failed; its y is NaN from there).
    """
    th = with_extras(as_theta(theta))
    u = np.ascontiguousarray(u_fine, dtype=np.float64)
    L, n = th.shape[0], u.size
    out_y = np.empty((L, n))
    out_s = np.empty((L, 7, n)) if sensitivities else np.empty((1, 7, 1))
    status = np.zeros(L, dtype=np.int64)
    _run_lanes(u, float(h), th, float(y0), float(v0), float(z0), float(ycap), out_y, out_s, bool(sensitivities),
               status)
    ok = status == 0
    if sensitivities and not ok.all():
        out_s[~ok] = np.nan
    return out_y, (out_s if sensitivities else None), ok


def fine_input(u: np.ndarray, r: int, *, periodic: bool = True, periods: int = 1, tail: int = 0,
               hold: bool = False) -> np.ndarray:
    """The fine input (``r`` values per sample of ``u``) that a simulation integrates:
    :func:`bandlimited_upsample` (``periodic``), or the samples held constant for ``r`` fine
    steps (``hold``, zero-order hold); a periodic record repeated ``periods`` times, plus
    ``tail`` samples of its next period."""
    uf = np.repeat(np.asarray(u, float), r) if hold else bandlimited_upsample(u, r, periodic=periodic)
    if periodic:
        reps = [uf] * int(periods)
        if tail:
            reps.append(uf[: int(tail) * r])
        uf = np.concatenate(reps)
    return uf


def coarse_output(y: np.ndarray, ok: np.ndarray, r: int, factors) -> np.ndarray:
    """The fine output ``y`` (lanes, n) at the sample rate: decimated by ``factors``
    (:func:`decimate`, diverged lanes NaN), or every ``r``-th fine sample when ``factors`` is
    None or ()."""
    if factors:
        y = decimate(np.nan_to_num(y, nan=0.0), factors)
        y[~ok] = np.nan
        return y
    return y[:, ::r]


def simulate(u: np.ndarray, theta, *, fs: float = FS, upsample: int = UPSAMPLE, periodic: bool = True,
             periods: int = 1, keep: slice | None = None, factors=(2, 2, 5), tail: int = 0,
             sensitivities: bool = False, **kw):
    """Simulate at ``fs * upsample`` from the samples ``u`` [N] at ``fs`` [Hz] and return the
    output at ``fs``.

    The input is reconstructed by :func:`bandlimited_upsample` (``periodic``); a periodic
    record is repeated ``periods`` times, plus ``tail`` extra samples of its next period
    (``tail`` keeps the decimation filter's end effects out of the kept samples, as the
    benchmark's extra period did). The fine output is decimated by ``factors``
    (:func:`decimate`; ``None`` or ``()`` reads every ``upsample``-th fine sample instead),
    and ``keep`` selects the returned coarse samples.

    Returns ``(y, dy, ok)`` as :func:`simulate_fine` but at ``fs``.
    """
    r = int(upsample)
    uf = fine_input(u, r, periodic=periodic, periods=periods, tail=tail)
    y, dy, ok = simulate_fine(uf, 1.0 / (fs * r), theta, sensitivities=sensitivities, **kw)
    y = coarse_output(y, ok, r, factors)
    if dy is not None:
        dy = decimate(dy, factors) if factors else dy[:, :, ::r]
    if keep is not None:
        y = y[:, keep]
        if dy is not None:
            dy = dy[:, :, keep]
    return y, dy, ok
