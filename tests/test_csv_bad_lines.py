"""Issue 18 (CSV recordings): one damaged line costs one tick, not the rest of the replay,
and is rejected with its line number, counted and reported; ``1_000`` is not a number.
Real CSV files, the real replay source, the real daemon in a subprocess."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cablesvc.config import load_robot
from cablesvc.recording import RecordingError, iter_csv_inputs, read_recording, write_recording
from cablesvc.simulate import simulate_recording
from cablesvc.sources import open_source
from cablesvc.netutil import free_tcp_port


@pytest.fixture(scope="module")
def good_csv(tmp_path_factory) -> Path:
    rec = simulate_recording("planar4", "trajectory", None, duration=2.0, rate=500.0, seed=2)
    path = tmp_path_factory.mktemp("csv") / "good.csv"
    write_recording(path, rec)
    return path


def _damaged(good: Path, tmp_path: Path, lineno: int, how) -> tuple[Path, int]:
    """A copy of ``good`` whose physical line ``lineno`` (1-based) is replaced by
    ``how(line)``; returns (path, number of data lines in the file)."""
    lines = good.read_bytes().split(b"\n")
    assert lines[-1] == b""
    lines[lineno - 1] = how(lines[lineno - 1])
    path = tmp_path / "damaged.csv"
    path.write_bytes(b"\n".join(lines))
    header = next(i for i, ln in enumerate(lines) if not ln.startswith(b"#")) + 1
    return path, len(lines) - 1 - header


def _replay_all(path: Path):
    src = open_source(load_robot("planar4"), {"kind": "replay", "path": str(path), "speed": 0})
    ticks = []
    with src:
        while (tick := src.recv(timeout=1.0)) is not None:
            ticks.append(tick)
        assert src.finished
        return ticks, src.problems(), src.counters, src


def _truncate(line: bytes) -> bytes:
    return line[: len(line) // 2]


def _garble(line: bytes) -> bytes:
    return line.replace(b",", b";", 3)


def _not_utf8(line: bytes) -> bytes:
    return line[:5] + b"\xff\xfe" + line[7:]


@pytest.mark.parametrize("how", [_truncate, _garble, _not_utf8], ids=["truncated", "garbled", "not-utf8"])
def test_replay_rejects_one_damaged_line_and_plays_all_the_others(good_csv: Path, tmp_path: Path, how):
    """The replay stopped at the damaged line (about half the file never played)."""
    bad_line = 500
    path, n_data = _damaged(good_csv, tmp_path, bad_line, how)
    ticks, problems, counters, src = _replay_all(path)
    assert len(ticks) == n_data - 1
    assert counters.accepted == n_data - 1 and dict(counters.rejected) == {"bad_line": 1}
    assert src.bad_lines == 1
    bad = [p for p in problems if p.reason == "bad_line"]
    assert len(bad) == 1 and f"line {bad_line}" in bad[0].message and "damaged.csv" in bad[0].message
    # the ticks after the damaged line are the file's, in order
    want = read_recording(good_csv)
    skipped = bad_line - (len(good_csv.read_text().splitlines()) - n_data) - 1   # its row index
    keep = np.delete(np.arange(want.n_ticks), skipped)
    np.testing.assert_array_equal([t.seq for t in ticks], want.seq[keep])
    np.testing.assert_array_equal(np.array([t.motor_length for t in ticks]), want.motor_length[keep])


@pytest.mark.parametrize("cell,column", [("1_000", "seq"), ("0.5_5", "l2"), ("\u0661", "l0")])
def test_digit_separators_and_non_ascii_digits_are_not_numbers(good_csv: Path, tmp_path: Path, cell: str,
                                                              column: str):
    """Python's int() and float() read `1_000` as 1000 and '\u0661' (Arabic-Indic one) as 1:
    a recording must not (a corrupted or hand-edited cell became a plausible number)."""
    lines = good_csv.read_text().splitlines()
    h = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    names = lines[h].split(",")
    row = h + 10                            # 0-based index; physical line row + 1
    cells = lines[row].split(",")
    cells[names.index(column)] = cell
    lines[row] = ",".join(cells)
    path = tmp_path / "sep.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(RecordingError) as e:
        read_recording(path)
    assert e.value.location == f"line {row + 1}, column {column}"
    assert repr(cell) in e.value.reason
    ticks, problems, counters, _ = _replay_all(path)
    assert dict(counters.rejected) == {"bad_line": 1} and len(ticks) == len(lines) - h - 2
    assert f"line {row + 1}, column {column}" in [p for p in problems if p.reason == "bad_line"][0].message


def test_read_recording_names_the_first_bad_line_and_counts_them_all(good_csv: Path, tmp_path: Path):
    """Offline reading (identify, discover, convert) is strict: an error naming the first
    bad line and how many there are, never a model fitted to a file with holes."""
    lines = good_csv.read_bytes().split(b"\n")
    for k in (100, 200, 300):
        lines[k - 1] = lines[k - 1][:20]
    path = tmp_path / "three.csv"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(RecordingError) as e:
        read_recording(path)
    assert e.value.location == "line 100"
    assert "wrong number of fields" in e.value.reason and "2 more bad lines: 200, 300" in e.value.reason
    # the streaming reader without a handler stops at the first, as documented
    it = iter_csv_inputs(path)
    with pytest.raises(RecordingError, match="line 100"):
        for _ in it:
            pass


def test_daemon_exit_summary_counts_the_rejected_lines(good_csv: Path, tmp_path: Path):
    path, n_data = _damaged(good_csv, tmp_path, 300, _truncate)
    proc = subprocess.run([sys.executable, "-m", "cablesvc", "run", "--robot", "planar4", "--source", "replay",
                           "--replay", str(path), "--speed", "0", "--no-view", "--no-snapshot",
                           "--listen", f"tcp/127.0.0.1:{free_tcp_port()}"],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"after {n_data - 1} ticks" in proc.stderr
    assert "line 300" in proc.stderr and '"bad_line": 1' in proc.stderr
    assert "1 line(s) rejected" in proc.stderr
