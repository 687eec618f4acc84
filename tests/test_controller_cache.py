"""The simulated controller's precomputed motion is cached on disk (the embedded demo
computed 10 s of twin motion at every start): a cached motion equals the computed one,
and a damaged cache file or other arguments never give another motion."""

from __future__ import annotations

import numpy as np

from cablesvc.config import load_robot
from cablesvc.sources.simulated import cached_there_and_back_recording, there_and_back_recording

FIELDS = ("t", "seq", "motor_length", "position", "orientation", "force", "temperature")


def _same(a, b):
    assert a.robot == b.robot and a.metadata == b.metadata
    for k in FIELDS:
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), k


def test_cached_motion_equals_the_computed_one(tmp_path, monkeypatch):
    monkeypatch.setenv("CABLESVC_CACHE_DIR", str(tmp_path))
    robot = load_robot("planar4")
    kw = dict(duration=0.5, rate=200.0, seed=3)
    first, how1 = cached_there_and_back_recording(robot, "trajectory", **kw)
    second, how2 = cached_there_and_back_recording(robot, "trajectory", **kw)
    assert (how1, how2) == ("computed", "cached")
    _same(first, second)
    _same(second, there_and_back_recording(robot, "trajectory", **kw))
    # another seed is another motion, never the cached one
    other, how3 = cached_there_and_back_recording(robot, "trajectory", **{**kw, "seed": 4})
    assert how3 == "computed" and not np.array_equal(other.force, first.force)


def test_a_damaged_cache_file_is_computed_again(tmp_path, monkeypatch):
    monkeypatch.setenv("CABLESVC_CACHE_DIR", str(tmp_path))
    robot = load_robot("planar4")
    kw = dict(duration=0.5, rate=200.0, seed=5)
    good, _ = cached_there_and_back_recording(robot, "trajectory", **kw)
    (f,) = list((tmp_path / "controller").glob("*.npz"))
    f.write_bytes(f.read_bytes()[:1000])               # a cut file (disk full, killed writer)
    again, how = cached_there_and_back_recording(robot, "trajectory", **kw)
    assert how == "computed"
    _same(good, again)
    assert cached_there_and_back_recording(robot, "trajectory", **kw)[1] == "cached"


def test_an_unwritable_cache_still_gives_the_motion(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("CABLESVC_CACHE_DIR", str(blocker))
    robot = load_robot("planar4")
    rec, how = cached_there_and_back_recording(robot, "trajectory", duration=0.5, rate=200.0, seed=1)
    assert how.startswith("computed (cache not written") and rec.n_ticks > 2
