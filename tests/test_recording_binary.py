"""Recording format 2: the binary input encoding (``cablesvc.InputBlock``, protobuf, one
MCAP message per block of ticks). Exact round trips (NaN and infinities included), the
schema and messages decoded by the official protobuf/MCAP libraries (what Foxglove and
the ``mcap`` tools use), files written by a third party with those libraries, both
encodings read by every reader, the writers' defaults and ``--encoding json`` options, the
daemon's recorder, kill -9, damaged blocks. Real files in tmp_path, no mocks."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.decoder import DecoderFactory

from cablesvc.bench.read import run_read_bench
from cablesvc.cli.main import main as cli_main
from cablesvc.recording import (
    FORCES_TOPIC,
    INPUT_TOPIC,
    McapRecordingWriter,
    Recording,
    RecordingError,
    RecordingTruncatedWarning,
    iter_inputs,
    read_mcap,
    read_metadata,
    read_recording,
    write_mcap,
    write_recording,
)
from cablesvc.recording import protobuf_block as pb
from cablesvc.service.recorder import Recorder
from cablesvc.sources.base import TickInput

REPO = Path(__file__).resolve().parents[1]


def gappy_recording(n: int = 2500, m: int = 8, seed: int = 1) -> Recording:
    """Every part present, with missing values, absent rows and non-finite values."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rec = Recording(robot="ipanema3", metadata={"site": "hall", "note": "gaps"},
                    t=5.0 + np.arange(n) * 1e-3, seq=np.arange(n, dtype=np.int64) - 7,
                    motor_length=rng.uniform(0.5, 5.0, (n, m)), position=rng.normal(size=(n, 3)),
                    orientation=q, force=rng.uniform(10, 900, (n, m)), temperature=rng.uniform(15, 30, n))
    rec.position[10:min(1200, n // 2)] = np.nan    # no pose in more than a whole block
    rec.orientation[10:min(1200, n // 2)] = np.nan
    rec.force[3] = np.nan                          # one tick without forces
    rec.force[4, 1] = np.inf                       # a saturated sensor: kept as it is
    rec.force[5, 1] = -np.inf
    rec.motor_length[6, 0] = np.nan                # a missing motor length
    rec.temperature[:min(1500, n // 2)] = np.nan   # temperature only late in the file
    rec.seq[min(100, n - 1)] = 2**62               # seq need not step by 1
    return rec


def message_class():
    """The InputBlock class built by the protobuf library from the schema in the file."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(pb.SCHEMA_DATA)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(pb.SCHEMA_NAME))


# ---------------------------------------------------------------------------- round trips
def test_protobuf_round_trip_is_exact_and_json_reads_the_same(tmp_path):
    rec = gappy_recording()
    binp, jsonp = tmp_path / "b.mcap", tmp_path / "j.mcap"
    write_recording(binp, rec)                                   # the default: protobuf
    write_recording(jsonp, rec, encoding="json")
    assert read_metadata(binp)["format"] == "2" and read_metadata(jsonp)["format"] == "1"
    back = read_recording(binp)
    assert back.equals(rec)                                      # bit-exact, infinities included
    assert back.force[4, 1] == np.inf and back.force[5, 1] == -np.inf
    old = read_recording(jsonp)                                  # JSON: non-finite -> null -> NaN
    assert np.isnan(old.force[4, 1]) and np.isnan(old.force[5, 1])
    fin = np.isfinite(rec.force)
    assert np.array_equal(old.force[fin], back.force[fin])
    for name in ("t", "seq", "motor_length", "position", "orientation", "temperature"):
        assert np.array_equal(getattr(old, name), getattr(back, name), equal_nan=True), name
    # streaming: the same ticks from both encodings (what a replay gets)
    ticks_b, ticks_j = list(iter_inputs(binp)), list(iter_inputs(jsonp))
    assert len(ticks_b) == len(ticks_j) == rec.n_ticks
    for k in (0, 3, 6, 10, 1199, 1200, 1499, 1500, rec.n_ticks - 1):
        b, j = ticks_b[k], ticks_j[k]
        assert (b["seq"], b["t"], b["temperature"]) == (j["seq"], j["t"], j["temperature"]), k
        assert np.array_equal(b["motor_length"], j["motor_length"], equal_nan=True), k
        for part in ("position", "orientation"):
            assert (b[part] is None) == (j[part] is None), (k, part)
            if b[part] is not None:
                assert np.array_equal(b[part], j[part]), (k, part)
    assert ticks_b[3]["force"] is None and ticks_b[10]["position"] is None
    assert ticks_b[4]["force"][1] == np.inf
    assert ticks_b[0]["temperature"] is None and ticks_b[1500]["temperature"] == rec.temperature[1500]
    ticks_b[0]["motor_length"][0] = -1.0                         # a tick's arrays are its own
    assert list(iter_inputs(binp))[0]["motor_length"][0] == rec.motor_length[0, 0]


def test_absent_parts_stay_absent_and_small_recordings(tmp_path):
    for m, kw in ((1, {}), (3, {"force": None, "temperature": None}), (2, {"position": None, "orientation": None})):
        n = 7
        base = dict(robot="r", metadata={}, t=np.arange(n) * 0.1, seq=np.arange(n),
                    motor_length=np.arange(n * m, dtype=float).reshape(n, m), position=np.zeros((n, 3)),
                    orientation=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), force=np.ones((n, m)),
                    temperature=np.full(n, 20.0))
        base.update(kw)
        rec = Recording(**base)
        p = tmp_path / f"m{m}.mcap"
        write_mcap(p, rec, block_ticks=3)                        # blocks of 3, 3 and 1 ticks
        back = read_mcap(p)
        assert back.equals(rec), kw
        assert (back.force is None) == ("force" in kw) and back.has_pose == ("position" not in kw)


def test_extra_topics_keep_their_order_with_blocks(tmp_path):
    rec = gappy_recording(n=300, m=2)
    rec.extra = {FORCES_TOPIC: [{"seq": int(s), "t": float(t), "force": [1.0, None]}
                                for s, t in zip(rec.seq[:50], rec.t[:50])]}
    p = tmp_path / "x.mcap"
    write_mcap(p, rec, block_ticks=64)
    back = read_mcap(p, keep_topics=[FORCES_TOPIC])
    assert back.equals(rec)
    with open(p, "rb") as f:   # each forces payload is stored after the block holding its tick
        order = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    first_forces = next(i for i, (topic, _) in enumerate(order) if topic == FORCES_TOPIC)
    assert order[first_forces - 1][0] == INPUT_TOPIC


# ---------------------------------------------------------------------------- the libraries read it
def test_schema_and_messages_decode_with_the_official_protobuf_and_mcap_libraries(tmp_path):
    rec = gappy_recording(n=2100, m=8)
    p = tmp_path / "b.mcap"
    write_mcap(p, rec)
    with open(p, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        (channel,) = [c for c in summary.channels.values() if c.topic == INPUT_TOPIC]
        schema = summary.schemas[channel.schema_id]
        assert (channel.message_encoding, schema.encoding, schema.name) == ("protobuf", "protobuf",
                                                                           "cablesvc.InputBlock")
        assert summary.statistics.message_count == 3              # 1000 + 1000 + 100 ticks
        decoded = list(reader.iter_decoded_messages(topics=[INPUT_TOPIC], log_time_order=False))
    k = 0
    for _, _, message, msg in decoded:
        n, m = msg.ticks, msg.cables
        assert m == 8 and message.log_time == round(rec.t[k] * 1e9)
        assert message.sequence == int(rec.seq[k]) & 0xFFFFFFFF
        assert list(msg.seq) == rec.seq[k:k + n].tolist()
        assert np.array_equal(np.array(msg.t), rec.t[k:k + n])
        assert np.array_equal(np.array(msg.motor_length).reshape(n, m), rec.motor_length[k:k + n],
                              equal_nan=True)
        assert np.array_equal(np.array(msg.force).reshape(n, m), rec.force[k:k + n], equal_nan=True)
        if len(msg.position):
            assert np.array_equal(np.array(msg.position).reshape(n, 3), rec.position[k:k + n], equal_nan=True)
        else:                                     # a block where no tick has a pose
            assert np.isnan(rec.position[k:k + n]).all()
        if len(msg.temperature):
            assert np.array_equal(np.array(msg.temperature), rec.temperature[k:k + n], equal_nan=True)
        else:
            assert np.isnan(rec.temperature[k:k + n]).all()
        k += n
    assert k == rec.n_ticks


def test_file_written_by_third_party_protobuf_library_is_read(tmp_path):
    """A writer that knows only the documented schema, the protobuf and mcap libraries."""
    cls = message_class()
    p = tmp_path / "third.mcap"
    rows = []
    with open(p, "wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        w.start()
        w.add_metadata("cablesvc", {"robot": "cogiro", "format": "2", "lab": "x"})
        sid = w.register_schema("cablesvc.InputBlock", "protobuf", pb.SCHEMA_DATA)
        cid = w.register_channel(INPUT_TOPIC, "protobuf", sid)
        other = w.register_channel("/camera", "json", 0)
        for b in range(3):
            msg = cls(cables=2, ticks=2)
            msg.seq.extend([2 * b, 2 * b + 1])
            msg.t.extend([0.1 * b, 0.1 * b + 0.05])
            msg.motor_length.extend([1.0 + b, 2.0, 3.0, 4.0 + b])
            if b != 1:
                msg.force.extend([10.0, math.nan, 30.0, 40.0])
            w.add_message(cid, 0, msg.SerializeToString(), 0)
            w.add_message(other, 0, b"{}", 0)
            rows += [[1.0 + b, 2.0], [3.0, 4.0 + b]]
        w.finish()
    rec = read_recording(p)
    assert rec.robot == "cogiro" and rec.metadata == {"lab": "x"} and rec.n_ticks == 6
    assert rec.motor_length.tolist() == rows and rec.seq.tolist() == list(range(6))
    assert not rec.has_pose and rec.temperature is None
    assert np.isnan(rec.force[2:4]).all() and np.isnan(rec.force[0, 1]) and rec.force[5, 1] == 40.0


def test_unpacked_fields_split_fields_and_unknown_fields_decode():
    """Valid protobuf that our writer does not produce: repeated doubles unpacked (one
    64-bit record each), a packed field split in two, an unknown field."""
    def key(num, wire):
        return pb._varint(num << 3 | wire)
    n = 2
    data = (key(2, 0) + pb._varint(n) + key(1, 0) + pb._varint(1)
            + b"".join(key(3, 1) + np.int64(s).tobytes() for s in (5, 6))
            + key(4, 1) + np.float64(0.5).tobytes() + key(4, 1) + np.float64(0.6).tobytes()
            + pb._len_field(5, np.float64(1.5).tobytes()) + pb._len_field(5, np.float64(2.5).tobytes())
            + key(99, 0) + pb._varint(7) + pb._len_field(98, b"ignored"))
    blk = pb.decode_block(data)
    assert blk["n"] == 2 and blk["seq"].tolist() == [5, 6] and blk["t"].tolist() == [0.5, 0.6]
    assert blk["motor_length"].tolist() == [[1.5], [2.5]] and blk["force"] is None
    assert cls_roundtrip(data) == blk["t"].tolist()


def cls_roundtrip(data: bytes) -> list:
    return list(message_class().FromString(data).t)


def test_json_and_protobuf_input_channels_in_one_file_read_in_file_order(tmp_path):
    import json
    p = tmp_path / "mixed.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("cablesvc", {"robot": "r", "format": "2"})
        jid = w.register_channel(INPUT_TOPIC, "json", w.register_schema("cablesvc.Input", "jsonschema", b"{}"))
        bid = w.register_channel(INPUT_TOPIC, "protobuf",
                                 w.register_schema("cablesvc.InputBlock", "protobuf", pb.SCHEMA_DATA))
        for i in range(3):
            w.add_message(jid, 0, json.dumps({"seq": i, "t": i * 0.1, "motor_length": [float(i)],
                                              "temperature": 20.0}).encode(), 0)
        w.add_message(bid, 0, pb.encode_block(np.array([3, 4]), np.array([0.3, 0.4]), np.array([[3.0], [4.0]])), 0)
        w.add_message(jid, 0, json.dumps({"seq": 5, "t": 0.5, "motor_length": [5.0]}).encode(), 0)
        w.finish()
    rec = read_mcap(p)
    assert rec.seq.tolist() == [0, 1, 2, 3, 4, 5] and rec.motor_length[:, 0].tolist() == [0, 1, 2, 3, 4, 5]
    assert rec.temperature[:3].tolist() == [20.0] * 3 and np.isnan(rec.temperature[3:]).all()
    assert [tk["seq"] for tk in iter_inputs(p)] == list(range(6))


# ---------------------------------------------------------------------------- bad files
def _file_with_block(path: Path, data: bytes, *, fmt: str = "2", schema_name: str = "cablesvc.InputBlock") -> None:
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("cablesvc", {"robot": "r", "format": fmt})
        good = pb.encode_block(np.arange(4), np.arange(4) * 0.1, np.ones((4, 2)))
        cid = w.register_channel(INPUT_TOPIC, "protobuf", w.register_schema(schema_name, "protobuf", pb.SCHEMA_DATA))
        w.add_message(cid, 0, good, 0)
        w.add_message(cid, 0, data, 0)
        w.finish()


@pytest.mark.parametrize("data,match", [
    (pb.encode_block(np.arange(3), np.arange(3) * 0.1, np.ones((3, 3))), r"field 'cables': is 3, expected 2"),
    (pb.encode_block(np.arange(3), np.arange(3) * 0.1, np.ones((3, 2)))[:-5], r"'motor_length': length"),
    (pb.encode_block(np.arange(3), np.array([0.0, np.nan, 0.2]), np.ones((3, 2))),
     r"message 5 on /cablesvc/input: field 't': must be finite"),
    (pb._int_field(1, 2) + pb._int_field(2, 3) + pb._len_field(3, np.arange(3).tobytes())
     + pb._len_field(4, np.zeros(2).tobytes()) + pb._len_field(5, np.ones(6).tobytes()),
     r"'t': has 2 values, expected 3 \(one per tick\)"),
    (pb.encode_block(np.arange(3), np.arange(3) * 0.1, np.ones((3, 2)), np.zeros((3, 3)), np.zeros((3, 4)))[:-(4 * 24 + 3)]
     + b"", r"block 1 is not a valid cablesvc.InputBlock"),
    (b"\x0b\x00", r"wire type 3"),
])
def test_damaged_block_names_message_block_and_field(tmp_path, data, match):
    p = tmp_path / "bad.mcap"
    _file_with_block(p, data)
    with pytest.raises(RecordingError, match=match) as ei:
        read_mcap(p)
    assert ei.value.location.startswith("message 4 on /cablesvc/input") or "message 5" in ei.value.location
    with pytest.raises(RecordingError, match=match):
        list(iter_inputs(p))


def test_protobuf_inputs_need_format_2_and_the_schema(tmp_path):
    good = pb.encode_block(np.arange(2), np.arange(2) * 0.1, np.ones((2, 2)))
    p = tmp_path / "f1.mcap"
    _file_with_block(p, good, fmt="1")
    with pytest.raises(RecordingError, match=r"needs format 2, but the file says format '1'"):
        read_mcap(p)
    _file_with_block(p, good, schema_name="foo.Bar")
    with pytest.raises(RecordingError, match=r"need the schema 'cablesvc.InputBlock'.*'foo.Bar'"):
        read_mcap(p)
    _file_with_block(p, good, fmt="3")
    with pytest.raises(RecordingError, match=r"format '3' is not supported: this cablesvc reads formats 1 and 2"):
        read_mcap(p)
    rec = gappy_recording(n=20, m=4)
    write_mcap(p, rec)
    with pytest.raises(RecordingError, match=r"message 0 on .*expected 8 \(the robot has 8 cables\)"):
        read_recording(p, robot_cables=8)
    assert read_recording(p, robot_cables=4).equals(rec)


# ---------------------------------------------------------------------------- the live writer
def test_tick_by_tick_writer_blocks_flush_and_close(tmp_path):
    p = tmp_path / "live.mcap"
    w = McapRecordingWriter(p, "r", block_ticks=10)
    for i in range(25):
        w.write_input(i, i * 1e-3, np.array([1.0, 2.0]) + i,
                      force=None if i % 3 else [5.0, np.inf], position=[0.1, 0.2, 0.3] if i > 20 else None,
                      orientation=[0, 0, 0, 1] if i > 20 else None, temperature=None if i < 5 else 20.0 + i)
        w.write(FORCES_TOPIC, i * 1e-3, {"seq": i, "t": i * 1e-3, "force": [1.0, 2.0]})
    assert w.n_inputs == 25
    w.flush()                                    # writes the block in progress (ticks 20..24)
    with pytest.warns(RecordingTruncatedWarning, match="ends after a complete record"):
        assert read_mcap(p).n_ticks == 25
    with pytest.raises(ValueError, match="motor_length has 3 values, expected 2"):
        w.write_input(25, 0.025, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="together"):
        w.write_input(25, 0.025, [1.0, 2.0], position=[0, 0, 0])
    with pytest.raises(ValueError, match="log_time"):
        w.write_input(25, -1.0, [1.0, 2.0])
    w.write_input(25, 0.025, [9.0, 9.0])
    w.close()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_mcap(p, keep_topics=[FORCES_TOPIC])
    assert rec.seq.tolist() == list(range(26)) and rec.motor_length[25].tolist() == [9.0, 9.0]
    assert len(rec.extra[FORCES_TOPIC]) == 25
    assert rec.force[0].tolist() == [5.0, np.inf] and np.isnan(rec.force[1]).all()
    assert np.isnan(rec.position[:21]).all() and rec.position[21].tolist() == [0.1, 0.2, 0.3]
    assert np.isnan(rec.temperature[:5]).all() and rec.temperature[5] == 25.0
    with open(p, "rb") as f:
        counts = make_reader(f).get_summary().statistics.channel_message_counts
    assert sorted(counts.values()) == [4, 25]     # blocks of 10, 10, 5 (flush) and 1; 25 forces


_KILL_SCRIPT = """
import os, signal, sys
from cablesvc.recording import McapRecordingWriter
path, flush, chunk_size = sys.argv[1], sys.argv[2] == "flush", int(sys.argv[3])
w = McapRecordingWriter(path, "killbot", chunk_size=chunk_size)
for i in range(1, 791):
    w.write_input(i, i * 0.001, [1.0 + i, 2.0, 3.0], force=[10.0, 20.0, 30.0])
    if i == 500 and flush:
        w.flush()
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("flush,chunk_size", [(True, 1 << 20), (False, 2048)])
def test_kill_9_loses_at_most_the_block_and_chunk_in_progress(tmp_path, flush, chunk_size):
    p = tmp_path / "killed.mcap"
    proc = subprocess.run([sys.executable, "-c", _KILL_SCRIPT, str(p), "flush" if flush else "no", str(chunk_size)],
                          env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    with pytest.warns(RecordingTruncatedWarning):
        rec = read_mcap(p)
    assert rec.seq.tolist() == list(range(1, rec.n_ticks + 1))
    assert rec.motor_length[:, 0].tolist() == [1.0 + i for i in range(1, rec.n_ticks + 1)]
    if flush:
        assert rec.n_ticks == 500
    else:
        # 3 cables, 2 KiB chunks: blocks of 2048 // 128 = 16 ticks, two blocks a chunk
        block = 2048 // (8 * (2 + 2 * 3 + 7 + 1))
        assert block == 16
        assert 790 - 3 * block <= rec.n_ticks < 790


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_daemon_recorder_writes_every_tick_in_either_encoding(tmp_path, encoding):
    p = tmp_path / f"rec-{encoding}.mcap"
    r = Recorder(p, "ipanema3", {"model": "amplitude"}, maxsize=10_000, block=True, encoding=encoding)
    rng = np.random.default_rng(0)
    sent = []
    for k in range(2345):
        tk = TickInput(seq=k, t=k * 1e-3, motor_length=1.0 + 1e-3 * rng.standard_normal(8),
                       position=np.array([0.1, 0.2, 0.3]), orientation=np.array([0.0, 0.0, 0.0, 1.0]),
                       force=100.0 + rng.standard_normal(8), temperature=21.5, stamp_ns=0)
        sent.append(tk)
        r.put((tk, {"seq": k, "t": tk.t, "force": [1.0] * 8}, []))
    assert r.close() == 0
    rec = read_mcap(p, keep_topics=[FORCES_TOPIC])
    assert read_metadata(p)["format"] == ("2" if encoding == "protobuf" else "1")
    assert rec.n_ticks == 2345 and len(rec.extra[FORCES_TOPIC]) == 2345
    assert rec.seq.tolist() == list(range(2345))
    assert np.array_equal(rec.motor_length, np.array([tk.motor_length for tk in sent]))
    assert np.array_equal(rec.force, np.array([tk.force for tk in sent]))


# ---------------------------------------------------------------------------- CLI and bench
def test_simulate_writes_protobuf_by_default_and_json_on_request(tmp_path, capsys):
    args = ["simulate", "--robot", "ipanema3", "--scenario", "hold-sine", "--duration", "0.5"]
    assert cli_main([*args, "--out", str(tmp_path / "a.mcap")]) == 0
    assert cli_main([*args, "--out", str(tmp_path / "b.mcap"), "--encoding", "json"]) == 0
    assert read_metadata(tmp_path / "a.mcap")["format"] == "2"
    assert read_metadata(tmp_path / "b.mcap")["format"] == "1"
    a, b = read_recording(tmp_path / "a.mcap"), read_recording(tmp_path / "b.mcap")
    assert a.n_ticks == 500 and a.equals(b)          # finite data: both encodings are exact


def test_bench_read_writes_and_reads_both_encodings_identically():
    res = run_read_bench(0.05, rate=1000.0, cables=3)
    assert [r["encoding"] for r in res["rows"]] == ["protobuf", "json"]
    for r in res["rows"]:
        assert r["ticks"] == r["ticks_read"] == 3000 and r["identical"], r
        assert r["file_mb"] > 0 and r["peak_rss_mb"] >= r["rss_before_read_mb"] > 0


def test_daemon_recorder_flushes_on_a_timer_so_a_kill_loses_little(tmp_path):
    """Blocks hold up to 1000 ticks: without the recorder's timer a slow robot (200 Hz)
    would keep 5 s of ticks in memory. With it, what was written a second ago is on disk."""
    p = tmp_path / "live.mcap"
    r = Recorder(p, "ipanema3", {}, maxsize=1000, block=True, flush_s=0.2)
    try:
        for k in range(50):
            tk = TickInput(seq=k, t=k * 5e-3, motor_length=np.full(8, 1.0 + k), position=None, orientation=None,
                           force=None, temperature=None, stamp_ns=0)
            r.put((tk, {"seq": k, "t": tk.t, "force": [0.0] * 8}, []))
        deadline = time.monotonic() + 10
        n = 0
        while time.monotonic() < deadline and n < 50:
            time.sleep(0.1)
            with pytest.warns(RecordingTruncatedWarning):   # still open: no summary yet
                n = read_mcap(p).n_ticks
        assert n == 50
    finally:
        assert r.close() == 0
    assert read_mcap(p).motor_length[:, 0].tolist() == [1.0 + k for k in range(50)]
