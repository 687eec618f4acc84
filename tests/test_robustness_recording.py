"""Recording layer robustness: files third parties write (raw mcap library, Python's csv
module) and edge values the readers and writers must turn into clear errors. Real files in
tmp_path, no mocks."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from cablesvc.recording import (
    ALARMS_TOPIC,
    INPUT_TOPIC,
    McapRecordingWriter,
    RecordingError,
    iter_csv_inputs,
    iter_mcap_inputs,
    read_csv,
    read_mcap,
    write_mcap,
)

BIG = 10**400  # a JSON integer literal no float holds


def _raw_mcap(path: Path, messages: list) -> Path:
    """A format-1 file written with nothing but the mcap library; messages are dicts
    (json.dumps'ed) or raw bytes."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("cablesvc", {"robot": "r", "format": "1"})
        sid = w.register_schema("cablesvc.Input", "jsonschema", b"{}")
        cid = w.register_channel(INPUT_TOPIC, "json", sid)
        for i, m in enumerate(messages):
            data = m if isinstance(m, bytes) else json.dumps(m).encode()
            w.add_message(cid, i * 1000, data, i * 1000)
        w.finish()
    return path


def _tick(**kw) -> dict:
    return {"seq": 0, "t": 0.0, "pose": None, "motor_length": [1.0, 2.0], "force": None,
            "temperature": None, **kw}


def _both_readers(path: Path) -> list[RecordingError]:
    errors = []
    for read in (read_mcap, lambda p: list(iter_mcap_inputs(p))):
        with pytest.raises(RecordingError) as ei:
            read(path)
        errors.append(ei.value)
    return errors


# ------------------------------------------------------------------------ MCAP reader
@pytest.mark.parametrize("field, msg, where", [
    ("t", _tick(t=BIG), "'t'"),
    ("temperature", _tick(temperature=BIG), "'temperature'"),
    ("motor_length", _tick(motor_length=[BIG, 1]), "'motor_length[0]'"),
    ("force", _tick(force=[1, BIG]), "'force[1]'"),
    ("pose", _tick(pose={"position": [0, 0, BIG], "orientation": [0, 0, 0, 1]}),
     "'pose.position[2]'"),
])
def test_mcap_integer_too_large_for_float_is_a_recording_error(tmp_path, field, msg, where):
    path = _raw_mcap(tmp_path / "big.mcap", [_tick(), _tick(seq=1, t=0.001), msg])
    for e in _both_readers(path):
        text = str(e)
        assert str(path) in text and f"message 2 on {INPUT_TOPIC}" in text
        assert where in text and "too large" in text


def test_mcap_deeply_nested_json_is_a_recording_error(tmp_path):
    path = _raw_mcap(tmp_path / "deep.mcap", [_tick(), b"[" * 100_000 + b"]" * 100_000])
    for e in _both_readers(path):
        assert f"message 1 on {INPUT_TOPIC}" in str(e) and "nested too deeply" in str(e)


def test_mcap_deeply_nested_extra_topic_is_a_recording_error(tmp_path):
    path = tmp_path / "deep_extra.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("cablesvc", {"robot": "r", "format": "1"})
        sid = w.register_schema("x", "jsonschema", b"{}")
        cin = w.register_channel(INPUT_TOPIC, "json", sid)
        cx = w.register_channel("/other", "json", sid)
        w.add_message(cin, 0, json.dumps(_tick()).encode(), 0)
        w.add_message(cx, 0, b"[" * 100_000 + b"]" * 100_000, 0)
        w.finish()
    with pytest.raises(RecordingError, match="message 0 on /other.*nested too deeply"):
        read_mcap(path, keep_topics=["/other"])


# ------------------------------------------------------------------------ MCAP writer
@pytest.mark.parametrize("seq", [2**63, -(2**63) - 1, np.uint64(2**63)])
def test_write_input_refuses_seq_outside_int64(tmp_path, seq):
    with McapRecordingWriter(tmp_path / "s.mcap", "r") as w:
        with pytest.raises(ValueError, match="64-bit"):
            w.write_input(seq, 0.0, [1.0])
        w.write_input(2**63 - 1, 0.0, [1.0])  # the edges are fine
        w.write_input(-(2**63), 0.001, [1.0])
    assert read_mcap(tmp_path / "s.mcap").seq.tolist() == [2**63 - 1, -(2**63)]


def test_write_input_refuses_t_whose_log_time_rounds_past_64_bits(tmp_path):
    from cablesvc.recording.mcap_writer import LOG_TIME_MAX_S

    with McapRecordingWriter(tmp_path / "t.mcap", "r") as w:
        with pytest.raises(ValueError, match="log_time"):
            w.write_input(0, LOG_TIME_MAX_S, [1.0])
        w.write_input(0, 1.8e10, [1.0])
    assert read_mcap(tmp_path / "t.mcap").n_ticks == 1


def test_write_input_writes_all_nonfinite_pose_and_force_as_null(tmp_path):
    path = tmp_path / "nulls.mcap"
    nan = math.nan
    with McapRecordingWriter(path, "r", encoding="json") as w:  # the JSON encoding's nulls
        w.write_input(0, 0.0, [1.0, 2.0], force=[nan, math.inf], position=[nan] * 3,
                      orientation=np.full(4, nan))
        w.write_input(1, 0.001, [1.0, 2.0], force=[nan, 3.0], position=[nan, 1.0, nan],
                      orientation=[nan] * 4)
    with open(path, "rb") as f:
        msgs = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages()]
    assert msgs[0]["pose"] is None and msgs[0]["force"] is None
    assert msgs[1]["force"] == [None, 3.0]  # partly finite parts keep their nulls
    assert msgs[1]["pose"] == {"position": [None, 1.0, None], "orientation": [None] * 4}
    rec = read_mcap(path)
    assert rec.force is not None and np.isnan(rec.force[0]).all()


# ------------------------------------------------------------------------ MCAP extras
def test_mcap_round_trip_keeps_each_extra_topics_file_order(tmp_path):
    src = tmp_path / "ex.mcap"
    with McapRecordingWriter(src, "r") as w:
        for i in range(5):
            w.write_input(i, i * 0.1, [1.0])
        w.write(ALARMS_TOPIC, 0.4, {"seq": 4, "t": 0.4, "severity": "info", "code": "late",
                                    "message": "m"})
        w.write(ALARMS_TOPIC, 0.4, {"seq": 1, "t": 0.1, "severity": "info", "code": "early",
                                    "message": "m"})
    rec = read_mcap(src, keep_topics=[ALARMS_TOPIC])
    assert [p["code"] for p in rec.extra[ALARMS_TOPIC]] == ["late", "early"]
    out = tmp_path / "ex2.mcap"
    write_mcap(out, rec)
    back = read_mcap(out, keep_topics=[ALARMS_TOPIC])
    assert [p["code"] for p in back.extra[ALARMS_TOPIC]] == ["late", "early"]
    assert back.equals(rec)


def test_write_mcap_extras_non_monotonic_t_on_two_topics(tmp_path):
    src = tmp_path / "a.mcap"
    with McapRecordingWriter(src, "r") as w:
        for i in range(3):
            w.write_input(i, float(i), [1.0])
    rec = read_mcap(src)
    rec.extra = {"/a": [{"t": 5.0, "k": 0}, {"t": 0.5, "k": 1}, {"t": 1.0, "k": 2}],
                 "/b": [{"t": 1.5, "k": 0}, {"t": 0.25, "k": 1}]}
    write_mcap(tmp_path / "b.mcap", rec)
    back = read_mcap(tmp_path / "b.mcap", keep_topics=["/a", "/b"])
    assert back.extra == rec.extra


# ------------------------------------------------------------------------ CSV
def test_csv_seq_outside_int64_names_the_line_in_both_readers(tmp_path):
    p = tmp_path / "seq.csv"
    p.write_text("t,seq,l0\n0,1,1\n0.1,99999999999999999999,1\n0.2,3,1\n")
    with pytest.raises(RecordingError, match=r"line 3, column seq: .*64-bit"):
        read_csv(p)
    with pytest.raises(RecordingError, match=r"line 3, column seq: .*64-bit"):
        list(iter_csv_inputs(p))
    p.write_text(f"t,seq,l0\n0,{2**63 - 1},1\n0.1,{-(2**63)},1\n")
    assert read_csv(p).seq.tolist() == [2**63 - 1, -(2**63)]


def test_csv_invalid_utf8_names_the_physical_line(tmp_path):
    lines = [b"# robot: r", b"t,seq,l0"] + [f"{i * 0.001!r},{i},1.0".encode() for i in range(3000)]
    lines[1500] += b"\xff"  # physical line 1501
    p = tmp_path / "bad.csv"
    p.write_bytes(b"\n".join(lines) + b"\n")
    for read in (read_csv, lambda q: list(iter_csv_inputs(q))):
        with pytest.raises(RecordingError) as ei:
            read(p)
        assert ei.value.location == "line 1501", str(ei.value)
        assert "UTF-8" in str(ei.value)
    lines[1500] = lines[1500][:-1]
    lines[0] = b"# robot: r\xe9"  # in the metadata
    p.write_bytes(b"\n".join(lines) + b"\n")
    with pytest.raises(RecordingError, match="line 1: not UTF-8"):
        read_csv(p)


@pytest.mark.parametrize("quoting", [csv.QUOTE_MINIMAL, csv.QUOTE_NONNUMERIC, csv.QUOTE_ALL])
def test_csv_written_by_the_csv_module_is_read(tmp_path, quoting):
    hdr = ["t", "seq", "x", "y", "z", "qx", "qy", "qz", "qw", "l0", "l1", "f0", "f1",
           "temperature"]
    rows = [[0.0, 0, None, None, None, None, None, None, None, 1.0, 2.0, None, None, None],
            [0.001, 1, 1, 2, 3, 0, 0, 0, 1, 1.25, 2.5, 5.0, 6.0, 21.5]]
    p = tmp_path / "q.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f, quoting=quoting)
        w.writerow(["# robot: ipanema3"])
        w.writerow(["# note: a, b"])  # quoted by every writer (has a comma)
        w.writerow(hdr)
        w.writerows(rows)
    rec = read_csv(p)
    assert rec.robot == "ipanema3" and rec.metadata == {"note": "a, b"}
    assert rec.seq.tolist() == [0, 1] and rec.t.tolist() == [0.0, 0.001]
    assert rec.motor_length.tolist() == [[1.0, 2.0], [1.25, 2.5]]
    assert np.isnan(rec.position[0]).all() and rec.position[1].tolist() == [1, 2, 3]
    assert np.isnan(rec.force[0]).all() and rec.force[1].tolist() == [5.0, 6.0]
    assert np.isnan(rec.temperature[0]) and rec.temperature[1] == 21.5
    ticks = list(iter_csv_inputs(p))
    assert ticks[0]["position"] is None and ticks[1]["force"].tolist() == [5.0, 6.0]


def test_csv_quoted_cells_keep_line_and_column_in_errors(tmp_path):
    p = tmp_path / "q.csv"
    p.write_text('"t","seq","l0"\n"0.0","0","1.0"\n"0.1","1","abc"\n')
    with pytest.raises(RecordingError, match=r"line 3, column l0: 'abc' is not a number"):
        read_csv(p)
    p.write_text('"t","seq","l0"\n"0.0","0","1.0"\n"0.1","1,"2"\n')
    with pytest.raises(RecordingError, match=r"line 3"):
        read_csv(p)


def test_csv_line_ends_and_bom_still_accepted(tmp_path):
    p = tmp_path / "cr.csv"
    p.write_bytes(b"\xef\xbb\xbf# robot: r\rt,seq,l0\r0,1,1\r\n0.1,2,1\n\n0.2,3,x\n")
    with pytest.raises(RecordingError, match=r"line 6, column l0"):
        read_csv(p)
    p.write_bytes(b"\xef\xbb\xbf# robot: r\rt,seq,l0\r0,1,1\r\n0.1,2,1\n")
    rec = read_csv(p)
    assert rec.robot == "r" and rec.seq.tolist() == [1, 2]
