"""Effectivity and cost of the reference's error estimate (fem_reference.estimate: p-enrichment,
one more solve at degree + 1 on the same mesh), in one run.

Effectivity = |estimated error| / |true error| of each quantity (probe displacement vectors, mm;
reaction vectors, mN), the true error taken against an answer computed independently of the
estimate:
  thick sphere  nearly incompressible / incompressible Neo-Hookean octant (inner surface pushed
                out 2 mm), mixed P2/P1 on curved cells, against the closed form of the
                incompressible shell (r^3 = R^3 + (A + UA)^3 - A^3; at nu = 0.4999 it is off by
                O(mu / kappa) ~ 1e-4 mm); on straight cells against the converged answer of the
                same facets (P3/P2 on the uniformly refined mesh) and against the true sphere
                (the faceting the estimate leaves out by design);
  Cook          Cook's membrane, linear, plane stress E = 1, nu = 1/3 (plane strain E* = 15/16,
                nu* = 1/4), unit shear load: against a fine P3 solve, and the mid-edge vertical
                displacement against the literature's 23.96;
  phantom       the phantom case (meshes/cases/phantom.toml, size 12: 1.2k tetrahedra, straight
                cells), A1 = 5 mm: the P1 answer against P2 on the uniformly refined mesh (10k
                tetrahedra filling the same cells: the same faceted dome and polygonal patch);
                with --fine the P2 answer against P3 on it (148k dofs, minutes).
Cost: the estimate's wall time (set-up of the enriched solver included) over the degree-p
solve's, and over a cold degree-(p+1) solve of the same case ("one more solve").

    .venv/bin/python bench/bench_estimate.py [--fine]
"""
from __future__ import annotations

import argparse
import gc
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import tissue_reference.fem_reference as fr
from tissue_reference.fem_reference.estimate import error_estimate
from tissue_reference.meshes.builders import cook_membrane, shell_octant
from tissue_reference.meshes.refine import refine_uniform
from tissue_reference.model.case import Boundary, Case, Material, Probe, load_case

A, B, UA = 10.0, 20.0, 2.0
ROWS: list = []
COSTS: list = []


def row(case, answer, quantity, est_vec, true_vec, truth_from):
    est, true = float(np.linalg.norm(est_vec)), float(np.linalg.norm(true_vec))
    ROWS.append((case, answer, quantity, est, true, est / true if true > 0 else float("nan"),
                 truth_from))


def cost(case, answer, res, est, cold_s=None):
    COSTS.append((case, answer, res.extra["n_dofs"], est.enriched.extra["n_dofs"],
                  res.wall_time_s, est.wall_time_s, est.setup_s, cold_s))


def label(res) -> str:
    d = res.discretization
    p = f"P{d['degree']}" + (f"/P{d['pressure_degree']}" if d.get("pressure_degree") else "")
    return p + (" curved" if d.get("geometry_order") == 2 else " straight")


# --------------------------------------------------------------------------- thick sphere
def shell(size, nu):
    bcs = [Boundary("xsym", "sliding", normal=[1, 0, 0]),
           Boundary("ysym", "sliding", normal=[0, 1, 0]),
           Boundary("zsym", "sliding", normal=[0, 0, 1]),
           Boundary("inner", "affine", gradient=(UA / A * np.eye(3)).tolist(), offset=[0, 0, 0])]
    probes = [Probe("pole", (0.0, 0.0, B)), Probe("mid_wall", (0.0, 0.0, 15.0)),
              Probe("diagonal", tuple(np.full(3, 15.0 / np.sqrt(3.0))))]
    return Case(mesh=shell_octant(size), material=Material("neo-hookean", E=6.0, nu=nu),
                boundaries=bcs, probes=probes, name="thick-sphere")


def closed_form(x):
    x = np.asarray(x, float)
    R = np.linalg.norm(x)
    return ((R ** 3 + (A + UA) ** 3 - A ** 3) ** (1 / 3) - R) * x / R


def inner_reaction(mu):
    """|x-component| (mN) of the inner support's force on the octant, incompressible closed
    form: P_rR(A) pi A^2 / 4 (per component, by symmetry)."""
    from scipy.integrate import quad

    a = A + UA
    c = a ** 3 - A ** 3
    b = (B ** 3 + c) ** (1 / 3)
    s_a = quad(lambda r: 2 * mu * (((r ** 3 - c) ** (1 / 3) / r) ** 4
                                   - (r / (r ** 3 - c) ** (1 / 3)) ** 2) / r, a, b,
               epsabs=0, epsrel=1e-12)[0]
    return abs(s_a * (a / A) ** 2) * np.pi * A ** 2 / 4


def bench_sphere():
    for nu, size in ((0.4999, 5.0), (0.4999, 3.0), (0.5, 5.0)):
        case = shell(size, nu)
        res = fr.solve(case)
        est = error_estimate(case, res)
        name = f"sphere nu={nu} {case.mesh.n_cells} tets"
        for k, p in ((p.name, p.point) for p in case.probes):
            row(name, label(res), k, est.probes[k], closed_form(p) - res.probes[k],
                "closed form")
        if nu == 0.5:
            f = res.reactions["inner"]
            truth = np.sign(f) * inner_reaction(case.material.mu)
            row(name, label(res), "R inner", est.reactions["inner"], truth - f,
                "closed form (*)")
        t = time.perf_counter()
        fr.solve(case, degree=3)
        cost(name, label(res), res, est, time.perf_counter() - t)
    # straight cells: the estimate excludes the faceting
    case = shell(5.0, 0.4999)
    res = fr.solve(case, curved=False)
    est = error_estimate(case, res, curved=False)
    fine = fr.solve(case.with_mesh(refine_uniform(case.mesh)), degree=3, curved=False)
    name = f"sphere nu=0.4999 {case.mesh.n_cells} tets"
    for k, p in ((p.name, p.point) for p in case.probes):
        row(name, label(res), k, est.probes[k], fine.probes[k] - res.probes[k],
            "same facets, P3/P2 x8 cells")
        row(name, label(res), k, est.probes[k], closed_form(p) - res.probes[k],
            "true sphere (faceting left out)")
    cost(name, label(res), res, est)


# --------------------------------------------------------------------------- Cook
def cook(size):
    return Case(mesh=cook_membrane(size), material=Material("linear-elastic", E=15 / 16, nu=0.25),
                boundaries=[Boundary("left", "fixed"),
                            Boundary("right", "traction", value=[0.0, 1.0 / 16.0])],
                probes=[Probe("mid_edge", (48.0, 52.0)), Probe("corner", (48.0, 60.0))],
                name="cook")


def bench_cook():
    truth = fr.solve(cook(0.5), degree=3).probes
    print(f"Cook: fine P3 (0.5 mm) mid-edge vertical {truth['mid_edge'][1]:.4f} "
          f"(literature 23.96), corner {truth['corner'][1]:.4f}", flush=True)
    for size in (4.0, 2.0):
        case = cook(size)
        for degree in (1, 2):
            res = fr.solve(case, degree=degree)
            est = error_estimate(case, res)
            name = f"Cook {case.mesh.n_cells} tris"
            for k in truth:
                row(name, label(res), k, est.probes[k], truth[k] - res.probes[k], "P3, 0.5 mm")
            if degree == 1:
                row(name, label(res), "mid_edge v", est.probes["mid_edge"][1],
                    23.96 - res.probes["mid_edge"][1], "literature 23.96")
            t = time.perf_counter()
            fr.solve(case, degree=degree + 1)
            cost(name, label(res), res, est, time.perf_counter() - t)


# --------------------------------------------------------------------------- phantom
def bench_phantom(fine_p3: bool):
    """Straight cells throughout (the same faceted dome and polygonal patches): the truth is a
    solve on the uniformly refined mesh, whose children fill the same cells."""
    push = {"A1": 5.0}
    case = load_case(Path(__file__).resolve().parents[1] / "meshes/cases/phantom.toml",
                     size=12.0)
    fine = case.with_mesh(refine_uniform(case.mesh))
    truths = {}
    for degree in ((2, 3) if fine_p3 else (2,)):
        t = time.perf_counter()
        r = fr.solve(fine, pushes=push, degree=degree)
        truths[degree] = r
        print(f"phantom: truth P{degree} on {fine.mesh.n_cells} tets ({r.extra['n_dofs']} dofs) "
              f"{time.perf_counter() - t:.1f} s", flush=True)
        gc.collect()
    name = f"phantom A1=5 {case.mesh.n_cells} tets"
    for degree in (1, 2):
        res = fr.solve(case, pushes=push, degree=degree, curved=False)
        est = error_estimate(case, res, pushes=push, curved=False)
        tdeg = degree + 1
        if tdeg in truths:
            src = f"P{tdeg}, 8x cells"
            truth = truths[tdeg]
            for k in res.probes:
                row(name, label(res), k, est.probes[k], truth.probes[k] - res.probes[k], src)
            row(name, label(res), "R act_px", est.reactions["act_px"],
                truth.reactions["act_px"] - res.reactions["act_px"], src)
        t = time.perf_counter()
        fr.solve(case, pushes=push, degree=degree + 1, curved=False)
        cost(name, label(res), res, est, time.perf_counter() - t)
    del truths, fine
    gc.collect()


def bench_cost(size):
    """The phantom at ``size`` (mm): P1 answers at the README's load (4 x 15 mm) and at
    4 x 5 mm, P2 answers at 4 x 5 mm, each with its estimate."""
    from tissue_reference.errors import ConvergenceError

    case = load_case(Path(__file__).resolve().parents[1] / "meshes/cases/phantom.toml",
                     size=size)
    for mm, degree in ((15.0, 1), (5.0, 1), (5.0, 2)):
        push = {a: mm for a in ("A1", "A2", "A3", "A4")}
        name = f"phantom 4x{mm:g} mm {case.mesh.n_cells} tets"
        res = fr.solve(case, pushes=push, degree=degree)
        try:
            est = error_estimate(case, res, pushes=push)
        except ConvergenceError as exc:
            print(f"{name} {label(res)}: the degree-{degree + 1} estimate failed: {exc}")
            continue
        t = time.perf_counter()
        fr.solve(case, pushes=push, degree=degree + 1,
                 curved=est.enriched.discretization["geometry_order"] == 2)
        cost(name + (" (*)" if degree >= 2 and not est.warm_start else ""), label(res), res, est,
             time.perf_counter() - t)
        gc.collect()


def print_effectivities():
    print("\nEffectivity |estimate| / |true error| (vectors; mm, reactions mN):")
    print(f"{'case':28s} {'answer':17s} {'quantity':11s} {'estimate':>10s} {'true error':>10s} "
          f"{'eff.':>6s}  truth")
    for c, a, q, e, t, eff, src in ROWS:
        print(f"{c:28s} {a:17s} {q:11s} {e:10.3e} {t:10.3e} {eff:6.2f}  {src}")
    print("(*) a reaction summed over the inner surface's nodes, which it shares with the "
          "symmetry planes: the estimate is low", flush=True)


def print_costs():
    print("\nCost: estimate (enriched solver set-up included) / degree-p solve, and / a cold "
          "degree-(p+1) solve of the same case:")
    print(f"{'case':34s} {'answer':17s} {'dofs':>8s} {'enriched':>9s} {'solve s':>8s} "
          f"{'estimate s':>10s} {'(setup s)':>9s} {'ratio':>6s} {'cold p+1 s':>10s} "
          f"{'ratio':>6s}")
    for c, a, n, ne, ts, te, su, tc in COSTS:
        cold = f"{tc:10.2f} {te / tc:6.2f}" if tc else f"{'-':>10s} {'-':>6s}"
        print(f"{c:34s} {a:17s} {n:8d} {ne:9d} {ts:8.2f} {te:10.2f} {su:9.2f} "
              f"{te / ts:6.1f} {cold}")
    print("P1 answers: the P2 estimate is solved from rest by design; (*) a P2 answer from which "
          "Newton did not converge: the P3 problem was solved from rest", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cost-size", type=float, default=8.0,
                    help="phantom size (mm) of the cost rows (default 8: 2.9k tetrahedra)")
    ap.add_argument("--fine", action="store_true",
                    help="also P3 on the refined phantom (148k dofs, minutes): the truth for "
                         "the phantom's P2 answer")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    bench_sphere()
    bench_cook()
    bench_phantom(args.fine)
    print_effectivities()
    bench_cost(args.cost_size)
    print_costs()
    print(f"\nbench_estimate: {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
