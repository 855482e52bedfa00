"""Convergence of the indenter phantom's answers at the seed's pushes (5, 10, 15 mm): P2 on the
phantom's symmetric part, remeshed with every cell size divided by sqrt 2 per level.

A1 alone (``--load one``) is symmetric about y = 0: the half phantom
(meshes/cases/phantom-indenter-half.toml); all four equal (``--load four``) about x = 0 and
y = 0: the quarter (phantom-indenter-quarter.toml). Level k has characteristic size 6 / 2^(k/2)
mm and sites 3.2 / 2^(k/2) mm; ``--path RATIO`` refines each tip's path into the tissue further
(cells of RATIO x the site size within 6 mm of the axis, 20 mm deep) and ``--base-rim RATIO``
the base rim, where the fixed base meets the free dome; ``--path-reach MM`` widens the refined
path (default 6 mm). Each level's pushes are
one warm-started load path; after every push the level's JSON (``--out``) is rewritten whole, so
a long run keeps what it reached.

Per push and level: validity (the skin may not pass inside the tip), the skin's deepest point
inside the tip (mm), the whole phantom's A1 force (mN: twice the cut tip's), T1..T4 (mm), Newton
iterations and wall time. The summary assesses each quantity over the levels
(``fem_reference.richardson.assess``: observed order, asymptotic-range check, Richardson value
only when asymptotic, GCI band otherwise) and states the finest level's value with that band.

    .venv/bin/python bench/bench_indenter_convergence.py --load one --level 0 --out out/conv
    .venv/bin/python bench/bench_indenter_convergence.py --load one --summarize --out out/conv
    (no --level and no --summarize: every level in turn, then the summary)

A study of the test data extends by a finer level without rerunning its coarser ones: run the
new level into an empty directory, then ``--summarize --with-study NAME`` writes the levels of
``NAME`` (tests/data/phantom_indenter_reference.json) beside it, after checking that they were
solved with the new level's settings, and assesses them all. A level the study has already (at
fewer pushes, say) is replaced by the new run of it, which must reproduce the study's forces at
their common pushes to REPRODUCED.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "phantom_indenter_reference.json"
CASES = {"one": ("phantom-indenter-half.toml", "phantom-half"),
         "four": ("phantom-indenter-quarter.toml", "phantom-quarter")}
SIZE, SITE = 6.0, 3.2          # level 0 (mm)
RATIO = math.sqrt(2.0)
LEVELS = 3
PROBES = ("T1", "T2", "T3", "T4")
# a level run again must give the forces of the study's run of it to this (relative): Newton stops
# on a relative residual, so two runs agree to about 1e-8, not to the last digit
REPRODUCED = 1e-6


def level_sizes(k: int) -> tuple[float, float]:
    return SIZE / RATIO ** k, SITE / RATIO ** k


def level_lengths(k: int, path: float | None = None, base_rim: float | None = None):
    """(size, site, path, base rim) cell sizes (mm; None where not refined) of level ``k``:
    ``path`` and ``base_rim`` are ratios to the site size."""
    size, site = level_sizes(k)
    return (size, site, None if path is None else site * path,
            None if base_rim is None else site * base_rim)


def level_case(load: str, k: int, path: float | None = None, radius: float | None = None,
               volumetric: str | None = None, idle_tips: bool = True,
               base_rim: float | None = None, path_reach: float | None = None):
    """The case of level ``k`` of the study of ``load`` (``run_level``'s options)."""
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    name, builder = CASES[load]
    size, site, path_mm, base_rim_mm = level_lengths(k, path, base_rim)
    case = load_case(ROOT / "meshes" / "cases" / name,
                     mesh=build(builder, size, site_size=site, path_size=path_mm,
                                base_rim_size=base_rim_mm, path_reach=path_reach))
    if volumetric is not None:   # the Neo-Hookean volumetric law (default: the case's)
        case = case.with_material(volumetric=volumetric)
    if radius is not None:   # a diagnostic: tips of another radius on the same meshes
        case = dataclasses.replace(case, actuators=tuple(dataclasses.replace(a, radius=radius)
                                                         for a in case.actuators))
    if not idle_tips:   # a diagnostic: only the pushed tips, no obstacles held at their start
        if load != "one":
            raise SystemExit("--without-idle-tips: only with --load one (all four are pushed)")
        case = dataclasses.replace(case, actuators=tuple(a for a in case.actuators
                                                         if a.name == "A1"))
    return case


def run_level(load: str, k: int, pushes, degree: int, out: Path, progress: bool = False,
              path: float | None = None, radius: float | None = None,
              volumetric: str | None = None, contact_quadrature="nodal",
              idle_tips: bool = True, base_rim: float | None = None,
              path_reach: float | None = None, tip_start: str = "nodes") -> dict:
    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.model.results import write_json

    size, site, path_mm, base_rim_mm = level_lengths(k, path, base_rim)
    case = level_case(load, k, path, radius, volumetric, idle_tips, base_rim, path_reach)
    s = fr.ReferenceSolver(case, degree=degree, contact_quadrature=contact_quadrature,
                           tip_start=tip_start)
    actuators = ["A1"] if load == "one" else [a.name for a in case.actuators]
    doc = {"load": load, "level": k, "size_mm": size, "site_mm": site, "path_mm": path_mm,
           "base_rim_mm": base_rim_mm, "base_rim_ratio": base_rim, "path_reach_mm": path_reach,
           "tip_start": tip_start,
           "tip_radius_mm": case.actuators[0].radius,
           "contact": case.actuators[0].contact,   # an indenter's, defaulted when loaded
           "volumetric": case.material.volumetric, "idle_tips": idle_tips,
           "degree": degree, "contact_quadrature": contact_quadrature,
           "cells": case.mesh.n_cells, "pushes": []}
    prev = None
    for p in pushes:
        t0 = time.perf_counter()
        try:
            res, converged = s.solve({a: p for a in actuators}, initial=prev,
                                     progress=progress), True
        except ConvergenceError as exc:
            res, converged = exc.last_converged, False
        ind = res.indenters["A1"]
        row = {"push": p, "reached": ind["push"], "converged": converged,
               "valid": bool(res.valid is not False),
               "why": res.invalid_reason,
               "min_J": res.extra.get("min_J"),   # how it was taken: res.extra["J_evaluated"]
               "surface_mm": ind["surface_penetration"], "nodal_mm": ind["max_penetration"],
               "force_mN": 2.0 * ind["force"],  # A1 is cut in half by the plane y = 0
               "area_mm2": 2.0 * ind["contact_area"],
               "probes": {n: [float(v) for v in res.probes[n]] for n in PROBES
                          if n in res.probes},
               "dofs": res.discretization["dofs"], "newton": res.iterations,
               "wall_s": time.perf_counter() - t0}
        doc["pushes"].append(row)
        write_json(doc, out / f"{load}-level{k}.json")
        print(f"level {k} (size {size:.2f}, site {site:.2f} mm, path {path_mm or site:.2f} mm, "
              f"{doc['cells']} cells, "
              f"{row['dofs']} dofs) push {p:g}: converged {converged}, valid {row['valid']}, "
              f"skin inside tip {row['surface_mm']:.3f} mm, min J {row['min_J']}, "
              f"force {row['force_mN']:.2f} mN, "
              f"T1 {np.round(row['probes']['T1'], 4).tolist()} mm, {row['newton']} Newton, "
              f"{row['wall_s']:.0f} s", flush=True)
        if not converged:
            break
        prev = res
    return doc


def write_study_levels(load: str, name: str, out: Path) -> None:
    """Write the levels of the study ``name`` of the test data as level files under ``out``,
    beside levels run there; refuse when the study's settings differ from theirs."""
    from tissue_reference.model.results import write_json

    studies = json.loads(DATA.read_text())["loads"]
    if name not in studies:
        raise SystemExit(f"--with-study {name}: {DATA} has no such study "
                         f"(it has {', '.join(sorted(studies))})")
    study = studies[name]
    runs = [json.loads(f.read_text()) for f in out.glob(f"{load}-level*.json")]
    if not runs:
        raise SystemExit(f"--with-study {name}: run a level into {out} first; the study's levels "
                         "are checked against its settings")
    run = runs[0]

    def ratio(lv, key):   # a refined length as a ratio to the site size, as the options give it
        return None if lv.get(key) is None else round(lv[key] / lv["site_mm"], 4)

    wanted = {"load": load, "degree": run["degree"],
              "contact_quadrature": run.get("contact_quadrature", "nodal"),
              "tip_radius_mm": run.get("tip_radius_mm"), "contact": run.get("contact"),
              "idle_tips": run.get("idle_tips", True), "path ratio": ratio(run, "path_mm"),
              "base rim ratio": ratio(run, "base_rim_mm"),
              "path_reach_mm": run.get("path_reach_mm")}
    have = {"load": study["load"], "degree": study["degree"],
            "contact_quadrature": study.get("contact_quadrature", "nodal"),
            "tip_radius_mm": study.get("tip_radius_mm", run.get("tip_radius_mm")),
            "contact": study.get("contact", "frictionless"),
            "idle_tips": study.get("idle_tips", True),
            "path ratio": ratio(study["levels"][0], "path_mm"),
            "base rim ratio": ratio(study["levels"][0], "base_rim_mm"),
            "path_reach_mm": study["levels"][0].get("path_reach_mm")}
    differ = {k: (have[k], wanted[k]) for k in wanted if str(have[k]) != str(wanted[k])}
    if differ:
        raise SystemExit(f"--with-study {name}: its settings differ from the levels under {out} "
                         f"(study, run): {differ}")
    taken = {d["level"]: d for d in runs}
    for lv in study["levels"]:
        if lv["level"] in taken:
            _supersede(name, lv["level"], study, taken[lv["level"]], out)
            continue
        doc = {key: run.get(key) for key in ("load", "degree", "contact_quadrature",
                                             "tip_radius_mm", "contact", "volumetric",
                                             "idle_tips", "tip_start", "base_rim_ratio",
                                             "path_reach_mm")}
        doc.update({key: lv.get(key) for key in ("level", "size_mm", "site_mm", "path_mm",
                                                 "base_rim_mm", "cells")})
        doc["from_study"] = name
        doc["pushes"] = []
        for entry in study["pushes"]:
            if lv["level"] not in entry["levels"]:
                continue
            i = entry["levels"].index(lv["level"])
            doc["pushes"].append({
                "push": entry["push_mm"], "converged": True, "valid": entry["valid"][i],
                "why": entry["why_invalid"][i], "surface_mm": entry["surface_penetration_mm"][i],
                "force_mN": entry["force_mN"][i],
                "probes": {n: v[i] for n, v in entry["probes_mm"].items()},
                "dofs": entry["dofs"][i], "newton": entry["newton"][i],
                "wall_s": entry["wall_s"][i]})
        write_json(doc, out / f"{load}-level{lv['level']}.json")
        print(f"level {lv['level']} of {name}: {len(doc['pushes'])} pushes written to {out}")


def _supersede(name: str, level: int, study: dict, run: dict, out: Path) -> None:
    """A level run under ``out`` that the study already has (at fewer pushes, say) replaces
    the study's, provided it reproduces the study's forces at their common pushes to
    REPRODUCED (relative); a run that does not is refused: one of the two is wrong."""
    if run.get("from_study"):
        raise SystemExit(f"--with-study {name}: level {level} under {out} was written from a "
                         f"study already; summarize into a directory holding only new runs")
    mine = {e["push"]: e["force_mN"] for e in run["pushes"] if e.get("converged")}
    common = []
    for entry in study["pushes"]:
        if level in entry["levels"] and entry["push_mm"] in mine:
            theirs = entry["force_mN"][entry["levels"].index(level)]
            rel = abs(mine[entry["push_mm"]] - theirs) / abs(theirs)
            if rel > REPRODUCED:
                raise SystemExit(
                    f"--with-study {name}: level {level} under {out} gives "
                    f"{mine[entry['push_mm']]:.6f} mN at {entry['push_mm']:g} mm, the study "
                    f"{theirs:.6f} mN ({rel:.1e} apart, more than {REPRODUCED:g})")
            common.append(f"{entry['push_mm']:g} mm ({rel:.1e})")
    print(f"level {level} of {name}: replaced by the run under {out}, which reproduces its "
          f"forces at {', '.join(common) or 'no common push'}")


def summarize(load: str, out: Path) -> None:
    from tissue_reference.fem_reference.richardson import assess
    from tissue_reference.model.results import write_json

    docs = sorted((json.loads(f.read_text()) for f in out.glob(f"{load}-level*.json")),
                  key=lambda d: d["level"])
    if not docs:
        raise SystemExit(f"no level results under {out} for --load {load}")
    defaults = {"contact_quadrature": "nodal", "contact": "frictionless", "idle_tips": True,
                "tip_start": "nodes"}
    for key in ("contact_quadrature", "contact", "volumetric", "degree", "tip_radius_mm",
                "idle_tips", "base_rim_ratio", "path_reach_mm", "tip_start"):
        if len({str(d.get(key) or defaults.get(key)) for d in docs}) > 1:
            raise SystemExit(f"the level results under {out} differ in {key}: "
                             f"{[(d['level'], d.get(key)) for d in docs]}; summarize one "
                             f"discretization at a time")
    what = "A1 alone (half model)" if load == "one" else "all four (quarter model)"
    print(f"indenter phantom, {what}, "
          f"P{docs[0]['degree']}, contact rule {docs[0].get('contact_quadrature', 'nodal')}; "
          f"levels: " + ", ".join(
              f"{d['level']}: size {d['size_mm']:.2f} / site {d['site_mm']:.2f} mm, "
              f"{d['cells']} cells" for d in docs))
    pushes = sorted({r["push"] for d in docs for r in d["pushes"]})
    summary = {"load": load, "degree": docs[0]["degree"], "ratio": RATIO,
               "contact_quadrature": docs[0].get("contact_quadrature", "nodal"),
               "tip_radius_mm": docs[0].get("tip_radius_mm"),
               "contact": docs[0].get("contact") or "frictionless",
               "idle_tips": docs[0].get("idle_tips", True),
               "levels": [{k: d.get(k) for k in ("level", "size_mm", "site_mm", "path_mm",
                                                 "path_reach_mm", "base_rim_mm", "cells")}
                          for d in docs], "pushes": []}
    for p in pushes:
        rows = [next((r for r in d["pushes"] if r["push"] == p and r["converged"]), None)
                for d in docs]
        have = [(d, r) for d, r in zip(docs, rows) if r is not None]
        entry = {"push_mm": p, "levels": [d["level"] for d, _ in have],
                 "valid": [r["valid"] for _, r in have],
                 "surface_penetration_mm": [r["surface_mm"] for _, r in have],
                 "dofs": [r["dofs"] for _, r in have], "newton": [r["newton"] for _, r in have],
                 "wall_s": [r["wall_s"] for _, r in have],
                 "why_invalid": [r["why"] for _, r in have],
                 "force_mN": [r["force_mN"] for _, r in have],
                 "probes_mm": {n: [r["probes"][n] for _, r in have] for n in PROBES
                               if all(n in r["probes"] for _, r in have)},
                 "quantities": {}}
        summary["pushes"].append(entry)
        print(f"\npush {p:g} mm: levels reached {entry['levels']}; valid {entry['valid']}; "
              f"skin inside the tip (mm) {[round(v, 3) for v in entry['surface_penetration_mm']]}")
        for d, r in have:
            print(f"  level {d['level']}: {r['dofs']} dofs, {r['newton']} Newton, "
                  f"{r['wall_s']:.0f} s")
        if len(have) < 3:
            entry["assessed"] = False
            print("  no convergence assessment: needs 3 levels that converged")
            continue
        entry["assessed"] = True
        if not all(entry["valid"]):
            print("  levels flagged invalid (skin inside the tip beyond 5 % of its radius): "
                  f"{[d['level'] for d, r in have if not r['valid']]}; assessed all the same, "
                  "their error shows in the orders")
        h = [d.get("path_mm") or d["site_mm"] for d, _ in have]   # the cells under the tips
        quantities = [("force A1", "mN", [r["force_mN"] for _, r in have])]
        for n in PROBES:
            if not all(n in r["probes"] for _, r in have):
                continue
            vals = np.array([r["probes"][n] for _, r in have])
            for c, axis in enumerate("xyz"):
                if np.abs(vals[:, c]).max() > 1e-3:
                    quantities.append((f"{n} u{axis}", "mm", list(vals[:, c])))
        print(f"  {'quantity':>9} {'unit':>4} " + " ".join(f"{'L' + str(d['level']):>10}"
                                                     for d, _ in have)
              + f" {'order':>6} {'asym':>5} {'extrap':>10} {'GCI band':>10} {'rel':>7}")
        for qname, unit, vals in quantities:
            a = assess(vals, h, expected_order=docs[0]["degree"] + 1, ratio=RATIO,
                       name=qname, unit=unit)
            entry["quantities"][qname] = a.to_json_dict()
            order = "-" if a.observed_order is None else f"{a.observed_order:.2f}"
            ext = "-" if a.extrapolated is None else f"{a.extrapolated:.4f}"
            rel = "-" if a.gci_rel is None else f"{100 * a.gci_rel:.1f}%"
            print(f"  {qname:>9} {unit:>4} " + " ".join(f"{v:10.4f}" for v in vals)
                  + f" {order:>6} {a.asymptotic!s:>5} {ext:>10} {a.gci:10.4f} {rel:>7}")
    write_json(summary, out / f"{load}-summary.json")
    print(f"\nsummary: {out / f'{load}-summary.json'}")


def main():
    from tissue_reference.model.case import TIP_STARTS
    from tissue_reference.tissue.common import contact_rule

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--load", choices=sorted(CASES), default="one")
    ap.add_argument("--pushes", type=float, nargs="+", default=[5.0, 10.0, 15.0])
    ap.add_argument("--level", type=int,
                    help="run this level only (0: size 6 / sites 3.2 mm; -1 is coarser still)")
    ap.add_argument("--levels", type=int, default=LEVELS)
    ap.add_argument("--degree", type=int, default=2)
    ap.add_argument("--summarize", action="store_true", help="only print the summary")
    ap.add_argument("--progress", action="store_true", help="Newton's progress on stderr")
    ap.add_argument("--radius", type=float, metavar="MM",
                    help="tips of this radius instead of the case's 5 mm (a diagnostic)")
    ap.add_argument("--path", type=float, metavar="RATIO",
                    help="cells of RATIO x the site size along each tip's path into the tissue "
                         "(meshes.builders_curved.PATH_DEPTH / PATH_REACH); default: none")
    ap.add_argument("--tip-start", choices=TIP_STARTS, default="nodes",
                    help="where each tip starts: touching the skin's nodes (the reference's "
                         "default) or its curved facets")
    ap.add_argument("--path-reach", type=float, metavar="MM",
                    help="the radius around each path that --path refines (default: the "
                         "builders' PATH_REACH, 6 mm)")
    ap.add_argument("--base-rim", type=float, metavar="RATIO",
                    help="cells of RATIO x the site size at the base rim, where the fixed base "
                         "meets the free dome; default: none")
    ap.add_argument("--volumetric", choices=["quadratic", "log"],
                    help="the Neo-Hookean volumetric law (default: the case's, the seed's)")
    ap.add_argument("--contact-quadrature", type=contact_rule,
                    default="nodal", metavar="RULE",
                    help="where the contact penalty is sampled: 'nodal' or a Gauss degree")
    ap.add_argument("--without-idle-tips", action="store_true",
                    help="--load one: A1's tip only, without the other tips the case holds at "
                         "their start as obstacles (a diagnostic: what they change)")
    ap.add_argument("--with-study", metavar="NAME",
                    help="--summarize: first write the levels of this study of the test data "
                         "beside the levels under --out (its settings must be theirs)")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "indenter-convergence")
    args = ap.parse_args()
    if args.with_study and not args.summarize:
        ap.error("--with-study goes with --summarize")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.with_study:
        write_study_levels(args.load, args.with_study, args.out)
    if not args.summarize:
        for k in ([args.level] if args.level is not None else range(args.levels)):
            run_level(args.load, k, args.pushes, args.degree, args.out, args.progress, args.path,
                      args.radius, args.volumetric, args.contact_quadrature,
                      not args.without_idle_tips, args.base_rim, args.path_reach,
                      args.tip_start)
    if args.level is None:
        summarize(args.load, args.out)


if __name__ == "__main__":
    main()
