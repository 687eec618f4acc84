"""Robot definition files: TOML, validated with pydantic v2, turned into numpy geometry.

A robot file describes one cable-driven parallel robot (CDPR) in SI units: frame anchors
a_i and platform anchors b_i (the points of eq 1 of paper 002, l_i = a_i - (r + R b_i)),
the wiring between them, the platform mass and centre of gravity (the gravity part of the
wrench w in eq 2 of 002), cable data and the optional redirection pulleys. The format,
every field and the pulley convention are documented in ``robots/README.md``.

Entry points:

- :func:`load_robot` reads a file (path, or bare name looked up in :func:`robot_search_path`)
  and returns a validated :class:`Robot`; every problem found is collected and raised at once
  as :class:`RobotFileError`.
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

from cablesvc.errors import ConfigError

__all__ = [
    "FORMAT_VERSION",
    "GRAVITY",
    "AXIS_UNIT_TOLERANCE",
    "Robot",
    "RobotFileError",
    "RobotGeometry",
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
            f"chunk), got {_short(v)}",
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


# --------------------------------------------------------------------------------------
# validation messages
# --------------------------------------------------------------------------------------


def _path_str(loc: tuple[Any, ...]) -> str:
    """Format a pydantic loc tuple as a field path: ('frame','anchors',3) -> frame.anchors[3]."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "<top level>"


def _short(v: Any, limit: int = 60) -> str:
    """repr() of an offending input value, cut to ``limit`` characters (units as in the file)."""
    s = repr(v)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _pydantic_message(err: dict[str, Any]) -> str:
    """Turn one pydantic error dict (type, loc, msg, input) into a plain-language reason."""
    t = err["type"]
    inp = err.get("input")
    if t == "extra_forbidden":
        return "unknown key (not part of the robot file format; see robots/README.md)"
    if t == "missing":
        return "required field is missing"
    if t == "finite_number":
        return f"must be a finite number, got {_short(inp)}"
    if t in ("float_type", "int_type", "string_type", "bool_type", "list_type", "model_type"):
        want = {
            "float_type": "a number",
            "int_type": "an integer",
            "string_type": "a string",
            "bool_type": "true or false",
            "list_type": "a list",
            "model_type": "a table",
        }[t]
        return f"must be {want}, got {_short(inp)}"
    if t == "greater_than":
        return f"must be > {err['ctx']['gt']}, got {_short(inp)}"
    if t == "greater_than_equal":
        return f"must be >= {err['ctx']['ge']}, got {_short(inp)}"
    if t == "too_short":
        return f"must not be empty, got {_short(inp)}"
    if t == "string_too_short":
        return "must not be empty"
    if t.startswith("cablesvc_"):
        return err["msg"]
    return f"{err['msg']} (got {_short(inp)})"


def _is_num(x: Any) -> bool:
    """True for a finite int/float that is not a bool (any unit)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _is_vec3(v: Any) -> bool:
    """True for a list of three finite numbers (a point in m or a direction)."""
    return isinstance(v, list) and len(v) == 3 and all(_is_num(c) for c in v)


def _semantic_problems(raw: dict[str, Any]) -> list[tuple[str, str]]:
    """Cross-field checks on the raw TOML table, done defensively so that they also run when
    some fields failed schema validation. Returns (field path, reason) pairs."""
    probs: list[tuple[str, str]] = []
    fmt = raw.get("format")
    if isinstance(fmt, int) and not isinstance(fmt, bool) and fmt != FORMAT_VERSION:
        probs.append(("format", f"unsupported format {fmt}; this version reads format {FORMAT_VERSION}"))

    frame = raw.get("frame") if isinstance(raw.get("frame"), dict) else {}
    platform = raw.get("platform") if isinstance(raw.get("platform"), dict) else {}
    fa = frame.get("anchors") if isinstance(frame.get("anchors"), list) else None
    pa = platform.get("anchors") if isinstance(platform.get("anchors"), list) else None
    m = len(fa) if fa is not None else None
    n_pa = len(pa) if pa is not None else None
    if m is not None and n_pa is not None and m != n_pa:
        probs.append(
            (
                "platform.anchors",
                f"has {n_pa} anchors but frame.anchors has {m}; every cable needs one of each",
            )
        )

    wiring = raw.get("wiring") if isinstance(raw.get("wiring"), dict) else {}
    w = wiring.get("platform_anchor")
    if isinstance(w, list) and all(isinstance(k, int) and not isinstance(k, bool) for k in w):
        if m is not None and len(w) != m:
            probs.append(
                ("wiring.platform_anchor", f"has {len(w)} entries but there are {m} cables")
            )
        if n_pa is not None:
            for k, idx in enumerate(w):
                if not 0 <= idx < n_pa:
                    probs.append(
                        (
                            f"wiring.platform_anchor[{k}]",
                            f"index {idx} out of range: platform anchors are 0..{n_pa - 1}",
                        )
                    )
        seen: dict[int, int] = {}
        for k, idx in enumerate(w):
            if idx in seen:
                probs.append(
                    (
                        f"wiring.platform_anchor[{k}]",
                        f"not a permutation: platform anchor {idx} is already used by cable "
                        f"{seen[idx]}",
                    )
                )
            else:
                seen[idx] = k

    cable = raw.get("cable") if isinstance(raw.get("cable"), dict) else {}
    dmin, dmax = cable.get("force_min"), cable.get("force_max")
    if _is_num(dmin) and _is_num(dmax) and dmin >= dmax:
        probs.append(("cable.force_min", f"force_min ({dmin} N) must be < force_max ({dmax} N)"))

    planar = raw.get("planar") is True
    if planar:
        for sect, anchors in (("frame", fa), ("platform", pa)):
            for k, a in enumerate(anchors or []):
                if _is_vec3(a) and a[2] != 0:
                    probs.append(
                        (f"{sect}.anchors[{k}]", f"planar robot anchors must have z == 0, got z = {a[2]}")
                    )

    defaults = raw.get("pulley") if isinstance(raw.get("pulley"), dict) else None
    cables = raw.get("cables")
    cables = cables if isinstance(cables, list) else []
    if m is not None and len(cables) > m:
        probs.append(("cables", f"has {len(cables)} entries but there are only {m} cables"))

    def _check_planar_axis(path: str, axis: Any) -> None:
        """A planar robot's pulley axis (unit vector) must lie in the z = 0 plane."""
        if axis == "vertical":
            probs.append((path, 'planar robots need an in-plane axis, not "vertical"'))
        elif _is_vec3(axis) and axis[2] != 0:
            probs.append((path, f"planar robot pulley axis must have z == 0, got z = {axis[2]}"))

    n_cables = m if m is not None else len(cables)
    any_default_used = False
    # resolved names (an entry without ``name`` is "cable<i>") must be unique
    names: dict[str, tuple[int, bool]] = {}
    for i in range(n_cables):
        ov = cables[i] if i < len(cables) and isinstance(cables[i], dict) else {}
        given = ov.get("name")
        if given is not None and not (isinstance(given, str) and given):
            continue                      # wrong type or empty: reported by the schema
        explicit = given is not None
        name = given if explicit else f"cable{i}"
        if name in names:
            j, j_explicit = names[name]
            if explicit:
                other = f"cable {j}" if j_explicit else f"the default name of cable {j}"
                probs.append((f"cables[{i}].name", f"duplicate cable name {name!r} (also {other})"))
            else:                         # default names are unique: the earlier one was given
                probs.append(
                    (
                        f"cables[{j}].name",
                        f"duplicate cable name {name!r} (also the default name of cable {i}, "
                        f"which has no name)",
                    )
                )
        else:
            names[name] = (i, explicit)
    for i in range(n_cables):
        ov = cables[i] if i < len(cables) and isinstance(cables[i], dict) else {}
        fmin = ov.get("force_min", dmin)
        fmax = ov.get("force_max", dmax)
        if ("force_min" in ov or "force_max" in ov) and _is_num(fmin) and _is_num(fmax) and fmin >= fmax:
            key = "force_min" if "force_min" in ov else "force_max"
            probs.append(
                (f"cables[{i}].{key}", f"effective force_min ({fmin} N) must be < force_max ({fmax} N)")
            )
        p = ov.get("pulley")
        if p is None:
            any_default_used = any_default_used or defaults is not None
        elif isinstance(p, dict):
            if "radius" not in p and not (defaults is not None and "radius" in defaults):
                probs.append(
                    (f"cables[{i}].pulley.radius", "required: no radius here and no [pulley] default")
                )
            if planar:
                axis = p.get("axis", (defaults or {}).get("axis", "vertical"))
                # the [pulley] default is to blame only when there is a [pulley] section
                from_default = "axis" not in p and defaults is not None
                _check_planar_axis("pulley.axis" if from_default else f"cables[{i}].pulley.axis", axis)
                c = p.get("center")
                if _is_vec3(c) and c[2] != 0:
                    probs.append(
                        (f"cables[{i}].pulley.center", f"planar robot pulley center must have z == 0, got z = {c[2]}")
                    )
    if planar and any_default_used:
        _check_planar_axis("pulley.axis", defaults.get("axis", "vertical"))
    # report each path once (the default axis may be reported for several cables)
    unique: list[tuple[str, str]] = []
    for pr in probs:
        if pr not in unique:
            unique.append(pr)
    return unique


def _validate(raw: dict[str, Any], path: Path) -> Robot:
    """Validate a parsed TOML table; raise RobotFileError listing every problem."""
    problems: list[str] = []
    data: Robot | None = None
    try:
        data = Robot.model_validate(raw)
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            problems.append(f"{path}: {_path_str(err['loc'])}: {_pydantic_message(err)}")
    for field_path, why in _semantic_problems(raw):
        problems.append(f"{path}: {field_path}: {why}")
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
