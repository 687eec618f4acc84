"""Fleets (cablesvc.batch, issue 17 item 3): discover / identify over many recordings on a
real Dask LocalCluster (2 worker processes on 127.0.0.1), with real MCAP recordings written
by the digital twin. The cluster's rows must be the serial run's rows, number for number; a
corrupt recording is reported with its reason while the others finish; paths, directories
and globs expand to the recordings."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from cablesvc.batch import FleetInputError, comparable, expand_recordings, run_fleet
from cablesvc.batch.jobs import recording_start
from cablesvc.cli.main import main
from cablesvc.config import load_robot
from cablesvc.config.params import default_params
from cablesvc.kinematics import inverse_kinematics
from cablesvc.recording import read_recording, write_recording
from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording

ROBOT = "ipanema3"
NIGHTS = ["2026-11-01T02:00:00+00:00", "2026-11-02T02:00:00+00:00", "2026-11-03T02:00:00+00:00"]
#: night 0 clean; the pulley effect appears on cable 1 on night 1 and stays
EFFECTS = ["", "pulley:0.02@1", "pulley:0.02@1"]


def _write(rec, path: Path, night: str) -> str:
    rec.metadata["start_time"] = night
    write_recording(path, rec)
    return str(path)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    (root / "a").mkdir()
    (root / "b").mkdir()
    traj = []
    for i, (spec, night) in enumerate(zip(EFFECTS, NIGHTS)):
        eff = [effect_from_spec(spec, 8)] if spec else []
        rec = simulate_recording(ROBOT, "trajectory", None, truth=TruthConfig(effects=eff, noise_std=0.1),
                                 duration=20.0, rate=100, seed=11 + i)
        traj.append(_write(rec, root / ("a" if i < 2 else "b") / f"{ROBOT}-{i}.mcap", night))
    # a corrupt log: the MCAP magic, then garbage
    corrupt = root / "b" / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 4)
    # identify: planar4 hold-sine, linear truth; night 1 the stiffness E*A of cable 2 is 20 % up
    rob = load_robot("planar4")
    geom = rob.geometry()
    home = inverse_kinematics(geom, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])).length[0]
    hold = []
    for i, night in enumerate(NIGHTS[:2]):
        ea = np.asarray(geom.ea, float).copy()
        if i == 1:
            ea[2] *= 1.2
        truth = TruthConfig(base=default_params(ea, home, "linear"), base_model="linear", noise_std=0.1)
        rec = simulate_recording("planar4", "hold-sine", None, truth=truth, rate=200.0, frequency=1.0, settle=0.5,
                                 rest=0.5, amplitudes=[5e-4, 1e-3], seed=3 + i)
        (root / "hold").mkdir(exist_ok=True)
        hold.append(_write(rec, root / "hold" / f"planar4-{i}.mcap", night))
    return {"root": root, "traj": traj, "corrupt": str(corrupt), "hold": hold}


@pytest.fixture(scope="module")
def cluster():
    from dask.distributed import LocalCluster
    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                     scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    yield c
    c.close()


def _cli(capsys, argv):
    code = main(argv)
    out = capsys.readouterr()
    return code, out


def test_paths_directories_and_globs_expand_to_the_recordings(fleet):
    root = fleet["root"]
    everything = sorted(fleet["traj"] + [fleet["corrupt"]] + fleet["hold"])
    assert expand_recordings([str(root)]) == everything
    assert expand_recordings([str(root / "a")]) == fleet["traj"][:2]
    assert expand_recordings([str(root / "*" / f"{ROBOT}-*.mcap")]) == fleet["traj"]
    assert expand_recordings([str(root / "**" / "*.mcap")]) == everything
    # overlapping specs: each recording once, sorted
    assert expand_recordings([fleet["traj"][2], str(root / "a"), fleet["traj"][0]]) == fleet["traj"]
    with pytest.raises(FleetInputError, match="matches no recording"):
        expand_recordings([str(root / "*.csv")])
    with pytest.raises(FleetInputError, match="no such file"):
        expand_recordings([str(root / "missing.mcap")])
    empty = root / "empty"
    empty.mkdir()
    with pytest.raises(FleetInputError, match="holds no recording"):
        expand_recordings([str(empty)])
    empty.rmdir()


def test_start_time_from_metadata_or_the_file_time(fleet, tmp_path):
    rec = read_recording(fleet["traj"][1])
    assert recording_start(fleet["traj"][1], rec) == (NIGHTS[1], "metadata")
    rec.metadata.pop("start_time")
    p = tmp_path / "no-start.mcap"
    write_recording(p, rec)
    os.utime(p, (1_800_000_000.0, 1_800_000_000.0))
    start, source = recording_start(str(p), read_recording(p))
    assert source == "file mtime - duration"
    assert datetime.fromisoformat(start).timestamp() == pytest.approx(1_800_000_000.0 - (rec.t[-1] - rec.t[0]), abs=1)


def test_discover_fleet_on_the_cluster_equals_serial_and_reports_the_corrupt_file(fleet, cluster, capsys):
    specs = [str(fleet["root"] / "a"), str(fleet["root"] / "b" / "*.mcap")]
    code_c, out_c = _cli(capsys, ["discover", *specs, "--scheduler", cluster.scheduler_address, "--json"])
    code_s, out_s = _cli(capsys, ["discover", *specs, "--serial", "--json"])
    assert code_c == code_s == 1              # one recording failed
    doc_c, doc_s = json.loads(out_c.out), json.loads(out_s.out)
    assert doc_c["engine"]["engine"] == "dask.distributed" and doc_c["engine"]["workers"] == 2
    assert doc_s["engine"]["engine"] == "serial"
    rows = doc_c["rows"]
    assert [r["recording"] for r in rows] == sorted(fleet["traj"] + [fleet["corrupt"]])
    assert comparable(rows) == comparable(doc_s["rows"])           # the same numbers, every field
    bad = next(r for r in rows if r["recording"] == fleet["corrupt"])
    assert bad["status"] == "failed" and "RecordingError" in bad["error"] and "corrupt.mcap" in bad["error"]
    assert fleet["corrupt"] in out_c.err                            # named on stderr too
    good = [r for r in rows if r["status"] == "ok"]
    assert len(good) == 3 and doc_c["ok"] == 3 and doc_c["failed"] == 1
    assert [r["start_time"] for r in good] == NIGHTS
    assert all(len(r["rmse_test_before"]) == 8 and r["discovery"]["cables"] == 8 for r in good)
    # the pulley effect appears on night 1 on cable 1: found there and on night 2, not on night 0
    has = [any(f["term"] == "pulley" and 1 in f["cables"] for f in r["findings"]) for r in good]
    assert has == [False, True, True]
    summ = doc_c["summary"]
    eff = [e for e in summ["robots"][ROBOT]["effects"] if e["term"] == "pulley" and e["cable"] == 1]
    assert eff and eff[0]["since"] == NIGHTS[1] and eff[0]["recordings"] == 2 and eff[0]["in_latest"]
    assert summ["failed"] == [{"recording": fleet["corrupt"], "robot": None, "error": bad["error"]}]
    assert any("pulley" in line and NIGHTS[1] in line for line in summ["lines"])
    # the terms found nowhere, with how small an effect the recordings could not show
    ns = {x["term"]: x for x in summ["robots"][ROBOT]["not_seen"]}
    assert "pulley" not in ns and {"creep", "sag"} <= set(ns)
    assert all(x["recordings"] == 3 and 0 < x["median_floor_rms_N"] <= x["median_limit_rms_N"] for x in ns.values())
    assert all(r["detection"] for r in good)
    assert any(line.startswith(f"{ROBOT} (") and "not found, and not told from the baseline's recalibration" in line
               for line in summ["lines"])


def test_identify_fleet_on_the_cluster_equals_serial_and_finds_the_drifting_cable(fleet, cluster, tmp_path):
    opts = {"model": "linear", "method": "lm"}
    res_c = run_fleet("identify", fleet["hold"], opts, scheduler=cluster.scheduler_address)
    res_s = run_fleet("identify", fleet["hold"], opts, serial=True)
    assert not res_c.failed and res_c.engine["workers"] == 2
    assert comparable(res_c.rows) == comparable(res_s.rows)
    ea = [[p["value"]["ea"] for p in r["parameters"]] for r in res_c.rows]
    assert ea[1][2] / ea[0][2] == pytest.approx(1.2, rel=0.02)
    drift = res_c.summary["robots"]["planar4"]["drift"]
    assert [d["cable"] for d in drift] == [2]
    assert drift[0]["since"] == NIGHTS[1] and drift[0]["parameters"]["ea"]["change"] == pytest.approx(0.2, abs=0.02)
    # the HTML and JSON report
    from cablesvc.batch.report import write_fleet_report
    files = write_fleet_report(res_c, tmp_path / "rep")
    page = Path(files["html"]).read_text()
    assert "cable 2 drifts since " + NIGHTS[1] in page and "planar4-1.mcap" in page
    assert json.loads(Path(files["json"]).read_text())["rows"][1]["parameters"][2]["value"]["ea"] == ea[1][2]


def test_default_local_cluster_from_the_command_line(fleet, tmp_path):
    """No --scheduler: cablesvc starts its own LocalCluster (2 workers); a directory with one
    good and one corrupt recording: the good one finishes, the corrupt one is reported. The
    workers, forked from the command's process whose BLAS already runs a thread per core,
    run one BLAS thread each (two each would oversubscribe the cores). The command runs as a
    user starts it, in its own process without the suite's one-thread variables
    (tests/conftest.py): in the test's process, already limited, the workers would run one
    thread whatever cablesvc does."""
    from cablesvc.threads import THREAD_VARS
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    proc = subprocess.run([sys.executable, "-m", "cablesvc", "discover", str(fleet["root"] / "b"),
                           "--report", str(tmp_path / "rep")], capture_output=True, text=True, env=env,
                          timeout=600)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "corrupt.mcap" in proc.stdout and "RecordingError" in proc.stdout
    doc = json.loads((tmp_path / "rep" / "fleet.json").read_text())
    assert doc["engine"]["scheduler"] == "LocalCluster" and doc["engine"]["workers"] == 2
    assert doc["engine"]["address"].startswith("tcp://127.0.0.1:")
    assert doc["engine"]["blas_threads_per_worker"] == 1
    assert [r["status"] for r in doc["rows"]] == ["failed", "ok"]
    html = (tmp_path / "rep" / "index.html").read_text()
    assert "Fleet summary" in html and "corrupt.mcap" in html and NIGHTS[2] in html


def test_fleet_refuses_one_recording_options_and_bad_inputs(fleet, capsys):
    code, out = _cli(capsys, ["discover", str(fleet["root"] / "a"), "--out", "x.toml", "--serial"])
    assert code == 1 and "--out is for one recording" in out.err
    code, out = _cli(capsys, ["identify", str(fleet["root"] / "nothing-*.mcap"), "--serial"])
    assert code == 1 and "matches no recording" in out.err
    code, out = _cli(capsys, ["discover", str(fleet["root"] / "a"), "--workers", "0"])
    assert code == 1 and "--workers" in out.err


def test_fleet_summary_not_seen_is_the_median_over_recordings():
    # an infinite limit (JSON null: the recalibration mimics the whole shape) counts as
    # infinite; a term found on the robot is not listed
    from cablesvc.batch.summary import fleet_summary

    def row(i, det, findings=()):
        return {"status": "ok", "robot": "r", "recording": f"{i}.mcap", "start_time": NIGHTS[i], "verdict": "v",
                "findings": list(findings), "recalibrated": [], "unexplained": [], "detection": det}
    det = [[{"term": "sag", "min_floor_rms_N": 1.0, "min_limit_rms_N": 2.0},
            {"term": "creep", "min_floor_rms_N": 0.1, "min_limit_rms_N": 0.3}],
           [{"term": "sag", "min_floor_rms_N": None, "min_limit_rms_N": None}],
           [{"term": "sag", "min_floor_rms_N": 3.0, "min_limit_rms_N": 5.0}]]
    rows = [row(0, det[0]), row(1, det[1]),
            row(2, det[2], [{"term": "creep", "label": "creep and settling drift", "cables": [4]}])]
    summ = fleet_summary("discover", rows)
    ns = summ["robots"]["r"]["not_seen"]
    assert [x["term"] for x in ns] == ["sag"]                    # creep was found on night 2
    assert ns[0]["recordings"] == 3 and ns[0]["median_floor_rms_N"] == 3.0 and ns[0]["median_limit_rms_N"] == 5.0
    assert any("sag 3 / 5 N RMS" in line for line in summ["lines"])
