"""Shared helpers of the tests (no tests here): an independent linear-elastic P1 stiffness,
the 1-D Laplacian (shifted: definite or not, as a test needs), central finite differences
along coordinate directions (of a function, and of the reference's probes in one push), and a
reference whose warm starts fail."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def linear_p1_stiffness(mesh, E, nu) -> sp.csr_matrix:
    """Textbook linear-elastic P1 stiffness (mN/mm), node-major, full size: sum_e V_e B_e^T D B_e
    with Voigt B matrices, written independently of the project's solvers."""
    X, cells = mesh.points, mesh.cells
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[np.arange(3), np.arange(3)] += 2 * mu
    D[np.arange(3, 6), np.arange(3, 6)] = mu
    rows, cols, vals = [], [], []
    for cell in cells:
        A = np.ones((4, 4))
        A[:, 1:] = X[cell]
        V = abs(np.linalg.det(A)) / 6.0
        grads = np.linalg.inv(A)[1:].T          # (4, 3): gradient of each barycentric function
        B = np.zeros((6, 12))
        for a in range(4):
            gx, gy, gz = grads[a]
            B[0, 3 * a], B[1, 3 * a + 1], B[2, 3 * a + 2] = gx, gy, gz
            B[3, 3 * a + 1], B[3, 3 * a + 2] = gz, gy      # yz
            B[4, 3 * a], B[4, 3 * a + 2] = gz, gx          # xz
            B[5, 3 * a], B[5, 3 * a + 1] = gy, gx          # xy
        Ke = V * B.T @ D @ B
        dofs = (3 * cell[:, None] + np.arange(3)).ravel()
        rows.append(np.repeat(dofs, 12))
        cols.append(np.tile(dofs, 12))
        vals.append(Ke.ravel())
    n = 3 * len(X)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n, n))


def laplacian_1d(n: int = 800, shift: float = 0.0) -> sp.csr_matrix:
    """The 1-D Laplacian tridiag(-1, 2, -1) + shift I (n x n): positive definite for shift > 0,
    with negative eigenvalues for shift < 0 (its smallest is 2 (1 - cos(pi / (n + 1))) +
    shift)."""
    off = -np.ones(n - 1)
    return sp.diags([off, np.full(n, 2.0 + shift), off], [-1, 0, 1], format="csr")


def central_differences(fun, u, count, seed, h=1e-6):
    """Yield (k, (fun(u + h e_k) - fun(u - h e_k)) / (2 h)) for ``count`` distinct coordinates k
    of the flat array ``u``, drawn by ``np.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    for k in rng.choice(u.size, count, replace=False):
        e = np.zeros_like(u)
        e[k] = h
        yield k, (fun(u + e) - fun(u - e)) / (2 * h)


def jacobian_column_error(case, actuator: str, push: float, h: float = 0.01) -> float:
    """The largest difference between the control Jacobian's column of ``actuator`` at a
    ``push`` (mm) pre-push and the central difference of the reference's probes over +-``h``
    mm, relative to the largest entry of the latter."""
    import tissue_reference.fem_reference as fr
    from tissue_reference.control.plants import jacobian_at

    out = jacobian_at(case, {actuator: push}, fd_h=0)
    col = np.asarray(out["J"])[:, out["actuators"].index(actuator)]
    plus = fr.solve(case, pushes={actuator: push + h}).probes
    minus = fr.solve(case, pushes={actuator: push - h}).probes
    fd = np.concatenate([(plus[t] - minus[t]) / (2 * h) for t in out["targets"]])
    return float(np.max(np.abs(col - fd)) / np.max(np.abs(fd)))


def refuse_warm_starts(monkeypatch):
    """Make every warm-started reference solve (``initial`` given) raise ConvergenceError, as
    Newton from an interpolated answer can on hard problems; solves from rest are untouched."""
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.fem_reference.solver import ReferenceSolver

    solve = ReferenceSolver.solve

    def no_warm_start(self, pushes=None, *, initial=None, **options):
        if initial is not None:
            raise ConvergenceError("forced", load_fraction=0.0)
        return solve(self, pushes, initial=initial, **options)

    monkeypatch.setattr(ReferenceSolver, "solve", no_warm_start)
