"""Issue 20 (recording side): every accepted tick is in the --record file when the daemon
exits, no file is destroyed by a --record, the recording's format follows its suffix, and a
replay that cannot play or a record target that cannot be written is one line and a
non-zero exit. Real files, real Zenoh (loopback, no scouting), real subprocesses."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from cablesvc.config.params import nominal_params
from cablesvc.config import load_robot
from cablesvc.recording import read_recording, write_recording
from cablesvc.service.daemon import Daemon, DaemonOptions
from cablesvc.service.recorder import Recorder
from cablesvc.simulate import simulate_recording
from cablesvc.sources.base import TickInput
from cablesvc.netutil import free_tcp_port


def _run(args: list[str], cwd: Path, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cablesvc", "run", *args, "--no-view", "--no-snapshot",
                           "--listen", f"tcp/127.0.0.1:{free_tcp_port()}"],
                          capture_output=True, text=True, timeout=timeout, cwd=cwd)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line_error(proc: subprocess.CompletedProcess, *words: str) -> str:
    """The process failed with one `cablesvc run: ...` line naming ``words``, no traceback."""
    assert proc.returncode != 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("cablesvc run:")]
    assert len(lines) == 1, proc.stderr[-3000:]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def replay_file(tmp_path_factory) -> tuple[Path, int]:
    """A 3 s, 1 kHz recording of the default robot (3000 ticks: 47 times the small record
    queue below, and each replay of it costs the suite ~1.6 s instead of ~5.5 s for 10 s)."""
    rec = simulate_recording("ipanema3", "trajectory", None, duration=3.0, rate=1000.0, seed=7)
    path = tmp_path_factory.mktemp("replay") / "traj.mcap"
    write_recording(path, rec)
    return path, rec.n_ticks


def _ticks(n: int, m: int = 8):
    rng = np.random.default_rng(0)
    for k in range(n):
        yield TickInput(seq=k, t=k * 1e-3, motor_length=1.0 + 1e-3 * rng.standard_normal(m),
                        position=np.array([0.1, 0.2, 0.3]), orientation=np.array([0.0, 0.0, 0.0, 1.0]),
                        force=100.0 + rng.standard_normal(m), temperature=21.5, stamp_ns=0)


# ---- 1. nothing lost at shutdown ---------------------------------------------------------

def _slow_disk(tmp_path: Path) -> tuple[Path, int]:
    """A FIFO as the recording file: a real slow disk. Whatever the writer writes waits in
    the 64 KiB pipe until the test reads it; (path, reading end, non-blocking until used)."""
    fifo = tmp_path / "slow.mcap"
    os.mkfifo(fifo)
    return fifo, os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)


def _drain(rfd: int, after_s: float, into: bytearray) -> threading.Thread:
    def run():
        time.sleep(after_s)
        os.set_blocking(rfd, True)
        while chunk := os.read(rfd, 1 << 16):
            into.extend(chunk)
        os.close(rfd)
    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_recorder_close_waits_for_a_slow_disk(tmp_path: Path):
    """The disk takes nothing for 3 s after close() is called, then everything: close must
    wait for the queue while the writer makes progress (it gave up after 1.5 s and closed
    the writer under its thread: "writer is closed", ticks lost)."""
    n = 20_000
    fifo, rfd = _slow_disk(tmp_path)
    rec = Recorder(fifo, "ipanema3", {}, 100_000)
    payload = {"robot": "ipanema3", "force": [1.0] * 8}
    for tick in _ticks(n):
        rec.put((tick, payload, ()))
    got = bytearray()
    reader = _drain(rfd, 3.0, got)
    rec.close()
    reader.join(30)
    (tmp_path / "copy.mcap").write_bytes(got)
    back = read_recording(tmp_path / "copy.mcap", keep_topics=["/cablesvc/forces"])
    assert back.n_ticks == n and len(back.extra["/cablesvc/forces"]) == n
    np.testing.assert_array_equal(back.seq, np.arange(n))
    assert rec.error is None and rec.written == n and rec.missing == 0


def test_recorder_close_gives_up_on_a_stalled_disk_and_counts_what_is_missing(tmp_path: Path):
    """A disk that takes nothing at all: close() returns after the stall time (not never)
    and says how many ticks are not in the file; the daemon turns that into its exit line."""
    n = 20_000
    fifo, rfd = _slow_disk(tmp_path)
    rec = Recorder(fifo, "ipanema3", {}, 100_000, stall_s=1.0)
    for tick in _ticks(n):
        rec.put((tick, {"robot": "ipanema3"}, ()))
    t0 = time.monotonic()
    missing = rec.close()
    assert time.monotonic() - t0 < 10
    assert missing == rec.missing == n - rec.written and missing > n // 2
    assert "stalled" in rec.error
    _drain(rfd, 0.0, bytearray()).join(30)           # let the writer thread finish


def test_a_hung_disk_does_not_hang_a_replay_loop(tmp_path: Path):
    """A replay's loop waits for room in the recorder's queue, but not for ever: a writer
    that takes nothing for the stall time turns waiting into dropping (counted), so the loop,
    and with it the shutdown that needs the loop's lock, goes on."""
    fifo, rfd = _slow_disk(tmp_path)
    rec = Recorder(fifo, "ipanema3", {}, 8, block=True, stall_s=1.0)
    t0 = time.monotonic()
    for tick in _ticks(10_000):
        rec.put((tick, {"robot": "ipanema3"}, ()))
    assert time.monotonic() - t0 < 15
    assert rec.dropped > 0 and rec.handed == 10_000
    assert rec.close() == 10_000 - rec.written > 0
    # unblock the abandoned writer thread; its file stays open (a stalled writer is left
    # behind), so the pipe never reaches EOF: do not wait for the drain to end
    _drain(rfd, 0.0, bytearray()).join(1.0)


def test_replay_into_a_small_record_queue_loses_nothing(tmp_path: Path, replay_file):
    """A replay at --speed 0 produces ticks faster than the disk takes them: the loop waits
    for the recorder (a replay has no deadline) instead of dropping from the full queue."""
    path, n = replay_file
    robot = load_robot("ipanema3")
    d = Daemon(DaemonOptions(robot=robot, params=nominal_params(robot.geometry()),
                             source={"kind": "replay", "path": str(path), "speed": 0},
                             record=tmp_path / "out.mcap", record_queue=64,
                             listen=(f"tcp/127.0.0.1:{free_tcp_port()}",)))
    try:
        d.run(threading.Event())
    finally:
        d.close()
    st = d.status()
    assert st["input"]["accepted"] == n
    assert read_recording(tmp_path / "out.mcap").n_ticks == n
    assert st["recording"]["dropped"] == 0 and st["recording"]["written"] == n and st["recording"]["missing"] == 0
    assert d.exit_problems() == []


def test_cli_replay_and_record_round_trip_at_speed_0(tmp_path: Path, replay_file):
    """The README's line: every accepted tick, input and forces, is in the recording."""
    path, n = replay_file
    proc = _run(["--source", "replay", "--replay", str(path), "--speed", "0", "--record", "out.mcap"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    back = read_recording(tmp_path / "out.mcap", keep_topics=["/cablesvc/forces"])
    src = read_recording(path)
    assert back.n_ticks == n and len(back.extra["/cablesvc/forces"]) == n
    np.testing.assert_array_equal(back.seq, src.seq)
    np.testing.assert_array_equal(back.motor_length, src.motor_length)
    assert f"{n} ticks written, 0 missing" in proc.stderr


def test_ticks_the_disk_refused_make_a_non_zero_exit_with_the_count(tmp_path: Path, replay_file):
    """/dev/full takes the CSV header into the buffer and then fails every write: the daemon
    must not report success; it says how many accepted ticks are not in the file."""
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    path, n = replay_file
    (tmp_path / "full.csv").symlink_to("/dev/full")
    proc = _run(["--source", "replay", "--replay", str(path), "--speed", "0", "--record", "full.csv",
                 "--overwrite"], tmp_path)
    line = _one_line_error(proc, "full.csv", "missing")
    missing = int(line.split(": ", 2)[2].split(" of ")[0])
    assert n - 100 <= missing <= n           # all but what the first buffer took


# ---- 2. no file destroyed; the format follows the suffix ---------------------------------

@pytest.mark.parametrize("spelling", ["relative", "symlink"])
def test_record_onto_the_replayed_file_is_refused(tmp_path: Path, replay_file, spelling: str):
    path, _ = replay_file
    keep = tmp_path / "keep.mcap"
    keep.write_bytes(path.read_bytes())
    before = _sha(keep)
    (tmp_path / "sub").mkdir()
    if spelling == "same":
        target = str(keep)
    elif spelling == "relative":
        target = "sub/../keep.mcap"
    else:
        (tmp_path / "link.mcap").symlink_to(keep)
        target = "link.mcap"
    # --overwrite too: even then the input is never a record target
    proc = _run(["--source", "replay", "--replay", str(keep), "--speed", "0", "--record", target, "--overwrite"],
                tmp_path)
    _one_line_error(proc, target, "--replay input")
    assert _sha(keep) == before


def test_an_existing_record_file_is_kept_unless_overwrite(tmp_path: Path, replay_file):
    path, n = replay_file
    old = tmp_path / "old.mcap"
    old.write_bytes(b"precious data")
    proc = _run(["--source", "replay", "--replay", str(path), "--speed", "0", "--record", "old.mcap"], tmp_path)
    _one_line_error(proc, "old.mcap", "exists", "--overwrite")
    assert old.read_bytes() == b"precious data"
    proc = _run(["--source", "replay", "--replay", str(path), "--speed", "0", "--record", "old.mcap",
                 "--overwrite"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert read_recording(old).n_ticks == n


def test_unreadable_replay_leaves_the_existing_recording_untouched(tmp_path: Path, replay_file):
    """Nothing is opened for writing before the input is read (the record target was
    replaced by an empty recording, and the run exited 0)."""
    path, _ = replay_file
    existing = tmp_path / "existing.mcap"
    existing.write_bytes(path.read_bytes())
    before = _sha(existing)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"this is not an MCAP file at all, just text\n" * 10)
    proc = _run(["--source", "replay", "--replay", str(bad), "--record", "existing.mcap", "--overwrite"], tmp_path)
    _one_line_error(proc, "bad.mcap")
    assert _sha(existing) == before


def test_record_csv_writes_a_csv_recording(tmp_path: Path, replay_file):
    """`--record out.csv` wrote MCAP bytes into the .csv file."""
    path, n = replay_file
    proc = _run(["--source", "replay", "--replay", str(path), "--speed", "0", "--record", "out.csv"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "out.csv").read_bytes()[:2] == b"# "
    back, src = read_recording(tmp_path / "out.csv"), read_recording(path)
    assert back.robot == "ipanema3" and back.n_ticks == n
    np.testing.assert_array_equal(back.t, src.t)
    np.testing.assert_array_equal(back.motor_length, src.motor_length)
    np.testing.assert_array_equal(back.force, src.force)
    np.testing.assert_array_equal(back.position, src.position)


def test_record_with_another_suffix_is_refused(tmp_path: Path, replay_file):
    path, _ = replay_file
    proc = _run(["--source", "replay", "--replay", str(path), "--record", "out.txt"], tmp_path)
    _one_line_error(proc, "out.txt", ".mcap", ".csv")
    assert not (tmp_path / "out.txt").exists()


def test_csv_writer_round_trip_and_no_overwrite(tmp_path: Path):
    """The streaming CSV writer: exact round trip (ticks without force / pose / temperature
    stay without), and overwrite=False keeps an existing file."""
    from cablesvc.recording.csv_io import CsvRecordingWriter

    out = tmp_path / "w.csv"
    ticks = list(_ticks(50, m=4))
    with CsvRecordingWriter(out, "planar4", {"source": "test"}) as w:
        for k, tk in enumerate(ticks):
            w.write_input(tk.seq, tk.t, tk.motor_length, None if k == 3 else tk.force,
                          None if k == 4 else tk.position, None if k == 4 else tk.orientation,
                          None if k == 5 else tk.temperature)
    back = read_recording(out)
    assert back.robot == "planar4" and back.metadata == {"source": "test"} and back.n_ticks == 50
    np.testing.assert_array_equal(back.motor_length, np.array([tk.motor_length for tk in ticks]))
    assert np.isnan(back.force[3]).all() and np.isnan(back.position[4]).all() and np.isnan(back.temperature[5])
    np.testing.assert_array_equal(back.force[6], ticks[6].force)
    with pytest.raises(FileExistsError):
        CsvRecordingWriter(out, "planar4", overwrite=False)
    assert read_recording(out).n_ticks == 50


# ---- 3. one line and a non-zero exit -----------------------------------------------------

def test_empty_replay_exits_non_zero(tmp_path: Path):
    (tmp_path / "r.mcap").write_bytes(b"")
    proc = _run(["--source", "replay", "--replay", "r.mcap"], tmp_path, timeout=60)
    _one_line_error(proc, "r.mcap")


@pytest.mark.parametrize("content", [b"", b"not an mcap\n", b"\x89MCAP0\r\n", b"t,seq\n1,2\n"])
def test_unreadable_replay_is_refused_at_start(tmp_path: Path, content: bytes):
    """(In process, the cheap variants): the daemon does not start on a replay it cannot
    read; the reason is one line naming the file."""
    from cablesvc.service.daemon import StartError

    path = tmp_path / ("r.csv" if content.startswith(b"t,") else "r.mcap")
    path.write_bytes(content)
    robot = load_robot("ipanema3")
    with pytest.raises(StartError) as e:
        Daemon(DaemonOptions(robot=robot, params=nominal_params(robot.geometry()),
                             source={"kind": "replay", "path": str(path), "speed": 0},
                             listen=(f"tcp/127.0.0.1:{free_tcp_port()}",)))
    assert str(path) in str(e.value) and "\n" not in str(e.value)


def test_replay_that_plays_no_tick_exits_non_zero(tmp_path: Path):
    """A valid recording with a header and no tick plays nothing: that is not a success."""
    (tmp_path / "empty.csv").write_text("# robot: ipanema3\n# format: 1\n"
                                        "t,seq,x,y,z,qx,qy,qz,qw,l0,l1,l2,l3,l4,l5,l6,l7\n")
    proc = _run(["--source", "replay", "--replay", "empty.csv"], tmp_path, timeout=60)
    _one_line_error(proc, "empty.csv", "no tick")


def test_record_into_a_missing_directory_is_one_line(tmp_path: Path, replay_file):
    path, _ = replay_file
    proc = _run(["--source", "replay", "--replay", str(path), "--record", "/nonexistent/dir/out.mcap"], tmp_path,
                timeout=60)
    _one_line_error(proc, "/nonexistent/dir/out.mcap", "does not exist")


def test_fleet_refuses_a_record_file_that_is_a_replay_input(tmp_path: Path, replay_file):
    """In a fleet, robot B's record file must not be robot A's replay input (and a robot's
    own input is refused by its daemon, before anything is written)."""
    import json as _json
    import tomllib

    from cablesvc.config.daemon import FleetConfigError, RunOverrides, fleet_config
    from cablesvc.service.plan import plan_fleet

    path, _ = replay_file
    a = tmp_path / "a.mcap"
    a.write_bytes(path.read_bytes())
    p4 = tmp_path / "p4.mcap"
    write_recording(p4, simulate_recording("planar4", "hold-sine", None, duration=0.2, rate=100.0, seed=1))
    before = _sha(a)
    text = (f'[[robots]]\nrobot = "ipanema3"\n[robots.source]\nkind = "replay"\npath = {_json.dumps(str(a))}\n'
            f'[[robots]]\nrobot = "planar4"\nrecord = {_json.dumps(str(tmp_path / "sub" / ".." / "a.mcap"))}\n'
            f'[robots.source]\nkind = "replay"\npath = {_json.dumps(str(p4))}\n')
    (tmp_path / "sub").mkdir()
    with pytest.raises(FleetConfigError, match=r"robots\[1\]\.record: .* is robots\[0\]'s replay input"):
        plan_fleet(fleet_config(tomllib.loads(text), "fleet.toml"), "fleet.toml", RunOverrides())
    from cablesvc.service.daemon import StartError
    robot = load_robot("ipanema3")
    with pytest.raises(StartError, match="--replay input"):
        Daemon(DaemonOptions(robot=robot, params=nominal_params(robot.geometry()),
                             source={"kind": "replay", "path": str(a), "speed": 0}, record=a, record_overwrite=True,
                             listen=(f"tcp/127.0.0.1:{free_tcp_port()}",)))
    assert _sha(a) == before
