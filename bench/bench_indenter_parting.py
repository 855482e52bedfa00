"""Where the indenter phantom's refinement levels part at deep pushes: all four tips, quarter
phantom, P2, the Gauss contact rule of degree 2, the tips' paths refined (the levels of
``bench_indenter_convergence.py --load four --path 0.5``).

Each level is solved along one warm-started load path (5, 10, 12.5, 13.75, 15 mm) and its vertex
displacements at the compared pushes are kept under ``--out`` (``level{k}_push{p}.npz``, written
whole). Then, per push and pair of consecutive levels, the finer level's displacement is
interpolated (linearly, in the reference configuration) at the coarser level's vertices and the
differences are printed: median, largest (mm) and where; and the displacement of the material
point on A1's axis 2.9 mm under its site (P2 nodes interpolated) on every level.

    .venv/bin/python bench/bench_indenter_parting.py --levels -2 -1 0 --out out/parting
    .venv/bin/python bench/bench_indenter_parting.py --levels -2 -1 0 --compare-only --out out/parting
"""
from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np
from bench_indenter_convergence import level_sizes  # the levels' cell sizes (this folder)

ROOT = Path(__file__).resolve().parents[1]
PATH = (5.0, 10.0, 12.5, 13.75, 15.0)
PROBE_POINT = np.array([44.21, 0.0, 15.16])   # on A1's axis, 2.9 mm under its site (mm)


def solve_level(k: int, keep, out: Path) -> None:
    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import build
    from tissue_reference.meshes.io import atomic_path
    from tissue_reference.model.case import load_case

    size, site = level_sizes(k)
    case = load_case(ROOT / "meshes" / "cases" / "phantom-indenter-quarter.toml",
                     mesh=build("phantom-quarter", size, site_size=site, path_size=0.5 * site))
    s = fr.ReferenceSolver(case, degree=2, contact_quadrature=2)
    names = [a.name for a in case.actuators]
    prev = None
    for p in PATH:
        if p > max(keep):
            break
        res = s.solve({a: p for a in names}, initial=prev)
        prev = res
        force = 2.0 * res.indenters["A1"]["force"]
        print(f"level {k}: push {p:g} mm, force per tip {force:.2f} mN, "
              f"T1 {np.round(res.probes['T1'], 4).tolist()} mm", flush=True)
        if p in keep:
            with atomic_path(out / f"level{k}_push{p:g}.npz") as tmp:
                np.savez(tmp, X=case.mesh.points, u=res.u, node_points=res.extra["node_points"],
                         node_u=res.extra["node_u"], force_mN=force)


def compare(levels, pushes, out: Path) -> None:
    from scipy.interpolate import LinearNDInterpolator

    for p in pushes:
        data = {k: np.load(out / f"level{k}_push{p:g}.npz") for k in levels}
        print(f"\npush {p:g} mm")
        for k in levels:
            d = data[k]
            u = LinearNDInterpolator(d["node_points"], d["node_u"])(PROBE_POINT[None])[0]
            print(f"  level {k}: force per tip {float(d['force_mN']):.2f} mN; the point "
                  f"{PROBE_POINT.tolist()} moved {np.round(u, 2).tolist()} mm")
        for a, b in itertools.pairwise(levels):
            A, B = data[a], data[b]
            ub = LinearNDInterpolator(B["X"], B["u"])(A["X"])
            ok = ~np.isnan(ub[:, 0])
            diff = np.linalg.norm(ub[ok] - A["u"][ok], axis=1)
            X = A["X"][ok]
            i = int(np.argmax(diff))
            print(f"  levels {a} -> {b}: median {np.median(diff):.3f} mm, largest "
                  f"{diff[i]:.3f} mm at {np.round(X[i], 2).tolist()} (reference position)")


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--levels", type=int, nargs="+", default=[-2, -1, 0])
    ap.add_argument("--pushes", type=float, nargs="+", default=[12.5, 15.0],
                    help=f"pushes compared, of {list(PATH)} (mm)")
    ap.add_argument("--compare-only", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "parting")
    args = ap.parse_args()
    bad = [p for p in args.pushes if p not in PATH]
    if bad:
        ap.error(f"--pushes {bad}: not on the load path {list(PATH)}")
    args.out.mkdir(parents=True, exist_ok=True)
    levels = sorted(args.levels)
    if not args.compare_only:
        for k in levels:
            solve_level(k, set(args.pushes), args.out)
    compare(levels, sorted(args.pushes), args.out)


if __name__ == "__main__":
    main()
