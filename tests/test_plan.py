"""The daemon's planner (cablesvc.service.plan.plan_daemon): a single-robot config and the
command line's overrides become DaemonOptions. The fleet planner is tested in
tests/test_fleet.py; both through ``cablesvc run`` in tests/test_cli.py and
tests/test_resource_limits.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from cablesvc.config import load_robot
from cablesvc.config.daemon import RobotOverrides, RunOverrides, daemon_config
from cablesvc.config.params import nominal_params
from cablesvc.errors import ConfigError
from cablesvc.limits import MAX_LIVE_RATE_HZ
from cablesvc.service.plan import SimRateError, plan_daemon


def _plan(cfg: dict, source: dict, run: RunOverrides | None = None, one: RobotOverrides | None = None):
    return plan_daemon(daemon_config(cfg, "d.toml"), source, run or RunOverrides(), one)


def test_state_file_and_interval_follow_the_source_and_the_overrides(tmp_path, monkeypatch):
    monkeypatch.setenv("CABLESVC_STATE_DIR", str(tmp_path / "state"))
    rec = tmp_path / "r.mcap"
    replay = {"kind": "replay", "path": str(rec), "speed": 0}
    shared, plan = _plan({"listen": ["tcp/127.0.0.1:7999"], "record": "out.mcap"}, replay)
    o = plan.options
    assert shared["listen"] == ("tcp/127.0.0.1:7999",) and shared["encoding"] == "json"
    assert o.robot.name == "ipanema3" and o.params.model == "amplitude" and o.params_file is None
    assert o.snapshot is None and o.snapshot_interval_s == 5.0         # a replay: no default state file
    assert o.record == Path("out.mcap") and o.source_id is None and plan.controller is None
    assert o.record_encoding == "protobuf" and not o.record_overwrite and o.wait_subscriber_s == 0.0
    # a live source: the robot's default state file; the config's interval, the flag's over it
    can = {"kind": "can", "interface": "virtual", "channel": "x"}
    _, plan = _plan({"snapshot_interval": 2.0}, can, one=RobotOverrides(robot="planar4"))
    assert plan.options.snapshot == tmp_path / "state" / "planar4.state.npz"
    assert plan.options.snapshot_interval_s == 2.0
    run = RunOverrides(snapshot_interval=0.5, no_snapshot=True, listen=("tcp/127.0.0.1:7001",), encoding="compact",
                       overwrite=True, record_encoding="json", wait_subscriber=1.5)
    shared, plan = _plan({"snapshot_interval": 2.0, "listen": ["tcp/127.0.0.1:7999"]}, can, run)
    assert plan.options.snapshot is None and plan.options.snapshot_interval_s == 0.5
    assert shared["listen"] == ("tcp/127.0.0.1:7001",) and plan.options.encoding == "compact"
    assert plan.options.record_overwrite and plan.options.record_encoding == "json"
    assert plan.options.wait_subscriber_s == 1.5
    _, plan = _plan({"snapshot": "a.npz"}, can, one=RobotOverrides(snapshot="b.npz"))
    assert plan.options.snapshot == Path("b.npz")


def test_parameters_of_another_robot_are_refused(tmp_path):
    p = nominal_params(load_robot("planar4").geometry())
    p.robot = "planar4"
    path = tmp_path / "p4.toml"
    p.save(path)
    with pytest.raises(ConfigError, match=r"p4\.toml was identified for robot 'planar4', not 'ipanema3'"):
        _plan({"params": str(path)}, {"kind": "replay", "path": "r.mcap"})
    _, plan = _plan({"params": str(path)}, {"kind": "replay", "path": "r.mcap"}, one=RobotOverrides(robot="planar4"))
    assert plan.options.params_file == str(path)


def test_a_sim_rate_the_daemon_cannot_follow_names_where_it_came_from():
    too_fast = float(MAX_LIVE_RATE_HZ + 1)
    with pytest.raises(SimRateError, match=r"^--rate .* cannot follow") as e:
        _plan({}, {"kind": "sim"}, one=RobotOverrides(rate=too_fast))
    assert e.value.exit_status == 2
    with pytest.raises(SimRateError, match=r"^source\.rate .* cannot follow"):
        _plan({"source": {"kind": "sim", "rate": too_fast}}, {"kind": "sim", "rate": too_fast})
