"""The verification suite's scorecard as one HTML page: per problem its expected value and
source, and per solver the value, relative error, pass / fail / refused, time and iterations."""
from __future__ import annotations

import html
from pathlib import Path

from tissue_reference.meshes.io import atomic_path

__all__ = ["write_scorecard"]

_STYLE = ("body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;margin:1em 0}"
          "td,th{border:1px solid #999;padding:3px 8px;text-align:right}th{background:#eee}"
          ".pass{background:#dfd}.fail{background:#fdd}.refused{background:#eee;color:#555}"
          "td.l{text-align:left}")


def result_cell(r) -> str:
    if "refused" in r:
        return f"<td class='refused' title='{html.escape(r['refused'])}'>refused</td>"
    if "error" in r:
        return f"<td class='fail' title='{html.escape(r['error'])}'>error</td>"
    cls = "pass" if r["passed"] else "fail"
    return (f"<td class='{cls}'>{r['value_mm']:.6g} mm<br>{r['error_rel']:.2e} rel<br>"
            f"{r['wall_time_s']:.2f} s, "
            + (f"{r['iterations']} its" if r.get("iterations") is not None
               else "iterations not reported") + "</td>")


def write_scorecard(out: dict, out_dir) -> Path:
    """Write ``out_dir``/suite.html (whole or not at all) and return its path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    solvers = list(out["summary"])
    head = "".join(f"<th>{html.escape(s)}</th>" for s in solvers)
    rows = []
    for p in out["problems"]:
        rows.append(
            f"<tr><td class='l'><b>{html.escape(p['name'])}</b><br>"
            f"{html.escape(p['description'])}</td><td>{p['expected_mm']:.6g} mm<br>"
            f"<small>{html.escape(p['source'])}</small></td><td>{p['tolerance_rel']:g}</td>"
            + "".join(result_cell(p["results"][s]) for s in solvers) + "</tr>")
    summary = "".join(
        f"<tr><td class='l'>{html.escape(s)}</td><td>{v['passed']}</td><td>{v['failed']}</td>"
        f"<td>{v['refused']}</td></tr>" for s, v in out["summary"].items())
    page = "\n".join([
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>tissue suite</title>",
        f"<style>{_STYLE}</style></head><body>",
        "<h1>Verification suite</h1>",
        ("<p>Each problem's expected value is known without finite elements (closed form, ODE "
         "solve or published figure). A solver passes when its relative error is within the "
         "tolerance; it runs on the problem's own mesh, so a P1 solver's score includes its "
         "discretization error. Hover over <i>refused</i> / <i>error</i> for the message.</p>"),
        ("<h2>Summary</h2><table><tr><th>solver</th><th>passed</th><th>failed</th>"
         f"<th>refused</th></tr>{summary}</table>"),
        "<h2>Problems</h2>",
        f"<table><tr><th>problem</th><th>expected</th><th>tolerance (rel)</th>{head}</tr>"
        + "".join(rows) + "</table>",
        "</body></html>"])
    path = out_dir / "suite.html"
    with atomic_path(path) as tmp:
        tmp.write_text(page + "\n")
    return path
