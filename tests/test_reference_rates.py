"""Tier 2: a manufactured Neo-Hookean solution in 2D plane strain converges at the textbook rates
(L2 error order 2 for P1, 3 for P2) under gmsh mesh refinement (size halved)."""
import dolfinx.fem
import numpy as np
import pytest
import ufl

import tissue_reference.fem_reference as fr
from tissue_reference.meshes.builders import rectangle
from tissue_reference.model.case import Boundary, Case, Material

MAT = Material("neo-hookean", E=6.0, nu=0.3)
L = 10.0
A = 0.4  # mm amplitude


def u_exact(x):
    s = ufl.sin(np.pi * x[0] / L) * ufl.sin(np.pi * x[1] / L)
    return ufl.as_vector([A * s, 0.5 * A * s * ufl.cos(np.pi * x[0] / L)])


def piola_plane_strain(F):
    # written independently of fem_reference.forms: P = mu J^-2/3 (F - I1/3 F^-T) + k J (J-1) F^-T
    J = ufl.det(F)
    FinvT = ufl.inv(F).T
    I1 = ufl.tr(F.T * F) + 1.0
    return MAT.mu * J ** (-2.0 / 3.0) * (F - I1 / 3 * FinvT) + MAT.kappa * J * (J - 1) * FinvT


def body_force(x):
    F = ufl.Identity(2) + ufl.grad(u_exact(x))
    return -ufl.div(piola_plane_strain(F))


def l2_error(solver):
    x = ufl.SpatialCoordinate(solver.dm.mesh)
    e = solver.u - u_exact(x)
    dx = ufl.Measure("dx", metadata={"quadrature_degree": 8})
    val = dolfinx.fem.assemble_scalar(dolfinx.fem.form(ufl.inner(e, e) * dx))
    return np.sqrt(val)


@pytest.mark.parametrize("degree,order", [(1, 2.0), (2, 3.0)])
def test_manufactured_solution_converges_at_textbook_order(degree, order):
    sizes = [2.5, 1.25, 0.625, 0.3125] if degree == 1 else [2.5, 1.25, 0.625]
    errors = []
    for h in sizes:
        mesh = rectangle(h, lengths=(L, L))
        case = Case(mesh=mesh, material=MAT, name="mms",
                    boundaries=[Boundary(e, "fixed") for e in ("xmin", "xmax", "ymin", "ymax")])
        solver = fr.ReferenceSolver(case, degree=degree, quadrature_degree=2 * degree + 2,
                                    body_force=body_force)
        res = solver.solve()
        assert res.converged
        errors.append(l2_error(solver))
    slope = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    assert abs(slope - order) < 0.3, (errors, slope)
