"""J = det F of a degree >= 2 displacement field inside its cells, for the state checks.

A P2 (or P3) displacement bends each cell: J varies within it (a polynomial of degree 3 in the
cell's reference coordinates for P2 on a straight cell), and the cell can fold between its
vertices while the straight cell through its displaced vertices looks fine, or the other way
round. ``cell_min_J`` samples J = det(I + grad u) of the field itself at the points of the
degree-3 lattice of every cell (20 points of a tetrahedron: its vertices, two points on each
edge, the face centroids; 10 of a triangle) and returns the smallest per cell, in the Case's
cell order. Serial runs only (the cells are matched to the Case's by their vertices).
"""
from __future__ import annotations

import itertools

import numpy as np

from .jit import compile_expression
from .transfer import dolfinx_cells

__all__ = ["LATTICE_ORDER", "cell_min_J", "lattice_points"]

LATTICE_ORDER = 3
"""The lattice J is sampled on: the reference points with barycentric coordinates i / 3."""


def lattice_points(tdim: int, order: int = LATTICE_ORDER) -> np.ndarray:
    """(n, tdim) reference coordinates of the order-``order`` lattice of the reference simplex
    (vertices at the origin and the unit points): every point whose barycentric coordinates
    are multiples of 1/order."""
    pts = [np.array(c, float) / order
           for c in itertools.product(range(order + 1), repeat=tdim) if sum(c) <= order]
    return np.array(pts)


def cell_min_J(solver) -> np.ndarray:
    """Per cell of ``solver.case.mesh`` (its order): the smallest J = det(I + grad u) of the
    solver's current displacement field over ``lattice_points``. Dimensionless."""
    import ufl

    mesh = solver.dm.mesh
    tdim = mesh.topology.dim
    u = solver.u
    F = ufl.Identity(len(u)) + ufl.grad(u)
    expr = compile_expression(ufl.det(F), lattice_points(tdim))
    cells = dolfinx_cells(solver)
    vals = expr.eval(np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32))
    return np.asarray(vals).reshape(len(cells), -1).min(axis=1)[cells]
