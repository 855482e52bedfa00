"""The reference solvers kept for reuse: ``solve`` and ``tangent_stiffness`` in one call on
them, and the freeing of their PETSc memory.

``solve``, ``tangent_stiffness``, the error estimate, the adaptive loop, dynamics and the control
plants ask ``solver_for`` for a solver; one built for the same mesh, degree and options is reused
(its forms are compiled and its matrices allocated once). At most KEEP are kept; the one used
least recently is forgotten first.

Why freeing needs care: petsc4py (from PETSc 3.18) does not destroy a PETSc object on a
communicator other than PETSC_COMM_SELF when its Python object goes. It queues the object until
``PETSc.garbage_cleanup(comm)`` is called on that communicator by every rank together (a
destroy is collective, and Python frees objects at different moments on different ranks). Every
dolfinx mesh has a communicator of its own, freed with the mesh, so nothing cleans it up unless
asked: each dropped solver would keep its matrices and its MUMPS factor (gigabytes for a large
P2 or P3 problem) until the process ends.

So a forgotten solver is watched until nothing refers to it any more (a caller may still hold
it), its mesh kept alive meanwhile; then its communicators are cleaned up. That happens whenever
a solver is built or forgotten here. ``ReferenceSolver.close`` frees one solver at once (for a
caller that owns it). Both are collective: every rank does the same.
"""
from __future__ import annotations

import gc
import weakref
from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from tissue_reference.meshes.answer_warnings import warn_about
from tissue_reference.meshes.case import Case
from tissue_reference.meshes.errors import CaseError
from tissue_reference.meshes.results import SolveResult

if TYPE_CHECKING:
    from .outputs import Tangent

# how many solvers ``solver_for`` keeps (each holds its tangent, factor and compiled forms)
KEEP = 8

_CACHE: OrderedDict = OrderedDict()
# forgotten solvers not yet freed: (weak reference, its dolfinx mesh, its communicator)
_FORGOTTEN: list = []


def release_petsc_garbage(*comms) -> None:
    """Destroy the PETSc objects of ``comms`` whose Python objects are gone (after a garbage
    collection, so that reference cycles are gone too). Collective on each communicator; call
    it with the same communicators in the same order on every rank, while they are alive."""
    gc.collect()
    seen = []
    for comm in comms:
        if comm is not None and not any(comm == c for c in seen):
            seen.append(comm)
            PETSc.garbage_cleanup(comm)


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
    built for the same mesh object, degree, material law, loads that enter the forms, contact
    and options, else a new one (kept; beyond KEEP, the least recently used is forgotten)."""
    from .contact import contact_key
    from .solver import ReferenceSolver, default_degree, resolve_formulation

    kw["formulation"] = resolve_formulation(kw.get("formulation", "auto"), case.material)
    if degree is None:
        degree = default_degree(case, kw["formulation"])
    key = (id(case.mesh), degree, case.material.model, case.material.volumetric, case.gravity,
           case.material.density,
           tuple((b.region, b.type, str(b.normal), str(b.value)) for b in case.boundaries
                 if b.type in ("traction", "sliding")), tuple(sorted(kw.items())),
           contact_key(case), case.reference_contact_quadrature, case.reference_tip_start)
    s = _CACHE.get(key)
    if s is not None and (s.__dict__.get("_closed") or s.case.mesh is not case.mesh):
        _forget(key)
        s = None
    if s is None:
        while len(_CACHE) >= KEEP:
            _forget(next(iter(_CACHE)))
        _release_forgotten()
        s = ReferenceSolver(case, degree=degree, **kw)
        _CACHE[key] = s
    _CACHE.move_to_end(key)
    s.case = case
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


def solve(case: Case, *, degree: int | None = None, pushes=None, initial=None,
          dirichlet_override=None, progress: bool = False, estimate: bool = False,
          **kw) -> SolveResult:
    """Solve a Case with the reference (compiled forms are cached per mesh and degree).

    degree, formulation (in ``kw``) and the other options: see ReferenceSolver; the default
    degree is the case's (``[reference] degree``), else mixed P2/P1 for nu >= 0.49 and P1
    displacement below.
    pushes: actuator name -> push (mm); initial: warm start (n_vertices, gdim) mm;
    dirichlet_override: (node-major Case dofs, values in mm) added to the Case's prescriptions.
    estimate: add the estimated discretization error (``fem_reference.estimate``: one more solve
    at degree + 1) to ``extra``: probe_error_estimates (mm), reaction_error_estimates (mN), ...
    A case file's measured accuracy for exactly this load and discretization
    (``[reference.measured]``, ``fem_reference.measured``) is in ``extra["measured_accuracy"]``.
    An answer that is not valid, past the loads where answers converge, or with an estimated
    error above 2 % also warns (``meshes.errors.TissueWarning``; ``meshes.answer_warnings``).
    """
    from .measured import with_measured_accuracy

    if estimate and dirichlet_override is not None:
        raise CaseError("estimate=True: the error estimate does not take dirichlet_override")
    s = solver_for(case, degree, **kw)
    res = s.solve(pushes, case=case, initial=initial, dirichlet_override=dirichlet_override,
                  progress=progress)
    if dirichlet_override is None:   # another problem than the case's: no row describes it
        res = with_measured_accuracy(case, res, pushes)
    if estimate:
        from .estimate import estimate as with_estimate

        res = with_estimate(case, res, pushes=pushes, progress=progress, **kw)
    return warn_about(res)


def tangent_stiffness(case: Case, u=None, *, degree: int | None = None, pushes=None,
                      formulation: str = "auto") -> Tangent:
    """Exact tangent K (scipy CSR, node-major, Case vertex numbering) at displacement ``u``
    (default: rest). Degree 2: pass the SolveResult of a degree-2 reference solve (or its full
    nodal state ``res.extra["node_u"]``); vertex values alone raise CaseError unless all zero."""
    s = solver_for(case, degree, formulation=formulation)
    if u is None:
        u = np.zeros((case.mesh.n_vertices, case.mesh.gdim))
    return s.tangent(u, pushes=pushes)
