"""Robot definition files: the shipped robots, name lookup, and validation messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cablesvc.config import Robot, RobotFileError, RobotGeometry, load_robot, robot_search_path
from cablesvc.config.robot import robot_files

REPO_ROBOTS = Path(__file__).resolve().parents[1] / "robots"
SHIPPED = sorted(p.stem for p in robot_files(REPO_ROBOTS))

IPANEMA_FRAME = [
    (-8.544, 5.463, 3.202), (8.184, 5.692, 3.236), (8.224, -5.492, 3.25), (-8.491, -5.322, 3.221),
    (-8.192, 5.648, -0.589), (7.208, 6.463, -0.548), (7.869, -5.557, -0.527), (-8.27, -5.545, -0.582),
]
IPANEMA_PLATFORM = [
    (-0.085, 0.748, 0.261), (0.095, 0.749, 0.26), (0.095, -0.745, 0.26), (-0.085, -0.746, 0.261),
    (-0.07, 0.648, -0.26), (0.06, 0.648, -0.262), (0.06, -0.651, -0.262), (-0.07, -0.651, -0.26),
]

# A small valid 4-cable robot; bad files are made from it by textual replacement.
BASE = """\
format = 1
name = "base4"
description = "test robot"

[frame]
anchors = [[2.0, 2.0, 3.0], [-2.0, 2.0, 3.0], [-2.0, -2.0, 0.0], [2.0, -2.0, 0.0]]

[platform]
anchors = [[0.1, 0.1, 0.1], [-0.1, 0.1, 0.1], [-0.1, -0.1, -0.1], [0.1, -0.1, -0.1]]
mass = 5.0
center_of_gravity = [0.0, 0.0, 0.01]

[wiring]
platform_anchor = [0, 1, 2, 3]

[cable]
diameter = 0.002
material = "Dyneema"
ea = 1.0e4
force_min = 5.0
force_max = 500.0

[pulley]
radius = 0.05
axis = "vertical"

[[cables]]
name = "c0"

[[cables]]
name = "c1"

[[cables]]
name = "c2"
pulley = { axis = [0.0, 0.0, -1.0] }
"""


def write(tmp_path: Path, text: str, name: str = "robot.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def problems_of(path: Path) -> list[str]:
    with pytest.raises(RobotFileError) as exc:
        load_robot(path)
    err = exc.value
    assert err.problems, "RobotFileError without problems"
    # str() lists every problem on its own line
    assert str(err).splitlines()[1:] == err.problems
    return err.problems


# ---------------------------------------------------------------------------------------
# shipped robots
# ---------------------------------------------------------------------------------------


def test_three_robots_are_shipped():
    assert {"ipanema3", "cogiro", "planar4"} <= set(SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_robot_loads_with_consistent_geometry(name):
    robot = load_robot(name)
    assert isinstance(robot, Robot)
    assert robot.source.resolve().parent == REPO_ROBOTS
    g = robot.geometry()
    assert isinstance(g, RobotGeometry)
    m = g.n_cables
    assert m == robot.n_cables >= 3
    for arr, shape in [
        (g.frame_anchors, (m, 3)), (g.platform_anchors, (m, 3)), (g.pulley_center, (m, 3)),
        (g.pulley_axis, (m, 3)), (g.pulley_radius, (m,)), (g.ea, (m,)), (g.force_min, (m,)),
        (g.force_max, (m,)), (g.diameter, (m,)), (g.center_of_gravity, (3,)), (g.gravity, (3,)),
    ]:
        assert arr.shape == shape and arr.dtype == np.float64
        assert np.all(np.isfinite(arr))
        assert not arr.flags.writeable
    assert g.has_pulley.dtype == bool and g.has_pulley.shape == (m,)
    np.testing.assert_array_equal(g.gravity, [0.0, 0.0, -9.81])
    assert len(g.cable_names) == m == len(set(g.cable_names))
    assert np.all(g.force_min < g.force_max) and np.all(g.force_min >= 0)
    assert np.all(g.ea > 0) and np.all(g.diameter > 0) and g.mass > 0
    # pulleys: unit axes and positive radius exactly where present, 0 elsewhere
    norms = np.linalg.norm(g.pulley_axis, axis=1)
    np.testing.assert_allclose(norms[g.has_pulley], 1.0, atol=1e-12)
    assert np.all(g.pulley_radius[g.has_pulley] > 0)
    assert np.all(g.pulley_radius[~g.has_pulley] == 0)
    assert g.planar == robot.planar
    # the description says where the numbers come from
    assert len(robot.description) > 40


def test_ipanema3_numbers_and_crossed_wiring():
    robot = load_robot("ipanema3")
    g = robot.geometry()
    assert g.name == "ipanema3" and g.n_cables == 8 and not g.planar
    np.testing.assert_array_equal(g.frame_anchors, IPANEMA_FRAME)
    # cable i: frame anchor i -> platform anchor (i + 4) mod 8; cable 0 -> platform anchor 4
    np.testing.assert_array_equal(g.platform_anchors[0], IPANEMA_PLATFORM[4])
    for i in range(8):
        np.testing.assert_array_equal(g.platform_anchors[i], IPANEMA_PLATFORM[(i + 4) % 8])
    assert robot.platform_anchor_of_cable == [4, 5, 6, 7, 0, 1, 2, 3]
    assert g.mass == 30.0
    np.testing.assert_array_equal(g.center_of_gravity, [0, 0, 0])
    assert g.has_pulley.all()
    np.testing.assert_array_equal(g.pulley_radius, 0.10)
    np.testing.assert_array_equal(g.pulley_center, g.frame_anchors)
    # "vertical": +z for the upper four anchors, -z for the lower four
    np.testing.assert_array_equal(g.pulley_axis[:4], [[0, 0, 1]] * 4)
    np.testing.assert_array_equal(g.pulley_axis[4:], [[0, 0, -1]] * 4)
    np.testing.assert_array_equal(g.diameter, 0.006)
    np.testing.assert_array_equal(g.ea, 1.5e5)
    np.testing.assert_array_equal(g.force_min, 10.0)
    np.testing.assert_array_equal(g.force_max, 3000.0)
    assert "cdpyr" in robot.description and "assum" in robot.description
    assert "cdpyr" in robot.source.read_text().split("format")[0]  # the comment says so too


def test_cogiro_numbers():
    g = load_robot("cogiro").geometry()
    assert g.n_cables == 8 and not g.has_pulley.any()
    assert g.mass == pytest.approx(91.058)
    np.testing.assert_array_equal(g.center_of_gravity, [-0.034, -0.013, 0.264])
    np.testing.assert_array_equal(g.frame_anchors[0], [-7.1775, -5.4361, 5.3911])
    np.testing.assert_array_equal(g.frame_anchors[7], [7.1608, -5.5342, 5.3973])
    np.testing.assert_array_equal(g.platform_anchors[1], [-0.5097, 0.3508, 0.9976])
    np.testing.assert_array_equal(g.platform_anchors[6], [0.5021, 0.2750, -0.0007])
    np.testing.assert_array_equal(g.force_min, 100.0)
    np.testing.assert_array_equal(g.force_max, 5000.0)
    np.testing.assert_array_equal(g.diameter, 0.004)
    np.testing.assert_array_equal(g.ea, 2.5e5)
    np.testing.assert_array_equal(g.pulley_center, g.frame_anchors)
    assert "CASPR" in load_robot("cogiro").description


def test_planar4_is_planar_with_in_plane_pulleys():
    robot = load_robot("planar4")
    g = robot.geometry()
    assert robot.planar and g.planar and g.n_cables == 4
    assert robot.platform_anchor_of_cable == [1, 0, 3, 2]  # crossed pairs
    np.testing.assert_array_equal(np.abs(g.frame_anchors[:, :2]), 1.0)
    assert np.all(g.frame_anchors[:, 2] == 0) and np.all(g.platform_anchors[:, 2] == 0)
    np.testing.assert_array_equal(np.abs(g.platform_anchors[:, :2]), 0.05)
    assert g.has_pulley.all() and np.all(g.pulley_axis[:, 2] == 0)
    np.testing.assert_array_equal(g.pulley_radius, 0.02)
    # axis along the vertical frame edge, pointing outward toward the corner
    np.testing.assert_array_equal(g.pulley_axis[:, 1], np.sign(g.frame_anchors[:, 1]))
    assert g.mass == 2.0
    np.testing.assert_array_equal(g.gravity, [0, 0, -9.81])
    np.testing.assert_array_equal(g.ea, 2.0e4)
    np.testing.assert_array_equal(g.force_min, 1.0)
    np.testing.assert_array_equal(g.force_max, 200.0)
    np.testing.assert_array_equal(g.diameter, 0.001)


# ---------------------------------------------------------------------------------------
# name lookup
# ---------------------------------------------------------------------------------------


def test_load_by_path_equals_load_by_name():
    a = load_robot(REPO_ROBOTS / "ipanema3.toml").geometry()
    b = load_robot(str(REPO_ROBOTS / "ipanema3.toml")).geometry()
    c = load_robot("ipanema3").geometry()
    for g in (b, c):
        np.testing.assert_array_equal(a.frame_anchors, g.frame_anchors)
        np.testing.assert_array_equal(a.platform_anchors, g.platform_anchors)


def test_env_search_path_comes_first(tmp_path, monkeypatch):
    d1, d2 = tmp_path / "one", tmp_path / "two"
    d1.mkdir()
    d2.mkdir()
    write(d2, BASE.replace('name = "base4"', 'name = "from_two"'), "ipanema3.toml")
    monkeypatch.setenv("CABLESVC_ROBOTS", f"{d1}{__import__('os').pathsep}{d2}")
    path = robot_search_path()
    assert path[0] == d1 and path[1] == d2
    assert path[-1].resolve() == REPO_ROBOTS
    robot = load_robot("ipanema3")
    assert robot.name == "from_two" and robot.source == d2 / "ipanema3.toml"


def test_unknown_name_lists_available_robots():
    with pytest.raises(RobotFileError) as exc:
        load_robot("no_such_robot_xyz")
    msg = str(exc.value)
    assert "no_such_robot_xyz" in msg
    for name in ("ipanema3", "cogiro", "planar4"):
        assert name in msg


def test_missing_file_is_reported(tmp_path):
    p = tmp_path / "absent.toml"
    probs = problems_of(p)
    assert str(p) in probs[0] and "not found" in probs[0]


# ---------------------------------------------------------------------------------------
# resolution of defaults and overrides
# ---------------------------------------------------------------------------------------


def test_base_file_is_valid_and_resolves_overrides(tmp_path):
    text = BASE + """
[[cables]]
name = "c3"
ea = 2.0e4
material = "steel"
force_max = 900.0
pulley = false
"""
    g = load_robot(write(tmp_path, text)).geometry()
    assert g.cable_names == ("c0", "c1", "c2", "c3")
    np.testing.assert_array_equal(g.has_pulley, [True, True, True, False])
    np.testing.assert_array_equal(g.pulley_radius, [0.05, 0.05, 0.05, 0.0])
    # "vertical": z = 3 >= mean 1.5 -> +z ; cable 2 overrides to -z explicitly
    np.testing.assert_array_equal(g.pulley_axis, [[0, 0, 1], [0, 0, 1], [0, 0, -1], [0, 0, 0]])
    np.testing.assert_array_equal(g.ea, [1e4, 1e4, 1e4, 2e4])
    np.testing.assert_array_equal(g.force_max, [500, 500, 500, 900])
    np.testing.assert_array_equal(g.pulley_center, g.frame_anchors)


def test_default_wiring_names_and_pulley_center_override(tmp_path):
    text = BASE.replace("[wiring]\nplatform_anchor = [0, 1, 2, 3]\n", "")
    text = text.replace('name = "c0"', 'pulley = { center = [2.1, 2.0, 3.2], radius = 0.07 }')
    text = text.replace('name = "c1"\n', "")
    g = load_robot(write(tmp_path, text)).geometry()
    np.testing.assert_array_equal(g.platform_anchors[3], [0.1, -0.1, -0.1])
    np.testing.assert_array_equal(g.pulley_center[0], [2.1, 2.0, 3.2])
    assert g.pulley_radius[0] == 0.07
    assert g.cable_names == ("cable0", "cable1", "c2", "cable3")


def test_axis_within_tolerance_is_kept_exactly_not_normalised(tmp_path):
    axis = [0.0, 0.0, 1.0 + 5e-7]
    text = BASE.replace('axis = "vertical"', f"axis = {axis}")
    g = load_robot(write(tmp_path, text)).geometry()
    np.testing.assert_array_equal(g.pulley_axis[0], axis)


# ---------------------------------------------------------------------------------------
# bad files: one problem each
# ---------------------------------------------------------------------------------------

BAD_CASES = {
    "vector_length": (
        ("[-2.0, 2.0, 3.0]", "[-2.0, 2.0]"), "frame.anchors[1]", "3 components"),
    "non_finite": (
        ("[[0.1, 0.1, 0.1]", "[[0.1, nan, 0.1]"), "platform.anchors[0][1]", "finite"),
    "inf_mass": (("mass = 5.0", "mass = inf"), "platform.mass", "finite"),
    "axis_not_unit": (('axis = "vertical"', "axis = [1.0, 1.0, 0.0]"), "pulley.axis", "unit"),
    "cable_axis_not_unit": (
        ("axis = [0.0, 0.0, -1.0]", "axis = [0.0, 0.0, -1.1]"), "cables[2].pulley.axis", "unit"),
    "axis_word": (('axis = "vertical"', 'axis = "up"'), "pulley.axis", "vertical"),
    "negative_radius": (("radius = 0.05", "radius = -0.05"), "pulley.radius", "> 0"),
    "zero_mass": (("mass = 5.0", "mass = 0.0"), "platform.mass", "> 0"),
    "negative_ea": (("ea = 1.0e4", "ea = -1.0e4"), "cable.ea", "> 0"),
    "zero_diameter": (("diameter = 0.002", "diameter = 0"), "cable.diameter", "> 0"),
    "string_number": (("diameter = 0.002", 'diameter = "0.002"'), "cable.diameter", "number"),
    "force_order": (("force_min = 5.0", "force_min = 500.0"), "cable.force_min", "force_max"),
    "negative_force_min": (("force_min = 5.0", "force_min = -1.0"), "cable.force_min", ">= 0"),
    "wiring_not_permutation": (
        ("platform_anchor = [0, 1, 2, 3]", "platform_anchor = [0, 0, 2, 3]"),
        "wiring.platform_anchor[1]", "permutation"),
    "wiring_out_of_range": (
        ("platform_anchor = [0, 1, 2, 3]", "platform_anchor = [0, 1, 2, 7]"),
        "wiring.platform_anchor[3]", "out of range"),
    "wiring_length": (
        ("platform_anchor = [0, 1, 2, 3]", "platform_anchor = [0, 1, 2]"),
        "wiring.platform_anchor", "3 entries"),
    "anchor_counts": (
        (", [0.1, -0.1, -0.1]]", "]"), "platform.anchors", "frame.anchors has 4"),
    "unknown_top_key": (('description = "test robot"', 'descripton = "test robot"'),
                        "descripton", "unknown key"),
    "unknown_nested_key": (('name = "c0"', 'name = "c0"\ncolour = "red"'),
                           "cables[0].colour", "unknown key"),
    "missing_field": (("mass = 5.0\n", ""), "platform.mass", "missing"),
    "format_version": (("format = 1", "format = 2"), "format", "unsupported"),
    "pulley_true": (('name = "c1"', 'name = "c1"\npulley = true'), "cables[1].pulley", "false"),
    "duplicate_names": (('name = "c1"', 'name = "c0"'), "cables[1].name", "duplicate"),
    "cable_force_override": (('name = "c1"', 'name = "c1"\nforce_max = 2.0'),
                             "cables[1].force_max", "force_min"),
    "planar_with_z": (('description = "test robot"', 'description = "x"\nplanar = true'),
                      "frame.anchors[0]", "z == 0"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_each_problem_names_file_and_field(tmp_path, case):
    (old, new), field, why = BAD_CASES[case]
    assert old in BASE, f"test case {case} does not apply to BASE"
    path = write(tmp_path, BASE.replace(old, new, 1), f"{case}.toml")
    probs = problems_of(path)
    hits = [p for p in probs if f": {field}: " in p]
    assert hits, f"no problem for {field!r} in {probs}"
    assert all(str(path) in p for p in probs)
    assert any(why in p for p in hits), hits


def test_planar_robot_rejects_out_of_plane_pulleys(tmp_path):
    text = (REPO_ROBOTS / "planar4.toml").read_text()
    text = text.replace("axis = [0.0, 1.0, 0.0]", 'axis = "vertical"')
    text = text.replace('name = "lower_right"', 'name = "lower_right"\nforce_min = 0.5')
    text = text.replace(
        'name = "lower_left"\npulley = { axis = [0.0, -1.0, 0.0] }',
        'name = "lower_left"\npulley = { axis = [0.0, 0.0, -1.0], center = [-1.0, -1.0, 0.1] }',
    )
    path = write(tmp_path, text)
    probs = problems_of(path)
    assert any(": pulley.axis: " in p and "in-plane" in p for p in probs), probs
    assert any(": cables[2].pulley.axis: " in p and "z == 0" in p for p in probs), probs
    assert any(": cables[2].pulley.center: " in p and "z == 0" in p for p in probs), probs
    assert len(probs) == 3, probs


def test_too_many_cable_overrides(tmp_path):
    text = BASE + '\n[[cables]]\nname = "c3"\n\n[[cables]]\nname = "c4"\n'
    probs = problems_of(write(tmp_path, text))
    assert any(": cables: " in p and "only 4 cables" in p for p in probs), probs


def test_toml_syntax_error_reports_line(tmp_path):
    lines = BASE.splitlines()
    lines[6] = "[platform"  # line 7: broken table header
    path = write(tmp_path, "\n".join(lines))
    probs = problems_of(path)
    assert len(probs) == 1
    assert str(path) in probs[0] and "TOML" in probs[0] and "line 7" in probs[0]


def test_several_problems_are_all_reported(tmp_path):
    text = (
        BASE.replace("[-2.0, 2.0, 3.0]", "[-2.0, 2.0]")
        .replace("mass = 5.0", "mass = -5.0")
        .replace("axis = [0.0, 0.0, -1.0]", "axis = [0.0, 0.6, -0.6]")
        .replace("platform_anchor = [0, 1, 2, 3]", "platform_anchor = [0, 1, 1, 9]")
        .replace("force_min = 5.0", "force_min = 600.0")
        .replace('name = "c0"', 'name = "c0"\nstretch = 1')
    )
    path = write(tmp_path, text)
    probs = problems_of(path)
    expected = [
        "frame.anchors[1]", "platform.mass", "cables[2].pulley.axis",
        "wiring.platform_anchor[2]", "wiring.platform_anchor[3]", "cable.force_min",
        "cables[0].stretch",
    ]
    for field in expected:
        assert any(f": {field}: " in p for p in probs), (field, probs)
    assert len(probs) >= len(expected)
    assert all(p.startswith(f"{path}: ") for p in probs)


def test_error_message_for_unit_axis_gives_norm(tmp_path):
    path = write(tmp_path, BASE.replace('axis = "vertical"', "axis = [0.0, 0.0, 2.0]"))
    (msg,) = [p for p in problems_of(path) if ": pulley.axis: " in p]
    assert float(msg.split("|axis| = ")[-1].split(";")[0]) == 2.0
    assert "not normalised" in msg
