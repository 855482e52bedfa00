"""The converged answers of the indenter phantom's refinement studies (the test data,
tests/data/phantom_indenter_reference.json, from bench/bench_indenter_convergence.py) as the
default-accuracy benches use them: which study and level stands for the converged answer at a
push, how well that level is itself known (its GCI bands), a default's differences from it, a
default that is itself a study level read from the data, and the ``[[reference.measured]]``
rows a case file keeps."""
from __future__ import annotations

import json
import math
import textwrap
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = {"indenter": ROOT / "meshes" / "cases" / "phantom-indenter.toml",
         "wide": ROOT / "meshes" / "cases" / "phantom-indenter-wide.toml",
         "control": ROOT / "meshes" / "cases" / "phantom-indenter-control.toml",
         "half": ROOT / "meshes" / "cases" / "phantom-indenter-half.toml",
         "quarter": ROOT / "meshes" / "cases" / "phantom-indenter-quarter.toml"}
STUDIES = {("indenter", "gauss"): ("{load}_gauss", "{load}"), ("indenter", "nodal"): ("{load}",),
           ("half", "gauss"): ("{load}_gauss", "{load}"), ("half", "nodal"): ("{load}",),
           ("quarter", "gauss"): ("{load}_gauss", "{load}"), ("quarter", "nodal"): ("{load}",),
           ("wide", "gauss"): ("{load}_wide",),
           ("control", "gauss"): ("{load}_gauss", "{load}"), ("control", "nodal"): ("{load}",)}
"""Per case and ``--study``: the studies in DATA searched for the push, in order (the tips started
on the skin's nodes; ``SURFACE`` for the curved facets)."""
SURFACE = "_surface"
"""The suffix of a study whose tips start on the skin's curved facets (``tip_start =
"surface"``): a default started there is compared with those studies only."""
DATA = ROOT / "tests" / "data" / "phantom_indenter_reference.json"
LOADS = {"one": ("A1",), "four": ("A1", "A2", "A3", "A4")}
MAX_BAND = 0.1
"""The largest GCI band on the force (relative) of a finest level used as the converged answer."""


def finest(load: str, push: float, study: str = "gauss", case: str = "indenter",
           start: str = "nodes") -> dict | None:
    """The finest level's answer at ``push`` (of the Gauss-rule study where it has the push, its
    tips started as ``start``) and the spread of all levels (relative); None when no study has
    three assessed levels there, when its levels do not contract (the force's last change not
    smaller than the one before) or when the force's GCI band is above MAX_BAND."""
    loads = json.loads(DATA.read_text())["loads"]
    suffix = SURFACE if start == "surface" else ""
    for key in (k.format(load=load) + suffix for k in STUDIES[case, study]):
        entry = next((e for e in loads.get(key, {}).get("pushes", [])
                      if e["push_mm"] == push and e.get("assessed")),   # >= 3 levels
                     None)
        if entry is not None:
            break
    else:
        return None
    force = np.array(entry["force_mN"])
    if abs(force[-1] - force[-2]) >= abs(force[-2] - force[-3]):
        return None         # the levels do not contract: no converged value to compare with
    band = entry.get("quantities", {}).get("force A1", {}).get("gci_rel")
    if band is not None and band > MAX_BAND:
        return None         # contracting, but known only to more than MAX_BAND
    probes = {n: np.array(v) for n, v in entry["probes_mm"].items()}
    spread = {"force": float(np.ptp(force) / abs(force[-1]))}
    for n, v in probes.items():
        spread[n] = float(max(np.linalg.norm(a - v[-1]) for a in v) / np.linalg.norm(v[-1]))
    gci = {q: a.get("gci_rel") for q, a in entry.get("quantities", {}).items()}
    return {"study": key, "rule": loads[key].get("contact_quadrature", "nodal"),
            "level": entry["levels"][-1], "levels": entry["levels"], "valid": entry["valid"],
            "dofs": entry["dofs"][-1], "force": float(force[-1]),
            "probes": {n: v[-1] for n, v in probes.items()}, "spread": spread, "gci": gci}


def study_level(load: str, pushes, study: str, case_name: str, rule,
                start: str | None) -> list[dict] | None:
    """The rows of the case's default along ``pushes`` read from the study data where that
    default is a level of a study (the same unknowns, contact rule and tip start: the half case
    is level 0 of the half's studies), so it is compared without solving it again; None where
    it is not, or where the study lacks a push. The unknowns and cells are counted on the
    default's mesh and must be the level's."""
    from tissue_reference.fem_reference.discretization import default_degree, resolve_formulation
    from tissue_reference.fem_reference.dof_counts import entity_counts, predicted_dofs
    from tissue_reference.model.case import load_case, tip_start_for

    loads = json.loads(DATA.read_text())["loads"]
    keys = [k.format(load=load) + s for k in STUDIES[case_name, study] for s in ("", SURFACE)]
    spec = tomllib.loads(CASES[case_name].read_text())["mesh"]
    lengths = [spec.get(k) for k in ("size", "site_size", "path_size")]
    if not any(all(math.isclose(a, b) if None not in (a, b) else a is b for a, b in
                   zip(lengths, (lv["size_mm"], lv["site_mm"], lv.get("path_mm"))))
               for k in keys for lv in loads.get(k, {}).get("levels", [])):
        return None   # no level meshed at the case's sizes: not worth building its mesh to count
    case = load_case(CASES[case_name])
    rule = rule if rule is not None else (case.reference_contact_quadrature or "nodal")
    start = start or case.reference_tip_start or tip_start_for(rule)
    formulation = resolve_formulation("auto", case.material)
    degree = case.reference_degree or default_degree(case, formulation)
    dofs = predicted_dofs(entity_counts(case.mesh), case.mesh.gdim, degree, formulation)
    suffix = SURFACE if start == "surface" else ""
    for key in (k.format(load=load) + suffix for k in STUDIES[case_name, study]):
        data = loads.get(key)
        if data is None or data.get("contact_quadrature", "nodal") != rule \
                or data["degree"] != degree:
            continue
        rows = []
        for push in pushes:
            entry = next((e for e in data["pushes"] if e["push_mm"] == push), None)
            if entry is None or dofs not in entry["dofs"]:
                break
            i = entry["dofs"].index(dofs)
            level = next(lv for lv in data["levels"] if lv["level"] == entry["levels"][i])
            if level["cells"] != case.mesh.n_cells:
                break
            rows.append({"push": push, "reached": push, "degree": degree, "rule": rule,
                         "start": start, "cells": case.mesh.n_cells, "dofs": dofs,
                         "converged": True, "valid": entry["valid"][i],
                         "why": entry["why_invalid"][i], "min_J": None,
                         "force": entry["force_mN"][i],   # the whole tip's, as solve's
                         "probes": {n: np.asarray(v[i]) for n, v in entry["probes_mm"].items()},
                         "newton": entry["newton"][i], "wall_s": entry["wall_s"][i],
                         "level": entry["levels"][i], "study": key})
        else:
            print(f"  [{load}: the default is level {rows[0]['level']} of {key} ({dofs} "
                  f"unknowns, rule {rule}, tips started on the {start}): its answers are the "
                  f"study data's, not solved again]", flush=True)
            return rows
    return None


def measured_row(load: str, push: float, r: dict, e: dict, ref: dict | None,
                 case_rule, case_pin: str | None, actuators=None) -> str:
    """The ``[[reference.measured]]`` table (TOML) of the default's answer ``r`` with its
    differences ``e`` from the converged answer ``ref`` (or, without one, converged = false);
    its contact rule where it is not the case's (``case_rule``) and its tip start where a row
    would not take it by default: the case's ``[reference] tip_start`` (``case_pin``), else the
    start of the row's rule (``fem_reference.measured`` reads rows so). ``actuators``: the
    case's actuator names, where a mirror plane leaves it fewer than the whole phantom's."""
    from tissue_reference.model.case import tip_start_for

    lines = ["[[reference.measured]]",
             "pushes = {" + ", ".join(f"{a} = {push:g}" for a in LOADS[load]
                                      if actuators is None or a in actuators) + "}",
             f"dofs = {r['dofs']}"]
    if r["rule"] != (case_rule or "nodal"):
        lines.append(f"contact_quadrature = {json.dumps(r['rule'])}")
    if r["start"] != (case_pin or tip_start_for(r["rule"])):
        lines.append(f"tip_start = {json.dumps(r['start'])}")
    if ref is None:
        lines += ["converged = false", 'why = "no study converges at this push"']
    elif (r["dofs"], r["rule"]) == (ref["dofs"], ref["rule"]):
        # the default is the study's finest level (same mesh, rule and start): its distance
        # from the converged value is that level's GCI bands, not a difference from itself
        force, probes = bands(ref)
        against = f"the GCI bands of tests/data/{DATA.name} {ref['study']} level " \
                  f"{ref['level']} ({ref['dofs']} dofs), which this discretization is"
        lines += [f"force = {force:.4f}", f"probes = {probes:.4f}", _toml_text(against)]
    else:
        force, probes = bands(ref)
        known = "" if force is None else \
            f", itself within {100 * force:.1f} % (force) and {100 * (probes or 0.0):.1f} % " \
            f"(targets) of the converged value by its GCI bands"
        against = f"tests/data/{DATA.name} {ref['study']} level {ref['level']} " \
                  f"({ref['dofs']} dofs){known}"
        lines += [f"force = {e['force']:.4f}",
                  f"probes = {max(v for k, v in e.items() if k != 'force'):.4f}",
                  _toml_text(against)]
    return "\n".join(lines)


def _toml_text(against: str) -> str:
    """``against = ...`` as a multi-line TOML string whose line-ending backslashes join the
    lines (wrapped at 92)."""
    return 'against = """\\\n' + " \\\n".join(textwrap.wrap(against, 92)) + '"""'


def bands(ref: dict) -> tuple[float | None, float | None]:
    """How well the converged answer ``ref`` itself is known: its force's GCI band and the
    targets' worst (each target's components' bands combined as its displacement's norm is,
    relative to it); None where the study gives no band."""
    gci = ref["gci"]
    worst = None
    for name, u in ref["probes"].items():
        parts = [gci.get(f"{name} u{'xyz'[i]}") for i in range(len(u))]
        if any(p is not None for p in parts):
            band = np.linalg.norm([(p or 0.0) * abs(c) for p, c in zip(parts, u)])
            worst = max(worst or 0.0, float(band / np.linalg.norm(u)))
    return gci.get("force A1"), worst


def errors(row: dict, ref: dict) -> dict:
    out = {"force": abs(row["force"] - ref["force"]) / abs(ref["force"])}
    for n, v in ref["probes"].items():
        out[n] = float(np.linalg.norm(row["probes"][n] - v) / np.linalg.norm(v))
    return out
