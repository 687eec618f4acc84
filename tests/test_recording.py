"""Recording format 1 (MCAP + CSV): round trips, interop with the raw mcap library,
error reporting, truncated files and crash behaviour. Real files in tmp_path, no mocks."""

from __future__ import annotations

import json
import math
import os
import signal
import string
import struct
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from cablesvc.recording import (
    ALARMS_TOPIC,
    FORCES_TOPIC,
    INPUT_JSON_SCHEMA,
    INPUT_SCHEMA_NAME,
    INPUT_TOPIC,
    McapRecordingWriter,
    Recording,
    RecordingError,
    RecordingTruncatedWarning,
    csv_header,
    iter_csv_inputs,
    iter_inputs,
    iter_mcap_inputs,
    read_csv,
    read_mcap,
    read_metadata,
    read_recording,
    write_csv,
    write_mcap,
    write_recording,
)

REPO = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------- helpers
def make_recording(
    n: int = 50,
    m: int = 4,
    *,
    pose: bool = True,
    force: bool = True,
    temperature: bool = True,
    seed: int = 0,
    robot: str = "ipanema3",
) -> Recording:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Recording(
        robot=robot,
        metadata={"operator": "jm", "site": "LIRMM hall"},
        t=10.0 + np.arange(n) * 0.001 + rng.uniform(0, 1e-5, n),
        seq=np.arange(1, n + 1),
        motor_length=rng.uniform(0.5, 5.0, (n, m)),
        position=rng.normal(size=(n, 3)) if pose else None,
        orientation=q if pose else None,
        force=rng.uniform(10, 900, (n, m)) if force else None,
        temperature=rng.uniform(15, 30, n) if temperature else None,
    )


def strict_json(data: bytes):
    """json.loads that rejects NaN/Infinity (not JSON)."""

    def bad(token):
        raise ValueError(f"non-JSON constant {token}")

    return json.loads(data, parse_constant=bad)


def raw_write(
    path: Path,
    messages: list,
    *,
    metadata: dict | None = None,
    metadata_name: str = "cablesvc",
    chunked: bool = True,
    metadata_last: bool = False,
    other_topics: bool = False,
    encoding: str = "json",
    finish: bool = True,
) -> None:
    """A third-party writer: only the mcap library + json, following the spec."""
    if metadata is None:
        metadata = {"robot": "thirdbot", "format": "1"}
    with open(path, "wb") as f:
        w = Writer(f, use_chunking=chunked, compression=CompressionType.NONE, chunk_size=2048)
        w.start(profile="", library="third-party-recorder")
        if metadata and not metadata_last:
            w.add_metadata(metadata_name, metadata)
        sid = w.register_schema(INPUT_SCHEMA_NAME, "jsonschema", b'{"type": "object"}')
        cid = w.register_channel(INPUT_TOPIC, encoding, sid)
        cam = None
        if other_topics:
            sid2 = w.register_schema("foo.Image", "protobuf", b"\x00\x01")
            cam = w.register_channel("/camera/image", "protobuf", sid2)
            sid3 = w.register_schema("foo.Status", "jsonschema", b"{}")
            status = w.register_channel("/cablesvc/status", "json", sid3)
        for msg in messages:
            data = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
            t = msg.get("t", 0.0) if isinstance(msg, dict) else 0.0
            log_time = round(t * 1e9)
            w.add_message(cid, log_time, data, log_time)
            if cam is not None:
                w.add_message(cam, log_time, b"\xff\xfe not json", log_time)
                w.add_message(status, log_time, b'{"ok": true}', log_time)
        if metadata and metadata_last:
            w.add_metadata(metadata_name, metadata)
        if finish:
            w.finish()


def spec_message(i: int, m: int = 3, pose: bool = True) -> dict:
    return {
        "seq": 100 + i,
        "t": 1.0 + 0.002 * i,
        "pose": {"position": [0.1 * i, 0.2, 1.5], "orientation": [0.0, 0.0, 0.0, 1.0]}
        if pose
        else None,
        "motor_length": [1.0 + 0.01 * i + c for c in range(m)],
        "force": [100.0 + i + c for c in range(m)],
        "temperature": 21.5,
    }


# ---------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".mcap", ".csv"])
@pytest.mark.parametrize(
    "pose,force,temperature",
    [(True, True, True), (False, True, True), (True, False, True), (True, True, False),
     (False, False, False)],
)
def test_round_trip_exact(tmp_path, suffix, pose, force, temperature):
    rec = make_recording(pose=pose, force=force, temperature=temperature)
    path = tmp_path / f"rec{suffix}"
    write_recording(path, rec)
    back = read_recording(path)
    assert back.equals(rec)
    assert back.has_pose == pose and back.has_force == force
    assert back.has_temperature == temperature
    assert back.truncation is None
    # streaming gives the same ticks
    ticks = list(iter_inputs(path))
    assert [tk["seq"] for tk in ticks] == rec.seq.tolist()
    assert np.array_equal(np.array([tk["motor_length"] for tk in ticks]), rec.motor_length)


@pytest.mark.parametrize("suffix", [".mcap", ".csv"])
def test_round_trip_ticks_missing_parts(tmp_path, suffix):
    """Individual ticks without pose / force / temperature come back as NaN rows."""
    rec = make_recording(n=6)
    rec.position[[1, 4]] = np.nan
    rec.orientation[[1, 4]] = np.nan
    rec.force[2] = np.nan
    rec.force[3, 1] = np.nan  # one sensor missing in one tick
    rec.temperature[0] = np.nan
    path = tmp_path / f"rec{suffix}"
    write_recording(path, rec)
    back = read_recording(path)
    assert back.equals(rec)
    ticks = list(iter_inputs(path))
    assert ticks[1]["position"] is None and ticks[1]["orientation"] is None
    assert ticks[2]["force"] is None
    assert np.isnan(ticks[3]["force"][1]) and ticks[3]["force"][0] == rec.force[3, 0]
    assert ticks[0]["temperature"] is None and ticks[1]["temperature"] == rec.temperature[1]


def test_mcap_to_csv_to_mcap(tmp_path):
    rec = make_recording(n=120, m=8)
    rec.position[5] = np.nan
    rec.orientation[5] = np.nan
    write_mcap(tmp_path / "a.mcap", rec)
    a = read_mcap(tmp_path / "a.mcap")
    write_csv(tmp_path / "b.csv", a)
    b = read_csv(tmp_path / "b.csv")
    write_mcap(tmp_path / "c.mcap", b)
    c = read_mcap(tmp_path / "c.mcap")
    assert a.equals(rec) and b.equals(rec) and c.equals(rec)


def test_csv_layout_is_the_spec(tmp_path):
    rec = make_recording(n=3, m=2)
    write_csv(tmp_path / "r.csv", rec)
    lines = (tmp_path / "r.csv").read_text().splitlines()
    assert lines[:4] == ["# robot: ipanema3", "# format: 1", "# operator: jm",
                         "# site: LIRMM hall"]
    assert lines[4] == "t,seq,x,y,z,qx,qy,qz,qw,l0,l1,f0,f1,temperature"
    assert lines[4].split(",") == csv_header(2, True, True)
    first = lines[5].split(",")
    assert float(first[0]) == rec.t[0] and first[0] == repr(float(rec.t[0])) and first[1] == "1"
    # no pose: the pose columns are there and empty; no force/temperature: no columns
    rec2 = make_recording(n=2, m=2, pose=False, force=False, temperature=False)
    write_csv(tmp_path / "s.csv", rec2)
    lines = (tmp_path / "s.csv").read_text().splitlines()
    assert lines[4] == "t,seq,x,y,z,qx,qy,qz,qw,l0,l1"
    assert lines[5].split(",")[2:9] == [""] * 7


def test_third_party_csv(tmp_path):
    """Hand-written CSV: CRLF, BOM, spaces, columns in another order, no metadata."""
    text = (
        "\ufeff# robot: cogiro\r\n# note: written by hand\r\n"
        "seq, t, l0, l1, x, y, z, qx, qy, qz, qw\r\n"
        "7, 0.5, 1.25, 2.5, , , , , , ,\r\n"
        "8, 0.501, 1.26, 2.51, 0.1, 0.2, 0.3, 0, 0, 0, 1\r\n"
        "\r\n"
    )
    p = tmp_path / "hand.csv"
    p.write_bytes(text.encode("utf-8"))
    rec = read_csv(p)
    assert rec.robot == "cogiro" and rec.metadata == {"note": "written by hand"}
    assert rec.seq.tolist() == [7, 8] and rec.t.tolist() == [0.5, 0.501]
    assert rec.motor_length.tolist() == [[1.25, 2.5], [1.26, 2.51]]
    assert np.isnan(rec.position[0]).all()
    assert rec.orientation[1].tolist() == [0, 0, 0, 1]
    assert rec.force is None and rec.temperature is None
    assert read_metadata(p) == {"robot": "cogiro", "format": "1", "note": "written by hand"}
    bare = tmp_path / "bare.csv"
    bare.write_text("t,seq,l0\n0.0,1,2.0\n")
    r = read_csv(bare)
    assert r.robot == "" and r.n_cables == 1 and not r.has_pose


# ---------------------------------------------------------------------------- raw mcap interop
@pytest.mark.parametrize("chunked", [True, False])
def test_third_party_raw_mcap_file(tmp_path, chunked):
    msgs = [spec_message(i) for i in range(40)]
    msgs[3]["pose"] = None
    msgs[4]["force"] = None
    msgs[5]["temperature"] = None
    msgs[6]["force"][1] = None  # non-finite sensor value written as null
    del msgs[7]["temperature"]  # lenient: an absent optional field is null
    p = tmp_path / "third.mcap"
    raw_write(p, msgs, chunked=chunked, metadata_last=not chunked, other_topics=True,
              metadata={"robot": "thirdbot", "format": "1", "lab": "x"})
    rec = read_mcap(p)
    assert rec.robot == "thirdbot" and rec.metadata == {"lab": "x"}
    assert rec.n_ticks == 40 and rec.n_cables == 3 and rec.extra == {}
    assert rec.seq.tolist() == [100 + i for i in range(40)]
    assert rec.t.tolist() == [m["t"] for m in msgs]
    assert rec.motor_length.tolist() == [m["motor_length"] for m in msgs]
    assert np.isnan(rec.position[3]).all() and rec.position[2].tolist() == [0.2, 0.2, 1.5]
    assert np.isnan(rec.force[4]).all() and np.isnan(rec.force[6, 1])
    assert rec.force[6, 0] == msgs[6]["force"][0]
    assert np.isnan(rec.temperature[[5, 7]]).all() and rec.temperature[8] == 21.5
    assert rec.validate() == []
    assert [tk["seq"] for tk in iter_mcap_inputs(p)] == rec.seq.tolist()


def test_cablesvc_file_read_with_raw_mcap(tmp_path):
    p = tmp_path / "ours.mcap"
    with McapRecordingWriter(p, "ipanema3", {"operator": "jm"}, encoding="json") as w:
        for i in range(20):
            f = [100.0 + i, math.nan, 300.0] if i == 5 else [100.0 + i, 200.0, 300.0]
            w.write_input(i + 1, 12.345 + 0.001 * i, np.array([1.0, 2.0, 3.0]) + i,
                          force=f, position=[0.1, 0.2, 0.3], orientation=[0, 0, 0, 1],
                          temperature=None if i == 2 else 21.5)
        w.write_input(21, 12.365, [1.0, 2.0, 3.0])  # no pose, no force
    with open(p, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().library.startswith("cablesvc/")
        metas = list(reader.iter_metadata())
        assert [(md.name, md.metadata) for md in metas] == [
            ("cablesvc", {"robot": "ipanema3", "format": "1", "operator": "jm"})
        ]
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        msgs = list(reader.iter_messages(log_time_order=False))
    assert len(msgs) == 21
    for i, (schema, channel, message) in enumerate(msgs):
        assert channel.topic == INPUT_TOPIC and channel.message_encoding == "json"
        assert schema.name == "cablesvc.Input" and schema.encoding == "jsonschema"
        assert json.loads(schema.data) == INPUT_JSON_SCHEMA
        payload = strict_json(message.data)
        assert set(payload) == {"seq", "t", "pose", "motor_length", "force", "temperature"}
        assert message.log_time == round(payload["t"] * 1e9)
        assert payload["seq"] == i + 1
    p5 = strict_json(msgs[5][2].data)
    assert p5["force"] == [105.0, None, 300.0]
    assert strict_json(msgs[2][2].data)["temperature"] is None
    last = strict_json(msgs[20][2].data)
    assert last["pose"] is None and last["force"] is None and last["temperature"] is None
    assert msgs[0][2].log_time == 12_345_000_000
    assert strict_json(msgs[0][2].data)["pose"] == {
        "position": [0.1, 0.2, 0.3], "orientation": [0.0, 0.0, 0.0, 1.0]}


def test_output_topics_and_unknown_topics(tmp_path):
    p = tmp_path / "live.mcap"
    with McapRecordingWriter(p, "ipanema3", encoding="json") as w:
        custom = w.register_topic("/cablesvc/debug", "cablesvc.Debug", {"type": "object"})
        assert w.register_topic("/cablesvc/debug", "cablesvc.Debug", {"type": "object"}) == custom
        for i in range(10):
            t = 0.01 * i
            w.write_input(i, t, [1.0, 2.0])
            w.write(FORCES_TOPIC, t, {"seq": i, "t": t, "force": np.array([1.5, np.nan])})
            w.write("/cablesvc/debug", t, {"k": np.int64(i)})
        w.write(ALARMS_TOPIC, 0.09, {"seq": 9, "t": 0.09, "severity": "warning",
                                      "code": "slack", "cable": 1, "message": "cable 1 slack"})
        with pytest.raises(KeyError):
            w.write("/not/registered", 0.1, {})
        with pytest.raises(ValueError):
            w.write(INPUT_TOPIC, 0.1, {})
    rec = read_mcap(p)
    assert rec.n_ticks == 10 and rec.extra == {}
    kept = read_mcap(p, keep_topics=[FORCES_TOPIC, ALARMS_TOPIC])
    assert kept.extra[FORCES_TOPIC][3] == {"seq": 3, "t": 0.03, "force": [1.5, None]}
    assert kept.extra[ALARMS_TOPIC][0]["code"] == "slack"
    with open(p, "rb") as f:
        by_topic: dict = {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            by_topic.setdefault(channel.topic, []).append((schema.name, strict_json(message.data)))
    assert by_topic[FORCES_TOPIC][0] == ("cablesvc.Forces", {"seq": 0, "t": 0.0,
                                                             "force": [1.5, None]})
    assert by_topic[ALARMS_TOPIC][0][0] == "cablesvc.Alarm"
    assert by_topic["/cablesvc/debug"][9] == ("cablesvc.Debug", {"k": 9})
    # extra payloads survive a write_mcap / read_mcap round trip
    write_mcap(tmp_path / "again.mcap", kept)
    again = read_mcap(tmp_path / "again.mcap", keep_topics=[FORCES_TOPIC, ALARMS_TOPIC])
    assert again.equals(kept)


# ---------------------------------------------------------------------------- errors
def test_recording_error_names_path_location_reason():
    e = RecordingError("/x/r.mcap", "message 17 on /cablesvc/input", "field 'force': bad")
    assert str(e) == "/x/r.mcap: message 17 on /cablesvc/input: field 'force': bad"
    assert (e.path, e.location, e.reason) == ("/x/r.mcap", "message 17 on /cablesvc/input",
                                              "field 'force': bad")


def test_error_not_mcap_and_empty(tmp_path):
    text = tmp_path / "looks.mcap"
    text.write_text("t,seq,l0\n0,1,2\n")
    with pytest.raises(RecordingError, match="not an MCAP file.*looks like text") as ei:
        read_mcap(text)
    assert ei.value.location == "byte 0"
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match="empty file"):
        read_mcap(empty)
    (tmp_path / "empty.csv").write_bytes(b"")
    with pytest.raises(RecordingError, match="empty file"):
        read_csv(tmp_path / "empty.csv")
    (tmp_path / "comments.csv").write_text("# robot: x\n\n")
    with pytest.raises(RecordingError, match="no header line"):
        read_csv(tmp_path / "comments.csv")
    with pytest.raises(RecordingError, match="no such file"):
        read_recording(tmp_path / "missing.mcap")
    with pytest.raises(RecordingError, match="unknown suffix"):
        read_recording(tmp_path / "x.bag")


def test_error_missing_metadata(tmp_path):
    p = tmp_path / "nometa.mcap"
    raw_write(p, [spec_message(0)], metadata={})
    with pytest.raises(RecordingError) as ei:
        read_mcap(p)
    assert ei.value.location == "metadata"
    assert "no metadata record named 'cablesvc'" in ei.value.reason
    assert "no metadata records" in ei.value.reason
    raw_write(p, [spec_message(0)], metadata_name="rosbag_info")
    with pytest.raises(RecordingError, match=r"named \['rosbag_info'\]"):
        read_mcap(p)
    raw_write(p, [spec_message(0)], metadata={"format": "1"})
    with pytest.raises(RecordingError, match="missing key 'robot'"):
        read_mcap(p)
    raw_write(p, [spec_message(0)], metadata={"robot": "r", "format": "3"})
    with pytest.raises(RecordingError, match="format '3' is not supported") as ei:
        read_mcap(p)
    assert "format" in ei.value.location


def test_error_no_input_channel_and_wrong_encoding(tmp_path):
    p = tmp_path / "noinput.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("cablesvc", {"robot": "r", "format": "1"})
        cid = w.register_channel("/other", "json", 0)
        w.add_message(cid, 0, b"{}", 0)
        w.finish()
    with pytest.raises(RecordingError, match=r"no channel on topic /cablesvc/input.*'/other'"):
        read_mcap(p)
    raw_write(p, [spec_message(0)], encoding="cbor")
    with pytest.raises(RecordingError, match="message encoding 'cbor'"):
        read_mcap(p)


@pytest.mark.parametrize(
    "k,bad,field,match",
    [
        (3, b'{"seq": 3, "t": 1.0, "motor_len', None, "not valid JSON"),
        (5, {"seq": 5, "t": 1.0, "pose": None, "force": None}, "motor_length",
         "missing required field"),
        (2, {"seq": 2, "motor_length": [1, 2, 3]}, "t", "missing required field"),
        (4, {"seq": 4, "t": 1.0, "motor_length": [1.0, 2.0]}, "motor_length",
         "has 2 values, expected 3"),
        (6, {"seq": 6, "t": 1.0, "motor_length": [1, 2, 3], "force": [1, 2, 3, 4]}, "force",
         "has 4 values, expected 3"),
        (1, {"seq": "1", "t": 1.0, "motor_length": [1, 2, 3]}, "seq", "expected an integer"),
        (7, {"seq": 7, "t": 1.0, "motor_length": [1, "x", 3]}, "motor_length[1]",
         "expected a number or null, got a string"),
        (2, {"seq": 2, "t": 1.0, "motor_length": [1, 2, 3], "pose": {"position": [0, 0, 0]}},
         "pose.orientation", "missing"),
        (0, [1, 2, 3], None, "expected a JSON object"),
    ],
)
def test_error_bad_input_message(tmp_path, k, bad, field, match):
    msgs = [spec_message(i) for i in range(8)]
    msgs[k] = bad
    p = tmp_path / "bad.mcap"
    raw_write(p, msgs)
    with pytest.raises(RecordingError) as ei:
        read_mcap(p)
    assert ei.value.location == f"message {k} on /cablesvc/input"
    assert match in ei.value.reason
    if field is not None:
        assert f"field '{field}'" in ei.value.reason
    with pytest.raises(RecordingError, match=f"message {k} on"):
        list(iter_mcap_inputs(p))


def test_error_robot_cable_count(tmp_path):
    rec = make_recording(n=5, m=4)
    write_mcap(tmp_path / "r.mcap", rec)
    write_csv(tmp_path / "r.csv", rec)
    assert read_recording(tmp_path / "r.mcap", robot_cables=4).equals(rec)
    with pytest.raises(RecordingError, match=r"message 0 on .*expected 8 \(the robot has 8"):
        read_recording(tmp_path / "r.mcap", robot_cables=8)
    with pytest.raises(RecordingError, match="4 motor-length columns but the robot has 8"):
        read_recording(tmp_path / "r.csv", robot_cables=8)


@pytest.mark.parametrize(
    "text,location,match",
    [
        ("t,seq,l0,l1\n0.0,1,1.0,2.0\n0.1,2,1.0,abc\n", "line 3, column l1",
         "'abc' is not a number"),
        ("# robot: r\nt,seq,l0\n0.0,1,1.0\n0.1,2\n", "line 4", "wrong number of fields: 2"),
        ("t,seq,l0\n0.0,1.5,1.0\n", "line 2, column seq", "'1.5' is not an integer"),
        ("t,seq,l0\n,1,1.0\n", "line 2, column t", "empty"),
        ("t,seq,l0,f0,f1\n", "line 1", "cable count inconsistency: 1 motor-length columns"),
        ("seq,l0,l1\n", "line 1", "missing required column 't'"),
        ("t,seq,x,y,z\n", "line 1", "missing required column 'l0'"),
        ("t,seq,l0,l2\n", "line 1", "missing column 'l1'"),
        ("t,seq,l0,force0\n", "line 1, column 'force0'", "unknown column"),
        ("t,seq,l0,l0\n", "line 1, column l0", "duplicate column"),
        ("t,seq,x,y,z,l0\n", "line 1", "pose columns ['qx', 'qy', 'qz', 'qw'] missing"),
        ("# format: 2\nt,seq,l0\n", "line 1", "format '2' is not supported"),
        ("t,seq,l0\n0.0,1,1.0\n# late: x\n", "line 3", "'#' line after the header"),
    ],
)
def test_csv_errors_name_line_and_column(tmp_path, text, location, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(RecordingError) as ei:
        read_csv(p)
    assert ei.value.location == location
    assert match in ei.value.reason
    assert str(p) in str(ei.value) and location in str(ei.value)


def test_writer_rejects_bad_input(tmp_path):
    with McapRecordingWriter(tmp_path / "w.mcap", "r") as w:
        w.write_input(1, 0.0, [1.0, 2.0])
        with pytest.raises(ValueError, match="has 3 values, expected 2"):
            w.write_input(2, 0.001, [1.0, 2.0, 3.0])
        with pytest.raises(ValueError, match="together"):
            w.write_input(2, 0.001, [1.0, 2.0], position=[0, 0, 0])
        with pytest.raises(ValueError, match="log_time"):
            w.write_input(2, math.nan, [1.0, 2.0])
        with pytest.raises(ValueError, match="log_time"):
            w.write_input(2, -1.0, [1.0, 2.0])
        with pytest.raises(TypeError):
            w.write_input(2.0, 0.001, [1.0, 2.0])
        w.write_input(np.int64(2), np.float64(0.001), np.array([1, 2]))
    assert read_mcap(tmp_path / "w.mcap").seq.tolist() == [1, 2]
    with pytest.raises(ValueError, match="set by the writer"):
        McapRecordingWriter(tmp_path / "x.mcap", "r", {"format": "2"})
    with pytest.raises(ValueError, match="closed"):
        w.write_input(3, 0.002, [1.0, 2.0])


# ---------------------------------------------------------------------------- validate / slice
def test_non_monotonic_seq_is_read_and_reported_by_validate(tmp_path):
    msgs = [spec_message(i) for i in range(6)]
    msgs[3]["seq"], msgs[4]["seq"] = msgs[4]["seq"], msgs[3]["seq"]
    p = tmp_path / "swap.mcap"
    raw_write(p, msgs)
    rec = read_mcap(p)
    assert rec.seq.tolist() == [100, 101, 102, 104, 103, 105]  # file order kept
    problems = rec.validate()
    assert len(problems) == 1 and "seq is not +1 per tick at 3 places" in problems[0]


def test_validate_and_slice():
    rec = make_recording(n=10, m=3)
    assert rec.validate() == []
    rec.t[4] = rec.t[3]
    rec.orientation[6] = [0, 0, 0, 2.0]
    rec.position[7, 0] = np.nan
    rec.motor_length[8, 2] = np.inf
    problems = "\n".join(rec.validate())
    assert "t does not increase at 1 places (first: index 3 -> 4" in problems
    assert "not a unit quaternion at 1 ticks (first at index 6" in problems
    assert "pose is partly missing at 1 ticks (first at index 7" in problems
    assert "motor_length is not finite at 1 ticks (first at index 8)" in problems
    bad = Recording(robot="r", metadata={}, t=np.zeros(3), seq=np.arange(3),
                    motor_length=np.zeros((2, 3)), force=np.zeros((3, 2)))
    assert bad.validate() == ["motor_length has shape (2, 3), expected (3, m)"]
    s = make_recording(n=10).slice(2, 5)
    assert s.n_ticks == 3 and s.seq.tolist() == [3, 4, 5] and s.position.shape == (3, 3)
    assert s.n_cables == 4 and s.has_force and s.has_temperature


# ---------------------------------------------------------------------------- truncation
def test_truncated_file_reads_complete_chunks(tmp_path):
    n = 3000
    rec = make_recording(n=n, m=8, seed=3)
    full = tmp_path / "full.mcap"
    write_mcap(full, rec, chunk_size=16 * 1024, encoding="json")
    data = full.read_bytes()
    cut = int(len(data) * 0.6)
    with open(full, "rb") as f:
        chunk_indexes = make_reader(f).get_summary().chunk_indexes
    assert len(chunk_indexes) > 5
    complete = [c for c in chunk_indexes if c.chunk_start_offset + c.chunk_length <= cut]
    last_end = max(c.message_end_time for c in complete)
    expected = sum(1 for t in rec.t.tolist() if round(t * 1e9) <= last_end)

    cut_path = tmp_path / "cut.mcap"
    cut_path.write_bytes(data[:cut])
    with pytest.warns(RecordingTruncatedWarning, match="incomplete"):
        back = read_mcap(cut_path)
    assert 0 < back.n_ticks < n
    assert back.n_ticks == expected
    assert back.seq.tolist() == list(range(1, expected + 1))
    assert back.equals(rec.slice(0, expected))  # the recovered data are exact
    tr = back.truncation
    assert tr is not None and not tr.data_complete and tr.file_bytes == cut
    assert "Chunk record" in tr.partial_record
    assert tr.lost_t_range[0] == pytest.approx(rec.t[expected], abs=1e-9)
    assert f"recovered {expected} ticks" in tr.message and "Lost:" in tr.message
    with pytest.warns(RecordingTruncatedWarning):
        streamed = [tk["seq"] for tk in iter_mcap_inputs(cut_path)]
    assert streamed == list(range(1, expected + 1))

    # only the summary cut off: every tick is still there
    with open(full, "rb") as f:
        f.seek(-(8 + 29), os.SEEK_END)
        _, _, summary_start, _, _ = struct.unpack("<BQQQI", f.read(29))
    (tmp_path / "nosummary.mcap").write_bytes(data[: summary_start + 20])
    with pytest.warns(RecordingTruncatedWarning, match="no ticks were lost"):
        whole = read_mcap(tmp_path / "nosummary.mcap")
    assert whole.n_ticks == n and whole.truncation.data_complete


_KILL_SCRIPT = """
import os, signal, sys
from cablesvc.recording import McapRecordingWriter
path, flush, chunk_size = sys.argv[1], sys.argv[2] == "flush", int(sys.argv[3])
w = McapRecordingWriter(path, "killbot", chunk_size=chunk_size, encoding="json")
for i in range(1, 801):
    w.write_input(i, i * 0.001, [1.0 + i, 2.0, 3.0], force=[10.0, 20.0, 30.0])
    if i == 500 and flush:
        w.flush()
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("flush,chunk_size", [(True, 1 << 20), (False, 1 << 20), (False, 2048)])
def test_kill_9_keeps_flushed_and_finished_chunks(tmp_path, flush, chunk_size):
    p = tmp_path / "killed.mcap"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run(
        [sys.executable, "-c", _KILL_SCRIPT, str(p), "flush" if flush else "no",
         str(chunk_size)],
        env=env, capture_output=True, timeout=60,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    with pytest.warns(RecordingTruncatedWarning) as rw:
        rec = read_mcap(p)
    assert rec.robot == "killbot" and rec.truncation is not None
    assert rec.seq.tolist() == list(range(1, rec.n_ticks + 1))
    if flush:
        assert rec.n_ticks == 500  # exactly what was written before flush()
    elif chunk_size == 1 << 20:
        assert rec.n_ticks == 0  # the only chunk was still open
        assert "recovered 0 ticks" in str(rw[0].message)
    else:
        per_chunk = 2048 // 100 + 2  # a tick is > 100 bytes of JSON
        assert 800 - per_chunk <= rec.n_ticks < 800


def test_flush_fsync_mid_file_is_readable_while_open(tmp_path):
    p = tmp_path / "open.mcap"
    w = McapRecordingWriter(p, "r")
    for i in range(10):
        w.write_input(i, i * 0.01, [1.0])
    w.flush(fsync=True)
    with pytest.warns(RecordingTruncatedWarning, match="ends after a complete record"):
        assert read_mcap(p).n_ticks == 10
    w.write_input(10, 0.1, [1.0])
    w.close()
    assert read_mcap(p).n_ticks == 11


# ---------------------------------------------------------------------------- property test
_META_KEY = st.text(string.ascii_letters + string.digits + "_.-", min_size=1, max_size=8)
_META_VAL = st.text(string.ascii_letters + string.digits + " _-/éµ°", max_size=12).map(str.strip)
_FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def recordings(draw):
    n = draw(st.integers(1, 12))
    m = draw(st.integers(1, 8))

    def present_mask():
        mask = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
        mask[draw(st.integers(0, n - 1))] = True
        return mask

    position = orientation = force = temperature = None
    if draw(st.booleans()):
        position = draw(arrays(np.float64, (n, 3), elements=_FINITE))
        orientation = draw(arrays(np.float64, (n, 4), elements=_FINITE))
        mask = present_mask()
        position[~mask] = np.nan
        orientation[~mask] = np.nan
    if draw(st.booleans()):
        force = draw(arrays(np.float64, (n, m), elements=_FINITE))
        force[~present_mask()] = np.nan
    if draw(st.booleans()):
        temperature = draw(arrays(np.float64, (n,), elements=_FINITE))
        temperature[~present_mask()] = np.nan
    metadata = draw(st.dictionaries(_META_KEY.filter(lambda k: k not in ("robot", "format")),
                                    _META_VAL, max_size=3))
    return Recording(
        robot=draw(st.text(string.ascii_letters + string.digits + "_-", min_size=1,
                           max_size=10)),
        metadata=metadata,
        t=draw(arrays(np.float64, (n,), elements=st.floats(0, 1e9))),
        seq=np.array(draw(st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n,
                                   max_size=n)), dtype=np.int64),
        motor_length=draw(arrays(np.float64, (n, m), elements=_FINITE)),
        position=position,
        orientation=orientation,
        force=force,
        temperature=temperature,
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rec=recordings())
def test_property_round_trip_both_formats(rec):
    with tempfile.TemporaryDirectory() as d:
        for suffix in (".mcap", ".csv"):
            path = Path(d) / f"r{suffix}"
            write_recording(path, rec)
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # a complete file must not warn
                back = read_recording(path)
            assert back.equals(rec), suffix
        ticks = list(iter_csv_inputs(Path(d) / "r.csv"))
        assert [tk["seq"] for tk in ticks] == rec.seq.tolist()
