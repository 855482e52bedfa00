"""The Mass Tensor Method with rigid tips against the P1 reference, in one run: the indenter
phantom meshed for control (``phantom-indenter-control``: 7.9k tets, four 5 mm spheres, Gauss
contact rule of degree 2, tips started on the nodes), all four tips pushed 5 mm.

Timed (each the best of ``--repeat`` runs): the P1 reference on the case's own law (Neo-Hookean)
and on the Mass Tensor model's (linear elasticity, the same E and nu: the same discrete problem,
penalty, contact rule and tip start), both on their kept solvers (compiled forms, as ``tissue
verify`` times them, after a first untimed call); the Mass Tensor solve cold (an empty model
cache: tensors, contact points, factorization and the compliance columns of the skin near the
tips made in the call; CHOLMOD through the ``factorize`` hook, as the command line passes it)
and warm (the same pushes again on the model the cold solve left: the kept factorization and
condensation, Newton on the condensed contact and one back-substitution), and a warm solve at
another push (A1..A4 = 4.5 mm). Each with its speed-up (reference time / its time) and its
largest vertex distance (mm) from each reference, and the tips' forces.

    .venv/bin/python bench/bench_mass_tensor_contact.py [--push 5] [--repeat 3]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from _timing import best  # this folder's

from tissue_reference.fem_reference import cholmod_factor
from tissue_reference.fem_reference import solve as reference_solve
from tissue_reference.model.answer_warnings import TissueWarning
from tissue_reference.model.case import load_case
from tissue_reference.solvers import mass_tensor as mt
from tissue_reference.solvers.mass_tensor import driver


def _dist(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a.u) - np.asarray(b.u), axis=1).max())


def _forces(res) -> str:
    return " ".join(f"{k} {v['force']:7.2f}" for k, v in res.indenters.items())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--push", type=float, default=5.0, help="every tip's push (mm)")
    ap.add_argument("--repeat", type=int, default=3, help="each time is the best of this many runs")
    a = ap.parse_args()
    warnings.simplefilter("ignore", TissueWarning)   # each answer's validity is in its result
    case = load_case("phantom-indenter-control")
    lin = case.with_law("linear-elastic")
    pushes = {t.name: a.push for t in case.indenters()}
    other = {k: 0.9 * v for k, v in pushes.items()}
    print(f"{case.name}: {case.mesh.n_cells} tets, {case.mesh.n_vertices} vertices, "
          f"{case.material.model} E = {case.material.E:g} kPa, nu = {case.material.nu:g}; "
          f"contact rule {case.reference_contact_quadrature}, tips start on the "
          f"{case.reference_tip_start}; pushes {pushes} mm")
    _ = case.mesh.edge_topology   # the mesh's, made once (as the reference makes its dof map)

    refs = {}
    for name, c in (("P1 reference (" + case.material.model + ")", case),
                    ("P1 reference (linear-elastic)", lin)):
        t0 = time.perf_counter()
        reference_solve(c, pushes=pushes, degree=1)                    # compiles the forms
        first = time.perf_counter() - t0
        res, t = best(lambda c=c: reference_solve(c, pushes=pushes, degree=1), a.repeat)
        refs[name] = (res, t)
        print(f"{name:34s} {t:7.3f} s (first call {first:6.2f} s), {res.iterations} Newton "
              f"its, {res.load_steps} load steps  forces {_forces(res)}", flush=True)

    def solve(p):
        return mt.solve(case, pushes=p, factorize=cholmod_factor)

    cold, t_cold = best(lambda: solve(pushes), a.repeat, before=driver.MODEL_CACHE.clear)
    warm, t_warm = best(lambda: solve(pushes), a.repeat)
    nxt, t_next = best(lambda: solve(other), 1)
    ref_other = reference_solve(lin, pushes=other, degree=1)
    ex = cold.extra
    print(f"Mass Tensor cold {t_cold:7.3f} s  warm {t_warm:7.3f} s  (Newton its "
          f"{ex['contact_newton_iterations']}, candidate vertices "
          f"{ex['contact_candidate_vertices']}, in contact {ex['contact_active_vertices']}, "
          f"compliance columns {ex['contact_columns']}, rounds {ex['contact_rounds']})  "
          f"forces {_forces(cold)}")
    for name, (res, t) in refs.items():
        df = max(abs(cold.indenters[k]["force"] / v["force"] - 1.0)
                 for k, v in res.indenters.items())
        print(f"  against the {name:30s} cold x{t / t_cold:5.1f}  warm x{t / t_warm:6.1f}  "
              f"max |u - u_ref| {_dist(cold, res):.2e} mm (warm {_dist(warm, res):.2e} mm)  "
              f"largest relative force difference {df:.2e}")
    print(f"  another push ({other} mm) warm {t_next:7.3f} s, {nxt.extra['contact_columns']} new "
          f"columns; max |u - u_ref| {_dist(nxt, ref_other):.2e} mm against the linear-elastic "
          f"P1 reference there")


if __name__ == "__main__":
    main()
