"""Fleet report: ``fleet.json`` and one ``index.html`` with the summary and a row per recording."""

from __future__ import annotations

import html
import json
import os
from pathlib import Path
from typing import Any

__all__ = ["write_fleet_report"]


def _cell(row: dict[str, Any], command: str) -> str:
    e = html.escape
    if row["status"] != "ok":
        return f"<span class='bad'>failed: {e(str(row['error']))}</span>"
    if command == "discover":
        finds = "; ".join(f"{f['term']} on cable{'s' if len(f['cables']) > 1 else ''} "
                          f"{','.join(map(str, f['cables']))}" for f in row["findings"]) or "no effect"
        drift = (f"; recalibrated cables {','.join(map(str, row['recalibrated']))}" if row["recalibrated"] else "")
        return e(finds + drift) + f"<br><small>{e(row['verdict'])}</small>"
    parts = []
    for p in row["parameters"]:
        vals = ", ".join(f"{k} {v:.4g}" for k, v in p["value"].items())
        parts.append(f"cable {p['cable']}: {vals}")
    return "<br>".join(e(x) for x in parts) + f"<br><small>RMSE [N]: {e(', '.join(f'{v:.3g}' for v in row['rmse']))}</small>"


def _secs(row: dict[str, Any]) -> str:
    return "" if row.get("seconds") is None else f"{row['seconds']:.1f}"


def write_fleet_report(result: Any, directory: str | os.PathLike) -> dict[str, str]:
    """Write ``fleet.json`` and ``index.html`` of a :class:`~cablesvc.batch.run.FleetResult`."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    doc = result.to_json()
    (out / "fleet.json").write_text(json.dumps(doc, indent=1))
    e = html.escape
    cmd = result.command
    rows = "".join(
        f"<tr><td>{e(str(r['recording']))}</td><td>{e(str(r.get('robot') or ''))}</td>"
        f"<td>{e(str(r.get('start_time') or ''))}</td><td>{e(r['status'])}</td><td class='l'>{_cell(r, cmd)}</td>"
        f"<td>{_secs(r)}</td></tr>"
        for r in result.rows)
    eng = result.engine
    engine = (f"{e(eng.get('engine', ''))}, {eng.get('workers')} worker(s), {eng.get('threads')} thread(s)"
              + (f", scheduler {e(str(eng.get('scheduler')))}" if eng.get("scheduler") else ""))
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>cablesvc {e(cmd)}: fleet</title>
<style>body{{font-family:sans-serif;max-width:75em;margin:auto}}td,th{{padding:2px 8px;text-align:left;vertical-align:top}}
.bad{{color:#b00}}tr:nth-child(even){{background:#f4f4f4}}</style></head><body>
<h1>cablesvc {e(cmd)}: {len(result.rows)} recordings</h1>
<p>{len(result.rows) - len(result.failed)} ok, {len(result.failed)} failed; {engine}; {result.seconds:.1f} s.</p>
<h2>Fleet summary</h2><ul>{''.join(f'<li>{e(x)}</li>' for x in result.summary['lines'])}</ul>
<h2>Recordings</h2><table><tr><th>recording</th><th>robot</th><th>start (UTC)</th><th>status</th><th>result</th><th>s</th></tr>
{rows}</table><p>All numbers: fleet.json.</p></body></html>"""
    (out / "index.html").write_text(page)
    return {"json": str(out / "fleet.json"), "html": str(out / "index.html")}
