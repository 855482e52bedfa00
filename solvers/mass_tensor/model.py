"""``MassTensorModel``: the tensors of one mesh and material, the edge-based forces, the same
tensors as one CSR matrix, the strain energy, and ``solve`` with given point types (target phase,
then the target -> sliding phase) returning an ``MTSolution``."""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError
from tissue_reference.meshes.mesh import edge_topology

from .iterations import IterationState
from .point_types import PointTypes
from .tensors import stiffness_tensors

METHODS = ("direct", "amg", "pcg", "descent")
"""How a solve reaches equilibrium: "direct" (one sparse factorization of the projected tensors
per phase or sliding round: the answer the iterations tend to, without their stopping error),
"amg" (conjugate gradients preconditioned by an AMG V-cycle, stopped when the distance still to
go, estimated from the contraction of its moves, is below half of ``stop_mm``: an estimate,
not a bound; work and memory O(n), for large meshes), "pcg" and "descent" (iterations stopped
by the seed's rule on the largest per-vertex move)."""


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
    with E, nu in kPa, as ``model.case.Material``); topology: the cells'
    ``meshes.mesh.EdgeTopology`` when the caller holds it (``MeshData.edge_topology``), else
    made here."""

    def __init__(self, points, cells, material=None, *, mu: float | None = None,
                 lmbda: float | None = None, topology=None):
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
        if topology is None:
            topology = edge_topology(self.cells, len(self.points))
        self.topology = topology
        self.T_ii, self.edges, self.T_ij = stiffness_tensors(self.points, self.cells, self.mu,
                                                             self.lmbda, topology)
        self._K = None
        # direct solves: the factorization of the projected tensors per pattern of point types
        # (which directions are prescribed where), kept while the model is: a solve with new
        # prescribed values (another push) only back-substitutes; "amg": its hierarchy
        self._factors: dict = {}
        # the rigid tips' contact points per tips and contact options (``driver.contact_set``)
        self._contact_sets: dict = {}
        self._norms = None

    def vertex_norms(self) -> np.ndarray:
        """||T_ii||_2 per vertex (mN/mm): the descent's step scale, computed once."""
        if self._norms is None:
            self._norms = np.linalg.norm(self.T_ii, ord=2, axis=(1, 2))
        return self._norms

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
            self._K = self.topology.block_csr(self.T_ii, self.T_ij)
        return self._K

    def kept_bytes(self) -> int:
        """Bytes the model keeps for its next solves: the direct solve's factorizations (a
        factorization's ``nbytes`` when it has one, else SuperLU's factor entries at 12 bytes),
        the "amg" hierarchies (``FreeVertexAmg.nbytes``) and the rigid tips' compliance blocks
        (``condensed.Compliance.nbytes``); the tensors not counted."""
        total = 0
        for kept in self._factors.values():
            nb = getattr(kept, "nbytes", None)
            total += int(nb) if nb is not None else 12 * (kept.L.nnz + kept.U.nnz)
        return total

    def energy(self, u) -> float:
        """Strain energy 1/2 u . F(u) (kPa mm^3 = uJ)."""
        u = np.asarray(u, float).reshape(-1)
        return 0.5 * float(u @ (self.matrix() @ u))

    def point_types(self) -> PointTypes:
        """A fresh all-free PointTypes for this mesh."""
        return PointTypes(self.n_vertices, self.gdim, self.points)

    def compliance(self, types: PointTypes, factorize=None):
        """The compliance of the free directions of ``types``, G = P A^-1 P (A = P K P + I - P,
        the direct solve's matrix, factorized once per pattern of point types and kept;
        ``factorize`` as for ``solve``): a ``condensed.Compliance``, kept with the
        factorization, whose condensed block grows as a solve asks for more vertices."""
        f = np.zeros((self.n_vertices, self.gdim))
        return IterationState(self, f, 1.0, 1, None, None, factorize).compliance(types)

    # -- solve
    def solve(self, types: PointTypes, *, f_ext=None, initial=None, method: str = "direct",
              stop_mm: float = 0.01, max_iter: int = 200000, step_scale: float | None = None,
              callback=None, factorize=None) -> MTSolution:
        """Quasi-static equilibrium with the given point types.

        f_ext (n, d) mN external nodal forces (default none); initial (n, d) mm warm start (its
        prescribed components are replaced by the prescriptions); method: one of ``METHODS``;
        stop when the largest per-vertex displacement in one iteration < stop_mm (mm; "amg":
        when the distance still to go, estimated from those moves, is below half of it);
        max_iter total iterations (converged=False when reached); step_scale: fixed descent
        step (see the package docstring); callback(it, u) after every iteration (u (n, d) mm;
        "amg" iterates in the compiled kernel when there is none, in numpy when there is).
        factorize(A, cache): optional, method "direct": a factorization of the SPD matrix A with
        ``solve(b)`` (and ``nbytes``, its memory, if it knows it), or None for SuperLU (e.g.
        ``fem_reference.cholmod_factor``, which this package does not import).
        """
        if method not in METHODS:
            raise CaseError(f"unknown Mass Tensor method {method!r}; methods: {list(METHODS)}")
        if isinstance(stop_mm, bool) or not (isinstance(stop_mm, numbers.Real) and stop_mm > 0):
            raise CaseError(f"stop_mm must be > 0 mm, got {stop_mm!r}")
        if types.n != self.n_vertices or types.d != self.gdim:
            raise CaseError(f"PointTypes for {types.n} vertices in {types.d}D does not match the "
                            f"model ({self.n_vertices} vertices, {self.gdim}D)")
        n, d = self.n_vertices, self.gdim
        f = np.zeros((n, d)) if f_ext is None else np.asarray(f_ext, float).reshape(n, d)
        u = np.zeros((n, d)) if initial is None else np.asarray(initial, float).reshape(n, d).copy()
        state = IterationState(self, f, stop_mm, max_iter, callback, step_scale, factorize)
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

