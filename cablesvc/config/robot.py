"""Robot definition files: TOML, validated with pydantic v2, turned into numpy geometry.

A robot file describes one cable-driven parallel robot (CDPR) in SI units: frame anchors
a_i and platform anchors b_i (the points of eq 1 of paper 002, l_i = a_i - (r + R b_i)),
the wiring between them, the platform mass and centre of gravity (the gravity part of the
wrench w in eq 2 of 002), cable data and the optional redirection pulleys. The format,
every field and the pulley convention are documented in ``robots/README.md``.

Entry points:

- :func:`load_robot` reads a file (path, or bare name looked up in :func:`robot_search_path`)
  and returns a validated :class:`Robot`; every problem found is collected and raised at once
  as :class:`RobotFileError` (its messages and the cross-field checks:
  :mod:`cablesvc.config.robot_checks`).
- :meth:`Robot.geometry` gives a frozen :class:`RobotGeometry` of read-only float64 arrays,
  already resolved per cable (wiring applied, per-cable overrides merged, pulley axes resolved).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    WrapValidator,
)
from pydantic_core import PydanticCustomError

from cablesvc.config.robot_checks import field_path, pydantic_reason, semantic_problems, short_value
from cablesvc.errors import ConfigError

__all__ = [
    "FORMAT_VERSION",
    "GRAVITY",
    "AXIS_UNIT_TOLERANCE",
    "Robot",
    "RobotFileError",
    "RobotGeometry",
    "available_robots",
    "load_robot",
    "robot_search_path",
]

#: The only file format version this code reads (top-level key ``format``).
FORMAT_VERSION = 1
#: Gravitational acceleration vector used for every robot, m/s^2, world frame (z up).
GRAVITY = (0.0, 0.0, -9.81)
#: Largest accepted deviation of | axis | from 1 (dimensionless); axes are never normalised.
AXIS_UNIT_TOLERANCE = 1e-6


# --------------------------------------------------------------------------------------
# errors
# --------------------------------------------------------------------------------------


class RobotFileError(ConfigError):
    """A robot file (or robot name) that cannot be used.

    ``path`` is the file (or the name that was looked up); ``problems`` is the list of every
    problem found, each a complete one-line message naming the file and the field path.
    ``str()`` lists them all, one per line.
    """

    def __init__(self, path: str | os.PathLike[str], problems: list[str]):
        self.path = str(path)
        self.problems = list(problems)
        super().__init__(self.__str__())

    def __str__(self) -> str:
        """Header line, then every problem on its own line."""
        n = len(self.problems)
        head = f"robot file {self.path}: {n} problem{'s' if n != 1 else ''}"
        return "\n".join([head, *self.problems])


# --------------------------------------------------------------------------------------
# field types
# --------------------------------------------------------------------------------------

# strict: TOML integers are accepted for floats, strings and booleans are not.
FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]
PositiveFloat = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0.0)]
NonNegativeFloat = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.0)]
StrictInt = Annotated[int, Field(strict=True)]
StrictStr = Annotated[str, Field(strict=True)]
StrictBool = Annotated[bool, Field(strict=True)]


def _custom(kind: str, message: str) -> PydanticCustomError:
    """A pydantic error whose message is ``message`` verbatim.

    Without a context pydantic does not format the template, so braces are left as they
    are (escaping them would show up doubled in the message)."""
    return PydanticCustomError(f"cablesvc_{kind}", message)


#: characters allowed in a robot name: the name is one key chunk of the Zenoh key
#: expressions the service publishes on (no '/', '*', '$', '?', '#', spaces)
ROBOT_NAME_PATTERN = re.compile(r"[A-Za-z0-9_.-]+")


def _check_robot_name(v: str) -> str:
    """A robot name: non-empty letters, digits, '_', '.', '-' (usable as a Zenoh key chunk)."""
    if v and not ROBOT_NAME_PATTERN.fullmatch(v):
        raise _custom(
            "robot_name",
            f"must contain only letters, digits, '_', '.' and '-' (it is used as a Zenoh key "
            f"chunk), got {short_value(v)}",
        )
    return v


def _check_vec3(v: list[float]) -> list[float]:
    """Require exactly three components (x, y, z) for a point or direction in m / unitless."""
    if len(v) != 3:
        raise _custom("vec3_length", f"must have 3 components [x, y, z], got {len(v)}: {v!r}")
    return v


Vec3 = Annotated[list[FiniteFloat], AfterValidator(_check_vec3)]


def _validate_axis(v: Any) -> str | tuple[float, float, float]:
    """Validate a pulley swivel axis: the string "vertical" or a unit 3-vector (unitless).

    The vector is never normalised: | axis | must be 1 within AXIS_UNIT_TOLERANCE.
    """
    expected = 'must be "vertical" or a unit vector [x, y, z]'
    if isinstance(v, str):
        if v != "vertical":
            raise _custom("axis_keyword", f"{expected}, got the string {v!r}")
        return v
    if not isinstance(v, list):
        raise _custom("axis_type", f"{expected}, got {v!r}")
    if len(v) != 3:
        raise _custom("vec3_length", f"must have 3 components [x, y, z], got {len(v)}: {v!r}")
    for k, c in enumerate(v):
        if isinstance(c, bool) or not isinstance(c, (int, float)):
            raise _custom("axis_component", f"component [{k}] must be a number, got {c!r}")
        if not math.isfinite(c):
            raise _custom("axis_component", f"component [{k}] must be finite, got {c!r}")
    norm = math.sqrt(sum(float(c) * float(c) for c in v))
    if abs(norm - 1.0) > AXIS_UNIT_TOLERANCE:
        raise _custom(
            "axis_not_unit",
            f"must be a unit vector (|axis| = 1 within {AXIS_UNIT_TOLERANCE:g}), got {v!r} "
            f"with |axis| = {norm:.9g}; axes are not normalised for you",
        )
    return (float(v[0]), float(v[1]), float(v[2]))


Axis = Annotated[Any, AfterValidator(_validate_axis)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FrameSection(_Strict):
    """``[frame]``: frame anchors a_i in m, world frame (eq 1 of 002)."""

    anchors: list[Vec3] = Field(min_length=1)


class PlatformSection(_Strict):
    """``[platform]``: platform anchors b_i in m (platform frame), mass in kg, cog in m."""

    anchors: list[Vec3] = Field(min_length=1)
    mass: PositiveFloat
    center_of_gravity: Vec3 = [0.0, 0.0, 0.0]


class WiringSection(_Strict):
    """``[wiring]``: cable i runs from frame anchor i to platform anchor platform_anchor[i]."""

    platform_anchor: Optional[list[StrictInt]] = None


class CableSection(_Strict):
    """``[cable]``: defaults for every cable (m, N, N, N)."""

    diameter: PositiveFloat
    material: StrictStr = ""
    ea: PositiveFloat
    force_min: NonNegativeFloat
    force_max: PositiveFloat


class PulleyDefaults(_Strict):
    """``[pulley]``: default redirection pulley of every cable (radius in m, unit axis)."""

    radius: PositiveFloat
    axis: Axis = "vertical"


class PulleyOverride(_Strict):
    """``cables[i].pulley``: per-cable pulley (center in m world frame, unit axis, radius m)."""

    center: Optional[Vec3] = None
    axis: Optional[Axis] = None
    radius: Optional[PositiveFloat] = None


def _pulley_false_or_table(v: Any, handler: Any) -> Any:
    """Accept ``pulley = false`` (no pulley on this cable) or a pulley table."""
    if v is False:
        return False
    if v is True:
        raise _custom("pulley_true", "must be a table {center=[..], axis=[..], radius=..} or false, got true")
    return handler(v)


class CableOverride(_Strict):
    """``[[cables]]`` entry: per-cable overrides; list index = cable index."""

    name: Optional[Annotated[StrictStr, Field(min_length=1)]] = None
    diameter: Optional[PositiveFloat] = None
    material: Optional[StrictStr] = None
    ea: Optional[PositiveFloat] = None
    force_min: Optional[NonNegativeFloat] = None
    force_max: Optional[PositiveFloat] = None
    pulley: Annotated[Optional[PulleyOverride], WrapValidator(_pulley_false_or_table)] = None


class Robot(_Strict):
    """A validated robot file (schema of the whole file, SI units).

    Fields mirror the file: ``format``, ``name``, ``description``, ``planar``, ``frame``,
    ``platform``, ``wiring``, ``cable``, ``pulley``, ``cables``. ``source`` is the file it was
    read from (None when built from a dict). ``planar`` is true only when the file says
    ``planar = true``; the loader rejects that flag unless every anchor has z == 0, so a
    planar robot always has all anchors in the z = 0 plane.
    """

    format: StrictInt
    name: Annotated[StrictStr, Field(min_length=1), AfterValidator(_check_robot_name)]
    description: StrictStr = ""
    planar: StrictBool = False
    frame: FrameSection
    platform: PlatformSection
    wiring: WiringSection = WiringSection()
    cable: CableSection
    pulley: Optional[PulleyDefaults] = None
    cables: list[CableOverride] = []

    _source: Optional[Path] = PrivateAttr(default=None)
    _geometry: Optional["RobotGeometry"] = PrivateAttr(default=None)

    @property
    def source(self) -> Path | None:
        """The file this robot was read from, or None."""
        return self._source

    @property
    def n_cables(self) -> int:
        """Number of cables m (= number of frame anchors)."""
        return len(self.frame.anchors)

    @property
    def platform_anchor_of_cable(self) -> list[int]:
        """Platform anchor index of each cable (identity when [wiring] gives none)."""
        w = self.wiring.platform_anchor
        return list(range(self.n_cables)) if w is None else list(w)

    def geometry(self) -> "RobotGeometry":
        """Build (once) the per-cable :class:`RobotGeometry`; units SI (m, kg, N, m/s^2)."""
        if self._geometry is None:
            self._geometry = _build_geometry(self)
        return self._geometry


# --------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RobotGeometry:
    """Per-cable numeric description of a robot, SI units, arrays read-only float64.

    Everything is already resolved per cable i (wiring applied, overrides merged):

    - ``frame_anchors`` (m,3) [m]: a_i in the world frame (eq 1 of 002).
    - ``platform_anchors`` (m,3) [m]: b_i in the platform frame, the anchor cable i is tied to.
    - ``has_pulley`` (m,) bool; ``pulley_center`` (m,3) [m] entry point C (world frame; equals
      a_i where there is no pulley); ``pulley_axis`` (m,3) unit swivel axis e along which the
      cable arrives (zeros where there is no pulley); ``pulley_radius`` (m,) [m], 0 where none.
    - ``mass`` [kg], ``center_of_gravity`` (3,) [m, platform frame], ``gravity`` (3,) [m/s^2].
    - ``ea`` (m,) [N] nominal axial stiffness E*A; ``force_min``/``force_max`` (m,) [N];
      ``diameter`` (m,) [m]; ``cable_names`` tuple of str.
    - ``planar``: only x, y and rotation about z are degrees of freedom; the wrench residual
      of a planar robot is meaningful only in rows fx, fy, mz (0, 1, 5).
    """

    name: str
    n_cables: int
    frame_anchors: np.ndarray
    platform_anchors: np.ndarray
    has_pulley: np.ndarray
    pulley_center: np.ndarray
    pulley_axis: np.ndarray
    pulley_radius: np.ndarray
    mass: float
    center_of_gravity: np.ndarray
    gravity: np.ndarray
    ea: np.ndarray
    force_min: np.ndarray
    force_max: np.ndarray
    diameter: np.ndarray
    cable_names: tuple[str, ...]
    planar: bool = False


def _ro(a: Any, dtype: Any = np.float64) -> np.ndarray:
    """Return a read-only, C-contiguous copy of ``a`` (units unchanged)."""
    arr = np.array(a, dtype=dtype, copy=True, order="C")
    arr.setflags(write=False)
    return arr


def _resolve_axis(axis: str | tuple[float, float, float], center_z: float, mean_z: float):
    """Resolve an axis spec to a unit vector (unitless): "vertical" is +z when the pulley
    entry point is at or above the mean height of the frame anchors, else -z."""
    if isinstance(axis, str):  # "vertical"
        return (0.0, 0.0, 1.0) if center_z >= mean_z else (0.0, 0.0, -1.0)
    return tuple(float(c) for c in axis)


def _build_geometry(robot: Robot) -> RobotGeometry:
    """Merge defaults, overrides and wiring into per-cable arrays (SI units)."""
    d = robot
    m = robot.n_cables
    frame = np.array(d.frame.anchors, dtype=np.float64)
    plat_all = np.array(d.platform.anchors, dtype=np.float64)
    wiring = robot.platform_anchor_of_cable
    mean_z = float(frame[:, 2].mean())
    overrides = list(d.cables) + [CableOverride()] * (m - len(d.cables))

    names, diam, ea, fmin, fmax = [], [], [], [], []
    has_p, pc, pa, pr = [], [], [], []
    for i, ov in enumerate(overrides):
        names.append(ov.name if ov.name is not None else f"cable{i}")
        diam.append(ov.diameter if ov.diameter is not None else d.cable.diameter)
        ea.append(ov.ea if ov.ea is not None else d.cable.ea)
        fmin.append(ov.force_min if ov.force_min is not None else d.cable.force_min)
        fmax.append(ov.force_max if ov.force_max is not None else d.cable.force_max)
        spec = _pulley_spec(d, ov)
        if spec is None:
            has_p.append(False)
            pc.append(frame[i])
            pa.append((0.0, 0.0, 0.0))
            pr.append(0.0)
        else:
            center, axis, radius = spec
            c = frame[i] if center is None else np.asarray(center, dtype=np.float64)
            has_p.append(True)
            pc.append(c)
            pa.append(_resolve_axis(axis, float(c[2]), mean_z))
            pr.append(radius)
    return RobotGeometry(
        name=d.name,
        n_cables=m,
        frame_anchors=_ro(frame),
        platform_anchors=_ro(plat_all[wiring]),
        has_pulley=_ro(has_p, dtype=bool),
        pulley_center=_ro(pc),
        pulley_axis=_ro(pa),
        pulley_radius=_ro(pr),
        mass=float(d.platform.mass),
        center_of_gravity=_ro(d.platform.center_of_gravity),
        gravity=_ro(GRAVITY),
        ea=_ro(ea),
        force_min=_ro(fmin),
        force_max=_ro(fmax),
        diameter=_ro(diam),
        cable_names=tuple(names),
        planar=robot.planar,
    )


def _pulley_spec(d: Robot, ov: CableOverride):
    """Return (center or None, axis spec, radius [m]) of a cable's pulley, or None."""
    if ov.pulley is False:
        return None
    if ov.pulley is None:
        if d.pulley is None:
            return None
        return None, d.pulley.axis, d.pulley.radius
    p = ov.pulley
    radius = p.radius if p.radius is not None else (d.pulley.radius if d.pulley else None)
    axis = p.axis if p.axis is not None else (d.pulley.axis if d.pulley else "vertical")
    return p.center, axis, radius


def _validate(raw: dict[str, Any], path: Path) -> Robot:
    """Validate a parsed TOML table; raise RobotFileError listing every problem."""
    problems: list[str] = []
    data: Robot | None = None
    try:
        data = Robot.model_validate(raw)
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            problems.append(f"{path}: {field_path(err['loc'])}: {pydantic_reason(err)}")
    for where, why in semantic_problems(raw, FORMAT_VERSION):
        problems.append(f"{path}: {where}: {why}")
    if problems:
        raise RobotFileError(path, problems)
    assert data is not None
    return data


# --------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------


def robot_search_path() -> list[Path]:
    """Folders searched for ``<name>.toml``, in order: each entry of $CABLESVC_ROBOTS
    (os.pathsep-separated), then ``./robots``, then the repository's ``robots/`` folder."""
    dirs: list[Path] = []
    env = os.environ.get("CABLESVC_ROBOTS", "")
    dirs.extend(Path(p) for p in env.split(os.pathsep) if p)
    dirs.append(Path.cwd() / "robots")
    dirs.append(Path(__file__).resolve().parents[2] / "robots")
    unique: list[Path] = []
    seen: set[Path] = set()
    for d in dirs:
        key = d.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(d)
    return unique


def robot_files(directory: str | os.PathLike[str]) -> list[Path]:
    """Robot definition files in ``directory``: ``NAME.toml`` whose NAME has no dot.

    Companion files of a robot (``NAME.modbus.toml`` register maps, ``NAME.params.toml``)
    live beside it and are not robots.
    """
    d = Path(directory)
    if not d.is_dir():
        return []
    return sorted(p for p in d.glob("*.toml") if "." not in p.stem)


def _available_names(dirs: list[Path]) -> list[str]:
    """Sorted robot names found in ``dirs``."""
    names: set[str] = set()
    for d in dirs:
        names.update(p.stem for p in robot_files(d))
    return sorted(names)


def available_robots() -> list[str]:
    """Names of the robot files on the search path (:func:`robot_search_path`)."""
    return _available_names(robot_search_path())


def _find(name_or_path: str | os.PathLike[str]) -> Path:
    """Resolve a path or bare robot name to an existing file; RobotFileError otherwise."""
    s = os.fspath(name_or_path)
    looks_like_path = (
        isinstance(name_or_path, os.PathLike)
        or s.endswith(".toml")
        or os.sep in s
        or (os.altsep is not None and os.altsep in s)
    )
    if looks_like_path:
        p = Path(s)
        if not p.is_file():
            raise RobotFileError(p, [f"{p}: file not found"])
        return p
    dirs = robot_search_path()
    for d in dirs:
        cand = d / f"{s}.toml"
        if cand.is_file():
            return cand
    avail = _available_names(dirs)
    raise RobotFileError(
        s,
        [
            f"{s}: no robot named {s!r} in {', '.join(str(d) for d in dirs)}; "
            f"available: {', '.join(avail) if avail else '(none)'}"
        ],
    )


def load_robot(name_or_path: str | os.PathLike[str]) -> Robot:
    """Read and validate a robot file.

    ``name_or_path``: a path to a ``.toml`` file, or a bare robot name (e.g. "ipanema3")
    looked up as ``<name>.toml`` in :func:`robot_search_path`. Units in the file are SI
    (m, kg, N). Raises :class:`RobotFileError` listing every problem found (TOML syntax
    error with its line, schema errors, cross-field errors), each naming file and field path.
    """
    path = _find(name_or_path)
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RobotFileError(path, [f"{path}: cannot read: {exc}"]) from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(path, [f"{path}: TOML syntax error: {exc}"]) from None
    robot = _validate(raw, path)
    robot._source = path
    return robot
