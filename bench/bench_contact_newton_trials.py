"""Trial variants of the contact Newton, each solving the same case in one run, with the ratios
against the first: what each does to Newton's iterations, factorizations and wall time.

The variants change how Newton gets to the answer, never the discrete problem, so every one that
converges gives the same answer (the force and T1 differences are printed). They are installed
for one solve each, in this process only, by wrapping the library's functions
(``unittest.mock.patch``); none is a setting of the library:

  default    the reference as shipped
  direct     ReferenceSolver(linear_solver="direct"): every tangent factorized (MUMPS LDL^T)
  cholmod    direct with CHOLMOD's Cholesky first (MUMPS LDL^T from a tangent that is not
             positive definite to the end of the solve)
  lagged     ReferenceSolver(linear_solver="lagged"): a factorization (CHOLMOD's in serial,
             MUMPS's where a tangent is not positive definite) reused as GMRES's preconditioner
             of later tangents until GMRES needs more than ``NewtonSettings.lag_max_its``
             iterations
  lagged-mumps  lagged with MUMPS LDL^T's factorizations only
  exact      Newton's matrix the exact tangent from the first iteration
             (``NewtonSettings.contact_curvature_below = inf``)
  blend85    where Newton uses the exact tangent, 0.85 of it plus 0.15 of the tangent without
             the tips' curvature (between the two matrices whose corrections see-saw)
  margin     the tangent without the tips' curvature also stiff (the full penalty stiffness
             along the tip's normal) at contact points less than --margin mm outside a tip:
             Newton's matrix sees skin about to enter a tip (the contact-set "look-ahead")
  entrants   curvilinear trials (``NewtonSettings.follow_tips``) that also put skin nodes a
             straight trial carries into a tip back on its surface (a projected step)

Prints, per variant: Newton iterations, factorizations, load steps, line-search cuts, wall
time, the largest force and the ratios against the first variant.

    .venv/bin/python bench/bench_contact_newton_trials.py [--case phantom-indenter-quarter]
        [--push 10] [--preload MM] [--degree D] [--trials default lagged ...] [--margin 0.1]

``--push`` is every actuator's push, or NAME=MM (repeatable) for some of them (the others at
the preload); ``--preload MM`` first solves every actuator at MM (not timed) and warm-starts the
timed solve from it, as a control loop's plant step is: e.g. ``--case phantom-seed --preload 3
--push A1=3.5 --push A2=3.25``.
"""
from __future__ import annotations

import argparse
import contextlib
import itertools
import math
import time
from pathlib import Path
from unittest import mock

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TRIALS = ("default", "direct", "cholmod", "lagged", "lagged-mumps", "exact", "blend85", "margin",
          "entrants")


@contextlib.contextmanager
def blended_tangent(theta: float):
    """Newton's exact matrix replaced by theta K + (1 - theta) K without the tips' curvature."""
    import dolfinx.fem.petsc
    from petsc4py import PETSc

    from tissue_reference.fem_reference import newton as nw

    plain = nw.Newton.assemble_tangent
    spare = {}

    def assemble(self, bcs, drop=False, extra_terms=None):
        plain(self, bcs, drop, extra_terms)
        if drop or self.K_halved_form is None:
            return
        B = spare.setdefault(id(self), self.A.duplicate())
        B.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(B, self.K_halved_form, bcs=bcs,
                                          diagonal=self.bc_stiffness())
        B.assemble()
        self.A.scale(theta)
        self.A.axpy(1.0 - theta, B, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)

    with mock.patch.object(nw.Newton, "assemble_tangent", assemble):
        yield


@contextlib.contextmanager
def margin_tangent(margin_mm: float):
    """The tangent without the tips' curvature, stiff along the normal at points less than
    ``margin_mm`` outside a tip too (installed before the solver compiles its forms)."""
    import ufl

    from tissue_reference.fem_reference import contact_indenter as ci

    gaps = []
    plain_gap, plain_init = ci.gap_ufl, ci.Indenter.__init__

    def gap(*args, **kwargs):
        g = plain_gap(*args, **kwargs)
        gaps.append(g)
        return g

    def init(self, a, case, beta, ds, X, u, h_cell, *rest, **kwargs):
        gaps.clear()
        plain_init(self, a, case, beta, ds, X, u, h_cell, *rest, **kwargs)
        self.trial_gap, self.trial_k = gaps[0], beta * kwargs["E"] / h_cell

    def soft(self, v, w):
        kk, n_y, dsc = self._normal_stiffness
        g = self.trial_gap
        near = ufl.conditional(ufl.ge(g, 0.0), ufl.conditional(ufl.lt(g, margin_mm), 1.0, 0.0),
                               0.0)
        return (kk + near * self.trial_k) * ufl.dot(n_y, w) * ufl.dot(n_y, v) * dsc

    with mock.patch.object(ci, "gap_ufl", gap), \
            mock.patch.object(ci.Indenter, "__init__", init), \
            mock.patch.object(ci.Indenter, "tangent_without_curvature", soft):
        yield


@contextlib.contextmanager
def projected_entrants():
    """Curvilinear trials that also put nodes a straight trial carries into a tip on its
    surface (along the tip's normal there)."""
    from tissue_reference.fem_reference import contact_indenter as ci
    from tissue_reference.model import tips

    def shift(y0, y1, o, d, flat, edge):
        s = tips.curvilinear_shift(y0, y1, o, d, flat, edge)
        g0, _ = tips.gap_and_normal(np.asarray(y0, float), o, d, flat, edge)
        g1, n1 = tips.gap_and_normal(np.asarray(y1, float), o, d, flat, edge)
        entering = (g0 >= 0.0) & (g1 < 0.0)
        return np.where(entering[:, None], -g1[:, None] * n1, s)

    with mock.patch.object(ci, "curvilinear_shift", shift):
        yield


def variant(name: str, margin_mm: float):
    """(NewtonSettings fields, ReferenceSolver keywords, context) of a trial."""
    if name == "direct":
        return {}, {"linear_solver": "direct"}, contextlib.nullcontext()
    if name == "cholmod":
        from tissue_reference.fem_reference import solver
        plain = solver.LinearSolver
        return {}, {"linear_solver": "direct"}, mock.patch.object(
            solver, "LinearSolver", lambda *a, **k: plain(*a, **{**k, "package": "cholmod"}))
    if name == "lagged":
        return {}, {"linear_solver": "lagged"}, contextlib.nullcontext()
    if name == "lagged-mumps":
        from tissue_reference.fem_reference import solver
        return {}, {"linear_solver": "lagged"}, mock.patch.object(solver, "has_cholmod",
                                                                  lambda: False)
    if name == "exact":
        return {"contact_curvature_below": math.inf}, {}, contextlib.nullcontext()
    if name == "blend85":
        return {}, {}, blended_tangent(0.85)
    if name == "margin":
        return {}, {}, margin_tangent(margin_mm)
    if name == "entrants":
        return {"follow_tips": True}, {}, projected_entrants()
    return {}, {}, contextlib.nullcontext()


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="phantom-indenter-quarter")
    ap.add_argument("--push", action="append", default=None,
                    help="every actuator's push (mm), or NAME=MM (repeatable); default 10")
    ap.add_argument("--preload", type=float, default=None,
                    help="solve every actuator at this push first and warm-start from it")
    ap.add_argument("--degree", type=int, default=None)
    ap.add_argument("--trials", nargs="+", choices=TRIALS, default=["default", "lagged"])
    ap.add_argument("--margin", type=float, default=0.1,
                    help="the margin trial's distance outside a tip (mm)")
    args = ap.parse_args()

    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.model.case import load_case

    case = load_case(ROOT / "meshes" / "cases" / f"{args.case}.toml")
    names = [a.name for a in case.actuators]
    base = {n: args.preload or 0.0 for n in names}
    pushes = dict(base)
    for p in args.push or ["10"]:
        if "=" in p:
            n, mm = p.split("=")
            pushes[n] = float(mm)
        else:
            pushes.update({n: float(p) for n in names})
    rows = []
    for name in args.trials:
        fields, kwargs, ctx = variant(name, args.margin)
        with ctx:
            s = fr.ReferenceSolver(case, degree=args.degree,
                                   settings=fr.NewtonSettings(**fields), **kwargs)
            start = s.solve(base) if args.preload else None
            t0 = time.perf_counter()
            try:
                res, done = s.solve(pushes, initial=start), True
            except ConvergenceError as exc:
                res, done = exc.last_converged, False
            wall = time.perf_counter() - t0
        loads = res.history["iterate_load"]
        force = max(abs(v["force"]) for v in res.indenters.values())
        rows.append({"trial": name, "done": done, "newton": res.iterations,
                     "factor": s.timings.factorizations, "steps": res.load_steps,
                     "cutbacks": sum(1 for a, b in itertools.pairwise(loads) if b < a),
                     "wall": wall, "force": force, "T1": np.asarray(res.probes["T1"])})
        print(f"  [{name}: {'converged' if done else 'stopped'}, {res.iterations} Newton "
              f"iterations, {wall:.1f} s]", flush=True)
        s.close()
    print(f"{args.case}, P{res.degree}, {res.extra['n_dofs']} unknowns, pushes "
          + ", ".join(f"{n} {v:g}" for n, v in pushes.items())
          + (f" from {args.preload:g} mm" if args.preload else " from rest"))
    print(f"{'trial':>9} {'newton':>6} {'factor':>6} {'steps':>5} {'cutbacks':>8} "
          f"{'wall_s':>7} {'force_mN':>12} {'vs first':>28}")
    first = rows[0]
    for r in rows:
        same = ""
        if r is not first and r["done"] and first["done"]:
            same = (f"{first['newton'] / r['newton']:.2f}x its, {first['wall'] / r['wall']:.2f}x "
                    f"wall, dF {abs(r['force'] / first['force'] - 1):.0e}, dT1 "
                    f"{np.abs(r['T1'] - first['T1']).max():.0e} mm")
        print(f"{r['trial']:>9} {r['newton']:6d} {r['factor']:6d} {r['steps']:5d} "
              f"{r['cutbacks']:8d} {r['wall']:7.1f} {r['force']:12.6f}  "
              f"{same if r['done'] else 'did not converge'}")


if __name__ == "__main__":
    main()
