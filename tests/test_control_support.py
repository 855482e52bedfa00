"""Shared helpers of the control tests (no tests here): a self-made linear-elastic P1 stiffness
(element B^T D B V, independent of the project's solvers) and a linear Dirichlet 'plant' on it."""
from __future__ import annotations

import time
from functools import cache

import numpy as np
import scipy.sparse.linalg as spla
from fem_checks import linear_p1_stiffness as _p1_stiffness

from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import Actuator, Boundary, Case, Material, Probe, load_case
from tissue_reference.model.results import SolveResult

PHANTOM = "meshes/cases/phantom.toml"
PHANTOM3 = "meshes/cases/phantom-3.toml"


@cache
def phantom(path=PHANTOM, size=12.0):
    return load_case(path, size=size)


def linear_p1_stiffness(case, E=None, nu=None):
    """Linear-elastic P1 stiffness (mN/mm), node-major, full size: sum_e V_e B_e^T D B_e
    (fem_checks.linear_p1_stiffness) with the Case's material unless E / nu are given."""
    E = case.material.E if E is None else E
    nu = case.material.nu if nu is None else nu
    return _p1_stiffness(case.mesh, E, nu)


class LinearPlant:
    """plant(case, pushes, initial) -> SolveResult of the linear Dirichlet problem K u = 0 with the
    Case's (pushed) prescriptions; K fixed (built for the unpushed Case's mesh)."""

    def __init__(self, K):
        self.K = K.tocsr()
        self._lu = {}

    def __call__(self, case, pushes, initial=None):
        t0 = time.perf_counter()
        c = case.with_pushes(pushes).constraints
        n = self.K.shape[0]
        u = np.zeros(n)
        u[c.dofs] = c.values
        free = np.setdiff1d(np.arange(n), c.dofs)
        key = c.dofs.tobytes()
        if key not in self._lu:
            self._lu[key] = spla.splu(self.K[free][:, free].tocsc())
        u[free] = self._lu[key].solve(-(self.K[free][:, c.dofs] @ c.values))
        U = u.reshape(-1, 3)
        return SolveResult(U, True, 1, 0.0, time.perf_counter() - t0, "linear-test",
                           probes=case.probe_values(U))


def linear_tangent(K):
    return lambda case, u: K


L, H = 10.0, 20.0   # mm


def column(n=3, nz=6) -> MeshData:
    """[0, L]^2 x [0, H] cut into n x n x nz cubes of 6 (Kuhn) tets; facet regions: ``base``
    (z = 0), ``pad_x`` (x = L, y < L/2, z > H/2), ``pad_y`` (y = L, x < L/2, z > H/2): the two pads
    share no vertex with each other or with the base."""
    xs, zs = np.linspace(0, L, n + 1), np.linspace(0, H, nz + 1)
    X = np.array([(x, y, z) for z in zs for y in xs for x in xs])

    def vid(i, j, k):
        return (k * (n + 1) + j) * (n + 1) + i
    kuhn = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    cells = []
    for k in range(nz):
        for j in range(n):
            for i in range(n):
                c = [vid(i + a, j + b, k + e) for e in (0, 1) for b in (0, 1) for a in (0, 1)]
                cells += [[c[q] for q in t] for t in kuhn]
    cells = np.array(cells)
    e = X[cells[:, 1:]] - X[cells[:, :1]]
    neg = np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2]) < 0
    cells[neg] = cells[neg][:, [1, 0, 2, 3]]
    faces = np.sort(np.concatenate([cells[:, f] for f in ([0, 1, 2], [0, 1, 3], [0, 2, 3],
                                                          [1, 2, 3])]), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    bnd = uniq[count == 1]
    P = X[bnd]
    tol = 1e-9
    top = P[:, :, 2] > H / 2 - tol
    regions = {"base": bnd[np.all(np.abs(P[:, :, 2]) < tol, axis=1)],
               "pad_x": bnd[np.all((np.abs(P[:, :, 0] - L) < tol) & (P[:, :, 1] < L / 2) & top,
                                   axis=1)],
               "pad_y": bnd[np.all((np.abs(P[:, :, 1] - L) < tol) & (P[:, :, 0] < L / 2) & top,
                                   axis=1)]}
    return MeshData(X, cells, facet_regions=regions, cell_regions={"tissue": np.arange(len(cells))})


def column_case() -> Case:
    """Neo-Hookean column on a fixed base, two pads pushed inward (A1 along -x, A2 along -y),
    target T1 on the axis and P strictly inside a cell."""
    return Case(mesh=column(), material=Material("neo-hookean", E=6.0, nu=0.45),
                boundaries=(Boundary("base", "fixed"),),
                actuators=(Actuator("A1", "pad_x", (-1.0, 0.0, 0.0)),
                           Actuator("A2", "pad_y", (0.0, -1.0, 0.0))),
                probes=(Probe("T1", (5.0, 5.0, 15.0)), Probe("P", (4.3, 6.1, 13.7))),
                name="column")
