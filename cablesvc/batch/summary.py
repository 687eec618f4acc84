"""The fleet summary: which robots and cables drift, which effects were found, since when.

:func:`fleet_summary` reads the rows (:mod:`cablesvc.batch.jobs`) and groups them per robot,
ordered by each recording's ``start_time``. "Since" is the start time of the earliest
recording that shows the item; ``recordings`` how many of the robot's recordings show it;
``in_latest`` whether its latest (good) recording still does.

* **discover**: ``effects`` are the named physics terms per cable (the findings);
  ``drift`` the cables whose baseline had to be recalibrated (the cable no longer
  matches its parameter file: stiffness, pretension, loop area; identified mode only);
  ``unexplained`` the cables with a residual no term explains; ``not_seen`` the candidate
  terms found in none of the robot's recordings, each with the median over the
  recordings of its floor and limit on its best cable (the least effect the recording
  could show beside the recalibration, with a perfect baseline and with this one's
  model form: :mod:`cablesvc.discover.detectability`), so that "no effect found" says how
  small an effect would have gone unseen.
* **identify**: the reference is the robot's earliest good recording (same model and
  cables); a cable *drifts* in a later recording when one of its parameters moved by more
  than :data:`DRIFT_REL` of the reference value *and* more than :data:`DRIFT_Z` combined
  standard errors (when both standard errors are finite). ``drift`` lists those cables
  with the parameters, the reference and the latest value.

``lines`` says the same in sentences (the CLI prints them; the HTML report lists them).
"""

from __future__ import annotations

import math
import statistics
from typing import Any, Optional, Sequence

__all__ = ["DRIFT_REL", "DRIFT_Z", "fleet_summary"]

#: identify: least relative change of a parameter against the robot's reference recording ...
DRIFT_REL = 0.05
#: ... and least change in combined standard errors, for a cable to count as drifting
DRIFT_Z = 5.0


def _by_robot(rows: Sequence[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if r["status"] == "ok":
            out.setdefault(r["robot"], []).append(r)
    for k in out:
        out[k].sort(key=lambda r: (r["start_time"], r["recording"]))
    return dict(sorted(out.items()))


def _failed(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{"recording": r["recording"], "robot": r.get("robot"), "error": r["error"]} for r in rows
            if r["status"] != "ok"]


def _track(found: dict[Any, list[dict[str, Any]]], latest: dict[str, Any]) -> dict[Any, dict[str, Any]]:
    return {k: {"since": rs[0]["start_time"], "since_recording": rs[0]["recording"], "recordings": len(rs),
                "in_latest": rs[-1] is latest} for k, rs in found.items()}


def _cables(cs: Sequence[int]) -> str:
    return ("cable " if len(cs) == 1 else "cables ") + ", ".join(str(c) for c in cs)


def _median_n(values: Sequence[Optional[float]]) -> float:
    """Median of limits [N], where None (JSON's null) is an infinite one."""
    return float(statistics.median(math.inf if v is None else float(v) for v in values))


def _not_seen(rs: Sequence[dict[str, Any]], found: set[str]) -> list[dict[str, Any]]:
    by: dict[str, list[dict[str, Any]]] = {}
    for r in rs:
        for x in r.get("detection", []) or []:
            if x["term"] not in found:
                by.setdefault(x["term"], []).append(x)
    out = [{"term": t, "recordings": len(xs), "median_floor_rms_N": _median_n([x["min_floor_rms_N"] for x in xs]),
            "median_limit_rms_N": _median_n([x["min_limit_rms_N"] for x in xs])} for t, xs in by.items()]
    return sorted(out, key=lambda x: -x["median_floor_rms_N"])


def _n(v: float) -> str:
    return "inf" if math.isinf(v) else f"{v:.2g}"


def _discover(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    robots: dict[str, Any] = {}
    lines: list[str] = []
    for robot, rs in _by_robot(rows).items():
        eff: dict[tuple[str, int], list[dict]] = {}
        labels: dict[str, str] = {}
        drift: dict[int, list[dict]] = {}
        unex: dict[int, list[dict]] = {}
        for r in rs:
            for f in r["findings"]:
                labels[f["term"]] = f["label"]
                for c in f["cables"]:
                    eff.setdefault((f["term"], c), []).append(r)
            for c in r["recalibrated"]:
                drift.setdefault(c, []).append(r)
            for u in r["unexplained"]:
                for c in u["cables"]:
                    unex.setdefault(c, []).append(r)
        latest = rs[-1]
        te = _track(eff, latest)
        effects = [{"term": t, "label": labels[t], "cable": c, **v} for (t, c), v in sorted(te.items())]
        drifts = [{"cable": c, **v} for c, v in sorted(_track(drift, latest).items())]
        unexplained = [{"cable": c, **v} for c, v in sorted(_track(unex, latest).items())]
        not_seen = _not_seen(rs, {e["term"] for e in effects})
        robots[robot] = {"recordings": len(rs), "first_start": rs[0]["start_time"], "last_start": latest["start_time"],
                         "effects": effects, "drift": drifts, "unexplained": unexplained, "not_seen": not_seen,
                         "latest_verdict": latest["verdict"]}
        head = f"{robot} ({len(rs)} recording{'s' if len(rs) != 1 else ''}, {rs[0]['start_time']} .. {latest['start_time']})"
        if not effects and not drifts and not unexplained:
            lines.append(f"{head}: no effect found, no cable drifts")
        for t in sorted({e["term"] for e in effects}):
            es = [e for e in effects if e["term"] == t]
            lines.append(f"{head}: {labels[t]} ({t}) on {_cables([e['cable'] for e in es])}, since "
                         f"{min(e['since'] for e in es)} (" + "; ".join(
                             f"cable {e['cable']}: {e['recordings']}/{len(rs)} recordings"
                             + (", in the latest" if e["in_latest"] else ", not in the latest") for e in es) + ")")
        if drifts:
            lines.append(f"{head}: baseline drifts (recalibrated) on {_cables([d['cable'] for d in drifts])}, since "
                         f"{min(d['since'] for d in drifts)}")
        if unexplained:
            lines.append(f"{head}: unexplained residual on {_cables([u['cable'] for u in unexplained])}, since "
                         f"{min(u['since'] for u in unexplained)}")
        if not_seen:
            lines.append(f"{head}: not found, and not told from the baseline's recalibration below (median over the "
                         "recordings, best cable; with a perfect baseline / with this one's model form): " + "; ".join(
                             f"{x['term']} {_n(x['median_floor_rms_N'])} / {_n(x['median_limit_rms_N'])} N RMS"
                             for x in not_seen))
    return {"robots": robots, "lines": lines}


def _param_drift(ref: dict[str, Any], cur: dict[str, Any]) -> dict[str, dict[str, float]]:
    out = {}
    for name, v0 in ref["value"].items():
        v = cur["value"].get(name)
        if v is None or not (math.isfinite(v0) and math.isfinite(v)):
            continue
        rel = (v - v0) / abs(v0) if v0 != 0 else (math.inf if v != 0 else 0.0)
        s0, s1 = ref["stderr"].get(name, math.nan), cur["stderr"].get(name, math.nan)
        se = math.hypot(s0, s1) if math.isfinite(s0) and math.isfinite(s1) else math.nan
        z = abs(v - v0) / se if math.isfinite(se) and se > 0 else math.nan
        if abs(rel) > DRIFT_REL and (not math.isfinite(se) or z > DRIFT_Z):
            out[name] = {"reference": v0, "value": v, "change": rel, "z": z}
    return out


def _identify(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    robots: dict[str, Any] = {}
    lines: list[str] = []
    for robot, rs in _by_robot(rows).items():
        ref = rs[0]
        same = [r for r in rs if r["model"] == ref["model"] and r["cables"] == ref["cables"]]
        refp = {p["cable"]: p for p in ref["parameters"]}
        found: dict[Any, list[dict]] = {}
        params: dict[Any, dict[str, Any]] = {}
        for r in same[1:]:
            for p in r["parameters"]:
                if p["cable"] not in refp:
                    continue
                d = _param_drift(refp[p["cable"]], p)
                if d:
                    found.setdefault(p["cable"], []).append(r)
                    params[p["cable"]] = d         # the latest drifting recording's numbers
        latest = same[-1]
        drifts = [{"cable": c, **v, "parameters": params[c]}
                  for c, v in sorted(_track(found, latest).items(), key=lambda kv: str(kv[0]))]
        robots[robot] = {"recordings": len(rs), "compared": len(same), "model": ref["model"],
                         "reference": ref["recording"], "reference_start": ref["start_time"],
                         "first_start": rs[0]["start_time"], "last_start": rs[-1]["start_time"], "drift": drifts,
                         "rmse_latest": latest["rmse"]}
        head = f"{robot} ({len(rs)} recording{'s' if len(rs) != 1 else ''}, model {ref['model']})"
        if not drifts:
            lines.append(f"{head}: no cable drifts against {ref['start_time']}")
        for d in drifts:
            what = ", ".join(f"{n} {v['change'] * 100:+.1f} %" for n, v in d["parameters"].items())
            lines.append(f"{head}: cable {d['cable']} drifts since {d['since']} ({what} against "
                         f"{ref['start_time']}; {d['recordings']} recording{'s' if d['recordings'] != 1 else ''}"
                         + (", in the latest" if d["in_latest"] else ", not in the latest") + ")")
    return {"robots": robots, "lines": lines, "drift_rule": {"rel": DRIFT_REL, "z": DRIFT_Z}}


def fleet_summary(command: str, rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The summary of ``command``'s rows (module docstring)."""
    s = _discover(rows) if command == "discover" else _identify(rows)
    failed = _failed(rows)
    s["failed"] = failed
    s["lines"] += [f"failed: {f['recording']}: {f['error']}" for f in failed]
    return s
