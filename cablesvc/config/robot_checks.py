"""The messages of a robot file that does not check (cablesvc.config.robot.load_robot): a
pydantic error in plain words naming the field (``frame.anchors[3]: must be a number``), and
the cross-field checks that pydantic's per-field validation cannot make (cable counts,
units, a planar robot's pulley axes), run even where some fields failed. One (field path,
reason) pair per problem; robot.py lists them all in its RobotFileError."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["field_path", "pydantic_reason", "semantic_problems", "short_value"]


def field_path(loc: tuple[Any, ...]) -> str:
    """Format a pydantic loc tuple as a field path: ('frame','anchors',3) -> frame.anchors[3]."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "<top level>"


def short_value(v: Any, limit: int = 60) -> str:
    """repr() of an offending input value, cut to ``limit`` characters (units as in the file)."""
    s = repr(v)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def pydantic_reason(err: dict[str, Any]) -> str:
    """Turn one pydantic error dict (type, loc, msg, input) into a plain-language reason."""
    t = err["type"]
    inp = err.get("input")
    if t == "extra_forbidden":
        return "unknown key (not part of the robot file format; see robots/README.md)"
    if t == "missing":
        return "required field is missing"
    if t == "finite_number":
        return f"must be a finite number, got {short_value(inp)}"
    if t in ("float_type", "int_type", "string_type", "bool_type", "list_type", "model_type"):
        want = {
            "float_type": "a number",
            "int_type": "an integer",
            "string_type": "a string",
            "bool_type": "true or false",
            "list_type": "a list",
            "model_type": "a table",
        }[t]
        return f"must be {want}, got {short_value(inp)}"
    if t == "greater_than":
        return f"must be > {err['ctx']['gt']}, got {short_value(inp)}"
    if t == "greater_than_equal":
        return f"must be >= {err['ctx']['ge']}, got {short_value(inp)}"
    if t == "too_short":
        return f"must not be empty, got {short_value(inp)}"
    if t == "string_too_short":
        return "must not be empty"
    if t.startswith("cablesvc_"):
        return err["msg"]
    return f"{err['msg']} (got {short_value(inp)})"


def _is_num(x: Any) -> bool:
    """True for a finite int/float that is not a bool (any unit)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _is_vec3(v: Any) -> bool:
    """True for a list of three finite numbers (a point in m or a direction)."""
    return isinstance(v, list) and len(v) == 3 and all(_is_num(c) for c in v)


def semantic_problems(raw: dict[str, Any], format_version: int) -> list[tuple[str, str]]:
    """Cross-field checks on the raw TOML table, done defensively so that they also run when
    some fields failed schema validation. Returns (field path, reason) pairs."""
    probs: list[tuple[str, str]] = []
    fmt = raw.get("format")
    if isinstance(fmt, int) and not isinstance(fmt, bool) and fmt != format_version:
        probs.append(("format", f"unsupported format {fmt}; this version reads format {format_version}"))

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
