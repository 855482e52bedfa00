"""Refinement study of the seed-scale phantom (meshes/cases/phantom-seed.toml: four rigid rounded
flat punches of radius 15 mm, Neo-Hookean E = 6 kPa, nu = 0.45, base fixed, Gauss contact rule of
degree 2): one actuator pushed alone along one warm-started load path (default A1 at 5, 10 and
15 mm), solved on the case's builtin remeshed with every cell size of its ``[mesh]`` table (size
6 mm, site_size 3 mm) divided by sqrt 2 per level (level 0: the case's own mesh; negative levels
are coarser: level -2 has size 12 mm and 6 mm sites; a level may be fractional, level -0.5 has
every size times 2^(1/4)). The whole levels are those of ``tissue converge phantom-seed
--levels-by remesh`` (level k there is level k here), which solves every push from rest and starts
at level 0; this script starts coarser, so that a P2 study whose finest level is the case's own
mesh (64k unknowns, 1.5-2 min per push on a shared core) fits a run; the shipped study adds
level 1 (167k unknowns, 5.5-7.5 min per push). Level -3 (17 mm, 8.5 mm sites) is too coarse for
P2: the heads' penetration check cannot map its points into its curved cells (dolfinx's
pull-back fails).

``--defaults`` solves the case's own mesh and contact rule at ``--degree`` (P2 is the case's
default; P1 its former one), each of ``--actuators`` alone along one warm-started load path:
``DIR/defaults-P{degree}.json``. ``--summarize --data`` compares those answers with the study's
finest level (A2..A4 against A1's turned) and prints the case file's ``[[reference.measured]]``
rows, one per actuator, push and degree; at P2, A1's answers are the study's level 0 (the same
mesh and degree) unless given. ``--from-data`` does so from the data file's own study and
answers, with the answers under ``DIR`` added.

The body, the heads and the targets turn into each other under rotations by 90 degrees about the
dome's axis (A1 -> A2 -> A3 -> A4 and T2 -> T3 -> T4 -> T5; the mesh itself is not symmetric),
so the converged answer of A1 alone, rotated, is that of A2, A3 or A4 alone. ``--rotation``
checks it on one level: the actuator's answers against A1's of the same level, rotated.

Per level (``--level K``): ``DIR/{ACT}-P{degree}-level{K}.json``: the cells and unknowns, and per
push the A1 force (mN, the pushed head's), the targets' displacements (mm), validity, Newton
iterations and wall time. ``--summarize`` assesses each quantity over the levels
(``fem_reference.richardson.assess``: observed orders, asymptotic-range check, Richardson value
only when asymptotic, GCI band otherwise; h the site cells' size) and writes
``DIR/{ACT}-P{degree}-summary.json``, the format of tests/data/phantom_seed_reference.json's
studies: per push the levels' values, each quantity's assessment, and the finest level's bands
(the force's GCI and, per target, its components' GCI combined as its displacement's norm is,
relative to it: ``bench/study_answers.py``'s ``bands``). Target components under 5 % of the
target's displacement on the finest level are not assessed: those the mirror plane y = 0 makes
zero are the mesh's asymmetry, not a converging quantity (T4's u_z, 2-5 %, is left out too).

    .venv/bin/python bench/bench_seed_convergence.py --level K [--degree 2] [--actuator A1]
        [--pushes 5 10 15] --out DIR            (the shipped study: each K of -2 -1 0 1)
    .venv/bin/python bench/bench_seed_convergence.py --defaults --degree 1|2 [--actuators A2 A3 A4]
        --out DIR
    .venv/bin/python bench/bench_seed_convergence.py --summarize [--levels -2 -1 0 1] --out DIR
        [--data tests/data/phantom_seed_reference.json]
    .venv/bin/python bench/bench_seed_convergence.py --summarize --from-data
        --data tests/data/phantom_seed_reference.json --out DIR
    .venv/bin/python bench/bench_seed_convergence.py --rotation A2 --level -2 --out DIR
    .venv/bin/python bench/bench_seed_convergence.py --level-rows -1
        --data tests/data/phantom_seed_reference.json --out DIR

``--level-rows K`` prints the case file rows of a case meshed as level K
(meshes/cases/phantom-seed-coarse.toml: level -1): A1's answers are the study's at that level,
A2..A4's the rotation checks' there (``--rotation ACT --level K`` for each, then
``--summarize --from-data`` to keep them in the data file).
"""
from __future__ import annotations

import argparse
import json
import math
import textwrap
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom-seed.toml"
RATIO = math.sqrt(2.0)
PROBES = ("T1", "T2", "T3", "T4", "T5")
COMPONENT_FLOOR = 0.05
"""Target components below this fraction of the target's displacement (finest level) are not
assessed: zero by the mirror plane y = 0 of a single push, their values are the mesh's
asymmetry."""
TURN = {"A1": 0, "A2": 1, "A3": 2, "A4": 3}
"""Quarter turns about the dome's axis (z) that take A1 to each actuator."""
TARGET_TURN = {"T1": "T1", "T2": "T3", "T3": "T4", "T4": "T5", "T5": "T2"}
"""Where a quarter turn takes each target (T2 faces A1, T3 A2, T4 A3, T5 A4)."""


def level_lengths(k: float) -> dict:
    """The case's ``[mesh]`` cell sizes (mm) divided by sqrt 2^k."""
    table = tomllib.loads(CASE.read_text())["mesh"]
    return {"size": table["size"] / RATIO ** k, "site_size": table["site_size"] / RATIO ** k}


def level_case(k: float):
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    lengths = level_lengths(k)
    builtin = tomllib.loads(CASE.read_text())["mesh"]["builtin"]
    mesh = build(builtin, lengths["size"], site_size=lengths["site_size"])
    return load_case(CASE, mesh=mesh), lengths


def run_level(k: float, degree: int, actuator: str, pushes, out: Path) -> Path:
    """Level ``k`` at ``degree`` along one warm-started load path of ``actuator``; the level's
    JSON is rewritten after every push, so a long run keeps what it reached."""
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.fem_reference.solver import ReferenceSolver
    from tissue_reference.model.results import write_json

    case, lengths = level_case(k)
    solver = ReferenceSolver(case, degree=degree)
    doc = {"level": k, "degree": degree, "actuator": actuator, "size_mm": lengths["size"],
           "site_mm": lengths["site_size"], "cells": case.mesh.n_cells,
           "contact_quadrature": case.reference_contact_quadrature, "pushes": []}
    path = level_path(out, actuator, degree, k)
    prev = None
    for p in pushes:
        t0 = time.perf_counter()
        try:
            r = solver.solve({actuator: float(p)}, initial=prev)
        except ConvergenceError as exc:
            print(f"level {k}, {actuator} = {p:g} mm: {exc}", flush=True)
            break
        prev = r
        row = {"push": float(p), "dofs": int(r.discretization["dofs"]),
               "force_mN": float(r.indenters[actuator]["force"]),
               "probes": {n: [float(x) for x in r.probes[n]] for n in PROBES},
               "valid": bool(r.valid), "why": r.invalid_reason, "newton": int(r.iterations),
               "wall_s": time.perf_counter() - t0}
        doc["pushes"].append(row)
        write_json(doc, path)
        print(f"level {k} ({case.mesh.n_cells} cells, {row['dofs']} dofs), {actuator} = {p:g} "
              f"mm: force {row['force_mN']:.6g} mN, {row['newton']} Newton, "
              f"{row['wall_s']:.1f} s, valid {row['valid']}", flush=True)
    solver.close()
    return path


def target_bands(quantities: dict, probes: dict) -> dict:
    """Per target: its components' GCI bands (absolute) combined as its displacement's norm,
    relative to that norm (the finest level's ``probes``)."""
    out = {}
    for n, u in probes.items():
        parts = [quantities.get(f"{n} u{'xyz'[i]}", {}).get("gci_mm") or 0.0
                 for i in range(3)]
        out[n] = float(np.linalg.norm(parts) / np.linalg.norm(u))
    return out


def level_path(out: Path, actuator: str, degree: int, k: float) -> Path:
    return out / f"{actuator}-P{degree}-level{k:g}.json"


def summarize(out: Path, degree: int, actuator: str, levels=None) -> dict:
    """Assess ``levels`` (default: every level of ``actuator`` at ``degree`` under ``out``),
    which must be equally spaced: their ratio is sqrt 2 ^ spacing."""
    from tissue_reference.fem_reference.richardson import assess
    from tissue_reference.model.results import write_json

    docs = sorted((json.loads(f.read_text())
                   for f in out.glob(f"{actuator}-P{degree}-level*.json")),
                  key=lambda d: d["level"])
    if levels is not None:
        docs = [d for d in docs if any(math.isclose(d["level"], k) for k in levels)]
    if len(docs) < 3:
        raise SystemExit(f"{out}: {len(docs)} levels of {actuator} at P{degree}; a study "
                         f"needs 3")
    steps = np.diff([d["level"] for d in docs])
    if not np.allclose(steps, steps[0]):
        raise SystemExit(f"levels {[d['level'] for d in docs]} are not equally spaced")
    ratio = RATIO ** float(steps[0])
    summary = {"actuator": actuator, "degree": degree, "ratio": ratio,
               "contact_quadrature": docs[0]["contact_quadrature"],
               "component_floor": COMPONENT_FLOOR,
               "levels": [{k: d[k] for k in ("level", "size_mm", "site_mm", "cells")}
                          for d in docs], "pushes": []}
    pushes = sorted({r["push"] for d in docs for r in d["pushes"]})
    for p in pushes:
        have = [(d, next(r for r in d["pushes"] if r["push"] == p)) for d in docs
                if any(r["push"] == p for r in d["pushes"])]
        entry = {"push_mm": p, "levels": [d["level"] for d, _ in have],
                 "dofs": [r["dofs"] for _, r in have], "valid": [r["valid"] for _, r in have],
                 "newton": [r["newton"] for _, r in have],
                 "wall_s": [r["wall_s"] for _, r in have],
                 "force_mN": [r["force_mN"] for _, r in have],
                 "probes_mm": {n: [r["probes"][n] for _, r in have] for n in PROBES},
                 "quantities": {}, "assessed": len(have) >= 3}
        summary["pushes"].append(entry)
        print(f"\n{actuator} = {p:g} mm, P{degree}: levels {entry['levels']}, unknowns "
              f"{entry['dofs']}, valid {entry['valid']}, Newton {entry['newton']}, wall "
              f"{[round(w) for w in entry['wall_s']]} s")
        if not entry["assessed"]:
            continue
        h = [d["site_mm"] for d, _ in have]
        quantities = [(f"force {actuator}", "mN", entry["force_mN"])]
        for n in PROBES:
            vals = np.array(entry["probes_mm"][n])
            for c, axis in enumerate("xyz"):
                if abs(vals[-1, c]) >= COMPONENT_FLOOR * np.linalg.norm(vals[-1]):
                    quantities.append((f"{n} u{axis}", "mm", list(vals[:, c])))
        print(f"  {'quantity':>9} " + " ".join(f"{'L' + str(k):>10}" for k in entry["levels"])
              + f" {'orders':>12} {'asym':>5} {'extrap':>10} {'GCI rel':>8}")
        for qname, unit, vals in quantities:
            a = assess(vals, h, expected_order=degree + 1 if unit == "mm" else 2 * degree,
                       ratio=ratio, name=qname, unit=unit)
            entry["quantities"][qname] = a.to_json_dict()
            orders = "/".join("-" if o is None else f"{o:.2f}" for o in a.orders)
            ext = "-" if a.extrapolated is None else f"{a.extrapolated:.4f}"
            rel = "-" if a.gci_rel is None else f"{100 * a.gci_rel:.2f}%"
            print(f"  {qname:>9} " + " ".join(f"{v:10.4f}" for v in vals)
                  + f" {orders:>12} {a.asymptotic!s:>5} {ext:>10} {rel:>8}")
        tb = target_bands(entry["quantities"], {n: v[-1] for n, v in
                                                entry["probes_mm"].items()})
        force_band = entry["quantities"][f"force {actuator}"]["gci_rel"]
        entry["bands"] = {"force": force_band, "targets": tb, "probes": max(tb.values())}
        print(f"  finest level's bands: force {100 * force_band:.2f} %, targets "
              + ", ".join(f"{n} {100 * v:.2f} %" for n, v in tb.items()))
    tag = "" if levels is None else "-" + "_".join(f"{k:g}" for k in levels)
    path = out / f"{actuator}-P{degree}-summary{tag}.json"
    write_json(summary, path)
    print(f"\nsummary: {path}")
    return summary


def rotate(u, turns: int) -> np.ndarray:
    """``u`` (x, y, z) turned by ``turns`` quarter turns about z."""
    u = np.asarray(u, dtype=float)
    for _ in range(turns % 4):
        u = np.array([-u[1], u[0], u[2]])
    return u


def rotated_targets(probes: dict, turns: int) -> dict:
    """A1's target displacements turned by ``turns`` quarter turns: the answer of the actuator
    ``turns`` quarter turns on, by target name."""
    out = dict(probes)
    for _ in range(turns % 4):
        out = {TARGET_TURN[n]: rotate(u, 1) for n, u in out.items()}
    return out


def rotation_check(out: Path, degree: int, actuator: str, k: int) -> None:
    """``actuator``'s answers on level ``k`` against A1's of the same level, rotated: the
    relative force difference and each target's |u - R u_A1| / |u_A1|."""
    a1 = json.loads(level_path(out, "A1", degree, k).read_text())
    other = json.loads(level_path(out, actuator, degree, k).read_text())
    for r in other["pushes"]:
        ref = next(x for x in a1["pushes"] if x["push"] == r["push"])
        turned = rotated_targets(ref["probes"], TURN[actuator])
        df = abs(r["force_mN"] - ref["force_mN"]) / abs(ref["force_mN"])
        dt = {n: float(np.linalg.norm(np.asarray(r["probes"][n]) - turned[n])
                       / np.linalg.norm(turned[n])) for n in PROBES}
        print(f"level {k}, P{degree}, {actuator} = {r['push']:g} mm against A1 rotated: force "
              f"{r['force_mN']:.5g} / {ref['force_mN']:.5g} mN ({100 * df:.2f} %), targets "
              + ", ".join(f"{n} {100 * v:.2f} %" for n, v in dt.items()))


def run_defaults(out: Path, pushes, degree: int | None = None, actuators=tuple(TURN)) -> Path:
    """The case's own mesh and contact rule (what ``tissue solve phantom-seed`` solves) at
    ``degree`` (None: the case's default degree) for each of ``actuators`` alone along one
    warm-started load path: ``DIR/defaults-P{degree}.json``."""
    from tissue_reference.fem_reference.solver import ReferenceSolver
    from tissue_reference.model.case import load_case
    from tissue_reference.model.results import write_json

    case = load_case(CASE)
    solver = ReferenceSolver(case, degree=degree)
    doc = {"degree": solver.degree, "cells": case.mesh.n_cells,
           "contact_quadrature": case.reference_contact_quadrature, "answers": {}}
    path = out / f"defaults-P{solver.degree}.json"
    for act in actuators:
        prev, rows = None, []
        for p in pushes:
            t0 = time.perf_counter()
            r = solver.solve({act: float(p)}, initial=prev)
            prev = r
            doc["dofs"] = int(r.discretization["dofs"])
            rows.append({"push": float(p), "force_mN": float(r.indenters[act]["force"]),
                         "probes": {n: [float(x) for x in r.probes[n]] for n in PROBES},
                         "valid": bool(r.valid), "newton": int(r.iterations),
                         "wall_s": time.perf_counter() - t0})
            print(f"default P{solver.degree} ({doc['dofs']} dofs), {act} = {p:g} mm: force "
                  f"{rows[-1]['force_mN']:.6g} mN, {rows[-1]['wall_s']:.1f} s", flush=True)
            doc["answers"][act] = rows
            write_json(doc, path)   # rewritten after every push: a long run keeps what it reached
    solver.close()
    return path


def distance(force: float, probes: dict, entry: dict, turns: int) -> dict:
    """An answer's relative distance from the finest level of a study ``entry`` (A1's), turned
    by ``turns`` quarter turns: the force's and each target's |u - R u_ref| / |R u_ref|."""
    ref = rotated_targets({n: v[-1] for n, v in entry["probes_mm"].items()}, turns)
    out = {"force": abs(force / entry["force_mN"][-1] - 1.0)}
    out.update({n: float(np.linalg.norm(np.asarray(probes[n]) - ref[n])
                         / np.linalg.norm(ref[n])) for n in PROBES})
    return out


def _row(act: str, push: float, dofs: int, degree: int, d: dict, entry: dict,
         against: str) -> str:
    """A ``[[reference.measured]]`` table (TOML): the distance ``d`` of an answer on the case's
    mesh at ``degree`` from the finest level ``entry`` of the study, with that level's bands."""
    worst = max(v for k, v in d.items() if k != "force")
    band = entry["bands"]
    against += (f", itself within {100 * band['force']:.1f} % (force) and "
                f"{100 * band['probes']:.1f} % (targets) of the converged value by its GCI "
                f"bands")
    return "\n".join([
        "[[reference.measured]]", f"pushes = {{{act} = {push:g}}}", f"dofs = {dofs}",
        f"degree = {degree}", f"force = {d['force']:.4f}", f"probes = {worst:.4f}",
        (f"band = {{force = {band['force']:.4f}, probes = {band['probes']:.4f}}}"
         "  # the finest level's GCI bands"),
        'against = """\\\n' + " \\\n".join(textwrap.wrap(against, 92)) + '"""'])


def _against(path: Path, entry: dict, turns: int) -> str:
    """What a row's answer is measured against: the finest level of the study ``entry`` in the
    data file ``path``, turned by ``turns`` quarter turns for A2..A4 (``_row`` adds its
    bands)."""
    turned = "" if turns == 0 else (
        f", turned by {90 * turns} degrees about the dome's axis (the case is symmetric under "
        f"quarter turns; its mesh is not)")
    return (f"tests/data/{path.name} A1 P2 level {entry['levels'][-1]:g} "
            f"({entry['dofs'][-1]} dofs){turned}")


def load_defaults(out: Path, data: dict | None = None) -> dict:
    """The answers on the case's own mesh by degree ("P1", "P2"; ``run_defaults``): those of
    the data file ``data`` where given, each actuator's replaced by or added from the
    ``defaults-P{degree}.json`` under ``out``."""
    found = {k: dict(v) for k, v in (data or {}).get("defaults", {}).items()}
    for f in sorted(out.glob("defaults-P*.json")):
        doc = json.loads(f.read_text())
        key = f"P{doc['degree']}"
        old = found.get(key, {"answers": {}})
        if old.get("dofs", doc["dofs"]) != doc["dofs"]:
            raise SystemExit(f"{f}: {doc['dofs']} unknowns, the data's {key} answers "
                             f"{old['dofs']}")
        found[key] = {**old, **doc, "answers": {**old["answers"], **doc["answers"]}}
    return found


def rotation_checks(out: Path) -> dict:
    """Each other actuator solved on a study level under ``out`` against A1 there, turned."""
    rotation = {}
    for f in sorted(out.glob("A[234]-P*-level*.json")):
        other = json.loads(f.read_text())
        a1 = json.loads(level_path(out, "A1", other["degree"], other["level"]).read_text())
        for r in other["pushes"]:
            ref = next(x for x in a1["pushes"] if x["push"] == r["push"])
            entry = {"push_mm": r["push"], "force_mN": [ref["force_mN"]],
                     "probes_mm": {n: [v] for n, v in ref["probes"].items()}}
            rotation.setdefault(f"{other['actuator']} P{other['degree']} level "
                                f"{other['level']:g}", []).append(
                {"push_mm": r["push"], "force_mN": r["force_mN"],
                 "probes_mm": r["probes"], "distance_from_A1_turned":
                     distance(r["force_mN"], r["probes"], entry, TURN[other["actuator"]])})
    return rotation


def write_data(out: Path, summary: dict, path: Path, data: dict | None = None) -> None:
    """The test data (``path``): the study's summary; the answers on the case's own mesh at
    P1 and P2 (``load_defaults``: under ``out``, and those of ``data``, the data file as it
    was, where given) and their distance from the study's finest level (A2..A4 against A1's
    turned; A1 at P2 is the study's level 0 where no answer of it is given); the rotation
    checks (under ``out``, else ``data``'s); and the case file's ``[[reference.measured]]``
    rows, printed."""
    from tissue_reference.model.results import write_json

    defaults = load_defaults(out, data)
    if "P2" in defaults or summary["degree"] == 2:
        level0 = {"dofs": None, "answers": {}}
        for entry in summary["pushes"]:   # the study's level 0 is the case's mesh at P2
            if summary["degree"] == 2 and 0 in entry["levels"][:-1]:
                i = entry["levels"].index(0)
                level0["dofs"] = entry["dofs"][i]
                level0["answers"].setdefault("A1", []).append(
                    {"push": entry["push_mm"], "force_mN": entry["force_mN"][i],
                     "probes": {n: v[i] for n, v in entry["probes_mm"].items()},
                     "valid": entry["valid"][i], "newton": entry["newton"][i],
                     "wall_s": entry["wall_s"][i], "from": "the study's level 0"})
        p2 = defaults.get("P2", {"degree": 2, "answers": {}})
        if level0["dofs"] is not None and "A1" not in p2["answers"]:
            if p2.get("dofs", level0["dofs"]) != level0["dofs"]:
                raise SystemExit(f"P2 on the case's mesh has {p2['dofs']} unknowns, the "
                                 f"study's level 0 {level0['dofs']}")
            defaults["P2"] = {**p2, "dofs": level0["dofs"],
                              "answers": {**level0["answers"], **p2["answers"]}}
    rows, measured = [], {}
    for key in sorted(defaults):
        doc = defaults[key]
        for act, turns in TURN.items():
            for a in doc["answers"].get(act, ()):
                entry = next(e for e in summary["pushes"] if e["push_mm"] == a["push"])
                d = distance(a["force_mN"], a["probes"], entry, turns)
                measured.setdefault(key, {}).setdefault(act, []).append(
                    {"push_mm": a["push"], **d})
                rows.append(_row(act, a["push"], doc["dofs"], doc["degree"], d, entry,
                                 _against(path, entry, turns)))
    rotation = {**(data or {}).get("rotation_checks", {}), **rotation_checks(out)}
    levels = " ".join(f"{lv['level']:g}" for lv in summary["levels"])
    write_json({
        "description": (
            "The seed-scale phantom (meshes/cases/phantom-seed.toml: four rigid rounded flat "
            "punches of radius 15 mm, frictionless penalty contact sampled at Gauss points of "
            "degree 2, Neo-Hookean E = 6 kPa, nu = 0.45, base fixed), A1 alone along one "
            "warm-started load path, solved by this project's reference at P2 on the case's "
            "builtin remeshed with every cell size divided by sqrt 2 per level (level 0: the "
            "case's own mesh, size 6 mm, 3 mm sites). 'study': per push the levels' A1 force "
            "(mN) and targets (mm), each quantity's assessment (observed orders, asymptotic-range "
            "check, GCI band; fem_reference.richardson) and the finest level's bands. "
            "'defaults': the case's own mesh and contact rule at P1 ('P1', A1..A4) and at P2 "
            "('P2', the case's default degree: A2..A4 solved, A1 the study's level 0) for each "
            "actuator alone along one warm-started load path; 'defaults_vs_finest': their "
            "relative distance from the finest level (A2..A4 from A1's turned by quarter turns "
            "about the dome's axis, under which the case, not its mesh, is symmetric); "
            "'rotation_checks': another actuator on a study level against A1 there, turned. "
            "These are this project's answers, not independent ones."),
        "command": (f"python bench/bench_seed_convergence.py --level L --out DIR for L in "
                    f"{levels}; --defaults --degree 1 --out DIR; --defaults --degree 2 "
                    f"--actuators A2 A3 A4 --out DIR; --rotation A2 --level "
                    f"{summary['levels'][0]['level']:g} --out DIR; --summarize --levels {levels} "
                    f"--data {path.name} --out DIR (from this file's own study and the answers "
                    f"on the case's mesh under DIR: --summarize --from-data --data {path.name} "
                    f"--out DIR)"),
        "study": summary, "defaults": defaults, "defaults_vs_finest": measured,
        "rotation_checks": rotation}, path)
    print("\n\n".join(rows))
    print(f"\nwrote {path}")


def level_rows(data: dict, level: float, path: Path) -> list[str]:
    """The ``[[reference.measured]]`` rows of a case whose mesh is the study's ``level`` at P2
    (meshes/cases/phantom-seed-coarse.toml is level -1): A1's answers are the study's own at
    that level, A2..A4's the rotation checks' there (``--rotation ACT --level K``), each
    against the study's finest level (turned for A2..A4), with that level's bands."""
    study = data["study"]
    first = study["pushes"][0]
    level_dofs = first["dofs"][first["levels"].index(level)]
    rows = []
    for act, turns in TURN.items():
        if act == "A1":
            answers = []
            for entry in study["pushes"]:
                i = entry["levels"].index(level)
                answers.append((entry["dofs"][i], entry["push_mm"], entry["force_mN"][i],
                                {n: v[i] for n, v in entry["probes_mm"].items()}))
        else:
            key = f"{act} P2 level {level:g}"
            if key not in data.get("rotation_checks", {}):
                raise SystemExit(f"{path}: no rotation check {key!r}: run --rotation {act} "
                                 f"--level {level:g}, then --summarize --from-data")
            answers = [(level_dofs, r["push_mm"], r["force_mN"], r["probes_mm"])
                       for r in data["rotation_checks"][key]]
        for dofs, push, force, probes in answers:
            entry = next(e for e in study["pushes"] if e["push_mm"] == push)
            rows.append(_row(act, push, dofs, 2, distance(force, probes, entry, turns), entry,
                             _against(path, entry, turns)))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", type=float, default=None)
    ap.add_argument("--levels", type=float, nargs="+", default=None,
                    help="--summarize: the levels assessed (equally spaced; default: all)")
    ap.add_argument("--degree", type=int, default=2, choices=(1, 2))
    ap.add_argument("--actuator", default="A1", choices=tuple(TURN))
    ap.add_argument("--actuators", nargs="+", default=list(TURN), choices=tuple(TURN),
                    help="--defaults: the actuators solved, each alone (default: all four)")
    ap.add_argument("--pushes", type=float, nargs="+", default=[5.0, 10.0, 15.0])
    ap.add_argument("--summarize", action="store_true")
    ap.add_argument("--rotation", choices=("A2", "A3", "A4"), default=None,
                    help="solve this actuator on --level (unless its JSON is there) and "
                         "compare it with A1's answers there, rotated")
    ap.add_argument("--defaults", action="store_true",
                    help="solve the case's own mesh and contact rule at --degree for each of "
                         "--actuators alone along --pushes")
    ap.add_argument("--data", type=Path, default=None,
                    help="--summarize: also write the test data file and print the case "
                         "file's rows (needs --defaults' answers under --out)")
    ap.add_argument("--from-data", action="store_true",
                    help="--summarize: take the study and the rotation checks from the --data "
                         "file itself (its levels' answers), adding or replacing the answers on "
                         "the case's mesh under --out (--defaults'), and write it again")
    ap.add_argument("--level-rows", type=float, default=None, metavar="K",
                    help="print the [[reference.measured]] rows of a case meshed as the "
                         "study's level K at P2, from the --data file")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.level_rows is not None:
        if args.data is None:
            raise SystemExit("--level-rows needs --data")
        print("\n\n".join(level_rows(json.loads(args.data.read_text()), args.level_rows,
                                     args.data)))
    elif args.summarize and args.from_data:
        if args.data is None:
            raise SystemExit("--from-data needs --data")
        data = json.loads(args.data.read_text())
        write_data(args.out, data["study"], args.data, data)
    elif args.summarize:
        summary = summarize(args.out, args.degree, args.actuator, args.levels)
        if args.data is not None:
            write_data(args.out, summary, args.data)
    elif args.defaults:
        run_defaults(args.out, args.pushes, args.degree, args.actuators)
    elif args.rotation:
        if args.level is None:
            raise SystemExit("--rotation needs --level")
        for act in ("A1", args.rotation):
            if not level_path(args.out, act, args.degree, args.level).exists():
                run_level(args.level, args.degree, act, args.pushes, args.out)
        rotation_check(args.out, args.degree, args.rotation, args.level)
    elif args.level is not None:
        run_level(args.level, args.degree, args.actuator, args.pushes, args.out)
    else:
        raise SystemExit("give --level K, --summarize or --rotation ACT --level K")


if __name__ == "__main__":
    main()
