"""Mass Tensor Method (seed 001 section 2.4; Cotin, Delingette & Ayache 2000), numpy/scipy only.

Laws (``require_law``; the registry's ``laws`` of "mass-tensor"): a linear-elastic Case, and a
Neo-Hookean one (seed 001's fast approximation of tissue) solved as linear elasticity of its E
and nu with the answer's ``model_note`` saying so; a Case of any other law is refused by name
(NotModeledError, a CaseError), with ``--material linear-elastic`` or another solver (admm,
fem: every law) as the way on.

Equation: linear elasticity, P1 simplices, K u = f (stiffness K in mN/mm, u in mm, f in mN),
psi = mu eps:eps + lambda/2 tr(eps)^2 (mu, lambda in kPa = mN/mm^2). The stiffness is stored the
Cotin way, as one d x d tensor per vertex and one per edge, precomputed once:

    T_ii = sum_{cells c of i}  K^c_ii,      T_ij = sum_{cells c of edge ij} K^c_ij,
    K^c_ab = V_c [ lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I ]

(g_a: gradient of the barycentric coordinate of local vertex a, 1/mm; V_c: cell volume, mm^3,
or area x 1 mm in 2D plane strain). The elastic force of the tissue on vertex i is -F_i with

    F_i = T_ii u_i + sum_{j ~ i} T_ij u_j          (mN; T_ji = T_ij^T),

which ``MassTensorModel.forces`` computes edge by edge. At equilibrium the force balance
F_i = f_ext_i holds at every free direction of every point.

Point types (seed 001): every vertex is one of

* free     -- moves with its force;
* border   -- does not move (u_i = 0);
* target   -- placed at a prescribed position (mm) regardless of its force;
* sliding  -- stays on a plane (``Plane(point, normal)``) or on a triangulated surface
  (``TriSurface(points, triangles)``) and moves with the tangential part of its force; on a
  surface it is projected to the closest surface point after each move;
* target -> sliding: a target point given ``then_slide=surface`` is switched to sliding on that
  plane/surface once it has reached its target (phase 1 = equilibrium with the target held,
  phase 2 = the same point released onto the surface, starting from that state).

A vertex may also carry partial linear prescriptions ``u_i . n = g`` (one component, or an
oblique plane: that is how the Case's axis-aligned / oblique ``sliding`` and ``components``
displacements arrive). Prescriptions on one vertex are combined; two that disagree (e.g. target
and border with different values, two targets, a plane the target does not lie on) are rejected
when the ``PointTypes`` is built, with a ``CaseError`` naming the vertex.

Solves (all on the same tensors):

* ``method="direct"`` (default) -- one sparse factorization of the projected tensors,
  P K P + (I - P), symmetric positive definite, per phase (and per round of surface sliding):
  by the ``factorize`` hook when given (the command line and ``tissue verify`` pass CHOLMOD
  through PETSc, ``fem_reference.cholmod_factor``), else SuperLU with a minimum-degree ordering.
  The factorization is kept in the model for each pattern of point types, so another push is
  one back-substitution. It is the equilibrium the iterations below tend to, to round-off, so
  the answer carries no stopping error. The iterations' rule (a largest per-vertex move below
  ``stop_mm``) bounds the last step, not the error: PCG stopped there on the phantom was 0.047 mm
  from the exact answer at A1 = 10 mm (5,965 tets), above its own 0.01 mm.

* ``method="amg"`` -- for large meshes: conjugate gradients on the same projected tensors,
  preconditioned by an aggregation AMG V-cycle (``solvers.admm.amg``) of the scalar matrix of
  the tensors' traces on the vertices not fully held (a scaled P1 Laplacian; one V-cycle per
  displacement component), kept in the model per pattern of point types like the
  factorization. It stops when the distance still to go, estimated from its last move s and
  the slowest contraction rho of its last moves as s rho / (1 - rho)
  (``iterations.distance_to_go``), is below half of ``stop_mm``. That is an estimate, not a
  bound: on the glued phantom at 0.01 mm it ended 1.8e-3 to 2.9e-3 mm from the exact answer
  in 15-25 iterations from 1.7k to 185k tets, but on a box at nu = 0.49 the error reached 1.1
  times the stop (it warns above nu = 0.48; "direct" has no stopping error). Work and memory
  are O(n): at 185k tets a first solve (tensors included) took 1.0 s against the direct
  solve's 7.2 s and the linear reference's 5.8 s, and kept 11 MiB for the next solve against
  the factor's 806 MiB (bench/bench_mass_tensor_speed.py).

The seed's iterations (both stop when the largest displacement of any vertex in one iteration is
below ``stop_mm``, seed value 0.01 mm):

* ``method="descent"`` -- the seed's quasi-static steepest descent: every free point moves along
  its (projected) force times its own step h_i = alpha / ||T_ii||_2, where the common factor
  alpha is the exact line search along that direction (the energy decreases every iteration,
  no step to tune). ``step_scale=s`` instead uses the fixed step h_i = s / ||T_ii||_2 (stable for
  s < 2 / lambda_max(diag(||T_ii||)^-1 K); larger values diverge and are reported).
* ``method="pcg"`` -- beyond the seed: preconditioned conjugate gradients on the
  same tensors, block-Jacobi preconditioner T_ii^-1 (restricted to each point's free
  directions). Same stopping rule; on the phantom (3.3k tets, 4 x 15 mm pushes, E = 48 kPa)
  34 iterations against descent's 267 at 0.01 mm, and within 0.1 mm of the exact solution there
  (descent needs 0.001 mm for that: see bench/bench_mass_tensor.py).

Inside the iterations the tensors are applied as one CSR matrix P K P (P: per-vertex projector on
the free directions; ``MassTensorModel.matrix`` holds exactly T_ii / T_ij; "amg" applies K and
then P rather than forming their product), which is the same arithmetic as the edge loop of
``forces`` but one compiled sparse product per iteration.

Rigid tips (frictionless indenters, method "direct"): the reference's discrete contact penalty
(``solvers.contact``, the energy the P1 reference and ADMM minimize: k phi(-g) at the points of
the contact rule, k = beta E / h) added to the linear model's energy, solved by Newton condensed
on the skin near the tips (``contact``): u = u_0 - G lam with u_0 the contactless answer,
G = P A^-1 P the compliance of the free directions and lam the tips' nodal forces, so each
Newton iteration is one dense solve on the dofs in contact, with G's block on the candidate
vertices made once (one back-substitution per column, ``condensed.Compliance``) and kept with
the factorization; the whole field is one more back-substitution. On the linear law it is the
P1 reference's discrete problem: the same answer to 1e-10 mm (tests/test_mass_tensor_contact.py;
all four tips of phantom-indenter-control at 5 mm: 3.8e-10 mm, 0.23 s cold and 0.08 s warm
against the linear P1 reference's 2.0 s, bench/bench_mass_tensor_contact.py). Tied tips and the
iterative methods with tips are refused by name (``require_modeled``).

Surface sliding is nonlinear (the tangent plane moves): descent projects and refreshes the
tangent planes every iteration; direct, amg and pcg solve with frozen tangent planes, project,
refresh and repeat until one such pass moves no vertex by ``stop_mm`` or more.

Lower-level API (for the implant-planning code)::

    model = MassTensorModel(points, cells, mu=..., lmbda=...)     # or material=Material(...)
    pts = PointTypes(model.n_vertices, model.gdim)
    pts.border(base_ids)
    pts.target(ids, positions, then_slide=Plane(p0, n))            # positions (k, d), mm
    pts.sliding(other_ids, TriSurface(surf_pts, surf_tris))
    sol = model.solve(pts, f_ext=None, method="direct")            # -> MTSolution
    x_new = model.points + sol.u

Case-level API: ``solve(case, ...) -> model.results.SolveResult`` (solver "mass-tensor").
Divergence (NaN, growth, non-positive curvature) raises ``SolverDivergedError`` naming the
iteration and the vertex.

Modules: ``tensors`` (stiffness tensors, block-sparse helpers), ``surfaces`` (Plane,
TriSurface), ``point_types`` (PointTypes), ``iterations`` (the direct solve, PCG and AMG-PCG,
descent, surface-sliding rounds, divergence checks), ``condensed`` (the compliance G and its
kept block), ``contact`` (the rigid tips' condensed Newton), ``model`` (MassTensorModel,
MTSolution), ``driver`` (Case-level ``solve``).
"""
from __future__ import annotations

from .driver import case_point_types, forget_factorizations, require_law, require_modeled, solve
from .model import METHODS, MassTensorModel, MTSolution
from .point_types import PointTypes
from .surfaces import Plane, TriSurface
from .tensors import stiffness_tensors

__all__ = [
    "METHODS",
    "MTSolution",
    "MassTensorModel",
    "Plane",
    "PointTypes",
    "TriSurface",
    "case_point_types",
    "forget_factorizations",
    "require_law",
    "require_modeled",
    "solve",
    "stiffness_tensors",
]
