"""The reference solvers kept for reuse, and ``tangent_stiffness`` in one call on them.

``answer.solve``, ``tangent_stiffness``, the error estimate, the adaptive loop, dynamics and the
control plants ask ``solver_for`` for a solver; one built for the same mesh, degree and options is
reused (its forms are compiled and its matrices allocated once). At most KEEP are kept; the one
used least recently is forgotten first.

A forgotten solver's PETSc memory is not freed with its Python object (``petsc_memory`` says
why), so a forgotten solver is watched until nothing refers to it any more (a caller may still
hold it), its mesh kept alive meanwhile; then its communicators are cleaned up. That happens
whenever a solver is built or forgotten here. ``ReferenceSolver.close`` frees one solver at once
(for a caller that owns it). Both are collective: every rank does the same.
"""
from __future__ import annotations

import gc
import weakref
from collections import OrderedDict

import numpy as np

from tissue_reference.model.case import Case

from .contact import contact_key
from .discretization import Discretization
from .outputs_tangent import Tangent
from .petsc_memory import release_petsc_garbage
from .solver import ReferenceSolver

# how many solvers ``solver_for`` keeps (each holds its tangent, factor and compiled forms)
KEEP = 8

_CACHE: OrderedDict = OrderedDict()
# forgotten solvers not yet freed: (weak reference, its dolfinx mesh, its communicator)
_FORGOTTEN: list = []


def _release_forgotten() -> None:
    """Free the PETSc objects of the forgotten solvers nothing refers to any more."""
    if not _FORGOTTEN:
        return
    gc.collect()
    gone = [f for f in _FORGOTTEN if f[0]() is None]
    _FORGOTTEN[:] = [f for f in _FORGOTTEN if f[0]() is not None]
    for _, mesh, comm in gone:
        release_petsc_garbage(mesh.comm, comm)


def _forget(key) -> None:
    s = _CACHE.pop(key)
    if not s.__dict__.get("_closed"):
        _FORGOTTEN.append((weakref.ref(s), s.dm.mesh, s.comm))


def solver_for(case, degree: int | None, **kw):
    """A ReferenceSolver for ``case`` at ``degree`` with options ``kw``: a kept one when one was
    built for the same mesh object, material law, loads that enter the forms, indenters and
    discretization (``Discretization.of(case, degree, **kw)``: every default resolved, so that an
    option left out and the same option given its default share a solver), else a new one
    (kept; beyond KEEP, the least recently used is forgotten)."""
    disc = Discretization.of(case, degree, **kw)
    key = (id(case.mesh), case.material.model, case.material.volumetric, case.gravity,
           case.material.density,
           tuple((b.region, b.type, str(b.normal), str(b.value)) for b in case.boundaries
                 if b.type in ("traction", "sliding")), contact_key(case), disc)
    s = _CACHE.get(key)
    if s is not None and (s.__dict__.get("_closed") or s.case.mesh is not case.mesh):
        _forget(key)
        s = None
    if s is None:
        while len(_CACHE) >= KEEP:
            _forget(next(iter(_CACHE)))
        _release_forgotten()
        s = ReferenceSolver(case, **disc.solver_options())
        _CACHE[key] = s
    _CACHE.move_to_end(key)
    s.use_case(case)
    return s


def forget_solvers(mesh=None) -> int:
    """Forget the kept solvers (those of the Case mesh ``mesh`` alone, if given); their
    matrices and factors are freed now, or once no caller holds them. Collective. Returns
    how many were forgotten."""
    keys = [k for k, s in _CACHE.items() if mesh is None or s.case.mesh is mesh]
    for k in keys:
        _forget(k)
    _release_forgotten()
    return len(keys)


def tangent_stiffness(case: Case, u=None, *, degree: int | None = None, pushes=None,
                      formulation: str = "auto") -> Tangent:
    """Exact tangent K (scipy CSR, node-major, Case vertex numbering) at displacement ``u``
    (default: rest). Degree 2: pass the SolveResult of a degree-2 reference solve (or its full
    nodal state ``res.node_u``); vertex values alone raise CaseError unless all zero.

    Parameters
    ----------
    case : Case
        The problem (mesh, material, boundaries, probes).
    u : array_like or SolveResult or None
        The state: (n_vertices, gdim) displacement (mm), at degree 2 a degree-2 SolveResult or its
        ``node_u``; None: rest.
    degree : int or None
        Lagrange degree of the displacement; None: the case's default (``ReferenceSolver``).
    pushes : dict or None
        Actuator name -> push (mm) at that state (the prescribed values, rigid tips' positions).
    formulation : str
        "displacement", "mixed" or "auto" (``ReferenceSolver``).

    Returns
    -------
    Tangent
        K (mN/mm, scipy CSR, node-major), its Dirichlet dofs and node points (mm).

    Raises
    ------
    CaseError
        At degree 2 for vertex values that are not all zero.
    """
    s = solver_for(case, degree, formulation=formulation)
    if u is None:
        u = np.zeros((case.mesh.n_vertices, case.mesh.gdim))
    return s.tangent(u, pushes=pushes)
