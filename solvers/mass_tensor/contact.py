"""Frictionless rigid tips on the Mass Tensor model: its linear stiffness with the reference's
discrete contact penalty (``solvers.contact.ContactSet``, the energy the P1 reference and ADMM
minimize) as the one nonlinear term, solved by Newton condensed on the skin near the tips.

Problem. With the point types' prescriptions u = u_c + P w (P the projector on the free
directions),

    minimize  1/2 u' K u - f' u + Pi_c(u),   Pi_c(u) = sum_p W_p k_p phi(-g(X_p + S_p u)),

whose stationarity on the free directions is P (K u - f + b(u)) = 0, b = dPi_c / du (mN), the
forces the tips take from the skin. With G = P A^-1 P (A = P K P + I - P, the direct solve's
matrix: ``condensed.Compliance``) and u_0 the contactless answer (G (f - K u_c) + u_c), every
solution is u = u_0 - G lam with lam = b(u): b lives on the dofs of the contact facets' vertices
only, so on the candidate vertices C (those of the contact points that can touch) the problem
is the small dense one

    lam = b(u_0,C - G_CC lam),

a fixed point in lam (|C| d unknowns), and the whole field follows from lam with one more
back-substitution, u = u_0 - G lam. Newton on R(lam) = b(u_C(lam)) - lam:
(I + H G_CC) dlam = R, H = d^2 Pi_c / du_C^2 (mN/mm), which is zero outside the dofs A of the
vertices of the points in contact (phi' > 0), so that dlam = -lam off A and

    (I + H_AA G_AA) dlam_A = R_A + H_AA G_AN lam_N,

one dense solve of |A| d unknowns. Its step is a descent direction of the total energy along
u = u_0 - G lam, M(lam) = 1/2 lam' G lam + Pi_c(u_0 - G lam) (+ the contactless energy; G K G =
G on the free directions), wherever H is positive semi-definite: the iterations start without
the tips' curvature term of the Hessian (``ContactSet.point_hessians``), take it once a full
step leaves the points in contact as they were (the last iterations converge quadratically),
and halve a step until M falls (``solvers.line_search.backtrack``; a step with the curvature
that does not descend is taken again without it). They stop once a step moves no candidate
vertex by ``tol_mm`` or more.

Candidates. C starts as the vertices of the contact points whose gap at the contactless answer
is below REACH_RADII of their tip's radius; the solution on C is exact for the whole skin when
no point outside C penetrates its tip at the whole field, which is checked after each Newton
solve: points that do are added (with their neighbours within reach) and Newton goes on from
where it was (``rounds``). G_CC is one column of G per candidate dof, kept with the model's
factorization per pattern of point types (``Compliance``), so another push on the same point
types makes only the columns of vertices not yet asked for.

Units: mm, kPa, mN.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tissue_reference.errors import SolverDivergedError

from ..line_search import backtrack

REACH_RADII = 0.1
"""Candidate vertices: those of the contact points whose gap to their tip is below this fraction
of the tip's radius at the contactless answer, and after each Newton solve at its answer."""
MAX_ROUNDS = 20
"""Newton solves on growing candidate sets at most (each adds the points found penetrating
outside the last set)."""
MAX_HALVINGS = 30
"""Steps a Newton iteration's line search tries (1, 1/2, ..., 2^-29): the first with M(lam + t
dlam) <= M(lam) + ARMIJO t M'(lam) dlam up to 1e-13 of the larger |M| is taken
(``solvers.line_search``)."""


@dataclass
class TipSolution:
    """The answer with tips: u (n, d) mm; lam (n, d) mN, the forces the tips take from the skin
    at the vertices (dPi_c / du); iterations (Newton's), rounds (candidate sets), converged,
    max_step_mm per Newton iteration, candidates: vertices in the condensed block, active: the
    vertices of the contact points inside their tips at the end (as last checked), columns:
    columns of G made in this solve (back-substitutions)."""

    u: np.ndarray
    lam: np.ndarray
    iterations: int
    rounds: int
    converged: bool
    max_step_mm: list = field(default_factory=list)
    candidates: int = 0
    active: int = 0
    columns: int = 0


class _Condensed:
    """The contact points whose vertices are all candidates, on the block of ``comp``."""

    def __init__(self, cset, comp, o, u0):
        self.cset, self.comp, self.d = cset, comp, comp.d
        self.at = np.flatnonzero(np.all(comp.pos[cset.pv] >= 0, axis=1))
        self.loc = comp.pos[cset.pv[self.at]]                    # (k, nv) places in the block
        self.N = cset.pN[self.at]
        self.X = cset.X[self.at]
        self.o = o[self.at]
        self.u0 = u0[comp.nodes]                                 # (m, d)
        self.G = comp.G
        self.m = len(comp.nodes)

    def state(self, lam):
        """Everything at lam (m d,): u_C, the points' positions and terms, b, M."""
        Glam = self.G @ lam
        uC = self.u0 - Glam.reshape(self.m, self.d)
        y = self.X + np.einsum("ka,kad->kd", self.N, uC[self.loc])
        e, f, _, nrm, d1, d2 = self.cset.point_terms(y, self.o, self.at)
        b = np.zeros((self.m, self.d))
        for a in range(self.loc.shape[1]):
            w = -self.N[:, a, None] * f
            for c in range(self.d):
                b[:, c] += np.bincount(self.loc[:, a], w[:, c], minlength=self.m)
        return {"lam": lam, "Glam": Glam, "uC": uC, "y": y, "nrm": nrm, "d1": d1, "d2": d2,
                "b": b.reshape(-1), "M": 0.5 * float(lam @ Glam) + float(e.sum()),
                "on": np.flatnonzero(d1 > 0)}

    def step(self, s, curvature: bool):
        """Newton's dlam at the state s (its module docstring) and the active vertices."""
        d = self.d
        on = s["on"]
        dlam = -s["lam"].copy()
        act = np.unique(self.loc[on])
        if not act.size:
            return dlam, act
        Ad = (d * act[:, None] + np.arange(d)).reshape(-1)
        place = np.full(self.m, -1)
        place[act] = np.arange(len(act))
        Hp = self.cset.point_hessians(s["y"][on], self.o[on], s["nrm"][on], s["d1"][on],
                                      s["d2"][on], self.at[on], curvature)
        H = self.cset.spread(Hp, place[self.loc[on]], self.N[on], len(act)).toarray()
        lamN = s["lam"].copy()
        lamN[Ad] = 0.0
        r = s["b"] - s["lam"]
        rhs = r[Ad] + H @ (self.G[Ad] @ lamN)
        dlam[Ad] = np.linalg.solve(np.eye(len(Ad)) + H @ self.G[np.ix_(Ad, Ad)], rhs)
        return dlam, act


def _newton(cond, lam, tol_mm, max_iter, it0, steps, callback, full):
    """Newton on the candidate block from lam (m d,); returns (lam, iterations, converged)."""
    s = cond.state(lam)
    curvature = False
    prev_act = None
    for it in range(max_iter):
        dlam, act = cond.step(s, curvature)
        Gd = cond.G @ dlam
        slope = -float((s["b"] - s["lam"]) @ Gd)   # M'(lam) dlam = (G lam - G b) . dlam
        if curvature and not slope < 0.0 and np.abs(Gd).max(initial=0.0) > 0.0:
            curvature = False
            dlam, act = cond.step(s, curvature)
            Gd = cond.G @ dlam
            slope = -float((s["b"] - s["lam"]) @ Gd)

        def trial(t, lam=s["lam"], dlam=dlam):
            at = cond.state(lam + t * dlam)
            return at["M"], at

        taken = backtrack(trial, s["M"], slope, tries=MAX_HALVINGS, round_off=1e-13,
                          round_off_of_both=True)
        if taken is None:
            if curvature:   # the exact tangent's step did not descend: again without it
                curvature = False
                continue
            raise SolverDivergedError(
                f"mass-tensor contact: Newton iteration {it0 + it + 1} found no step that lowers "
                f"the energy ({MAX_HALVINGS} halvings)")
        t, s = taken.t, taken.state
        move = float(np.max(np.linalg.norm((t * Gd).reshape(-1, cond.d), axis=1), initial=0.0))
        steps.append(move)
        if callback is not None:
            callback(it0 + it + 1, full(s["lam"]))
        if not np.isfinite(move):
            raise SolverDivergedError(f"mass-tensor contact: Newton iteration {it0 + it + 1} "
                                      f"gave a non-finite displacement")
        same = prev_act is not None and np.array_equal(act, prev_act)
        if move < tol_mm and t == 1.0 and (curvature or not act.size):
            return s["lam"], it + 1, True
        # the exact tangent once a full step keeps the contact set: quadratic convergence
        curvature = t == 1.0 and same
        prev_act = act
    return s["lam"], max_iter, False


def solve_tips(cset, comp, pushes, u0, *, tol_mm: float = 1e-10, max_iter: int = 100,
               callback=None, it0: int = 0) -> TipSolution:
    """The equilibrium with the tips of ``cset`` (``solvers.contact.ContactSet``) pushed by
    ``pushes`` (mm, in tip order), on the compliance ``comp`` (``condensed.Compliance``) of the
    point types whose contactless answer is u0 (n, d) mm (module docstring). callback(it, u)
    after every Newton iteration (u (n, d): a back-substitution each)."""
    n, d = comp.n, comp.d
    o = cset.origins(pushes)
    radius = np.concatenate([np.full(t.sl.stop - t.sl.start, t.shape.radius)
                             for t in cset.tips]) if cset.tips else np.zeros(0)
    u0 = np.asarray(u0, float).reshape(n, d)
    lam_full = np.zeros((n, d))
    cols0 = comp.columns
    steps: list = []
    iterations = 0
    converged = False

    def full(lam_c, nodes):
        out = np.zeros((n, d))
        out[nodes] = lam_c.reshape(-1, d)
        return out

    def field(lam):
        return u0 - np.asarray(comp.apply(lam.reshape(-1))).reshape(n, d)

    u = u0
    rounds = 0
    while rounds < MAX_ROUNDS:
        y = cset.X + cset.S @ u
        _, _, g, _, _, _ = cset.point_terms(y, o)
        act_n = len(np.unique(cset.pv[g < 0.0]))
        inside = np.all(comp.pos[cset.pv] >= 0, axis=1)
        outside = (g < 0.0) & ~inside
        if not np.any(outside) and (rounds or not np.any(g < 0.0)):
            converged = converged or not rounds
            break   # no point outside the candidates presses on a tip: the answer is exact
        near = (g < REACH_RADII * radius) | (outside if rounds else False)
        rounds += 1
        comp.grow(np.unique(cset.pv[near]))
        cond = _Condensed(cset, comp, o, u0)
        nodes = comp.nodes
        lam, k, converged = _newton(
            cond, lam_full[nodes].reshape(-1), tol_mm, max_iter - iterations, it0 + iterations,
            steps, callback, lambda lam_c, nodes=nodes: field(full(lam_c, nodes)))
        iterations += k
        lam_full = full(lam, nodes)
        u = field(lam_full)
        if not converged:
            break
    else:
        converged = False
    return TipSolution(u=u, lam=lam_full, iterations=iterations, rounds=rounds,
                       converged=bool(converged), max_step_mm=steps,
                       candidates=len(comp.nodes), active=act_n,
                       columns=int(comp.columns - cols0))
