"""An example solver that is not part of the toolkit: small-strain linear elasticity on the
case mesh's linear simplices (P1), assembled with numpy and solved with scipy, in about fifty
lines. It follows the solver protocol of ``verification.plugins``: ``solve(case, pushes,
**options)`` returns the displacement at every vertex (mm, one row per vertex of ``case.mesh``).

Score it against the reference from the command line::

    tissue verify meshes/cases/phantom.toml --push A1=2 --solvers examples.linear_plugin:solve

or from Python::

    from tissue_reference.verification.verify import verify
    from examples.linear_plugin import solve
    verify(case, {"A1": 2.0}, solvers=[solve])

It is a linear model: at small pushes it agrees with the Neo-Hookean reference to first order in
the strain, and its error grows with the push, which is what the scores show. Oblique sliding
conditions are not handled (the example refuses such cases).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def _stiffness(points, cells, E, nu):
    """Global P1 stiffness (node-major dofs), kPa * mm = mN/mm."""
    n, d = points.shape
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    T = points[cells[:, 1:]] - points[cells[:, :1]]            # (c, d, d), edges as rows
    vol = np.abs(np.linalg.det(T)) / (2 if d == 2 else 6)
    G = np.linalg.inv(T)                                        # columns: grad of lambda_1..d
    grads = np.concatenate([-G.sum(axis=2, keepdims=True), G], axis=2)   # (c, d, d+1)
    # K_(a i)(b j) = vol (mu (g_a . g_b) delta_ij + mu g_a_j g_b_i + lam g_a_i g_b_j)
    gg = np.einsum("cka,ckb->cab", grads, grads)
    eye = np.eye(d)
    Ke = (mu * gg[:, :, None, :, None] * eye[None, None, :, None, :]
          + mu * np.einsum("cja,cib->caibj", grads, grads)
          + lam * np.einsum("cia,cjb->caibj", grads, grads)) * vol[:, None, None, None, None]
    dofs = (d * cells[:, :, None] + np.arange(d)).reshape(len(cells), -1)    # (c, (d+1) d)
    m = dofs.shape[1]
    rows = np.repeat(dofs, m, axis=1).ravel()
    cols = np.tile(dofs, (1, m)).ravel()
    return sp.csr_matrix((Ke.reshape(len(cells), m * m).ravel(), (rows, cols)),
                         shape=(n * d, n * d))


def solve(case, pushes, **options):
    """Linear-elastic displacement (mm, (n, gdim)) of ``case`` with ``pushes`` (name -> mm)."""
    c = case.with_pushes(pushes)
    con = c.constraints
    if con.sliding:
        raise ValueError("oblique sliding boundaries are not handled by this example")
    X, cells = c.mesh.points, c.mesh.cells
    n, d = X.shape
    K = _stiffness(X, cells, c.material.E, c.material.nu)
    u = np.zeros(n * d)
    u[con.dofs] = con.values
    free = np.setdiff1d(np.arange(n * d), con.dofs)
    f = c.external_forces() - K @ u
    u[free] = spla.spsolve(K[free][:, free].tocsc(), f[free])
    return u.reshape(n, d)
