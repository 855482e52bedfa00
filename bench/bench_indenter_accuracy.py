"""``--accuracy`` on the indenter phantom (``fem_reference.adapt.solve_to_accuracy``), and how
honest its estimates are there, in one run.

The half phantom (meshes/cases/phantom-indenter-half.toml: A1 a rigid 5 mm sphere in
frictionless contact, the mirror plane y = 0 sliding), meshed at size 12 mm with the case's
3.2 mm site cells, P2, refined locally (energy indicators, Doerfler marking) until every
target's estimated error (p-enrichment: the P3 solve on the same cells) is within the asked
fraction of its displacement. Per push: each level's cells, unknowns, worst target and its
estimated relative error, seconds; whether the accuracy was reached.

Effectivity: at 5 mm the accepted answer's estimates are set against the finest level of the
indenter convergence study (tests/data/phantom_indenter_reference.json, 208k unknowns on 1.6 mm
site cells), taken as the truth: estimate / |u - u_study| per target. That level is itself
known to about the spread of the study's levels (1.4 %), which bounds what an effectivity near
the accuracy asked can mean.

    .venv/bin/python bench/bench_indenter_accuracy.py [--pushes 2 5] [--accuracy 0.01]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from study_answers import finest  # the study's finest level (this folder)

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom-indenter-half.toml"


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pushes", type=float, nargs="+", default=[2.0, 5.0], help="A1 (mm)")
    ap.add_argument("--accuracy", type=float, default=0.01)
    ap.add_argument("--size", type=float, default=12.0, help="the half phantom's size (mm)")
    ap.add_argument("--max-dofs", type=int, default=200_000)
    args = ap.parse_args()

    from tissue_reference.fem_reference.adapt import AccuracyNotReached, solve_to_accuracy
    from tissue_reference.meshes.builders import build
    from tissue_reference.meshes.refine import projector_for
    from tissue_reference.model.case import load_case

    for push in args.pushes:
        # the half case's body at --size with its 3.2 mm sites, without its refined paths
        case = load_case(CASE, mesh=build("phantom-half", args.size, site_size=3.2))
        t0 = time.perf_counter()
        try:
            out = solve_to_accuracy(case, {"A1": push}, accuracy=args.accuracy,
                                    max_dofs=args.max_dofs, project=projector_for("phantom-half"),
                                    progress=False)
            why = None
        except AccuracyNotReached as exc:
            out, why = exc.result, str(exc)
        wall = time.perf_counter() - t0
        print(f"\nA1 = {push:g} mm, accuracy {args.accuracy:g}: "
              f"{'reached' if out is not None and out.reached else 'NOT reached'} in "
              f"{wall:.0f} s" + (f" ({why})" if why else ""))
        if out is None:
            continue
        print(f"  {'level':>5} {'deg':>3} {'cells':>7} {'dofs':>7} {'est dofs':>8} "
              f"{'worst':>5} {'est rel':>8} {'seconds':>8}")
        for st in out.steps:
            name, ratio = st.worst
            print(f"  {st.level:>5} {st.degree:>3} {st.cells:>7} {st.dofs:>7} "
                  f"{st.estimate_dofs:>8} {name:>5} {100 * ratio * args.accuracy:7.2f}% "
                  f"{st.wall_time_s:8.1f}")
        study = finest("one", push)
        if study is None:
            continue
        last = out.steps[-1]
        print("  effectivity against the study's finest level (estimate / |u - u_study|):")
        for n, ref in study["probes"].items():
            err = float(np.linalg.norm(np.asarray(last.probes[n]) - ref))
            est = last.estimates[n]
            print(f"    {n}: estimate {est:.2e} mm, difference {err:.2e} mm "
                  f"({100 * err / np.linalg.norm(ref):.2f} %), effectivity {est / err:.2f}")


if __name__ == "__main__":
    main()
