"""Where the contact penalty is sampled, and what it costs: the nodal rule (one point per skin
node, the default) against Gauss rules on each skin facet, on the quarter block ``indent-block``
(symmetry planes sliding, bottom fixed), P2, frictionless penalty contact (beta = 1e3).

1. Accuracy, shallow: a sphere R = 10 mm pushed d = 0.1 mm into the linear-elastic block
   (E = 6 kPa, nu = 0.45) against Hertz's force 4/3 E* sqrt(R) d^(3/2), per cell size h under
   the tip and per rule. A Gauss rule samples the gap more often than the P2 skin has nodes, so
   it over-constrains the skin and stiffens the contact (locking); the nodal rule does not.
   On cells wider than the contact (``--sizes 2 1.5 1``: h = 2, 1.5, 1 contact radii) the
   few facets in contact cannot follow the tip at the Gauss points and the rule fails.
2. Depth: a ball-ended rod R = 1 mm pushed into the Neo-Hookean block (0.3 mm cells) through
   the given depths on one warm-started load path, per rule: whether Newton converges, the
   force (mN, the whole tip), the smallest J and the state's validity. With the nodal rule the
   gap is known only at the nodes: deep under the tip the skin's facets can bulge into the tip
   between them, and past about 2.4 R the exact tangent turns indefinite (``--eigen`` prints
   its smallest eigenvalues and where their modes live) and Newton stops; a Gauss rule
   penalizes the facets' interiors as well.

    .venv/bin/python bench/bench_contact_rule.py                      # both parts, ~15 min
    .venv/bin/python bench/bench_contact_rule.py --part hertz --sizes 0.5 0.35
    .venv/bin/python bench/bench_contact_rule.py --part depth --rules nodal --eigen
"""
from __future__ import annotations

import argparse
import json
import math
import time

E, NU = 6.0, 0.45
E_STAR = E / (1 - NU ** 2)


def _quarter(mesh, actuator, model):
    from tissue_reference.model.case import Boundary, Case, Material

    return Case(mesh, Material(model, E, NU),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[actuator])


def _sphere(R):
    from tissue_reference.model.case import Actuator

    return Actuator("I", "tip", (0.0, 0.0, -1.0), type="indenter", tip="sphere", radius=R,
                    point=(0.0, 0.0, 0.0), contact_region="top")


def hertz(sizes, rules) -> list[dict]:
    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import indent_block

    R, d = 10.0, 0.1
    F_hertz = 4.0 / 3.0 * E_STAR * math.sqrt(R) * d ** 1.5
    rows = []
    print(f"Hertz: sphere R = {R:g} mm, d = {d:g} mm, linear elastic, P2; F_Hertz = "
          f"{F_hertz:.5f} mN, contact radius {math.sqrt(R * d):.3f} mm", flush=True)
    for h in sizes:
        mesh = indent_block(h)
        case = _quarter(mesh, _sphere(R), "linear-elastic")
        for rule in rules:
            t0 = time.perf_counter()
            s = fr.ReferenceSolver(case, degree=2, contact_quadrature=rule)
            res = s.solve({"I": d})
            F = 4 * res.indenters["I"]["force"]
            rows.append({"h_mm": h, "rule": rule, "force_mN": F,
                         "error": F / F_hertz - 1, "dofs": s.W.dofmap.index_map.size_global * s.W.dofmap.index_map_bs,
                         "seconds": time.perf_counter() - t0})
            print(f"  h {h:g} mm ({mesh.n_cells} tets), rule {rule!s:>5}: F = {F:.5f} mN "
                  f"({100 * (F / F_hertz - 1):+.2f} % vs Hertz), {rows[-1]['seconds']:.0f} s",
                  flush=True)
    return rows


def smallest_eigenvalues(solver, n: int = 3) -> list[tuple[float, str]]:
    """The n smallest eigenvalues (mN/mm) of the exact tangent at the solver's state (SLEPc,
    shift-invert about -1 with MUMPS), each with the reference places (radius from the axis,
    height) of the two nodes its mode moves most."""
    import numpy as np
    from slepc4py import SLEPc

    bcs = [e[0] for e in solver.boundary.dirichlet_bcs(solver.case, 1.0)]
    solver.newton.assemble_tangent(bcs, False)
    A = solver.A
    eps = SLEPc.EPS().create(solver.comm)
    eps.setOperators(A)
    eps.setProblemType(SLEPc.EPS.ProblemType.HEP)
    eps.setDimensions(n)
    eps.setTarget(-1.0)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_REAL)
    st = eps.getST()
    st.setType("sinvert")
    st.getKSP().setType("preonly")
    st.getKSP().getPC().setType("lu")
    st.getKSP().getPC().setFactorSolverType("mumps")
    eps.solve()
    coords = solver.V.tabulate_dof_coordinates()
    bs = solver.V.dofmap.index_map_bs
    out = []
    for i in range(min(n, eps.getConverged())):
        v = A.createVecRight()
        lam = eps.getEigenpair(i, v).real
        mag = np.linalg.norm(v.array.reshape(-1, bs), axis=1)
        top = np.argsort(mag)[-2:][::-1]
        where = ", ".join(f"r {math.hypot(*coords[k, :2]):.2f} z {coords[k, 2]:.2f}" for k in top)
        out.append((float(lam), where))
    return out


def past_stop(solver, depth_R: float, radius: float) -> list[tuple[float, str]]:
    """From the last converged state, the tip moved to ``depth_R`` radii and eight Newton
    iterations run there (they stall near the state Newton cannot leave): the tangent's
    smallest eigenvalues at that iterate (``smallest_eigenvalues``)."""
    from dataclasses import replace

    ind = solver.contact.indenters[0]
    ind.q.value = ind.q0 + depth_R * radius * ind.d
    bcs = [e[0] for e in solver.boundary.dirichlet_bcs(solver.case, 1.0)]
    solver.newton.iterate(replace(solver.settings, max_iterations=8), bcs, False, "past the stop")
    return smallest_eigenvalues(solver)


def depth(size, radius, depths, rules, eigen: bool) -> list[dict]:
    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.fem_reference.field_jacobian import cell_min_J
    from tissue_reference.meshes.builders import indent_block

    mesh = indent_block(size)
    case = _quarter(mesh, _sphere(radius), "neo-hookean")
    print(f"Depth: ball-ended rod R = {radius:g} mm into the Neo-Hookean block, {size:g} mm "
          f"cells ({mesh.n_cells} tets), P2", flush=True)
    rows = []
    for rule in rules:
        s = fr.ReferenceSolver(case, degree=2, contact_quadrature=rule)
        prev = None
        for d in depths:
            t0 = time.perf_counter()
            try:
                res, ok = s.solve({"I": d * radius}, initial=prev), True
            except ConvergenceError as exc:
                res, ok = exc.last_converged, False
            ind = res.indenters["I"]
            row = {"rule": rule, "depth_R": d, "converged": ok,
                   "reached_R": ind["push"] / radius, "force_mN": 4 * ind["force"],
                   "min_J": float(cell_min_J(s).min()), "valid": bool(res.valid),
                   "newton": int(res.iterations), "seconds": time.perf_counter() - t0}
            line = (f"  rule {rule!s:>5}, depth {d:g} R: converged {ok}, reached "
                    f"{row['reached_R']:.3f} R, force {row['force_mN']:.3f} mN, smallest J "
                    f"{row['min_J']:.3f}, valid {row['valid']}, {row['newton']} Newton, "
                    f"{row['seconds']:.0f} s")
            if eigen and ok:
                row["eigenvalues"] = smallest_eigenvalues(s)
                line += "\n      smallest eigenvalues of the tangent (mN/mm): " + "; ".join(
                    f"{lam:.4f} (mode at {where})" for lam, where in row["eigenvalues"])
            if eigen and not ok:
                row["eigenvalues_past_stop"] = past_stop(s, row["reached_R"] + 0.04, radius)
                line += ("\n      8 Newton iterations at {:.2f} R, smallest eigenvalues of the "
                         "tangent (mN/mm): ".format(row["reached_R"] + 0.04) + "; ".join(
                             f"{lam:.4f} (mode at {where})"
                             for lam, where in row["eigenvalues_past_stop"]))
            print(line, flush=True)
            rows.append(row)
            if not ok:
                break
            prev = res
    return rows


def main():
    from tissue_reference.tissue.common import contact_rule

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", choices=["hertz", "depth", "both"], default="both")
    ap.add_argument("--rules", type=contact_rule, nargs="+", default=["nodal", 2],
                    help="'nodal' and/or Gauss degrees")
    ap.add_argument("--sizes", type=float, nargs="+", default=[0.5, 0.35, 0.25],
                    help="cell sizes under the tip for the Hertz part (mm)")
    ap.add_argument("--size", type=float, default=0.3, help="cell size, depth part (mm)")
    ap.add_argument("--radius", type=float, default=1.0, help="tip radius, depth part (mm)")
    ap.add_argument("--depths", type=float, nargs="+", default=[1.0, 2.0, 2.4, 2.7, 3.0],
                    help="depths in tip radii")
    ap.add_argument("--eigen", action="store_true",
                    help="the tangent's smallest eigenvalues at each converged depth")
    ap.add_argument("--json", help="write the rows there")
    args = ap.parse_args()
    out = {}
    if args.part in ("hertz", "both"):
        out["hertz"] = hertz(args.sizes, args.rules)
    if args.part in ("depth", "both"):
        out["depth"] = depth(args.size, args.radius, args.depths, args.rules, args.eigen)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
