"""Dirichlet conditions of a Case on the reference's function space: fixed, displacement,
affine, axis-aligned sliding, and per-vertex overrides, each as one DirichletBC per displacement
component (values in mm); the ReferenceSolver owns one (``Boundary``)."""
from __future__ import annotations

import dolfinx
import dolfinx.fem
import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Case


class Boundary:
    """The DirichletBCs of a Case on the displacement part ``Wu`` of the unknown's space, and the
    nodes of its facet regions. V: the (collapsed) displacement space; dm: the DolfinxMesh;
    oblique: the sliding regions held by a penalty instead (no DirichletBC); degree: the
    displacement's; node_vertex: the Case vertex of each displacement node (-1 for edge
    nodes), of the Case mesh's n_vertices; n_unknowns: the local size of the unknown's array;
    umap: the unknown's dof of each displacement dof. The collapsed component spaces and
    region nodes are cached."""

    def __init__(self, *, Wu, V, dm, gdim: int, oblique, degree: int, node_vertex,
                 n_vertices: int, n_unknowns: int, umap):
        self.Wu, self.V, self.dm, self.gdim = Wu, V, dm, gdim
        self.oblique = tuple(oblique)
        self.degree, self.node_vertex, self.n_vertices = degree, node_vertex, n_vertices
        self.n_unknowns, self.umap = n_unknowns, umap
        self._subs = {}
        self._region_dofs = {}

    def dirichlet_bcs(self, case: Case, scale: float, override=None):
        """Dirichlet conditions of ``case`` at load ``scale`` (topological on facet regions), as
        (DirichletBC, its value Function, parent dofs, collapsed dofs) per component."""
        V, mesh = self.Wu, self.dm.mesh
        tdim = mesh.topology.dim
        bcs = []
        for b in case.boundaries:
            if b.type in ("traction",) or b.region in self.oblique:
                continue
            facets = self._facets(b.region)
            if b.type == "fixed":
                comps = {c: (lambda x: np.zeros(x.shape[1])) for c in range(self.gdim)}
            elif b.type == "displacement":
                val = np.asarray(b.value, float)
                cs = b.components if b.components is not None else range(self.gdim)
                comps = {c: (lambda x, c=c, val=val: np.full(x.shape[1], scale * val[c])) for c in cs}
            elif b.type == "affine":
                G = np.asarray(b.gradient if b.gradient is not None else np.zeros((self.gdim,) * 2))
                c0 = np.asarray(b.offset if b.offset is not None else np.zeros(self.gdim))
                comps = {c: (lambda x, c=c, G=G, c0=c0: scale * (G[c] @ x[:self.gdim] + c0[c]))
                         for c in range(self.gdim)}
            elif b.type == "sliding":
                n = np.asarray(b.normal, float)
                n = n / np.linalg.norm(n)
                k = int(np.argmax(np.abs(n)))
                g = scale * float(b.value or 0.0) * np.sign(n[k])
                comps = {k: (lambda x, g=g: np.full(x.shape[1], g))}
            else:  # pragma: no cover - Boundary validates types
                raise CaseError(f"unknown boundary type {b.type!r}")
            for c, fn in comps.items():
                Vc, _ = self._sub(c)
                dofs = dolfinx.fem.locate_dofs_topological((V.sub(c), Vc), tdim - 1, facets)
                bcs.append(self._component_bc(c, dofs, fn))
        if override is not None:
            bcs.extend(self._override_bcs(*override))
        return bcs

    def _sub(self, c):
        """(collapsed component space, parent dof of each collapsed dof), cached."""
        if c not in self._subs:
            Vc, cmap = self.Wu.sub(c).collapse()
            self._subs[c] = (Vc, np.asarray(cmap, np.int64))
        return self._subs[c]

    def _component_bc(self, c, dofs, fn=None, values=None):
        """(DirichletBC, value Function, parent dofs, collapsed dofs) of one component."""
        Vc, _ = self._sub(c)
        gfun = dolfinx.fem.Function(Vc)
        if fn is not None:
            gfun.interpolate(fn)
        else:
            gfun.x.array[dofs[1]] = values
        bc = dolfinx.fem.dirichletbc(gfun, dofs, self.Wu.sub(c))
        return bc, gfun, np.asarray(dofs[0]), np.asarray(dofs[1])

    def _override_bcs(self, dofs, values):
        """Per-vertex prescriptions (Case node-major dofs, values at full load); degree 1."""
        if self.degree != 1:
            raise CaseError("dirichlet_override is supported for degree 1 only")
        dofs = np.asarray(dofs, np.int64)
        values = np.asarray(values, float)
        vert_to_node = -np.ones(self.n_vertices, np.int64)
        has = self.node_vertex >= 0
        vert_to_node[self.node_vertex[has]] = np.flatnonzero(has)
        node = vert_to_node[dofs // self.gdim]
        comp = dofs % self.gdim
        out = []
        for c in range(self.gdim):
            sel = (node >= 0) & (comp == c)
            if not np.any(sel):
                continue
            _, cmap = self._sub(c)
            inv = np.full(self.n_unknowns, -1, np.int64)
            inv[cmap] = np.arange(len(cmap))
            parent = self.umap[node[sel] * self.gdim + c]
            pair = [parent.astype(np.int32), inv[parent].astype(np.int32)]
            out.append(self._component_bc(c, pair, values=values[sel]))
        return out

    def _facets(self, region):
        if region not in self.dm.region_tags:
            raise CaseError(f"Dirichlet conditions need a boundary (facet) region; {region!r} is "
                            f"not one; facet regions: {sorted(self.dm.region_tags)}")
        ft = self.dm.facet_tags
        return ft.indices[ft.values == self.dm.region_tags[region]]

    def region_dofs(self, region) -> np.ndarray:
        """Local (owned + ghost) block indices of the nodes on a facet region."""
        if region not in self._region_dofs:
            self._region_dofs[region] = dolfinx.fem.locate_dofs_topological(
                self.V, self.dm.mesh.topology.dim - 1, self._facets(region))
        return self._region_dofs[region]

