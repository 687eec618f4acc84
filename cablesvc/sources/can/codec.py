"""DBC signals compiled into numpy plans: frame bytes <-> signal values without cantools.

The DBC is the single source of truth: it is loaded with cantools, and every start bit,
width, byte order, signedness, scale, offset, float type and ``not_available`` value is
taken from cantools' signal objects (:func:`signal_of`). They are compiled once into a plan
(byte indices, shifts, masks, sign bits, scales as numpy arrays: :class:`FrameCodec` for one
message, :class:`TickCodec` for all frames of a tick laid end to end), so encoding and
decoding never call cantools per frame: one numpy gather/scatter per tick. The tests prove
the plan equal to cantools' own ``decode_message``/``encode_message``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence, Union

import can
import numpy as np

from cablesvc.sources.base import TickInput
from cablesvc.sources.can.dbc import NOT_AVAILABLE, POSE_SIGNALS

__all__ = ["FrameCodec", "Signal", "TickCodec", "signal_of"]

_I64 = np.dtype("<i8")  # frame bytes are read and written as little-endian 64-bit words
_I64_MIN = -(1 << 63)
_F32_MAX = float(np.finfo(np.float32).max)
_F64_MAX = float(np.finfo(np.float64).max)
_BELOW_2_63 = float(np.nextafter(2.0 ** 63, 0.0))


@dataclass(frozen=True)
class Signal:
    """One DBC signal as cantools describes it (what the compiled plan needs)."""

    name: str
    start: int  # cantools' start bit (DBC numbering; big-endian: the most significant bit)
    length: int
    signed: bool
    scale: float
    offset: float
    little_endian: bool
    not_available: Optional[int]  # raw value meaning "not measured", or None (floats: NaN)
    is_float: bool = False

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    def span(self) -> tuple[int, int, int]:
        """(first byte, number of bytes, right shift): the bytes holding the signal, read as
        one integer (little-endian signals: least significant byte first; big-endian: most
        significant first), hold the raw value at bit ``shift``."""
        if self.little_endian:
            first, shift = divmod(self.start, 8)
            return first, (shift + self.length + 7) // 8, shift
        msb = (self.start // 8) * 8 + (7 - self.start % 8)  # bit index counted MSB-first
        lsb = msb + self.length - 1
        return msb // 8, lsb // 8 - msb // 8 + 1, 7 - lsb % 8


class _BitPlan:
    """Signals at fixed bit positions of a byte buffer (one frame, or the frames of a tick
    one after the other), compiled into numpy arrays.

    Decoding is one gather: for signal k, the (up to 8) bytes of its span are picked into
    place k of an (n, 8) byte matrix (in little-endian order: big-endian spans reversed,
    unused places from a zero pad byte) that is viewed as n int64 words; shifting the field
    to the top and arithmetic-shifting it down sign-extends it (unsigned fields are masked
    after); physical = raw * scale + offset, exactly as cantools computes it. Encoding
    reverses it: raw = (value - offset) / scale rounded half to even (cantools' ``round``),
    masked and shifted words, their bytes scattered back with one ``bincount`` (signals
    never share a bit, so adding the bytes is OR-ing them).
    """

    def __init__(self, placed: Sequence[tuple[Signal, int]], length: int):
        n = len(placed)
        self.n = n
        self.length = int(length)
        self.signals = [s for s, _ in placed]
        idx = np.full((n, 8), self.length, dtype=np.intp)
        self.shift = np.zeros(n, np.int64)  # where the raw value starts in the gathered word
        self.lsh = np.zeros(n, np.int64)  # decode: field to the top ...
        self.rsh = np.zeros(n, np.int64)  # ... and down again, sign-extending
        self.umask = np.full(n, -1, np.int64)  # decode: unsigned fields masked after
        self.mask = np.zeros(n, np.int64)  # encode: the field's bits
        self.scale = np.ones(n)
        self.offset = np.zeros(n)
        self.lo = np.zeros(n)  # raw range that encodes a value (the not_available raw excluded)
        self.hi = np.zeros(n)
        self.na = np.full(n, _I64_MIN, np.int64)  # the not_available raw (none: a value no field < 64 bits has)
        self.has_na = np.zeros(n, dtype=bool)
        self.na_raw = np.zeros(n)
        f32: list[int] = []
        f64: list[int] = []
        full_width = False
        for k, (s, off) in enumerate(placed):
            first, nbytes, shift = s.span()
            if nbytes > 8:
                raise ValueError(f"signal {s.name}: {s.length} bits from bit {s.start} span {nbytes} bytes; "
                                 f"cablesvc handles signals within 8 consecutive bytes")
            if off + first + nbytes > self.length:
                raise ValueError(f"signal {s.name} does not fit in {self.length} bytes")
            pos = np.arange(nbytes)
            idx[k, :nbytes] = off + first + (pos if s.little_endian else pos[::-1])
            field_mask = (1 << s.length) - 1
            self.shift[k] = shift
            self.lsh[k] = 64 - shift - s.length
            self.rsh[k] = 64 - s.length
            self.mask[k] = _as_i64(field_mask)
            if not s.signed or s.is_float:
                self.umask[k] = _as_i64(field_mask)
            self.scale[k] = s.scale
            self.offset[k] = s.offset
            if s.is_float:
                (f32 if s.length == 32 else f64).append(k)
                self.has_na[k] = True  # NaN
                self.na_raw[k] = math.nan
                lim = _F32_MAX if s.length == 32 else _F64_MAX
                self.lo[k], self.hi[k] = -lim, lim
                continue
            if s.length == 64 and not s.signed:
                raise ValueError(f"signal {s.name}: unsigned 64-bit integers are not supported")
            full_width |= s.length == 64
            lo, hi = s.raw_min, s.raw_max
            if s.not_available is not None:
                self.has_na[k] = True
                self.na_raw[k] = s.not_available
                self.na[k] = s.not_available
                if s.not_available == lo:
                    lo += 1
                elif s.not_available == hi:
                    hi -= 1
            self.lo[k], self.hi[k] = float(lo), min(float(hi), _BELOW_2_63)
        self.idx = idx.ravel()
        self.f32 = np.array(f32, dtype=np.intp)
        self.f64 = np.array(f64, dtype=np.intp)
        self.floats = np.array(sorted(f32 + f64), dtype=np.intp)
        self.any_offset = bool(np.any(self.offset != 0.0))
        self._na_needs_mask = full_width  # a 64-bit field can hold the "no sentinel" value

    # ---------------------------------------------------------------- decode
    def words(self, buf: Union[bytes, bytearray]) -> np.ndarray:
        """Raw value of every signal (int64; sign-extended; float signals: their IEEE bits)
        from ``buf``: ``length`` bytes and one zero byte after them."""
        x = np.frombuffer(buf, np.uint8)[self.idx].view(_I64)
        x <<= self.lsh
        x >>= self.rsh
        x &= self.umask
        return x

    def phys(self, x: np.ndarray) -> np.ndarray:
        """Physical values (float64): raw * scale + offset, floats from their IEEE bits."""
        v = x.astype(np.float64)
        v *= self.scale
        if self.any_offset:
            v += self.offset
        if self.floats.size:
            with np.errstate(all="ignore"):  # NaN/inf bit patterns and overflow: as IEEE (and cantools) say
                if self.f32.size:
                    k = self.f32
                    v[k] = x[k].astype(np.uint32).view(np.float32) * self.scale[k] + self.offset[k]
                if self.f64.size:
                    k = self.f64
                    v[k] = x[k].view(np.float64) * self.scale[k] + self.offset[k]
        return v

    def not_available(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Which signals hold their not_available raw value (float signals: NaN)."""
        na = x == self.na
        if self._na_needs_mask:
            na &= self.has_na
        if self.floats.size:
            na[self.floats] = np.isnan(v[self.floats])
        return na

    # ---------------------------------------------------------------- encode
    def raw(self, vals: np.ndarray) -> np.ndarray:
        """Physical values -> raw values as floats: (value - offset) / scale, rounded half to
        even for integer signals (cantools' ``round``). NaN stays NaN."""
        r = (vals - self.offset) / self.scale if self.any_offset else vals / self.scale
        if self.floats.size:
            keep = r[..., self.floats].copy()
            np.rint(r, out=r)
            r[..., self.floats] = keep
        else:
            np.rint(r, out=r)
        return r

    def scatter(self, x: np.ndarray) -> np.ndarray:
        """Masked, shifted words (n,) or (rows, n) int64 -> the buffer bytes (length,) or
        (rows, length) uint8."""
        b = x.astype(_I64, copy=False).view(np.uint8)
        if x.ndim == 1:
            return np.bincount(self.idx, weights=b, minlength=self.length + 1)[: self.length].astype(np.uint8)
        rows, width = x.shape[0], self.length + 1
        flat = (self.idx[None, :] + width * np.arange(rows, dtype=np.intp)[:, None]).ravel()
        out = np.bincount(flat, weights=b.ravel(), minlength=rows * width).reshape(rows, width)
        return out[:, : self.length].astype(np.uint8)

    def pack(self, vals: np.ndarray, what: str) -> np.ndarray:
        """Physical values (n,) or (rows, n), NaN = not_available -> buffer bytes.

        Raises ValueError naming ``what`` and the signal when a value cannot be sent.
        """
        r = self.raw(vals)
        if np.count_nonzero((r >= self.lo) & (r <= self.hi)) != r.size:  # NaN fails both
            r = self._not_ok(vals, r, what)
        if self.floats.size:
            ri = r.copy()
            ri[..., self.floats] = 0.0
            x = ri.astype(np.int64)
            if self.f32.size:
                x[..., self.f32] = r[..., self.f32].astype(np.float32).view(np.uint32)
            if self.f64.size:
                x[..., self.f64] = r[..., self.f64].view(np.int64)
        else:
            x = r.astype(np.int64)
        x &= self.mask
        x <<= self.shift
        return self.scatter(x)

    def _not_ok(self, vals: np.ndarray, r: np.ndarray, what: str) -> np.ndarray:
        nan = np.isnan(r)
        bad = nan & ~self.has_na
        if bad.any():
            at = tuple(np.argwhere(bad)[0])
            s = self.signals[at[-1]]
            raise ValueError(f"{what}{_row(at)}: signal {s.name} has no {NOT_AVAILABLE} value; "
                             f"cannot send a missing value")
        r = np.where(nan, self.na_raw, r)
        bad = ~nan & ~((r >= self.lo) & (r <= self.hi))
        if bad.any():
            at = tuple(np.argwhere(bad)[0])
            k = at[-1]
            s, v = self.signals[k], float(vals[at])
            if not math.isfinite(v):
                raise ValueError(f"{what}{_row(at)}: signal {s.name}: value {v!r} is not finite")
            lo, hi = self.lo[k] * s.scale + s.offset, self.hi[k] * s.scale + s.offset
            raise ValueError(f"{what}{_row(at)}: signal {s.name}: {v!r} is outside the range "
                             f"[{lo:g}, {hi:g}] of the DBC")
        return r


def _as_i64(v: int) -> int:
    """An unsigned 64-bit pattern as the int64 with the same bits."""
    return v - (1 << 64) if v >= 1 << 63 else v


def _row(at: tuple[int, ...]) -> str:
    return f" (row {at[0]})" if len(at) > 1 else ""


class FrameCodec:
    """One DBC message (a cantools ``Message``) compiled into a plan: its bytes <-> its
    signals without calling cantools.

    :meth:`decode` gives what ``db.decode_message(id, data, decode_choices=False)`` gives
    (physical values), :meth:`encode` what ``db.encode_message(id, values)`` gives (bytes;
    a None/NaN value is sent as the signal's ``not_available`` raw value), and
    :meth:`decode_raw` / :meth:`encode_raw` work on raw integers (float signals: the float).
    """

    def __init__(self, msg: Any, signals: Optional[list[Signal]] = None):
        self.msg = msg
        self.name: str = msg.name
        self.frame_id: int = msg.frame_id
        self.is_extended: bool = bool(msg.is_extended_frame)
        self.is_fd: bool = bool(getattr(msg, "is_fd", False))
        self.length: int = int(msg.length)
        self.bitrate_switch: bool = self.is_fd and _brs(msg)
        if signals is None:
            signals = [signal_of(s, msg.name, None) for s in msg.signals]
        self.signals = signals
        self.index = {s.name: k for k, s in enumerate(signals)}
        self.plan = _BitPlan([(s, 0) for s in signals], self.length)

    def _words(self, data: Union[bytes, bytearray]) -> np.ndarray:
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} data bytes, the DBC says {self.length}")
        return self.plan.words(bytes(data) + b"\0")

    def decode(self, data: Union[bytes, bytearray]) -> dict[str, float]:
        """Physical value of every signal (not_available raws decode like any other value)."""
        v = self.plan.phys(self._words(data))
        return dict(zip(self.index, v.tolist()))

    def decode_raw(self, data: Union[bytes, bytearray]) -> tuple[Union[int, float], ...]:
        """Raw value of every signal, in DBC order (integers; float signals: the float)."""
        w = self._words(data)
        raws: list[Any] = w.tolist()
        for k in self.plan.floats.tolist():
            fmt, n = ("<f", 4) if self.signals[k].length == 32 else ("<d", 8)
            raws[k] = struct.unpack(fmt, (int(w[k]) & ((1 << 8 * n) - 1)).to_bytes(n, "little"))[0]
        return tuple(raws)

    def encode(self, values: Mapping[str, Optional[float]]) -> bytes:
        """Frame bytes from physical values (every signal; None/NaN = not_available)."""
        vals = np.array([math.nan if values[s.name] is None else float(values[s.name]) for s in self.signals],
                        dtype=np.float64)
        return self.plan.pack(vals, self.name).tobytes()

    def encode_raw(self, raws: Sequence[Union[int, float]]) -> bytes:
        """Frame bytes from raw values in DBC order (integers; float signals: the float)."""
        raws = list(raws)
        if len(raws) != len(self.signals):
            raise ValueError(f"{self.name}: {len(raws)} raw values for {len(self.signals)} signals")
        u = np.zeros(len(raws), np.int64)
        for k, (s, v) in enumerate(zip(self.signals, raws)):
            if s.is_float:
                fmt = "<f" if s.length == 32 else "<d"
                u[k] = _as_i64(int.from_bytes(struct.pack(fmt, float(v)), "little"))
            else:
                u[k] = _as_i64(int(v) & ((1 << s.length) - 1))
        u <<= self.plan.shift
        return self.plan.scatter(u).tobytes()


def _brs(msg: Any) -> bool:
    """The message's CANFD_BRS attribute (bit rate switch), default on."""
    spec = getattr(msg, "dbc", None)
    if spec is None:
        return True
    definition = (spec.attribute_definitions or {}).get("CANFD_BRS")
    attr = (spec.attributes or {}).get("CANFD_BRS")
    value: Any = attr.value if attr is not None else (definition.default_value if definition is not None else 1)
    choices = definition.choices if definition is not None else None
    if choices and isinstance(value, int) and 0 <= value < len(choices):
        value = choices[value]
    return str(value).strip() != "0"


def signal_of(sig: Any, where: str, problems: Optional[list[str]]) -> Signal:
    """A cantools signal as a :class:`Signal`; a multiplexed signal adds a line to
    ``problems`` (when given) naming ``where``."""
    na = None
    choices = getattr(sig, "choices", None) or {}
    for raw, label in choices.items():
        if str(label) == NOT_AVAILABLE:
            na = int(raw)
    if problems is not None and (getattr(sig, "is_multiplexer", False) or getattr(sig, "multiplexer_ids", None)):
        problems.append(f"{where}: signal {sig.name} is multiplexed; not supported")
    return Signal(
        name=sig.name, start=int(sig.start), length=int(sig.length), signed=bool(sig.is_signed),
        scale=float(sig.scale), offset=float(sig.offset),
        little_endian=sig.byte_order == "little_endian", not_available=None if sig.is_float else na,
        is_float=bool(sig.is_float),
    )


# --------------------------------------------------------------------------------------
# the tick codec: all frames of a tick in one plan
# --------------------------------------------------------------------------------------


def _get(tick: Any, key: str) -> Any:
    if isinstance(tick, Mapping):
        return tick.get(key)
    return getattr(tick, key, None)


class TickCodec:
    """Every signal of a tick in one :class:`_BitPlan` over the frames laid end to end
    (data frames in sending order, then SYNC, then one zero pad byte).

    Value order: motor_length_0..m-1, force_0..m-1, the seven pose signals, temperature
    (those the DBC has), t, seq, then the tick_counter of each data frame.
    """

    def __init__(self, lay: Any):
        """``lay``: a :class:`~cablesvc.sources.can.layout.CanLayout` (its frames, signals and widths)."""
        m = lay.n_cables
        frames = lay.frames
        self.offsets: list[int] = []
        off = 0
        for c in frames:
            self.offsets.append(off)
            off += c.length
        self.length = off
        at = {c.name: o for c, o in zip(frames, self.offsets)}
        names = [f"motor_length_{i}" for i in range(m)]
        k = m
        self.k_ml = slice(0, m)
        self.k_force: Optional[slice] = None
        self.k_pos: Optional[slice] = None
        self.k_ori: Optional[slice] = None
        self.k_pose: Optional[slice] = None
        self.k_temp: Optional[int] = None
        if lay.has_force:
            names += [f"force_{i}" for i in range(m)]
            self.k_force = slice(k, k + m)
            k += m
        if lay.has_pose:
            names += list(POSE_SIGNALS)
            self.k_pos, self.k_ori, self.k_pose = slice(k, k + 3), slice(k + 3, k + 7), slice(k, k + 7)
            k += 7
        self.n_vectors = k  # values that come from the tick's arrays
        if lay.has_temperature:
            names.append("temperature")
            self.k_temp = k
            k += 1
        names += ["t", "seq"]
        self.k_t, self.k_seq = k, k + 1
        placed = [(codec.signals[j], at[codec.name]) for codec, j in (lay.where[n] for n in names)]
        placed += [(c.signals[c.index["tick_counter"]], at[c.name]) for c in lay.data]
        self.names = names + [f"{c.name}.tick_counter" for c in lay.data]
        self.plan = _BitPlan(placed, self.length)
        self.n = len(placed)
        self.m = m
        self.m_shape = (m,)
        self.k_counters = slice(self.k_seq + 1, self.n)
        # the values after the vectors: temperature (NaN: not available), t, seq, counters
        self.tail = np.zeros(self.n - self.n_vectors)
        if self.k_temp is not None:
            self.tail[0] = math.nan
        self.nan_m = np.full(m, math.nan)
        self.nan3 = np.full(3, math.nan)
        self.nan4 = np.full(4, math.nan)
        self.seq_mask = (1 << lay.seq_bits) - 1
        self.cmask = (1 << lay.counter_bits) - 1
        self.meta = [(c.frame_id, c.is_extended, c.is_fd, c.bitrate_switch, o, o + c.length)
                     for c, o in zip(frames, self.offsets)]
        # what the controller adds to a precomputed row every tick: t, seq and the counters,
        # as (first byte, end byte, byte order, shift, mask) in the tick's bytes
        self._stamp_fields = []
        for sig, off in placed[self.k_t:]:
            first, nbytes, shift = sig.span()
            self._stamp_fields.append((off + first, off + first + nbytes,
                                       "little" if sig.little_endian else "big", shift, (1 << sig.length) - 1))
        self._counter_bits: dict[int, int] = {}  # tick counter -> its bits in all data frames
        self.t_signal = placed[self.k_t][0]
        if self.t_signal.is_float:
            raise ValueError("SYNC.t: a float signal; cablesvc sends t as an integer count")

    # ---------------------------------------------------------------- encode
    def values(self, tick: Any) -> tuple[np.ndarray, int]:
        """(physical values in plan order, NaN = not available; seq) of a tick; seq and the
        counters already reduced to their widths."""
        if type(tick) is TickInput:
            seq, t, ml, force = tick.seq, tick.t, tick.motor_length, tick.force
            pos, ori, temp = tick.position, tick.orientation, tick.temperature
        else:
            seq, t, ml, force = _get(tick, "seq"), _get(tick, "t"), _get(tick, "motor_length"), _get(tick, "force")
            pos, ori, temp = _get(tick, "position"), _get(tick, "orientation"), _get(tick, "temperature")
        seq = int(seq)
        ml = np.asarray(ml, dtype=np.float64)
        if ml.shape != self.m_shape:
            raise ValueError(f"tick seq {seq}: motor_length has shape {ml.shape}, the DBC has {self.m} cables")
        parts = [ml]
        if force is not None:
            force = np.asarray(force, dtype=np.float64)
            if force.shape != self.m_shape:
                raise ValueError(f"tick seq {seq}: force has shape {force.shape}, the DBC has {self.m} cables")
        if self.k_force is not None:
            parts.append(self.nan_m if force is None else force)
        if self.k_pos is not None:
            if pos is not None:
                pos = np.asarray(pos, dtype=np.float64)
                if pos.shape != (3,):
                    raise ValueError(f"tick seq {seq}: position has shape {pos.shape}, expected (3,)")
            if ori is not None:
                ori = np.asarray(ori, dtype=np.float64)
                if ori.shape != (4,):
                    raise ValueError(f"tick seq {seq}: orientation has shape {ori.shape}, expected (4,)")
            parts.append(self.nan3 if pos is None else pos)
            parts.append(self.nan4 if ori is None else ori)
        parts.append(self.tail)
        vals = np.concatenate(parts)
        if self.k_temp is not None and temp is not None:
            vals[self.k_temp] = temp
        vals[self.k_t] = t
        vals[self.k_seq] = seq & self.seq_mask
        if self.k_counters.start < self.n:
            vals[self.k_counters] = seq & self.cmask
        return vals, seq

    def encode(self, tick: Any) -> np.ndarray:
        """All frame bytes of the tick, end to end (uint8, ``length``)."""
        vals, seq = self.values(tick)
        return self.plan.pack(vals, f"tick seq {seq}")

    def messages(self, buf: Union[bytes, bytearray]) -> list[can.Message]:
        """The frames of a tick's bytes, as python-can messages in sending order."""
        return [can.Message(arbitration_id=fid, is_extended_id=ext, is_fd=fd, bitrate_switch=brs,
                            data=buf[a:b], check=False)
                for fid, ext, fd, brs, a, b in self.meta]

    def encode_rows(self, motor_length: np.ndarray, force: Optional[np.ndarray] = None,
                    position: Optional[np.ndarray] = None, orientation: Optional[np.ndarray] = None,
                    temperature: Optional[np.ndarray] = None, chunk: int = 4096) -> np.ndarray:
        """Frame bytes of many ticks at once, with t, seq and the counters left 0
        (:meth:`stamp` adds them): (rows, ``length``) uint8. NaN is sent as not_available; a
        row whose position or orientation is all NaN has no pose (both not_available), as
        ``SimulatedController.tick_at`` plays it."""
        ml = np.asarray(motor_length, dtype=np.float64)
        rows = ml.shape[0]
        if ml.shape[1:] != self.m_shape:
            raise ValueError(f"motor_length has shape {ml.shape}, the DBC has {self.m} cables")
        out = np.empty((rows, self.length), dtype=np.uint8)
        base = np.concatenate([np.zeros(self.n_vectors), self.tail])
        for a in range(0, rows, chunk):
            b = min(rows, a + chunk)
            vals = np.tile(base, (b - a, 1))
            vals[:, self.k_ml] = ml[a:b]
            if self.k_force is not None:
                vals[:, self.k_force] = math.nan if force is None else force[a:b]
            if self.k_pos is not None:
                if position is None or orientation is None:
                    vals[:, self.k_pose] = math.nan
                else:
                    p = np.asarray(position[a:b], np.float64)
                    q = np.asarray(orientation[a:b], np.float64)
                    gone = (np.isnan(p).all(axis=1) | np.isnan(q).all(axis=1))[:, None]
                    vals[:, self.k_pos] = np.where(gone, math.nan, p)
                    vals[:, self.k_ori] = np.where(gone, math.nan, q)
            if self.k_temp is not None and temperature is not None:
                vals[:, self.k_temp] = temperature[a:b]
            out[a:b] = self.plan.pack(vals, f"rows {a}-{b - 1}")
        return out

    def _place(self, v: int, a: int, b: int, order: str, shift: int, mask: int) -> int:
        """Field value ``v`` as bits of the tick's bytes read as one little-endian integer."""
        if order == "little":
            return (v & mask) << (8 * a + shift)
        return int.from_bytes(((v & mask) << shift).to_bytes(b - a, "big"), "little") << (8 * a)

    def stamp(self, row: Union[np.ndarray, bytes, int], seq: int, t: float) -> bytes:
        """A row of :meth:`encode_rows` (its bytes, or those read as one little-endian
        integer) with this tick's t, seq and counters: the tick's bytes, equal to
        :meth:`encode` of the tick. A few integer operations, no numpy."""
        s = self.t_signal
        raw = round((t - s.offset) / s.scale)
        if not s.raw_min <= raw <= s.raw_max:
            raise ValueError(f"tick seq {seq}: signal t: {t!r} is outside the range of the DBC")
        if not isinstance(row, int):
            row = int.from_bytes(row.tobytes() if isinstance(row, np.ndarray) else row, "little")
        c = seq & self.cmask
        counters = self._counter_bits.get(c)
        if counters is None:
            counters = self._counter_bits[c] = sum(
                (self._place(c, *f) for f in self._stamp_fields[2:]), 0)
        word = (row | counters | self._place(raw, *self._stamp_fields[0])
                | self._place(seq & self.seq_mask, *self._stamp_fields[1]))
        return word.to_bytes(self.length, "little")

    # ---------------------------------------------------------------- decode
    def decode(self, buf: Union[bytes, bytearray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(raw values, physical values, not_available mask) of a tick's bytes plus the pad byte."""
        plan = self.plan
        x = plan.words(buf)
        v = plan.phys(x)
        return x, v, plan.not_available(x, v)

