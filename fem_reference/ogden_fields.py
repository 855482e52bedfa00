"""The reference's Ogden law: its isochoric part on quadrature-point Functions, the volumetric
part in UFL.

UFL has no eigen-decomposition, and differentiating a closed-form (trigonometric) eigenvalue
formula is singular where principal stretches coincide (at rest among others), so the isochoric
energy W, its stress P = dW/dF and its tangent A = dP/dF are computed in numpy by
``fem_reference.ogden.OgdenIsochoric`` (exact at equal stretches) at the quadrature points of
the forms, and held by Functions of ``Quadrature`` elements of the forms' degree (``"default"``
scheme): psi (scalar), P (d x d) and A (d*d x d*d, rows (iJ), columns (kL)). The forms then read

    energy    W_q dx_q,
    residual  P_q : grad v dx_q,
    tangent   (A_q grad w) . grad v dx_q    (grad flattened row-major),

with dx_q the measure of the quadrature points; the volumetric energy k/2 G(J)^2 (or the mixed
formulation's -p G(J) - p^2 / (2 kappa)) stays UFL, differentiated as for the other laws.

The Functions hold the law at one state of the unknown, so whatever assembles a form that reads
them calls ``update()`` first (``ReferenceSolver.refresh_fields``, ``Newton.assemble_residual``,
``Newton.assemble_tangent``, ``Contact.total_energy``): it evaluates F = I + grad u at the
quadrature points of every local cell (a ``dolfinx.fem.Expression``) and refills the three
Functions, or does nothing when the unknown has not changed since the last refill. Where
det F <= 0 the values are NaN, as the UFL energies of the other uncoupled laws give there.
"""
from __future__ import annotations

import basix
import dolfinx
import dolfinx.fem
import numpy as np
import ufl

from .ogden import OgdenIsochoric

__all__ = ["OgdenFields"]

_CELLS = {"triangle": basix.CellType.triangle, "tetrahedron": basix.CellType.tetrahedron}


class OgdenFields:
    """The Ogden law's isochoric psi, P and A on quadrature-point Functions (module docstring).

    Parameters
    ----------
    mesh : dolfinx.mesh.Mesh
        The solver's mesh (triangles or tetrahedra).
    x : dolfinx.fem.Function
        The solver's unknown (displacement, or displacement and pressure).
    u : ufl.core.expr.Expr
        Its displacement (``x`` itself, or its first part).
    degree : int
        The quadrature degree of the forms.
    material : tissue_reference.model.case.Material
        An Ogden material (its ``ogden_mu`` and ``ogden_alpha``).
    """

    def __init__(self, mesh, x, u, degree: int, material):
        self.x = x
        self.law = OgdenIsochoric(material.ogden_mu, material.ogden_alpha)
        d = mesh.geometry.dim
        self.d = d
        cell = mesh.ufl_cell()
        points, _ = basix.make_quadrature(_CELLS[cell.cellname()], degree)
        self.metadata = {"quadrature_degree": degree, "quadrature_scheme": "default"}
        self.dx = ufl.Measure("dx", domain=mesh, metadata=self.metadata)
        spaces = [dolfinx.fem.FunctionSpace(mesh, e) for e in (
            ufl.FiniteElement("Quadrature", cell, degree, quad_scheme="default"),
            ufl.TensorElement("Quadrature", cell, degree, quad_scheme="default"),
            ufl.TensorElement("Quadrature", cell, degree, shape=(d * d, d * d),
                              quad_scheme="default"))]
        self.psi, self.P, self.A = (dolfinx.fem.Function(s) for s in spaces)
        tdim = mesh.topology.dim
        imap = mesh.topology.index_map(tdim)
        self.cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
        self.n_points = len(points)
        self._F = dolfinx.fem.Expression(ufl.Identity(d) + ufl.grad(u), points)
        # each Function's entries in (cell, point, component) order
        self._index = []
        for s in spaces:
            bs = s.dofmap.bs
            blocks = s.dofmap.list.array.reshape(len(self.cells), self.n_points)
            self._index.append((blocks[:, :, None] * bs + np.arange(bs)).reshape(-1))
        self._state = None

    def set_material(self, material) -> None:
        """Take ``material``'s Ogden coefficients and exponents (a solve of a case whose
        material differs from the solver's in them); the next ``update`` refills.

        Parameters
        ----------
        material : tissue_reference.model.case.Material
            An Ogden material.
        """
        law = OgdenIsochoric(material.ogden_mu, material.ogden_alpha)
        if not (np.array_equal(law.mu, self.law.mu) and np.array_equal(law.alpha, self.law.alpha)):
            self.law = law
            self._state = None

    # ------------------------------------------------------------------ the forms' terms
    def energy(self):
        """The isochoric energy W_q dx_q (UFL, uJ)."""
        return self.psi * self.dx

    def _flat(self, g):
        return ufl.as_vector([g[i, j] for i in range(self.d) for j in range(self.d)])

    def residual(self, v):
        """P_q : grad v dx_q for the displacement test function ``v``."""
        return ufl.inner(self.P, ufl.grad(v)) * self.dx

    def tangent(self, v, w):
        """(A_q grad w) . grad v dx_q for the displacement test and trial functions."""
        return ufl.dot(self.A * self._flat(ufl.grad(w)), self._flat(ufl.grad(v))) * self.dx

    # ------------------------------------------------------------------ the refill
    def update(self) -> bool:
        """Refill psi, P and A from the unknown's current value; does nothing (returns False)
        when it has not changed since the last refill.

        Returns
        -------
        bool
            Whether the Functions were refilled.
        """
        x = self.x.x.array
        if self._state is not None and np.array_equal(self._state, x):
            return False
        d = self.d
        F = self._F.eval(self.cells).reshape(-1, d, d)
        v = self.law.evaluate(F)
        J = np.linalg.det(F)
        bad = ~(J > 0)
        psi, P, A = v.psi, v.P.reshape(len(F), -1), v.A.reshape(len(F), -1)
        if bad.any():
            psi[bad], P[bad], A[bad] = np.nan, np.nan, np.nan
        for f, values, index in zip((self.psi, self.P, self.A), (psi, P, A), self._index):
            f.x.array[index] = values.reshape(-1)
        self._state = x.copy()
        return True
