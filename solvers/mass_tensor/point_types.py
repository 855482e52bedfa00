"""Point types of the vertices (free, border, target, sliding, target -> sliding) stored as
per-vertex linear prescriptions u_i . q_l = g_l with orthonormal q_l, conflicts between
prescriptions on one vertex rejected with a ``CaseError`` naming the vertex; and the projector on
each vertex's free directions that the iterations use."""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import CaseError

from .surfaces import Plane, check_surface


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
        cur = self.label[verts]
        plain = (cur == "free") | (cur == lab)
        self.label[verts[plain]] = lab
        self.label[verts[~plain]] = [f"{c}+{lab}" for c in cur[~plain]]

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
        reached its target (see the package docstring). Needs ``reference_points``."""
        if self.X is None:
            raise CaseError("PointTypes.target needs reference_points (use model.point_types())")
        v = self._ids(verts)
        pos = np.broadcast_to(np.asarray(positions, float), (len(v), self.d))
        self.displacement(v, pos - self.X[v], label="target")
        if then_slide is not None:
            check_surface(then_slide, self.d)
            for vi in v.tolist():
                self.then_slide[vi] = then_slide
        return self

    def sliding(self, verts, surface):
        """Sliding points on a Plane (linear: exact projection) or a TriSurface (projected to
        the closest surface point, tangent plane refreshed as the point moves)."""
        check_surface(surface, self.d)
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

