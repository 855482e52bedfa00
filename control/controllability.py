"""Positive-basis controllability and the manipulability index of seed 000 (section III-B).

Definitions 1-4 and Theory 1 of seed 000 (Davis 1954): a set of r vectors a_i (the columns of A,
n x r) *positively spans* R^n when every vector is a combination with lambda_i >= 0. Rigorous test
used here (Davis' theorem): A positively spans R^n  <=>  rank A = n and there is lambda with
A lambda = 0 and lambda_i >= 1 for all i (strictly positive null combination) -- one LP.
*Positively independent*: no a_i lies in the cone of the others (one LP per column, residual
minimized in the 1-norm). A *positive basis* is a positively independent, positively spanning set;
it has between n + 1 (minimal) and 2n (maximal) vectors (Theory 1). Note: a maximal positive
basis of R^2 consists of two exactly opposite pairs; the target-plane columns of a real J_s for four
actuators at 90 deg are slightly off that, so three of them already positively span and the set is
a positive spanning set, not a positive basis -- ``positively_spans`` is the controllability test.

Manipulability (eq. 21): index = ||p||_2 / sum_i ||q_i||_2 with q_i = u_i d_i the displacement of
actuator i (u_i >= 0 mm, ||q_i|| = u_i since |d_i| = 1), found from the inverse problem (eq. 22)

    min_u ||p - J_s u||_2   s.t.  u_i >= 0  (push only).

Tie-break (the minimizer is not unique when J_s is 2x4): the point reached p* = J_s u is unique
(the Euclidean projection of p onto the convex cone of J_s's columns, computed by NNLS); among all
u >= 0 with J_s u = p*, take the least total actuator travel sum_i u_i (an LP). Its optimal value,
hence the index ||p*|| / sum u, is unique whatever solver computes it (tested against a second
solver). When p* != p (goal outside the positive span) ``reachable`` is False and p* is the closest
reachable displacement.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog, nnls

from tissue_reference.errors import CaseError, TissueError

from .dof_maps import point_matrix
from .jacobian import dirichlet_jacobian
from .mpc import quiet_qpoases

log = logging.getLogger("tissue.control")

__all__ = [
    "TASKS",
    "ManipulabilityResult",
    "UnreachableGoalError",
    "basis_kind",
    "inverse_push",
    "is_positive_basis",
    "manipulability",
    "manipulability_map",
    "positively_independent",
    "positively_spans",
    "task_goal",
]


class UnreachableGoalError(TissueError):
    """The goal lies outside the positive span of the actuators' Jacobian columns.

    ``closest`` is the closest reachable displacement (mm, controlled coordinates), ``pushes`` the
    push-only actuator displacements (mm) that reach it."""

    def __init__(self, message, *, closest=None, pushes=None):
        super().__init__(message)
        self.closest = closest
        self.pushes = pushes


def _mat(A, what="A"):
    A = np.asarray(A, float)
    if A.ndim != 2 or A.size == 0 or not np.all(np.isfinite(A)):
        raise CaseError(f"{what} must be a finite non-empty (n, r) matrix (columns are vectors), "
                        f"got shape {A.shape}")
    return A


def positively_spans(A, *, tol=1e-9) -> bool:
    """Do the columns of A (n x r) positively span R^n? (Davis: rank n and a strictly positive
    null combination.) tol: relative rank tolerance."""
    A = _mat(A)
    n, r = A.shape
    s = np.linalg.svd(A, compute_uv=False)
    if r < n + 1 or s.size < n or s[n - 1] <= tol * s[0]:
        return False
    res = linprog(np.ones(r), A_eq=A, b_eq=np.zeros(n), bounds=[(1.0, None)] * r, method="highs")
    return bool(res.status == 0)


def _cone_residual(B, a, method="highs"):
    """min_lambda>=0 ||B lambda - a||_1 (LP)."""
    n, m = B.shape
    if m == 0:
        return float(np.abs(a).sum())
    c = np.concatenate([np.zeros(m), np.ones(2 * n)])
    Aeq = np.hstack([B, np.eye(n), -np.eye(n)])
    res = linprog(c, A_eq=Aeq, b_eq=a, bounds=[(0, None)] * (m + 2 * n), method=method)
    if res.status != 0:
        raise RuntimeError(f"linprog failed on a feasible LP: {res.message}")
    return float(res.fun)


def positively_independent(A, *, tol=1e-9) -> bool:
    """No column of A is a positive combination of the others (Definition 3)."""
    A = _mat(A)
    for i in range(A.shape[1]):
        a = A[:, i]
        if _cone_residual(np.delete(A, i, axis=1), a) <= tol * max(np.abs(a).sum(), 1e-300):
            return False
    return True


def is_positive_basis(A, *, tol=1e-9) -> bool:
    """Positively spanning and positively independent (Definition 4)."""
    return positively_spans(A, tol=tol) and positively_independent(A, tol=tol)


def basis_kind(A, *, tol=1e-9) -> str:
    """'minimal' (n + 1 vectors), 'maximal' (2n), 'intermediate', or 'not a positive basis'."""
    A = _mat(A)
    if not is_positive_basis(A, tol=tol):
        return "not a positive basis"
    n, r = A.shape
    return "minimal" if r == n + 1 else "maximal" if r == 2 * n else "intermediate"


# ----------------------------------------------------------------------------- eq. 21-22
@dataclass(frozen=True)
class ManipulabilityResult:
    """index (dimensionless, eq. 21); pushes u (mm, >= 0); reached p* = J_s u (mm);
    reachable: p* equals p to tol; residual ||p - p*|| (mm)."""

    index: float
    pushes: np.ndarray
    reached: np.ndarray
    reachable: bool
    residual: float


def inverse_push(Js, p, *, solver="highs", tol=1e-7):
    """Eq. 22 with the least-travel tie-break (module docstring). Js (m, r) mm/mm, p (m,) mm.

    solver: "highs" | "highs-ds" | "highs-ipm" (scipy linprog) or "casadi:<conic plugin>"
    (e.g. "casadi:qpoases", "casadi:highs") for the travel LP. Returns (u, p_star, residual)."""
    Js = _mat(Js, "J_s")
    p = np.asarray(p, float).reshape(-1)
    if p.shape != (Js.shape[0],):
        raise CaseError(f"goal p of shape {p.shape} does not match J_s rows {Js.shape[0]}")
    scale = max(np.abs(Js).max(), 1e-300)
    u0, _ = nnls(Js / scale, p)
    p_star = Js @ (u0 / scale)
    residual = float(np.linalg.norm(p - p_star))
    if residual <= tol * max(np.linalg.norm(p), 1.0):
        p_star = p  # reachable: reach p itself exactly
    r = Js.shape[1]
    if solver.startswith("casadi:"):
        u = _travel_lp_casadi(Js, p_star, solver.split(":", 1)[1])
    else:
        if solver not in ("highs", "highs-ds", "highs-ipm"):
            raise CaseError(f"unknown solver {solver!r}: highs, highs-ds, highs-ipm, "
                            f"casadi:<plugin>")
        # the LP on the scaled rows (the same feasible set, entries of order 1)
        out = linprog(np.ones(r), A_eq=Js / scale, b_eq=p_star / scale, bounds=[(0, None)] * r,
                      method=solver, options={"primal_feasibility_tolerance": 1e-10,
                                              "dual_feasibility_tolerance": 1e-10})
        if out.status == 0:
            u = np.maximum(out.x, 0.0)
        else:
            # p* = J_s u0 with u0 >= 0, so the LP is feasible and only its tolerances failed:
            # keep the non-negative least-squares pushes, without the least-travel tie-break
            log.warning("least-travel LP (%s) did not solve (%s): using the non-negative "
                        "least-squares pushes", solver, out.message)
            u = u0 / scale
    return u, p_star, residual


def _travel_lp_casadi(Js, p_star, plugin):
    import casadi as ca

    _, r = Js.shape
    qp = {"h": ca.DM(r, r).sparsity(), "a": ca.DM(Js).sparsity()}
    opts = {"qpoases": {"printLevel": "none"}, "highs": {"highs": {"output_flag": False}}}
    with quiet_qpoases():
        S = ca.conic("travel", plugin, qp, opts.get(plugin, {}))
        sol = S(h=ca.DM(r, r), g=np.ones(r), a=Js, lba=p_star, uba=p_star, lbx=np.zeros(r),
                ubx=np.full(r, np.inf))
    if not S.stats()["success"]:
        raise RuntimeError(f"least-travel LP failed (casadi {plugin}): "
                           f"{S.stats()['return_status']}")
    return np.maximum(np.asarray(sol["x"]).ravel(), 0.0)


def manipulability(Js, p, *, solver="highs") -> ManipulabilityResult:
    """Eq. 21: ||p*||_2 / sum_i u_i with u from :func:`inverse_push` (p* = p when reachable)."""
    u, p_star, residual = inverse_push(Js, p, solver=solver)
    travel = float(u.sum())
    idx = float(np.linalg.norm(p_star) / travel) if travel > 0 else 0.0
    reachable = bool(np.allclose(p_star, p, rtol=0, atol=1e-12))
    return ManipulabilityResult(idx, u, np.asarray(p_star, float), reachable, residual)


# ----------------------------------------------------------------------------- tasks
# Seed 000 section III-B, in the target plane (x, y), displacements in mm; None = free coordinate.
TASKS = {1: (-5.0, None), 2: (None, -5.0), 3: (5.0, 5.0)}


def task_goal(task, gdim=3, distance: float = 5.0):
    """(goal (gdim,) mm with 0 on free coordinates, mask (gdim,) bool of controlled coordinates)
    for seed task 1, 2 or 3 (z is always free), each controlled coordinate moved ``distance`` mm
    (the seed's 5 mm by default; smaller for bodies whose targets move little per mm of push)."""
    if task not in TASKS:
        raise CaseError(f"unknown task {task!r}; tasks: {sorted(TASKS)} (1: -x 5 mm, y free; "
                        f"2: -y 5 mm, x free; 3: +x and +y 5 mm)")
    if isinstance(distance, bool) or not isinstance(distance, (int, float, np.floating)) or \
            not (np.isfinite(distance) and distance > 0):
        raise CaseError(f"task distance must be a number of mm > 0, got {distance!r}")
    spec = TASKS[task]
    goal = np.zeros(gdim)
    mask = np.zeros(gdim, bool)
    for c, v in enumerate(spec):
        if v is not None:
            goal[c] = v / 5.0 * distance
            mask[c] = True
    return goal, mask


def manipulability_map(case, K, *, plane_z=15.0, spacing=4.0, tasks=(1, 2, 3), solver="highs"):
    """Manipulability index (eq. 21) over the section z = plane_z (mm) on a grid of ``spacing`` mm,
    from the Dirichlet Jacobian of the Case (P1) at tangent K (mN/mm): one factorization gives the
    full-field sensitivity du/ds_i, interpolated at every grid point.

    Returns a dict: "x", "y" (grid axes, mm), "inside" (grid mask), "actuators", and per task
    "task<k>": {"index": grid (NaN outside the mesh or where the goal is unreachable),
    "reachable": grid mask}."""
    import scipy.sparse as sp

    if not (np.isfinite(spacing) and spacing > 0):
        raise CaseError(f"map spacing must be > 0 mm, got {spacing!r}")
    n = K.shape[0]
    if n != case.mesh.gdim * case.mesh.n_vertices:
        raise CaseError(f"manipulability_map needs a P1 tangent ({case.mesh.gdim}*"
                        f"{case.mesh.n_vertices} dofs), got K of shape {K.shape}")
    X = case.mesh.points
    lo, hi = X[:, :2].min(0), X[:, :2].max(0)
    xs = np.arange(np.ceil(lo[0] / spacing) * spacing, hi[0] + 1e-9, spacing)
    ys = np.arange(np.ceil(lo[1] / spacing) * spacing, hi[1] + 1e-9, spacing)
    gx, gy = np.meshgrid(xs, ys)
    pts = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, plane_z)])
    Pm, inside = point_matrix(case.mesh, pts, n_dofs=n)
    du = dirichlet_jacobian(case, K, P=sp.identity(n, format="csr")).J   # (n, r)
    Jgrid = np.asarray(Pm @ du)                                           # (3 * npts, r)
    out = {"x": xs, "y": ys, "inside": inside.reshape(gx.shape), "plane_z": plane_z,
           "actuators": [a.name for a in case.actuators]}
    for t in tasks:
        goal, mask = task_goal(t)
        idx = np.full(len(pts), np.nan)
        reach = np.zeros(len(pts), bool)
        for i in np.flatnonzero(inside):
            r = manipulability(Jgrid[3 * i: 3 * i + 3][mask], goal[mask], solver=solver)
            reach[i] = r.reachable
            if r.reachable:
                idx[i] = r.index
        out[f"task{t}"] = {"index": idx.reshape(gx.shape), "reachable": reach.reshape(gx.shape)}
    return out
