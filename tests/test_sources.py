"""Input sources: DBC frames, CAN (in-process virtual bus and across processes), Modbus TCP
(real pymodbus server on 127.0.0.1), replay of real MCAP/CSV files, and the shared
validator. Real components only; nothing leaves the loopback host."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest

from cablesvc.config import load_robot
from cablesvc.recording import Recording, read_recording, write_recording
from cablesvc.simulate import simulate_recording
from cablesvc.sources import (
    CanSource,
    ModbusSource,
    Rejection,
    ReplaySource,
    SourceConfigError,
    TickAssembler,
    TickInput,
    TickValidator,
    encode_tick,
    load_can_layout,
    load_register_map,
    make_dbc,
    open_source,
)
from cablesvc.netutil import free_tcp_port, free_udp_port, loopback_bus_config
from cablesvc.sources.can import FD_LENGTHS, FrameCodec
from cablesvc.sources.simulated import CanController, ModbusController

REPO = Path(__file__).resolve().parents[1]
DBC = REPO / "robots" / "ipanema3.dbc"
FD_DBC = REPO / "robots" / "ipanema3-fd.dbc"
MODBUS_MAP = REPO / "robots" / "ipanema3.modbus.toml"

# half of the DBC resolutions: what a value may move in one encode/decode
TOL_CAN = {"motor_length": 0.5e-8, "force": 0.5e-3, "position": 0.5e-7, "orientation": 0.5e-8,
           "temperature": 0.5e-2, "t": 0.5e-6}


@pytest.fixture(scope="module")
def robot():
    return load_robot("ipanema3")


@pytest.fixture(scope="module")
def layout(robot):
    return load_can_layout(DBC, robot.n_cables)


@pytest.fixture(scope="module")
def fd_layout(robot):
    return load_can_layout(FD_DBC, robot.n_cables)


@pytest.fixture(scope="module")
def twin(robot) -> Recording:
    """A short digital-twin recording (1 s at 500 Hz) shared by the controllers."""
    return simulate_recording(robot, "trajectory", None, duration=1.0, rate=500.0, seed=3)


def _tick(rng, seq=7, t=1.234567, force=True, pose=True, temperature=True, m=8) -> TickInput:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return TickInput(
        seq=seq, t=t, motor_length=rng.uniform(0.5, 21.0, m),
        position=rng.uniform(-5, 5, 3) if pose else None, orientation=q if pose else None,
        force=rng.uniform(-50, 8000, m) if force else None,
        temperature=float(rng.uniform(-40, 120)) if temperature else None, stamp_ns=0,
    )


def _feed_all(asm: TickAssembler, msgs, ts=100.0):
    out = []
    for k, msg in enumerate(msgs):
        msg.timestamp = ts + k * 1e-5
        out += asm.feed(msg, now_ns=123)
    return out


def _assert_close(got: TickInput, want: TickInput, tol: dict[str, float]) -> None:
    assert got.seq == want.seq
    assert abs(got.t - want.t) <= tol["t"] + 1e-12
    np.testing.assert_allclose(got.motor_length, want.motor_length, rtol=0, atol=tol["motor_length"] + 1e-15)
    for name in ("force", "position", "orientation"):
        g, w = getattr(got, name), getattr(want, name)
        assert (g is None) == (w is None), name
        if w is not None:
            np.testing.assert_allclose(g, w, rtol=0, atol=tol[name] + 1e-15, err_msg=name)
    assert (got.temperature is None) == (want.temperature is None)
    if want.temperature is not None:
        assert abs(got.temperature - want.temperature) <= tol["temperature"] + 1e-12


# --------------------------------------------------------------------------------------
# DBC and the assembler (pure)
# --------------------------------------------------------------------------------------


def test_shipped_dbc_is_the_generated_layout_and_documents_its_signals(robot, layout):
    assert DBC.read_text() == make_dbc(robot)
    assert layout.n_cables == 8 and layout.has_force and layout.has_pose and layout.has_temperature
    assert layout.counter_bits == 8 and layout.seq_bits == 24
    assert [c.name for c in layout.data] == [f"CABLE_{i}" for i in range(8)] + [
        "PLATFORM_X", "PLATFORM_Y", "PLATFORM_Z", "PLATFORM_QXY", "PLATFORM_QZW"]
    for msg in layout.db.messages:
        assert msg.length == 8 and not msg.is_extended_frame and msg.comment
        for sig in msg.signals:
            assert sig.comment, (msg.name, sig.name)
    ml = layout.signal("motor_length_0")
    assert ml.length == 32 and ml.scale <= 1e-8
    assert layout.signal("force_3").scale <= 1e-3 and layout.signal("position_z").scale <= 1e-7
    assert layout.signal("orientation_qw").scale <= 1e-8
    t = layout.signal("t")
    assert t.scale <= 1e-6 and (2 ** t.length) * t.scale > 24 * 3600  # no wrap within a day


def test_dbc_round_trip_within_resolution_and_agrees_with_cantools(layout):
    rng = np.random.default_rng(0)
    for k in range(40):
        want = _tick(rng, seq=int(rng.integers(0, 2**24)), t=float(rng.uniform(0, 1e6)),
                     force=k % 3 != 0, pose=k % 4 != 1, temperature=k % 5 != 2)
        msgs = encode_tick(layout, want)
        assert len(msgs) == len(layout.data) + 1 and msgs[-1].arbitration_id == layout.sync.frame_id
        assert all(len(m.data) == 8 and not m.is_fd for m in msgs)
        # cantools, reading the same DBC, decodes the same physical values
        for msg in msgs:
            codec = layout.by_id[(msg.arbitration_id, False)]
            phys = codec.msg.decode(bytes(msg.data), decode_choices=False)
            for s, raw in zip(codec.signals, codec.decode_raw(bytes(msg.data))):
                assert phys[s.name] == pytest.approx(raw * s.scale + s.offset, abs=1e-12)
        out = _feed_all(TickAssembler(layout), msgs)
        assert len(out) == 1 and isinstance(out[0], TickInput), out
        assert out[0].stamp_ns == 123
        _assert_close(out[0], want, TOL_CAN)


def test_encode_refuses_values_the_dbc_cannot_carry(layout):
    rng = np.random.default_rng(1)
    tick = _tick(rng)
    tick.force = tick.force.copy()
    tick.force[2] = 9000.0  # int24 at 1 mN ends at 8388.607 N
    with pytest.raises(ValueError, match="force_2"):
        encode_tick(layout, tick)


def test_missing_frame_rejects_the_tick_naming_the_frame(layout):
    rng = np.random.default_rng(2)
    msgs = encode_tick(layout, _tick(rng, seq=300))
    dropped = [m for m in msgs if m.arbitration_id != 0x103]  # CABLE_3
    out = _feed_all(TickAssembler(layout), dropped)
    assert len(out) == 1 and isinstance(out[0], Rejection)
    assert out[0].reason == "missing_frames"
    assert "CABLE_3" in out[0].message and "seq 300" in out[0].message
    assert "CABLE_2" not in out[0].message


def test_tick_without_sync_expires_at_the_deadline_and_late_frames_are_named(layout):
    rng = np.random.default_rng(3)
    msgs = encode_tick(layout, _tick(rng, seq=41))
    asm = TickAssembler(layout, deadline_s=0.005)
    assert _feed_all(asm, msgs[:-1], ts=50.0) == []
    assert asm.pending == 1
    assert asm.expire(bus_time=50.002) == []  # still within the deadline
    out = asm.expire(bus_time=50.010)
    assert [r.reason for r in out] == ["missing_frames"]
    assert "SYNC" in out[0].message and "CABLE_0" not in out[0].message
    sync = msgs[-1]
    sync.timestamp = 50.011
    late = asm.feed(sync)
    assert [r.reason for r in late] == ["late_frame"] and "seq 41" in late[0].message
    # nothing of that tick is ever delivered, and the next tick is assembled normally
    nxt = _tick(rng, seq=42)
    out = _feed_all(asm, encode_tick(layout, nxt), ts=50.02)
    assert len(out) == 1 and isinstance(out[0], TickInput) and out[0].seq == 42


def test_garbage_frames_are_bad_frames_and_named(layout):
    asm = TickAssembler(layout)
    unknown = asm.feed(can.Message(arbitration_id=0x7FF, data=b"\x01\x02", is_extended_id=False, timestamp=1.0))
    assert [r.reason for r in unknown] == ["bad_frame"] and "0x7FF" in unknown[0].message
    short = asm.feed(can.Message(arbitration_id=0x100, data=b"\x01\x02\x03", is_extended_id=False, timestamp=1.0))
    assert [r.reason for r in short] == ["bad_frame"] and "CABLE_0" in short[0].message
    assert "3 data bytes" in short[0].message
    err = asm.feed(can.Message(arbitration_id=0x100, is_error_frame=True, timestamp=1.0))
    assert [r.reason for r in err] == ["bad_frame"]
    assert asm.pending == 0


def test_interleaved_ticks_do_not_mix(layout):
    rng = np.random.default_rng(4)
    a, b = _tick(rng, seq=510), _tick(rng, seq=511)
    fa, fb = encode_tick(layout, a), encode_tick(layout, b)
    order = fa[:5] + fb[:9] + fa[5:-1] + fb[9:-1] + [fa[-1], fb[-1]]
    out = _feed_all(TickAssembler(layout), order)
    assert [type(x) for x in out] == [TickInput, TickInput]
    _assert_close(out[0], a, TOL_CAN)
    _assert_close(out[1], b, TOL_CAN)


def test_a_frame_of_the_next_round_closes_a_tick_that_lost_its_sync(layout):
    rng = np.random.default_rng(5)
    a = _tick(rng, seq=20)
    b = _tick(rng, seq=20 + 256)  # same tick_counter
    out = _feed_all(TickAssembler(layout, deadline_s=10.0), encode_tick(layout, a)[:-1] + encode_tick(layout, b))
    assert isinstance(out[0], Rejection) and out[0].reason == "missing_frames" and "SYNC" in out[0].message
    assert isinstance(out[1], TickInput)
    _assert_close(out[1], b, TOL_CAN)


def test_some_forces_not_available_is_rejected_not_filled(layout):
    rng = np.random.default_rng(6)
    tick = _tick(rng, seq=9)
    tick.force = tick.force.copy()
    tick.force[5] = math.nan  # sent as not_available
    out = _feed_all(TickAssembler(layout), encode_tick(layout, tick))
    assert [r.reason for r in out] == ["nonfinite"] and "force_5" in out[0].message


def test_dbc_that_breaks_the_conventions_is_refused_naming_file_and_signal(tmp_path, robot):
    text = make_dbc(robot).replace("force_2 ", "forse_2 ")  # signal, comment and VAL_
    bad = tmp_path / "bad.dbc"
    bad.write_text(text)
    with pytest.raises(SourceConfigError) as ei:
        load_can_layout(bad, 8)
    msg = str(ei.value)
    assert str(bad) in msg and "forse_2" in msg and "CABLE_2" in msg
    with pytest.raises(SourceConfigError, match="motor_length"):
        load_can_layout(DBC, 6)


# --------------------------------------------------------------------------------------
# the compiled codec against cantools, and the CAN FD layout
# --------------------------------------------------------------------------------------

# every kind of signal the plan must handle: big-endian across bytes, odd widths and starts,
# offsets, 1-bit, IEEE float32 / float64 (big-endian too), 57- and 64-bit integers
SYNTH_DBC = """VERSION ""

NS_ :
\tCM_
\tVAL_
\tSIG_VALTYPE_

BS_:

BU_: A B

BO_ 100 MIXED: 8 A
 SG_ le3 : 0|3@1+ (1,0) [0|7] "" B
 SG_ le_odd : 3|5@1- (2,1) [-31|31] "" B
 SG_ be12 : 13|12@0- (0.5,-3) [-1027|1020.5] "" B
 SG_ one : 24|1@1+ (1,0) [0|1] "" B
 SG_ be_small : 27|3@0- (1,0) [-4|3] "" B
 SG_ be20u : 39|20@0+ (0.001,10) [10|1058.575] "" B
 SG_ le_tail : 60|4@1+ (1,0) [0|15] "" B

BO_ 101 FLOATS: 16 A
 SG_ f32le : 0|32@1- (1,0) [0|0] "" B
 SG_ f64be : 39|64@0- (2,0.5) [0|0] "" B
 SG_ u16be : 111|16@0+ (1,0) [0|65535] "" B

BO_ 102 WIDE: 16 A
 SG_ i64 : 0|64@1- (1,0) [0|0] "" B
 SG_ i57 : 67|57@1- (1e-09,0) [0|0] "" B

SIG_VALTYPE_ 101 f32le : 1;
SIG_VALTYPE_ 101 f64be : 2;
VAL_ 100 be12 -2048 "not_available" ;
"""


def _same(a, b) -> bool:
    """cantools' value (int or float) equals ours (float): exactly, or both NaN."""
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return float(a) == b


def _edge_raws(codec: FrameCodec, rng) -> list[dict[str, float]]:
    """Raw values per signal: min, max, -1, 0, 1, the not_available raw, and random ones."""
    out = []
    for case in range(12):
        raws = {}
        for s in codec.signals:
            if s.is_float:
                raws[s.name] = [0.0, -0.0, 1.5, -2.25, 3.4e38 if s.length == 32 else 1.7e308, float("inf"),
                                float(rng.normal() * 10.0 ** int(rng.integers(-20, 20)))][min(case, 6)]
                continue
            lo, hi = s.raw_min, s.raw_max
            pick = [lo, hi, max(lo, -1), 0, min(hi, 1),
                    s.not_available if s.not_available is not None else lo]
            raws[s.name] = pick[case] if case < len(pick) else int(rng.integers(lo, hi, endpoint=True))
        out.append(raws)
    return out


@pytest.mark.parametrize("which", ["classic", "fd", "synthetic"])
def test_compiled_codec_equals_cantools_on_random_and_edge_values(which, tmp_path):
    import cantools

    path = {"classic": DBC, "fd": FD_DBC}.get(which)
    if path is None:
        path = tmp_path / "synthetic.dbc"
        path.write_text(SYNTH_DBC)
    db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    rng = np.random.default_rng(11)
    for msg in db.messages:
        codec = FrameCodec(msg)
        assert [s.name for s in codec.signals] == [s.name for s in msg.signals]
        # decoding: random payloads and bit patterns at the edges
        payloads = [bytes(msg.length), b"\xff" * msg.length, b"\x80" * msg.length, b"\x7f" * msg.length,
                    bytes(range(msg.length))]
        payloads += [rng.integers(0, 256, msg.length, dtype=np.uint8).tobytes() for _ in range(300)]
        for data in payloads:
            want = db.decode_message(msg.frame_id, data, decode_choices=False)
            got = codec.decode(data)
            for name, value in want.items():
                assert _same(value, got[name]), (msg.name, name, data.hex(), value, got[name])
            want_raw = db.decode_message(msg.frame_id, data, decode_choices=False, scaling=False)
            for s, raw in zip(codec.signals, codec.decode_raw(data)):
                assert _same(want_raw[s.name], float(raw)) if s.is_float else want_raw[s.name] == raw, \
                    (msg.name, s.name, data.hex())
            # and back: the raw values give the same bytes as cantools gives them
            assert codec.encode_raw(codec.decode_raw(data)) == db.encode_message(
                msg.frame_id, want_raw, scaling=False, strict=False), (msg.name, data.hex())
        # encoding: edge raws (min, max, negative, not_available) and random ones
        for raws in _edge_raws(codec, rng):
            want = db.encode_message(msg.frame_id, raws, scaling=False, strict=False)
            assert codec.encode_raw([raws[s.name] for s in codec.signals]) == want, (msg.name, raws)
            # physical values are float64: integers beyond 2**53 are not exact there
            exact = all(s.is_float or abs(raws[s.name]) <= 2**53 for s in codec.signals)
            phys = {s.name: (raws[s.name] * s.scale + s.offset) for s in codec.signals
                    if s.is_float or raws[s.name] != s.not_available}
            if exact and len(phys) == len(codec.signals) and all(math.isfinite(v) for v in phys.values()):
                # physical values: cantools' scaling and rounding, bit for bit
                assert codec.encode(phys) == db.encode_message(msg.frame_id, phys, strict=False), (msg.name, phys)
            # None is the not_available raw; the other values scaled as cantools scales them
            na = {s.name: (None if s.not_available is not None and raws[s.name] == s.not_available
                           else raws[s.name] * s.scale + s.offset) for s in codec.signals}
            if exact and all(v is None or math.isfinite(v) for v in na.values()):
                sig = {x.name: x for x in msg.signals}
                as_raw = {n: (codec.signals[codec.index[n]].not_available if v is None
                              else sig[n].conversion.numeric_scaled_to_raw(v)) for n, v in na.items()}
                assert codec.encode(na) == db.encode_message(msg.frame_id, as_raw, scaling=False, strict=False), \
                    (msg.name, na)
    if which == "synthetic":
        codec = FrameCodec(db.get_message_by_name("MIXED"))
        with pytest.raises(ValueError, match="le_odd"):
            codec.encode({"le3": 1, "le_odd": 1000.0, "be12": 0.0, "one": 1, "be_small": 0, "be20u": 11.0,
                          "le_tail": 3})
        with pytest.raises(ValueError, match="le3.*no not_available"):
            codec.encode({"le3": None, "le_odd": 1.0, "be12": 0.0, "one": 1, "be_small": 0, "be20u": 11.0,
                          "le_tail": 3})


def test_shipped_fd_dbc_is_the_generated_layout_with_the_classic_resolutions(robot, layout, fd_layout):
    assert FD_DBC.read_text() == make_dbc(robot, fd=True)
    assert fd_layout.fd and not layout.fd
    assert [c.name for c in fd_layout.frames] == ["PLATFORM", "SYNC"]
    assert fd_layout.frames_per_tick == 2 and layout.frames_per_tick == 14
    assert fd_layout.n_cables == 8 and fd_layout.has_force and fd_layout.has_pose and fd_layout.has_temperature
    assert fd_layout.counter_bits == 8 and fd_layout.seq_bits == 24
    for msg in fd_layout.db.messages:  # cantools reads them as CAN FD frames (VFrameFormat)
        assert msg.is_fd and msg.length in FD_LENGTHS and msg.length <= 64 and msg.comment
        assert not msg.is_extended_frame
        for sig in msg.signals:
            assert sig.comment, (msg.name, sig.name)
    assert all(c.bitrate_switch for c in fd_layout.frames)
    # every signal: the same width, scale, signedness and not_available as the classic layout
    for name, (codec, k) in layout.where.items():
        a, b = layout.signal(name), fd_layout.signal(name)
        assert (a.length, a.scale, a.offset, a.signed, a.not_available) == \
            (b.length, b.scale, b.offset, b.signed, b.not_available), name


@pytest.mark.parametrize("m", [4, 13, 26])
def test_fd_layout_for_other_cable_counts(m, tmp_path):
    # make_dbc reads the robot's name, cable count and cable names
    from types import SimpleNamespace

    bot = SimpleNamespace(name=f"robot{m}", geometry=lambda: SimpleNamespace(
        n_cables=m, cable_names=[f"c{i}" for i in range(m)]))
    path = tmp_path / f"robot{m}-fd.dbc"
    path.write_text(make_dbc(bot, fd=True))
    lay = load_can_layout(path, m)
    # up to 8 cables ride in the SYNC, the others in CABLES_<k> frames of 9, sent before it
    extra = -(-(m - 8) // 9) if m > 8 else 0
    assert [c.name for c in lay.frames] == [f"CABLES_{k}" for k in range(extra)] + ["PLATFORM", "SYNC"]
    assert all(c.is_fd and c.length in FD_LENGTHS for c in lay.frames)
    rng = np.random.default_rng(m)
    for seq in (0, 255, 256, 2**24 - 1):
        want = _tick(rng, seq=seq, m=m, force=seq != 255)
        out = _feed_all(TickAssembler(lay), encode_tick(lay, want))
        assert len(out) == 1 and isinstance(out[0], TickInput), out
        _assert_close(out[0], want, TOL_CAN)


def test_fd_round_trip_within_resolution_and_agrees_with_cantools(fd_layout):
    rng = np.random.default_rng(20)
    for k in range(40):
        want = _tick(rng, seq=int(rng.integers(0, 2**24)), t=float(rng.uniform(0, 1e6)),
                     force=k % 3 != 0, pose=k % 4 != 1, temperature=k % 5 != 2)
        msgs = encode_tick(fd_layout, want)
        assert [(m.arbitration_id, len(m.data), m.is_fd, m.bitrate_switch) for m in msgs] == [
            (0x140, 32, True, True), (0x150, 64, True, True)]
        for msg in msgs:  # cantools decodes the same physical values from the same bytes
            phys = fd_layout.db.decode_message(msg.arbitration_id, bytes(msg.data), decode_choices=False)
            codec = fd_layout.by_id[(msg.arbitration_id, False)]
            assert phys == pytest.approx(codec.decode(bytes(msg.data)), abs=0, rel=0)
            assert phys["tick_counter" if "tick_counter" in phys else "seq"] == want.seq % (
                256 if "tick_counter" in phys else 2**24)
        out = _feed_all(TickAssembler(fd_layout), msgs)
        assert len(out) == 1 and isinstance(out[0], TickInput), out
        _assert_close(out[0], want, TOL_CAN)
        assert out[0].motor_length.dtype == np.float64 and out[0].motor_length.flags.c_contiguous


def test_fd_assembler_names_missing_frames_and_refuses_classic_frames(fd_layout):
    rng = np.random.default_rng(21)
    platform, sync = encode_tick(fd_layout, _tick(rng, seq=700))
    out = _feed_all(TickAssembler(fd_layout), [sync])
    assert [r.reason for r in out] == ["missing_frames"] and "PLATFORM" in out[0].message
    assert "seq 700" in out[0].message
    asm = TickAssembler(fd_layout)
    classic = can.Message(arbitration_id=0x150, data=bytes(sync.data[:8]), is_extended_id=False, timestamp=1.0)
    bad = asm.feed(classic)
    assert [r.reason for r in bad] == ["bad_frame"] and "SYNC" in bad[0].message and "classic" in bad[0].message
    short = can.Message(arbitration_id=0x140, data=bytes(48), is_fd=True, is_extended_id=False, timestamp=1.0)
    bad = asm.feed(short)
    assert [r.reason for r in bad] == ["bad_frame"] and "48 data bytes" in bad[0].message
    assert asm.pending == 0
    # two ticks interleaved, a tick whose pose is half not_available
    a, b = _tick(rng, seq=255), _tick(rng, seq=256)
    fa, fb = encode_tick(fd_layout, a), encode_tick(fd_layout, b)
    out = _feed_all(asm, [fa[0], fb[0], fa[1], fb[1]])
    assert [type(x) for x in out] == [TickInput, TickInput]
    _assert_close(out[0], a, TOL_CAN)
    _assert_close(out[1], b, TOL_CAN)
    half = _tick(rng, seq=300)
    half.position = np.array([0.1, math.nan, 0.3])
    out = _feed_all(asm, encode_tick(fd_layout, half))
    assert [r.reason for r in out] == ["nonfinite"] and "position_y (PLATFORM)" in out[0].message


def test_a_sync_only_fd_layout_delivers_one_frame_ticks(robot, tmp_path):
    # leave PLATFORM out of the FD DBC: no pose, no temperature, the SYNC is the whole tick
    lines = [ln for ln in make_dbc(robot, fd=True).split("\n\n")]
    text = "\n\n".join(block for block in lines if not block.startswith("BO_ 320 "))
    text = "\n".join(ln for ln in text.split("\n")
                     if not any(ln.startswith(p) for p in ("CM_ SG_ 320 ", "CM_ BO_ 320 ", "VAL_ 320 ",
                                                           'BA_ "VFrameFormat" BO_ 320 ')))
    path = tmp_path / "sync-only.dbc"
    path.write_text(text)
    lay = load_can_layout(path, 8)
    assert lay.data == [] and lay.frames_per_tick == 1 and not lay.has_pose and not lay.has_temperature
    rng = np.random.default_rng(22)
    want = _tick(rng, seq=5)
    msgs = encode_tick(lay, want)
    assert len(msgs) == 1 and len(msgs[0].data) == 64
    out = _feed_all(TickAssembler(lay), msgs)
    assert len(out) == 1 and isinstance(out[0], TickInput)
    assert out[0].position is None and out[0].temperature is None
    np.testing.assert_allclose(out[0].force, want.force, atol=TOL_CAN["force"])
    # with the source: a classic bus cannot carry an FD DBC
    with pytest.raises(SourceConfigError, match=r"source\.fd"):
        open_source(robot, {"kind": "can", "dbc": str(FD_DBC)})
    src = open_source(robot, {"kind": "can", "fd": True})
    assert Path(src.layout.path).name == "ipanema3-fd.dbc"


def test_encode_refuses_fd_values_the_dbc_cannot_carry(fd_layout):
    rng = np.random.default_rng(23)
    tick = _tick(rng)
    tick.force = tick.force.copy()
    tick.force[2] = -9000.0
    with pytest.raises(ValueError, match="force_2"):
        encode_tick(fd_layout, tick)
    tick = _tick(rng)
    tick.motor_length = tick.motor_length.copy()
    tick.motor_length[4] = math.nan
    with pytest.raises(ValueError, match="motor_length_4"):
        encode_tick(fd_layout, tick)


def test_simulated_controller_forces_follow_the_played_motion_backwards_too(robot):
    """The embedded controller plays its twin motion there and back. Its measured forces must
    be what the cable gives on the motion actually played: forces recorded going forward and
    read backwards would flip the hysteretic damping term and show the daemon a model error
    of newtons (the demo then raised drift alarms at every reversal). The kernel with the
    twin's truth parameters must therefore match them within the 0.1 N sensor noise over
    whole cycles, in both directions and across the seam where the cycle loops."""
    from cablesvc.config.params import nominal_params
    from cablesvc.kernel import Predictor
    from cablesvc.sources.simulated import SimulatedController

    geom = robot.geometry()
    c = SimulatedController(robot, scenario="trajectory", rate=200.0, seed=1, duration=3.0)
    period = c.recording.n_ticks
    assert c.periodic and period == 2 * 600 - 2
    ticks = [c.tick_at(k) for k in range(3 * period)]
    seq = np.array([tk.seq for tk in ticks])
    assert np.all(np.diff(seq) == 1) and np.all(np.diff([tk.t for tk in ticks]) > 0)
    ml = np.array([tk.motor_length for tk in ticks])
    assert np.max(np.abs(np.diff(ml, axis=0))) < 5 * np.max(np.abs(np.diff(ml[:period], axis=0)))  # no jump at the seam
    pred = Predictor(geom, nominal_params(geom))
    res = np.array([pred.tick(tk.t, tk.motor_length, tk.position, tk.orientation, tk.force).residual.copy()
                    for tk in ticks])
    backward = slice(period + period // 2 + 10, 2 * period)            # second cycle, motion reversed
    seam = slice(2 * period - 50, 2 * period + 50)
    for part in (backward, seam, slice(period, 3 * period)):
        rms = np.sqrt(np.mean(res[part] ** 2))
        assert rms < 0.15, (part, rms)                                # 0.1 N noise; the bug gave > 1 N


def test_controller_precomputed_frames_equal_encode_tick(robot, twin):
    rec = twin.slice(0, 60)
    rec.force = rec.force.copy()
    rec.force[10] = math.nan  # no force this tick
    rec.position = rec.position.copy()
    rec.position[20] = math.nan  # no pose this tick
    rec.temperature = rec.temperature.copy()
    rec.temperature[30] = math.nan
    for fd in (False, True):
        ctl = CanController(robot, {"interface": "virtual", "channel": "unused"}, fd=fd, recording=rec,
                            rate=1000.0, start_seq=2**24 - 50)
        assert ctl.fd is fd and ctl.layout.fd is fd and ctl.precompute_error is None
        for k in list(range(0, 130, 7)) + [10, 20, 30, 49, 50, 51, 118]:
            tick = ctl.tick_at(k)
            want = encode_tick(ctl.layout, tick)
            got = ctl.frames(k)
            assert [bytes(m.data) for m in got] == [bytes(m.data) for m in want], (fd, k)
            assert [(m.arbitration_id, m.is_fd, m.bitrate_switch) for m in got] == \
                [(m.arbitration_id, m.is_fd, m.bitrate_switch) for m in want]
        assert ctl.tick_at(10).force is None and ctl.tick_at(20).position is None
        assert ctl.tick_at(30).temperature is None


def test_codec_bench_reports_both_layouts_and_the_cantools_baseline():
    import argparse

    from cablesvc.bench.can_codec import add_parser, run_codec_bench

    res = run_codec_bench(300, baseline_n=50)
    assert res["n"] == 300 and res["baseline_n"] == 50
    assert res["classic"]["frames_per_tick"] == 14 and res["fd"]["frames_per_tick"] == 2
    for name in ("classic", "fd"):
        for key in ("encode_us", "assemble_us", "total_us", "cantools_encode_us", "cantools_decode_us",
                    "cantools_total_us"):
            assert 0 < res[name][key]["p50"] <= res[name][key]["p99"], (name, key)
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="bench"))
    args = parser.parse_args(["can-codec", "--json", "-n", "10"])
    assert args.ticks == 10 and args.json and callable(args.func)


# --------------------------------------------------------------------------------------
# CAN sources
# --------------------------------------------------------------------------------------


def test_can_controller_to_can_source_over_a_virtual_bus(robot, twin):
    channel = f"cablesvc-test-{time.monotonic_ns()}"
    n = 300
    # generous deadline: here the controller shares the interpreter (and its GIL) with the
    # source, so a tick's frames can be a few ms apart; across processes 5 ms is plenty
    src = open_source(robot, {"kind": "can", "interface": "virtual", "channel": channel, "deadline_s": 0.5})
    assert isinstance(src, CanSource)
    ctl = CanController(robot, {"interface": "virtual", "channel": channel}, rate=1000.0, recording=twin,
                        history=n)
    got: list[TickInput] = []
    with src:
        ctl.start(ticks=n)
        try:
            while len(got) < n:
                tick = src.recv(timeout=5.0)
                assert tick is not None, (len(got), src.counters.as_dict(), src.problems())
                got.append(tick)
        finally:
            ctl.stop()
    sent = ctl.sent()
    assert ctl.ticks_sent == n and ctl.send_errors == 0
    assert [t.seq for t in got] == [t.seq for t in sent] == list(range(n))
    for g, s in zip(got, sent):
        _assert_close(g, s, {**TOL_CAN, "orientation": 1e-8})
        assert g.motor_length.flags.c_contiguous and g.motor_length.dtype == np.float64
    assert src.counters.accepted == n and not src.counters.rejected
    assert src.problems() == []
    src.close()  # idempotent


def test_switching_to_a_sink_and_back_loses_no_tick_and_keeps_the_order(robot, twin):
    """The daemon opens its source before it starts its loop, then switches the receive
    thread to deliver straight to the kernel (set_sink), and back to the queue at the end.
    Ticks accepted before the switch must come back from set_sink, ticks during a switch
    must go either way but never nowhere, and the order must hold (the demo lost the
    ticks queued before the switch: accepted exceeded processed)."""
    channel = f"cablesvc-test-{time.monotonic_ns()}"
    n = 1500
    src = open_source(robot, {"kind": "can", "interface": "virtual", "channel": channel, "deadline_s": 0.5})
    ctl = CanController(robot, {"interface": "virtual", "channel": channel}, rate=1000.0, recording=twin)
    got: list[int] = []
    sunk: list[int] = []
    queued: list[int] = []
    with src:
        ctl.start(ticks=n)
        try:
            deadline = time.monotonic() + 20
            while src.counters.accepted < 100 and time.monotonic() < deadline:
                time.sleep(0.005)
            got += [t.seq for t in src.set_sink(lambda tk: sunk.append(tk.seq))]   # queued before the switch
            assert len(got) >= 100
            while len(sunk) < 200 and time.monotonic() < deadline:
                time.sleep(0.005)
            assert src.set_sink(None) == []
            while src.counters.accepted < n and time.monotonic() < deadline:
                time.sleep(0.005)
        finally:
            ctl.stop()
        while True:
            tick = src.recv(timeout=0.5)
            if tick is None:
                break
            queued.append(tick.seq)
    assert src.counters.accepted == n and not src.counters.rejected
    assert len(sunk) >= 200 and queued
    assert got + sunk + queued == list(range(n))


def test_can_source_reopens_its_bus_after_a_bus_error(robot, twin):
    channel = f"cablesvc-test-{time.monotonic_ns()}"
    src = open_source(robot, {"kind": "can", "interface": "virtual", "channel": channel, "deadline_s": 0.5})
    ctl = CanController(robot, {"interface": "virtual", "channel": channel}, rate=500.0, recording=twin, history=2000)
    with src:
        ctl.start()
        try:
            assert len(_collect(src, 20)) == 20
            src._bus.shutdown()  # the interface goes away under the receive thread
            reasons: list[str] = []
            end = time.monotonic() + 10
            while "reconnected" not in reasons and time.monotonic() < end:
                src.recv(timeout=0.1)
                reasons += [p.reason for p in src.problems()]
            assert reasons[:1] == ["disconnected"] and "reconnected" in reasons
            after = _collect(src, 20)
            assert len(after) == 20
            sent = _by_seq(ctl.sent())
            for tick in after:
                _assert_close(tick, sent[tick.seq], {**TOL_CAN, "orientation": 1e-8})
        finally:
            ctl.stop()
    assert src.counters.events["disconnected"] == 1 and src.counters.events["reconnected"] == 1
    with pytest.raises(SourceConfigError, match="source.interface.*nonexistent"):
        open_source(robot, {"kind": "can", "interface": "nonexistent"}).open()


def _across_processes(robot, tmp_path, *, fd: bool, rate: float, n: int) -> dict:
    """A controller process sends n ticks over the udp_multicast loopback bus to a CanSource
    here; every tick sent after the source was listening must arrive, in order, with its
    values. Returns the controller's summary line."""
    port = free_udp_port()
    cfg = loopback_bus_config(port, fd=fd)
    assert cfg["interface"] == "udp_multicast" and cfg["bus_kwargs"]["hop_limit"] == 0
    assert cfg["channel"].lower().startswith("ff11:") or cfg["channel"].startswith("239.")
    assert cfg["fd"] is fd and cfg["bus_kwargs"]["fd"] is fd
    record = tmp_path / f"sent-{'fd' if fd else 'classic'}.mcap"
    # the deadline is for a real bus; on a shared test machine the controller process can be
    # descheduled for milliseconds in the middle of a tick, so give it room here
    src = open_source(robot, {"kind": "can", **cfg, "deadline_s": 0.5})
    assert src.layout.fd is fd and Path(src.layout.path).name == ("ipanema3-fd.dbc" if fd else "ipanema3.dbc")
    got: list[TickInput] = []
    with src:
        proc = subprocess.Popen(
            [sys.executable, "-m", "cablesvc.sources.simulated", "--transport", "can", "--port", str(port),
             "--rate", str(rate), "--ticks", str(n), "--seconds", "40", "--duration", "0.5", "--seed", "5",
             "--record", str(record)] + (["--fd"] if fd else []),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
        )
        try:
            while True:
                tick = src.recv(timeout=0.2)
                if tick is not None:
                    got.append(tick)
                elif proc.poll() is not None:
                    break
        finally:
            if proc.poll() is None:
                proc.kill()
            out, err = proc.communicate(timeout=30)
        while (tick := src.recv(timeout=0.3)) is not None:
            got.append(tick)
    assert proc.returncode == 0, err
    lines = [json.loads(x) for x in out.splitlines() if x.strip()]
    assert lines[0]["event"] == "ready" and lines[0]["fd"] is fd and lines[-1]["ticks_sent"] == n
    assert lines[0]["frames_per_tick"] == (2 if fd else 14)
    sent = read_recording(record)
    assert sent.n_ticks == n
    # every tick sent after the source was listening arrived, in order, with its values
    assert got, src.counters.as_dict()
    first = got[0].seq
    assert [t.seq for t in got] == list(range(first, n)), (src.counters.as_dict(), src.problems()[:5])
    assert first < n // 2
    for tick in got:
        i = tick.seq
        _assert_close(tick, TickInput(seq=i, t=float(sent.t[i]), motor_length=sent.motor_length[i],
                                      position=sent.position[i], orientation=sent.orientation[i],
                                      force=sent.force[i], temperature=float(sent.temperature[i]), stamp_ns=0),
                      {**TOL_CAN, "orientation": 1e-8})
    assert not src.counters.rejected, src.problems()
    return lines[-1]


@pytest.mark.skipif(importlib.util.find_spec("msgpack") is None,
                    reason="python-can's udp_multicast interface needs msgpack (python-can[multicast])")
def test_can_across_processes_on_the_loopback_multicast_bus(robot, tmp_path):
    _across_processes(robot, tmp_path, fd=False, rate=500.0, n=400)


@pytest.mark.skipif(importlib.util.find_spec("msgpack") is None,
                    reason="python-can's udp_multicast interface needs msgpack (python-can[multicast])")
def test_can_fd_across_processes_at_1khz(robot, tmp_path):
    summary = _across_processes(robot, tmp_path, fd=True, rate=1000.0, n=1500)
    # the controller reports how it kept up (numbers depend on the machine: not asserted)
    assert {"overruns", "late_ticks", "late_p99_us", "send_p50_us"} <= set(summary)
    assert summary["send_errors"] == 0


# --------------------------------------------------------------------------------------
# Modbus
# --------------------------------------------------------------------------------------


def _collect(src, n: int, timeout: float = 10.0) -> list[TickInput]:
    got: list[TickInput] = []
    end = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < end:
        tick = src.recv(timeout=0.2)
        if tick is not None:
            got.append(tick)
    return got


def _by_seq(ticks):
    return {t.seq: t for t in ticks}


TOL_MODBUS = {"motor_length": 0.5e-7, "force": 0.5e-3, "position": 0.5e-7, "orientation": 1e-8,
              "temperature": 0.5e-2, "t": 1e-12}


def test_modbus_controller_to_source_read_only_and_recovers_after_loss(robot, twin):
    port = free_tcp_port()
    ctl = ModbusController(robot, port=port, rate=200.0, recording=twin, history=4000)
    ctl.start()
    src = open_source(robot, {"kind": "modbus", "port": port, "rate_hz": 400.0, "timeout_s": 0.5})
    assert isinstance(src, ModbusSource)
    try:
        with src:
            got = _collect(src, 40)
            assert len(got) == 40, (src.counters.as_dict(), src.problems())
            sent = _by_seq(ctl.sent())
            seqs = [t.seq for t in got]
            assert seqs == sorted(set(seqs))  # increasing, no repeats
            for tick in got:
                _assert_close(tick, sent[tick.seq], TOL_MODBUS)
            assert src.counters.rejected == {}

            # the controller's server goes away: reported, then back: ticks flow again
            ctl.server_down()
            end = time.monotonic() + 10
            reasons: list[str] = []
            while "disconnected" not in reasons and time.monotonic() < end:
                src.recv(timeout=0.1)
                reasons += [p.reason for p in src.problems()]
            assert "disconnected" in reasons
            while src.recv(timeout=0) is not None:  # ticks polled before the server went down
                pass
            last_before = src.counters.accepted
            ctl.server_up()
            after = _collect(src, 10)
            assert len(after) == 10, (src.counters.as_dict(), src.problems())
            assert after[0].seq > got[-1].seq
            sent = _by_seq(ctl.sent())
            for tick in after:
                _assert_close(tick, sent[tick.seq], TOL_MODBUS)
            assert src.counters.accepted >= last_before + 10
            assert src.counters.events["reconnected"] >= 1
    finally:
        ctl.stop()
    assert ctl.read_requests > 0
    assert ctl.write_requests == 0 and set(ctl.function_codes) == {3}


SPLIT_MAP = """
format = 1
registers = "input"
[fields.seq]
address = 100
type = "uint16"
[fields.t]
address = 0
type = "uint32"
scale = 1e-6
word_order = "little"
[fields.motor_length]
address = 10
type = "float64"
stride = 5
word_order = "little"
[fields.force]
address = 60
type = "float32"
[fields.temperature]
address = 300
type = "int16"
scale = 0.01
missing = -32768
"""


def test_register_map_codec_round_trip_and_split_reads(tmp_path, robot, twin):
    path = tmp_path / "split.modbus.toml"
    path.write_text(SPLIT_MAP)
    rmap = load_register_map(path, 8)
    # t, motor_length, force ... are far apart: several requests, none over 125 registers
    assert len(rmap.read_plan) >= 3 and all(n <= 125 for _, n in rmap.read_plan)
    assert rmap.seq_bits == 16
    want = TickInput(seq=70001, t=12.345678, motor_length=np.linspace(3, 17, 8), position=None, orientation=None,
                     force=np.linspace(-5, 2500, 8), temperature=None, stamp_ns=0)
    got = rmap.decode(dict(rmap.encode(want)), stamp_ns=5)
    assert isinstance(got, TickInput)
    assert got.seq == 70001 % 2**16 and abs(got.t - want.t) < 1e-6
    np.testing.assert_array_equal(got.motor_length, want.motor_length)  # float64: exact
    np.testing.assert_allclose(got.force, want.force, rtol=1e-7)  # float32
    assert got.position is None and got.orientation is None and got.temperature is None

    # live, through a real server, with input registers and the seq re-read after the split reads
    port = free_tcp_port()
    # 50 Hz: a split read (several requests) takes ~1 ms, far less than a controller tick,
    # so torn reads stay rare even on a loaded machine
    ctl = ModbusController(robot, port=port, register_map=path, rate=50.0, recording=twin, history=4000)
    ctl.start()
    try:
        with open_source(robot, {"kind": "modbus", "port": port, "register_map": str(path), "rate_hz": 300.0}) as src:
            ticks = _collect(src, 15)
            assert len(ticks) == 15, (src.counters.as_dict(), src.problems())
            sent = _by_seq(ctl.sent())
            for tick in ticks:
                s = sent[tick.seq]
                np.testing.assert_array_equal(tick.motor_length, s.motor_length)
                np.testing.assert_allclose(tick.force, s.force, rtol=1e-6, atol=1e-4)
                assert tick.position is None and abs(tick.t - s.t) < 1e-6
    finally:
        ctl.stop()
    assert ctl.write_requests == 0 and set(ctl.function_codes) == {4}


def test_register_map_errors_name_the_file_and_the_entry(tmp_path):
    bad = tmp_path / "bad.modbus.toml"
    bad.write_text(SPLIT_MAP.replace('type = "float32"', 'type = "float16"').replace("address = 300", "address = 62"))
    with pytest.raises(SourceConfigError) as ei:
        load_register_map(bad, 8)
    assert str(bad) in str(ei.value) and "fields.force.type" in str(ei.value)
    overlap = tmp_path / "overlap.modbus.toml"
    overlap.write_text(SPLIT_MAP.replace("address = 300", "address = 62"))
    with pytest.raises(SourceConfigError) as ei:
        load_register_map(overlap, 8)
    assert "fields.temperature" in str(ei.value) and "force[" in str(ei.value)
    assert load_register_map(MODBUS_MAP, 8).read_plan == [(0, 53)]  # the shipped map: one request


# --------------------------------------------------------------------------------------
# replay
# --------------------------------------------------------------------------------------


def _drain(src) -> list[TickInput]:
    out = []
    while not src.finished:
        tick = src.recv(timeout=5.0)
        if tick is not None:
            out.append(tick)
    return out


def test_replay_of_mcap_and_csv_is_identical_and_unpaced_at_speed_0(tmp_path, robot, twin):
    rec = twin.slice(0, 200)
    mcap, csv = tmp_path / "r.mcap", tmp_path / "r.csv"
    write_recording(mcap, rec)
    write_recording(csv, rec)
    runs = []
    for path in (mcap, csv):
        src = open_source(robot, {"kind": "replay", "path": str(path), "speed": 0})
        assert isinstance(src, ReplaySource)
        with src:
            ticks = []
            while (tick := src.recv(timeout=0)) is not None:  # never held back at speed 0
                ticks.append(tick)
            assert src.finished and src.problems() == []
        runs.append(ticks)
    a, b = runs
    assert len(a) == len(b) == 200
    for x, y, i in zip(a, b, range(200)):
        assert x.seq == y.seq == int(rec.seq[i]) and x.t == y.t == float(rec.t[i])
        np.testing.assert_array_equal(x.motor_length, y.motor_length)
        np.testing.assert_array_equal(x.motor_length, rec.motor_length[i])
        np.testing.assert_array_equal(x.force, y.force)
        np.testing.assert_array_equal(x.position, y.position)
        np.testing.assert_array_equal(x.orientation, y.orientation)
        assert x.temperature == y.temperature


def test_replay_paces_by_t_and_loops_with_increasing_seq_and_t(tmp_path, robot, twin):
    rec = twin.slice(0, 3)
    rec.t = np.array([0.0, 100.0, 200.0])  # 100 s apart: real-time pacing must hold tick 2 back
    path = tmp_path / "slow.mcap"
    write_recording(path, rec)
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": 1.0}) as src:
        assert src.recv(timeout=1.0).seq == 0
        assert src.recv(timeout=0.01) is None and not src.finished
    fast = twin.slice(0, 5)
    path = tmp_path / "loop.csv"
    write_recording(path, fast)
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": 0, "loop": True}) as src:
        ticks = [src.recv(timeout=1.0) for _ in range(12)]
    assert [t.seq for t in ticks] == list(range(12))
    assert all(b.t > a.t for a, b in zip(ticks, ticks[1:]))
    np.testing.assert_array_equal(ticks[5].motor_length, fast.motor_length[0])


def test_damaged_recordings_become_problems_not_exceptions(tmp_path, robot, twin):
    rec = twin.slice(0, 400)
    good = tmp_path / "good.mcap"
    write_recording(good, rec)
    data = good.read_bytes()
    # cut in the middle: the summary and footer are gone
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with open_source(robot, {"kind": "replay", "path": str(cut), "speed": 0}) as src:
        ticks = _drain(src)
        reasons = [p.reason for p in src.problems()]
    assert len(ticks) < 400 and {"truncated", "recording_error"} & set(reasons), reasons
    assert [t.seq for t in ticks] == list(range(len(ticks)))
    # not a recording at all
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 4)
    with open_source(robot, {"kind": "replay", "path": str(junk), "speed": 0}) as src:
        assert src.recv(timeout=0.5) is None and src.finished
        problems = src.problems()
    assert problems and problems[0].reason == "recording_error" and "junk.mcap" in problems[0].message
    # a CSV with a broken number: that line is rejected, named, and the others are played
    csv = tmp_path / "bad.csv"
    write_recording(csv, rec.slice(0, 10))
    lines = csv.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("t,"))
    cells = lines[head + 6].split(",")
    cells[10] = "abc"
    lines[head + 6] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    with open_source(robot, {"kind": "replay", "path": str(csv), "speed": 0}) as src:
        ticks = _drain(src)
        problems = src.problems()
    assert [t.seq for t in ticks] == [0, 1, 2, 3, 4, 6, 7, 8, 9]
    assert [p.reason for p in problems] == ["bad_line"]
    assert f"line {head + 7}" in problems[0].message


def test_problem_buffer_is_bounded_and_counts_what_it_drops(tmp_path, robot, twin):
    n = 1100
    rec = Recording(robot="ipanema3", metadata={}, t=np.arange(n) * 1e-3, seq=np.arange(n),
                    motor_length=np.full((n, 8), -1.0))  # every tick invalid
    path = tmp_path / "neg.csv"
    write_recording(path, rec)
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": 0}) as src:
        assert _drain(src) == []
        problems = src.problems()
        counts = src.counters.as_dict()
    assert len(problems) == 1000 and counts["problems_dropped"] == 100
    assert counts["rejected"] == {"out_of_range": 1100} and counts["accepted"] == 0
    assert problems[-1].message.endswith("m is <= 0 m") and "seq 1099" in problems[-1].message


# --------------------------------------------------------------------------------------
# the validator and configuration
# --------------------------------------------------------------------------------------


def _good(seq: int, t: float) -> TickInput:
    return TickInput(seq=seq, t=t, motor_length=np.full(8, 10.0), position=np.zeros(3),
                     orientation=np.array([0.0, 0.0, 0.0, 1.0]), force=np.full(8, 100.0), temperature=20.0,
                     stamp_ns=0)


def test_validator_rejects_bad_ticks_by_reason_and_accepts_the_next_good_one(robot):
    v = TickValidator(robot)
    assert v.check(_good(0, 0.0)) is None
    cases = []
    nan = _good(1, 0.001)
    nan.motor_length[3] = math.nan
    cases.append((nan, "nonfinite", "motor_length[3]"))
    neg = _good(1, 0.001)
    neg.motor_length[0] = -0.2
    cases.append((neg, "out_of_range", "motor_length[0]"))
    big = _good(1, 0.001)
    big.force[6] = 1e6
    cases.append((big, "out_of_range", "force[6]"))
    back = _good(1, -0.5)
    cases.append((back, "time_backwards", "t -0.5"))
    dup = _good(0, 0.001)
    cases.append((dup, "duplicate_seq", "seq 0"))
    quat = _good(1, 0.001)
    quat.orientation = np.array([0.0, 0.0, 0.1, 1.0])
    cases.append((quat, "bad_quaternion", "norm"))
    shape = _good(1, 0.001)
    shape.position = np.zeros(2)
    cases.append((shape, "bad_shape", "position"))
    for tick, reason, text in cases:
        rej = v.check(tick)
        assert rej is not None and rej.reason == reason and text in rej.message, (reason, rej)
    assert v.counters.rejected == {"nonfinite": 1, "out_of_range": 2, "time_backwards": 1, "duplicate_seq": 1,
                                   "bad_quaternion": 1, "bad_shape": 1}
    ok = _good(1, 0.001)
    ok.orientation = np.array([0.0, 0.0, 0.0, 1.0005])  # within 1e-3: renormalised
    assert v.check(ok) is None
    assert ok.orientation[3] == 1.0 and v.counters.accepted == 2
    assert v.check(_good(5, 0.002)) is None and v.counters.missed_ticks == 3


def test_validator_follows_a_wrapping_counter_and_resyncs_after_a_restart(robot):
    v = TickValidator(robot, seq_bits=8, resync_after=3)
    for k, raw in enumerate([254, 255, 0, 1]):
        tick = _good(raw, 0.001 * k)
        assert v.check(tick) is None
        assert tick.seq == 254 + k
    assert v.check(_good(300, 1.0)).reason == "out_of_range"  # does not fit 8 bits
    # controller restart: clock and counter start again
    for k in range(3):
        assert v.check(_good(10 + k, 0.001 * k)).reason == "time_backwards"
    restart = _good(13, 0.003)
    assert v.check(restart) is None and v.resync_note and restart.seq == 258
    assert v.counters.events["resync"] == 1


def test_open_source_rejects_bad_configuration_naming_the_field(tmp_path, robot):
    with pytest.raises(SourceConfigError, match="source.kind.*'ethercat'.*can, modbus, replay"):
        open_source(robot, {"kind": "ethercat"})
    with pytest.raises(SourceConfigError, match=r"source\.port"):
        open_source(robot, {"kind": "modbus", "port": 70000})
    with pytest.raises(SourceConfigError, match=r"source\.deadline_s"):
        open_source(robot, {"kind": "can", "deadline_s": -1})
    with pytest.raises(SourceConfigError, match=r"source\.speed"):
        open_source(robot, {"kind": "replay", "path": "x.mcap", "speed": -2})
    with pytest.raises(SourceConfigError, match=r"source\.bogus"):
        open_source(robot, {"kind": "can", "bogus": 1})
    with pytest.raises(SourceConfigError, match=r"source\.path.*nope\.mcap"):
        open_source(robot, {"kind": "replay", "path": str(tmp_path / "nope.mcap")})
    with pytest.raises(SourceConfigError, match=r"source\.dbc"):
        open_source(robot, {"kind": "can", "dbc": str(tmp_path / "none.dbc")})
    # every shipped robot has its DBC files: a robot file of our own without them
    text = (Path(__file__).resolve().parent.parent / "robots" / "planar4.toml").read_text()
    (tmp_path / "nodbc.toml").write_text(text.replace('name = "planar4"', 'name = "nodbc"'))
    planar = load_robot(tmp_path / "nodbc.toml")
    with pytest.raises(SourceConfigError, match=r"source\.dbc.*nodbc\.dbc"):
        open_source(planar, {"kind": "can"})
