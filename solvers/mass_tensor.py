"""Mass Tensor Method (seed 001 section 2.4; Cotin, Delingette & Ayache 2000), numpy/scipy only.

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

Iterations (both use the same tensors and the same stopping rule: stop when the largest
displacement of any vertex in one iteration is below ``stop_mm``, seed value 0.01 mm):

* ``method="descent"`` -- the seed's quasi-static steepest descent: every free point moves along
  its (projected) force times its own step h_i = alpha / ||T_ii||_2, where the common factor
  alpha is the exact line search along that direction (the energy decreases every iteration,
  no step to tune). ``step_scale=s`` instead uses the fixed step h_i = s / ||T_ii||_2 (stable for
  s < 2 / lambda_max(diag(||T_ii||)^-1 K); larger values diverge and are reported).
* ``method="pcg"`` (default) -- beyond the seed: preconditioned conjugate gradients on the
  same tensors, block-Jacobi preconditioner T_ii^-1 (restricted to each point's free
  directions). Same stopping rule; on the phantom (3.3k tets, 4 x 15 mm pushes, E = 48 kPa)
  34 iterations against descent's 267 at 0.01 mm, and within 0.1 mm of the exact solution there
  (descent needs 0.001 mm for that: see bench/bench_mass_tensor.py).

Inside the iterations the tensors are applied as one CSR matrix P K P (P: per-vertex projector on
the free directions; ``MassTensorModel.matrix`` holds exactly T_ii / T_ij), which is the same
arithmetic as the edge loop of ``forces`` but one compiled sparse product per iteration.

Surface sliding is nonlinear (the tangent plane moves): descent projects and refreshes the
tangent planes every iteration; pcg solves with frozen tangent planes, projects, refreshes and
repeats until one such pass moves no vertex by ``stop_mm`` or more.

Lower-level API (for the implant-planning code)::

    model = MassTensorModel(points, cells, mu=..., lmbda=...)     # or material=Material(...)
    pts = PointTypes(model.n_vertices, model.gdim)
    pts.border(base_ids)
    pts.target(ids, positions, then_slide=Plane(p0, n))            # positions (k, d), mm
    pts.sliding(other_ids, TriSurface(surf_pts, surf_tris))
    sol = model.solve(pts, f_ext=None, method="pcg", stop_mm=0.01)  # -> MTSolution
    x_new = model.points + sol.u

Case-level API: ``solve(case, ...) -> meshes.results.SolveResult`` (solver "mass-tensor").
Divergence (NaN, growth, non-positive curvature) raises ``SolverDivergedError`` naming the
iteration and the vertex.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from meshes.errors import CaseError, SolverDivergedError
from meshes.mesh import deformation_state
from meshes.results import SolveResult

log = logging.getLogger("tissue.mass_tensor")

__all__ = [
    "MTSolution",
    "MassTensorModel",
    "Plane",
    "PointTypes",
    "TriSurface",
    "case_point_types",
    "solve",
    "stiffness_tensors",
]


# --------------------------------------------------------------------------- tensors
def _gradients(points: np.ndarray, cells: np.ndarray):
    """Barycentric gradients (m, d+1, d) in 1/mm and cell measures (m,) in mm^d."""
    x = points[cells]
    D = x[:, 1:] - x[:, :1]                      # (m, d, d) rows = edge vectors from vertex 0
    d = points.shape[1]
    det = np.linalg.det(D)
    vol = np.abs(det) / (6.0 if d == 3 else 2.0)
    inv = np.linalg.inv(D)                       # grad lambda_k (k>=1) = column k-1 of inv
    g = np.empty((len(cells), d + 1, d))
    g[:, 1:] = np.transpose(inv, (0, 2, 1))
    g[:, 0] = -g[:, 1:].sum(axis=1)
    return g, vol


def stiffness_tensors(points, cells, mu: float, lmbda: float):
    """Cotin's per-vertex and per-edge stiffness tensors.

    points (n, d) mm, cells (m, d+1), mu and lmbda in kPa. Returns ``(T_ii, edges, T_ij)``:
    T_ii (n, d, d) and T_ij (e, d, d) in mN/mm, edges (e, 2) with edges[:, 0] < edges[:, 1];
    the block of row j, column i is T_ij^T.
    """
    points = np.asarray(points, float)
    cells = np.asarray(cells, np.int64)
    n, d = points.shape
    g, vol = _gradients(points, cells)
    eye = np.eye(d)

    def block(a, b):
        ga, gb = g[:, a], g[:, b]
        k = (lmbda * ga[:, :, None] * gb[:, None, :] + mu * gb[:, :, None] * ga[:, None, :]
             + mu * np.einsum("mk,mk->m", ga, gb)[:, None, None] * eye)
        return k * vol[:, None, None]

    T_ii = np.zeros((n, d * d))
    for a in range(d + 1):
        kaa = block(a, a).reshape(-1, d * d)
        for c in range(d * d):
            T_ii[:, c] += np.bincount(cells[:, a], kaa[:, c], minlength=n)
    ii, jj, blocks = [], [], []
    for a in range(d + 1):
        for b in range(a + 1, d + 1):
            kab = block(a, b)
            i, j = cells[:, a], cells[:, b]
            swap = i > j
            kab[swap] = np.transpose(kab[swap], (0, 2, 1))
            ii.append(np.where(swap, j, i))
            jj.append(np.where(swap, i, j))
            blocks.append(kab.reshape(-1, d * d))
    ii, jj = np.concatenate(ii), np.concatenate(jj)
    blocks = np.concatenate(blocks)
    key = ii * n + jj
    uniq, inv = np.unique(key, return_inverse=True)
    T_ij = np.empty((len(uniq), d * d))
    for c in range(d * d):
        T_ij[:, c] = np.bincount(inv, blocks[:, c], minlength=len(uniq))
    edges = np.stack([uniq // n, uniq % n], axis=1)
    return T_ii.reshape(n, d, d), edges, T_ij.reshape(-1, d, d)


# --------------------------------------------------------------------------- surfaces
@dataclass(frozen=True)
class Plane:
    """The plane through ``point`` (mm) with normal ``normal`` (normalized on construction)."""

    point: tuple
    normal: tuple

    def __post_init__(self):
        p = np.asarray(self.point, float).reshape(-1)
        nv = np.asarray(self.normal, float).reshape(-1)
        nn = np.linalg.norm(nv)
        if p.shape != nv.shape or not np.isfinite(nn) or nn == 0 or not np.all(np.isfinite(p)):
            raise CaseError(f"Plane needs a finite point and a non-zero normal of the same "
                            f"dimension, got point={self.point!r}, normal={self.normal!r}")
        object.__setattr__(self, "point", tuple(p.tolist()))
        object.__setattr__(self, "normal", tuple((nv / nn).tolist()))

    def closest(self, x: np.ndarray):
        """Closest points (k, d) on the plane to x (k, d) and the unit normals there."""
        n = np.asarray(self.normal)
        y = x - ((x - np.asarray(self.point)) @ n)[:, None] * n
        return y, np.broadcast_to(n, x.shape).copy()


class TriSurface:
    """A triangulated surface in 3D: points (k, 3) mm, triangles (t, 3) vertex ids.

    ``closest(x)`` returns the closest surface points (exact point-triangle distance over the
    ``candidates`` triangles with the nearest centroids) and the unit face normals there.
    """

    def __init__(self, points, triangles, *, candidates: int = 16):
        from scipy.spatial import cKDTree

        self.points = np.asarray(points, float)
        self.triangles = np.asarray(triangles, np.int64)
        if self.points.ndim != 2 or self.points.shape[1] != 3 or self.triangles.ndim != 2 \
                or self.triangles.shape[1] != 3 or len(self.triangles) == 0:
            raise CaseError(f"TriSurface needs points (k, 3) and triangles (t, 3), got "
                            f"{self.points.shape} and {self.triangles.shape}")
        if self.triangles.min() < 0 or self.triangles.max() >= len(self.points):
            raise CaseError(f"TriSurface triangle ids out of range [0, {len(self.points)})")
        tri = self.points[self.triangles]
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area2 = np.linalg.norm(nrm, axis=1)
        if np.any(area2 == 0):
            raise CaseError(f"TriSurface has degenerate triangles, first "
                            f"{np.flatnonzero(area2 == 0)[:5].tolist()}")
        self._tri = tri
        self._normals = nrm / area2[:, None]
        self._tree = cKDTree(tri.mean(axis=1))
        self._k = min(candidates, len(tri))

    def closest(self, x: np.ndarray):
        x = np.asarray(x, float)
        _, cand = self._tree.query(x, k=self._k)
        cand = cand.reshape(len(x), -1)
        a, b, c = (self._tri[cand, k] for k in range(3))          # (q, k, 3)
        p = x[:, None, :]
        best = _closest_on_triangles(p, a, b, c)                  # (q, k, 3)
        dist = np.linalg.norm(best - p, axis=2)
        k = np.argmin(dist, axis=1)
        rows = np.arange(len(x))
        return best[rows, k], self._normals[cand[rows, k]]


def _closest_on_segment(p, a, b):
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-300), 0, 1)
    return a + t[..., None] * ab


def _closest_on_triangles(p, a, b, c):
    """Exact closest point on triangles (a, b, c) to p (broadcast over leading axes)."""
    e0, e1 = b - a, c - a
    n = np.cross(e0, e1)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    q = p - np.sum((p - a) * n, axis=-1)[..., None] * n           # projection on the plane
    d00, d01, d11 = (np.sum(e0 * e0, -1), np.sum(e0 * e1, -1), np.sum(e1 * e1, -1))
    w = q - a
    d20, d21 = np.sum(w * e0, -1), np.sum(w * e1, -1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    t = (d00 * d21 - d01 * d20) / den
    inside = (v >= 0) & (t >= 0) & (v + t <= 1)
    cands = [_closest_on_segment(p, a, b), _closest_on_segment(p, b, c), _closest_on_segment(p, c, a)]
    dists = np.stack([np.linalg.norm(s - p, axis=-1) for s in cands])
    k = np.argmin(dists, axis=0)
    edge = np.choose(k[..., None], cands)
    return np.where(inside[..., None], q, edge)


# --------------------------------------------------------------------------- point types
class PointTypes:
    """Point types of every vertex of a mesh with n vertices in dimension d (default all free).

    Linear prescriptions are stored per vertex as orthonormal normals q_l with values g_l
    (u_i . q_l = g_l, mm). Every method checks the new prescription against what the vertex
    already has and raises ``CaseError`` naming the vertex on a conflict.
    """

    def __init__(self, n_vertices: int, gdim: int = 3, reference_points=None):
        self.n, self.d = int(n_vertices), int(gdim)
        self.X = None if reference_points is None else np.asarray(reference_points, float)
        self.N = np.zeros((self.n, self.d, self.d))     # rows: constrained unit normals
        self.m = np.zeros(self.n, np.int64)             # number of constrained directions
        self.g = np.zeros((self.n, self.d))             # u . N[l] = g[l]
        self.label = np.array(["free"] * self.n, dtype=object)
        self.surface_of: dict[int, object] = {}          # vertex -> Plane/TriSurface (nonlinear)
        self.then_slide: dict[int, object] = {}          # target vertex -> surface for phase 2

    # -- helpers
    def _ids(self, verts):
        v = np.atleast_1d(np.asarray(verts, dtype=np.int64)).ravel()
        if v.size and (v.min() < 0 or v.max() >= self.n):
            raise CaseError(f"vertex ids out of range [0, {self.n}): {v[(v < 0) | (v >= self.n)][:5]}")
        return v

    def _add_many(self, verts, normals, values, what: str, tol: float = 1e-9):
        """Vectorized ``_add`` over vertices (repeated vertices handled in successive rounds)."""
        verts = np.asarray(verts, np.int64)
        normals = np.asarray(normals, float)
        values = np.asarray(values, float)
        if self.surface_of:
            hit = [v for v in verts.tolist() if v in self.surface_of]
            if hit:
                raise CaseError(f"vertex {hit[0]}: {what} conflicts with its sliding-on-surface type")
        todo = np.arange(len(verts))
        while todo.size:
            _, first = np.unique(verts[todo], return_index=True)
            now, todo = todo[first], np.delete(todo, first)
            v = verts[now]
            n = normals[now] / np.linalg.norm(normals[now], axis=1, keepdims=True)
            Q = self.N[v]                                    # unused rows are zero
            coef = np.einsum("kld,kd->kl", Q, n)
            r = n - np.einsum("kl,kld->kd", coef, Q)
            rn = np.linalg.norm(r, axis=1)
            implied = np.einsum("kl,kl->k", coef, self.g[v])
            dep = rn < 1e-9
            bad = dep & (np.abs(implied - values[now]) > tol * np.maximum(1.0, np.abs(values[now])))
            if np.any(bad):
                b = int(np.flatnonzero(bad)[0])
                vb = int(v[b])
                raise CaseError(
                    f"conflicting point types on vertex {vb}: {what} requires u.n = "
                    f"{values[now][b]:g} mm along n = {np.round(n[b], 6).tolist()}, but its "
                    f"{self.label[vb]} type gives {implied[b]:g} mm")
            ind = ~dep
            vi, k = v[ind], self.m[v[ind]]
            self.N[vi, k] = r[ind] / rn[ind, None]
            self.g[vi, k] = (values[now][ind] - implied[ind]) / rn[ind]
            self.m[vi] = k + 1

    def _set_labels(self, verts, lab):
        cur = self.label[verts].astype(str)
        self.label[verts] = np.where((cur == "free") | (cur == lab), lab, np.char.add(cur, "+" + lab))

    # -- public
    def free(self, verts):
        """No-op (every vertex is free unless given another type); kept for symmetry."""
        self._ids(verts)
        return self

    def border(self, verts):
        """Border points: u_i = 0."""
        v = np.unique(self._ids(verts))
        for c in range(self.d):
            self._add_many(v, np.broadcast_to(np.eye(self.d)[c], (len(v), self.d)),
                           np.zeros(len(v)), "border")
        self._set_labels(v, "border")
        return self

    def prescribe(self, verts, normals, values, *, label: str = "prescribed"):
        """Partial linear prescription u_i . n_i = g_i (mm) for each vertex (normals (k, d) or (d,),
        values (k,) or scalar). One component of a displacement, or sliding on a plane."""
        v = self._ids(verts)
        nrm = np.broadcast_to(np.asarray(normals, float), (len(v), self.d))
        val = np.broadcast_to(np.asarray(values, float), (len(v),))
        if not np.all(np.isfinite(nrm)) or np.any(np.linalg.norm(nrm, axis=1) == 0) \
                or not np.all(np.isfinite(val)):
            raise CaseError(f"{label}: normals must be finite and non-zero, values finite")
        self._add_many(v, nrm, val, label)
        self._set_labels(np.unique(v), label)
        return self

    def displacement(self, verts, values, *, label: str = "target"):
        """Target points given by their displacement (k, d) or (d,) mm."""
        v = self._ids(verts)
        val = np.broadcast_to(np.asarray(values, float), (len(v), self.d))
        if not np.all(np.isfinite(val)):
            raise CaseError(f"{label}: displacements must be finite")
        eye = np.eye(self.d)
        for c in range(self.d):
            self._add_many(v, np.broadcast_to(eye[c], (len(v), self.d)), val[:, c], label)
        self._set_labels(np.unique(v), label)
        return self

    def target(self, verts, positions, *, then_slide=None):
        """Target points: vertex i is placed at positions[i] (k, d) mm regardless of its force.
        With ``then_slide`` (Plane or TriSurface) the point becomes sliding on it once it has
        reached its target (see module docstring). Needs ``reference_points``."""
        if self.X is None:
            raise CaseError("PointTypes.target needs reference_points (use model.point_types())")
        v = self._ids(verts)
        pos = np.broadcast_to(np.asarray(positions, float), (len(v), self.d))
        self.displacement(v, pos - self.X[v], label="target")
        if then_slide is not None:
            _check_surface(then_slide, self.d)
            for vi in v.tolist():
                self.then_slide[vi] = then_slide
        return self

    def sliding(self, verts, surface):
        """Sliding points on a Plane (linear: exact projection) or a TriSurface (projected to
        the closest surface point, tangent plane refreshed as the point moves)."""
        _check_surface(surface, self.d)
        v = self._ids(verts)
        if isinstance(surface, Plane):
            if self.X is None:
                raise CaseError("sliding on a Plane needs reference_points")
            n = np.asarray(surface.normal)
            g = (np.asarray(surface.point) - self.X[v]) @ n       # u . n = (p0 - X) . n
            return self.prescribe(v, n, g, label="sliding")
        for vi in v.tolist():
            if self.m[vi] > 0 or vi in self.surface_of:
                raise CaseError(f"conflicting point types on vertex {vi}: sliding on a surface "
                                f"and {self.label[vi]}")
            self.surface_of[vi] = surface
            self.label[vi] = "sliding"
        return self

    def copy(self) -> PointTypes:
        out = PointTypes(self.n, self.d, self.X)
        out.N, out.m, out.g = self.N.copy(), self.m.copy(), self.g.copy()
        out.label = self.label.copy()
        out.surface_of = dict(self.surface_of)
        out.then_slide = dict(self.then_slide)
        return out

    # -- derived
    def projector(self) -> np.ndarray:
        """(n, d, d) projector onto each vertex's free directions."""
        P = np.broadcast_to(np.eye(self.d), (self.n, self.d, self.d)).copy()
        for k in range(self.d):
            sel = self.m > k
            q = self.N[sel, k]
            P[sel] -= q[:, :, None] * q[:, None, :]
        return P

    def prescribed_part(self) -> np.ndarray:
        """(n, d) the prescribed component sum_l g_l q_l of every vertex's displacement (mm)."""
        return np.einsum("nl,nld->nd", self.g, self.N)

    def counts(self) -> dict:
        labs, cnt = np.unique(self.label.astype(str), return_counts=True)
        return dict(zip(labs.tolist(), cnt.tolist()))


def _check_surface(s, d):
    if isinstance(s, Plane):
        if len(s.normal) != d:
            raise CaseError(f"Plane of dimension {len(s.normal)} used on a {d}D mesh")
    elif isinstance(s, TriSurface):
        if d != 3:
            raise CaseError("TriSurface sliding needs a 3D mesh")
    else:
        raise CaseError(f"a sliding surface must be a Plane or a TriSurface, got {type(s).__name__}")


# --------------------------------------------------------------------------- model
@dataclass(frozen=True)
class MTSolution:
    """Result of ``MassTensorModel.solve``: u (n, d) mm; iterations; converged (stopping rule met);
    residual = largest free-direction force imbalance (mN); max_step_mm per iteration;
    phases: iteration count at the end of each phase (target phase, sliding phase)."""

    u: np.ndarray
    iterations: int
    converged: bool
    residual: float
    max_step_mm: list = field(default_factory=list)
    phases: list = field(default_factory=list)


class MassTensorModel:
    """Linear-elastic P1 Mass Tensor model of a tetrahedral (3D) or triangular (2D plane strain)
    mesh: points (n, d) mm, cells (m, d+1); Lame parameters mu, lmbda in kPa (or ``material``
    with E, nu in kPa, as ``meshes.case.Material``)."""

    def __init__(self, points, cells, material=None, *, mu: float | None = None,
                 lmbda: float | None = None):
        if material is not None:
            mu, lmbda = material.mu, material.lmbda
        if mu is None or lmbda is None or not (np.isfinite(mu) and np.isfinite(lmbda)):
            raise CaseError(f"MassTensorModel needs material=... or finite mu and lmbda (kPa), "
                            f"got mu={mu!r}, lmbda={lmbda!r}")
        self.points = np.asarray(points, float)
        self.cells = np.asarray(cells, np.int64)
        if self.points.ndim != 2 or self.points.shape[1] not in (2, 3) \
                or self.cells.shape[1:] != (self.points.shape[1] + 1,):
            raise CaseError(f"points (n, 2|3) and cells (m, d+1) expected, got {self.points.shape} "
                            f"and {self.cells.shape}")
        self.mu, self.lmbda = float(mu), float(lmbda)
        self.n_vertices, self.gdim = self.points.shape
        self.T_ii, self.edges, self.T_ij = stiffness_tensors(self.points, self.cells, self.mu,
                                                             self.lmbda)
        self._K = None

    # -- forces
    def forces(self, u) -> np.ndarray:
        """Edge-based F_i = T_ii u_i + sum_j T_ij u_j (mN), (n, d), for u (n, d) mm. The elastic
        force of the tissue on vertex i is -F_i."""
        u = np.asarray(u, float).reshape(self.n_vertices, self.gdim)
        i, j = self.edges[:, 0], self.edges[:, 1]
        F = np.einsum("nab,nb->na", self.T_ii, u)
        fi = np.einsum("eab,eb->ea", self.T_ij, u[j])
        fj = np.einsum("eba,eb->ea", self.T_ij, u[i])
        for c in range(self.gdim):
            F[:, c] += np.bincount(i, fi[:, c], minlength=self.n_vertices)
            F[:, c] += np.bincount(j, fj[:, c], minlength=self.n_vertices)
        return F

    def matrix(self) -> sp.csr_matrix:
        """The same tensors as a node-major (dof = d*i + c) CSR matrix (mN/mm); used for the fast
        matrix-vector product inside the iterations (identical numbers to ``forces``)."""
        if self._K is None:
            d, n = self.gdim, self.n_vertices
            i, j = self.edges[:, 0], self.edges[:, 1]
            rows = np.concatenate([np.arange(n), i, j])
            cols = np.concatenate([np.arange(n), j, i])
            data = np.concatenate([self.T_ii, self.T_ij, np.transpose(self.T_ij, (0, 2, 1))])
            self._K = _bsr_from_blocks(rows, cols, data, n, d)
        return self._K

    def energy(self, u) -> float:
        """Strain energy 1/2 u . F(u) (kPa mm^3 = uJ)."""
        u = np.asarray(u, float).reshape(-1)
        return 0.5 * float(u @ (self.matrix() @ u))

    def point_types(self) -> PointTypes:
        """A fresh all-free PointTypes for this mesh."""
        return PointTypes(self.n_vertices, self.gdim, self.points)

    # -- solve
    def solve(self, types: PointTypes, *, f_ext=None, initial=None, method: str = "pcg",
              stop_mm: float = 0.01, max_iter: int = 200000, step_scale: float | None = None,
              callback=None) -> MTSolution:
        """Quasi-static equilibrium with the given point types.

        f_ext (n, d) mN external nodal forces (default none); initial (n, d) mm warm start (its
        prescribed components are replaced by the prescriptions); method "pcg" | "descent";
        stop when the largest per-vertex displacement in one iteration < stop_mm (mm);
        max_iter total iterations (converged=False when reached); step_scale: fixed descent
        step (see module docstring); callback(it, u) after every iteration (u (n, d) mm).
        """
        if method not in ("pcg", "descent"):
            raise CaseError(f"unknown Mass Tensor method {method!r}; methods: ['pcg', 'descent']")
        if not (isinstance(stop_mm, (int, float)) and stop_mm > 0):
            raise CaseError(f"stop_mm must be > 0 mm, got {stop_mm!r}")
        if types.n != self.n_vertices or types.d != self.gdim:
            raise CaseError(f"PointTypes for {types.n} vertices in {types.d}D does not match the "
                            f"model ({self.n_vertices} vertices, {self.gdim}D)")
        n, d = self.n_vertices, self.gdim
        f = np.zeros((n, d)) if f_ext is None else np.asarray(f_ext, float).reshape(n, d)
        u = np.zeros((n, d)) if initial is None else np.asarray(initial, float).reshape(n, d).copy()
        state = _State(self, f, stop_mm, max_iter, callback, step_scale)
        phases = []
        u = state.run(types, u, method)
        phases.append(state.it)
        if types.then_slide and state.it < max_iter:
            t2 = types.copy()
            for v, surf in types.then_slide.items():
                t2.N[v] = 0.0
                t2.m[v] = 0
                t2.g[v] = 0.0
                t2.label[v] = "free"
            t2.then_slide = {}
            for surf in {id(s): s for s in types.then_slide.values()}.values():
                vs = [v for v, s in types.then_slide.items() if s is surf]
                t2.sliding(vs, surf)
            u = state.run(t2, u, method)
            phases.append(state.it)
        return MTSolution(u, state.it, state.it < max_iter and state.ok, state.residual,
                          state.steps, phases)


def _bsr_from_blocks(rows, cols, data, n, d):
    order = np.lexsort((cols, rows))
    rows, cols, data = rows[order], cols[order], data[order]
    indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))]
    return sp.bsr_matrix((data, cols, indptr), shape=(d * n, d * n)).tocsr()


def _blockdiag(B):
    """(n, d, d) blocks -> block-diagonal CSR matrix (n d, n d)."""
    n, d, _ = B.shape
    return sp.bsr_matrix((B, np.arange(n), np.arange(n + 1)), shape=(n * d, n * d)).tocsr()


class _State:
    """Iteration bookkeeping shared by the phases of one solve."""

    def __init__(self, model, f, stop_mm, max_iter, callback, step_scale):
        self.model, self.f, self.stop = model, f, float(stop_mm)
        self.max_iter, self.callback, self.step_scale = int(max_iter), callback, step_scale
        self.K = model.matrix()
        self.it = 0
        self.steps: list = []
        self.residual = float("nan")
        self.ok = True
        self.hnorm = np.linalg.norm(model.T_ii, ord=2, axis=(1, 2))   # ||T_ii||_2, mN/mm
        ext = np.ptp(model.points, axis=0).max() if len(model.points) else 1.0
        self.blowup = 1e6 * max(1.0, ext)

    # linear algebra on (n, d) arrays
    def Kx(self, x):
        return (self.K @ x.reshape(-1)).reshape(x.shape)

    def _prec(self, types, P, method):
        """Per-vertex preconditioner blocks (n, d, d), restricted to the free directions."""
        if method == "descent":
            return P / self.hnorm[:, None, None]
        T = self.model.T_ii
        c = np.trace(T, axis1=1, axis2=2)[:, None, None] / self.model.gdim
        NN = np.einsum("nla,nlb->nab", types.N, types.N)         # rows beyond m are zero
        Minv = np.linalg.inv(T + c * NN)
        return np.einsum("nab,nbc,ncd->nad", P, Minv, P)

    def _planes(self, types, u):
        """Refresh tangent planes of surface-sliding vertices at their closest surface point."""
        if not types.surface_of:
            return types, 0.0
        X = self.model.points
        t = types.copy()
        moved = 0.0
        for surf in {id(s): s for s in types.surface_of.values()}.values():
            vs = np.array([v for v, s in types.surface_of.items() if s is surf], np.int64)
            y, nrm = surf.closest(X[vs] + u[vs])
            moved = max(moved, float(np.max(np.linalg.norm(y - X[vs] - u[vs], axis=1))))
            u[vs] = y - X[vs]
            t.N[vs] = 0.0
            t.N[vs, 0] = nrm
            t.m[vs] = 1
            t.g[vs] = 0.0
            t.g[vs, 0] = np.einsum("kd,kd->k", u[vs], nrm)
        return t, moved

    # surface sliding (pcg): rounds of (solve on fixed tangent planes, re-project) stop as
    # stalled when the largest move of a round has not shrunk by 1% over this many rounds
    # (a vertex at a crease of the surface can cycle between two triangles' planes)
    STALL_ROUNDS = 20

    def run(self, types, u, method):
        nonlinear = bool(types.surface_of)
        lin, _ = self._planes(types, u)
        best, since = np.inf, 0
        while True:
            start = u.copy()
            it0 = self.it
            u = self._linear(lin, u, method, refresh=types if (nonlinear and method == "descent")
                             else None)
            if not nonlinear or method == "descent" or self.it >= self.max_iter:
                return u
            lin, _ = self._planes(types, u)
            move = float(np.max(np.linalg.norm(u - start, axis=1)))
            if move < self.stop or self.it == it0:
                return u
            if move < 0.99 * best:
                best, since = move, 0
            else:
                since += 1
            if since >= self.STALL_ROUNDS:
                self.ok = False   # reported as not converged, with the state reached
                log.warning("mass-tensor: surface sliding stalled after %d iterations: a round "
                            "still moves a vertex %.3g mm (stopping rule %.3g mm)", self.it, move,
                            self.stop)
                return u

    def _operators(self, types, method, fold):
        """Projector P, preconditioner M and projected stiffness P K P as block-diagonal / CSR
        matrices acting on (n, d) arrays (fold: precompute P K P once for the phase)."""
        P = types.projector()
        Pm = _blockdiag(P)
        Mm = _blockdiag(self._prec(types, P, method))
        shape = (self.model.n_vertices, self.model.gdim)
        KP = (Pm @ self.K @ Pm).tocsr() if fold else None

        def proj(x):
            return (Pm @ x.reshape(-1)).reshape(shape)

        def applyM(x):
            return (Mm @ x.reshape(-1)).reshape(shape)

        def Kproj(x):   # x is in the free subspace: P K P x = P K x
            if KP is not None:
                return (KP @ x.reshape(-1)).reshape(shape)
            return proj(self.Kx(x))

        return proj, applyM, Kproj

    def _linear(self, types, u, method, refresh=None):
        """Iterate on u = u_c + P w until the stopping rule (refresh: re-project surfaces each
        iteration, descent only)."""
        proj, applyM, Kproj = self._operators(types, method, fold=refresh is None)
        u = types.prescribed_part() + proj(u)
        r = proj(self.f - self.Kx(u))
        z = applyM(r)
        p = z.copy()
        rz = float(np.vdot(r, z))
        r0 = max(float(np.abs(r).max(initial=0.0)), 1e-300)
        self.residual = float(np.abs(r).max(initial=0.0))
        while self.it < self.max_iter:
            if rz <= 0.0:
                if rz == 0.0:
                    break
                self._diverged("non-positive preconditioned residual", r)
            self.it += 1
            if method == "pcg":
                q = Kproj(p)
                pq = float(np.vdot(p, q))
                if not pq > 0.0:
                    self._diverged(f"non-positive curvature p.Kp = {pq:g} (stiffness not positive "
                                   f"definite)", p)
                alpha = rz / pq
                step = alpha * p
            else:
                q = Kproj(z)
                if self.step_scale is None:
                    zq = float(np.vdot(z, q))
                    if not zq > 0.0:
                        self._diverged(f"non-positive curvature z.Kz = {zq:g}", z)
                    alpha = rz / zq
                else:
                    alpha = float(self.step_scale)
                step = alpha * z
            u = u + step
            smax_v = np.linalg.norm(step, axis=1)
            k = int(np.argmax(smax_v)) if len(smax_v) else 0
            smax = float(smax_v[k]) if len(smax_v) else 0.0
            if not np.isfinite(smax) or smax > self.blowup:
                bad = np.flatnonzero(~np.isfinite(smax_v))
                v = int(bad[0]) if bad.size else k
                raise SolverDivergedError(
                    f"mass-tensor {method}: diverged at iteration {self.it}: vertex {v} moved "
                    f"{smax_v[v]:g} mm in one iteration")
            self.steps.append(smax)
            if refresh is not None:
                types, _ = self._planes(refresh, u)
                proj, applyM, Kproj = self._operators(types, method, fold=False)
                r = proj(self.f - self.Kx(u))
            else:
                r = r - alpha * q
            rmax = float(np.abs(r).max(initial=0.0))
            self.residual = rmax
            if not np.isfinite(rmax) or rmax > 1e12 * r0:
                self._diverged(f"residual grew from {r0:g} to {rmax:g} mN", r)
            if self.callback is not None:
                self.callback(self.it, u)
            if smax < self.stop:
                break
            z = applyM(r)
            rz_new = float(np.vdot(r, z))
            if method == "pcg":
                p = z + (rz_new / rz) * p
            rz = rz_new
        self.residual = float(np.abs(proj(self.f - self.Kx(u))).max(initial=0.0))
        return u

    def _diverged(self, why, field_):
        a = np.linalg.norm(np.nan_to_num(field_, nan=np.inf), axis=1)
        v = int(np.argmax(a)) if len(a) else 0
        raise SolverDivergedError(f"mass-tensor: diverged at iteration {self.it}, vertex {v}: {why}")


# --------------------------------------------------------------------------- Case level
def _axis_of(normal, tol=1e-12):
    n = np.abs(normal)
    k = int(np.argmax(n))
    return k if np.all(np.delete(n, k) <= tol) else None


def case_point_types(case) -> PointTypes:
    """Point types of a Case: prescribed dofs (fixed / displacement / affine / axis-aligned sliding)
    become per-component prescriptions (border / target points when all components are set),
    oblique sliding becomes planar sliding u . n = value."""
    mesh = case.mesh
    d = mesh.gdim
    c = case.constraints
    types = PointTypes(mesh.n_vertices, d, mesh.points)
    verts, comps = c.dofs // d, c.dofs % d
    eye = np.eye(d)
    for k in range(d):
        sel = comps == k
        if np.any(sel):
            types.prescribe(verts[sel], eye[k], c.values[sel], label="prescribed")
    for vs, nrm, g in c.sliding:
        types.prescribe(vs, nrm, g, label="sliding")
    full = types.m == d
    zero = full & np.all(np.abs(types.g) == 0.0, axis=1)
    types.label[full] = "target"
    types.label[zero] = "border"
    return types


_MODELS: dict = {}


def _model_for(case) -> MassTensorModel:
    key = (id(case.mesh), case.material.mu, case.material.lmbda)
    m = _MODELS.get(key)
    same = m is not None and (m.points is case.mesh.points or np.array_equal(m.points, case.mesh.points)) \
        and (m.cells is case.mesh.cells or np.array_equal(m.cells, case.mesh.cells))
    if not same:
        m = MassTensorModel(case.mesh.points, case.mesh.cells, case.material)
        _MODELS.clear()
        _MODELS[key] = m
    return m


def solve(case, *, pushes=None, initial=None, method: str = "pcg", stop_mm: float = 0.01,
          max_iter: int = 200000, callback=None, progress: bool = False,
          step_scale: float | None = None) -> SolveResult:
    """Mass Tensor solve of a Case (linear elasticity with the Case's E, nu, whatever its model).

    pushes: actuator name -> push (mm); initial (n, d) mm warm start; method "pcg" | "descent";
    stop_mm: stopping rule (largest per-vertex displacement in one iteration, mm); callback(it, u)
    every iteration. Returns SolveResult(solver="mass-tensor"): u (n, d) mm, probes (mm),
    reactions per Dirichlet region = sum over its prescribed directions of F(u) - f_ext (mN),
    strain_energy 1/2 u.F(u) (kPa mm^3), iterations, residual (largest free-direction force
    imbalance, mN), history={"max_step_mm": [...]}.
    """
    t0 = time.perf_counter()
    case.material.require_compressible("the Mass Tensor solver")
    case.require_no_contact("the Mass Tensor solver")
    case = case.with_pushes(pushes)   # idle patches held unless the Case frees them
    model = _model_for(case)
    types = case_point_types(case)
    n, d = case.mesh.n_vertices, case.mesh.gdim
    f = case.external_forces(1.0).reshape(n, d)
    cb = callback
    if progress:
        def cb(it, u, _cb=callback):
            if it % 100 == 0:
                print(f"mass-tensor {method}: iteration {it}", flush=True)
            if _cb is not None:
                _cb(it, u)
    sol = model.solve(types, f_ext=f, initial=initial, method=method, stop_mm=stop_mm,
                      max_iter=max_iter, step_scale=step_scale, callback=cb)
    u = sol.u
    F = model.forces(u)
    r = F - f
    reactions = _reactions(case, r)
    wall = time.perf_counter() - t0
    return SolveResult(
        u=u, converged=sol.converged, iterations=sol.iterations, residual=sol.residual,
        wall_time_s=wall, solver="mass-tensor", probes=case.probe_values(u), reactions=reactions,
        strain_energy=0.5 * float(np.vdot(u, F)), load_steps=1, degree=1, case_name=case.name,
        n_vertices=n, n_cells=case.mesh.n_cells, history={"max_step_mm": list(sol.max_step_mm)},
        extra={"method": method, "stop_mm": float(stop_mm), "point_types": types.counts(),
               "model": "linear-elastic",
               **({"model_note": f"the Mass Tensor Method is a linear model: it solved linear "
                                 f"elasticity with the case's E and nu, not its "
                                 f"{case.material.model} material"}
                  if case.material.model != "linear-elastic" else {}),
               **deformation_state(case.mesh, u)})


def _reactions(case, r):
    """Region -> (d,) reaction (mN): r summed over the region's prescribed dofs / normals."""
    d = case.mesh.gdim
    c = case.constraints
    out = case.prescribed_reactions(r)
    oblique = [b for b in case.boundaries if b.type == "sliding"
               and _axis_of(np.asarray(b.normal, float) / np.linalg.norm(b.normal)) is None]
    taken = np.zeros((case.mesh.n_vertices, d), bool)
    taken.reshape(-1)[c.dofs] = True
    for b, (vs, nrm, _) in zip(oblique, c.sliding):
        out.setdefault(b.region, np.zeros(d))
        pure = ~taken[vs].any(axis=1)               # only the sliding condition on the vertex
        out[b.region] += (r[vs[pure]] @ nrm).sum() * nrm
        mixed = vs[~pure]                           # prescribed dofs already counted by owner
        out[b.region] += np.where(taken[mixed], 0.0, r[mixed]).sum(axis=0)
        taken[vs] = True                            # a vertex counts once
    return out
