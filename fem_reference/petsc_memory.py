"""Freeing a reference solver's PETSc memory.

petsc4py (from PETSc 3.18) does not destroy a PETSc object on a communicator other than
PETSC_COMM_SELF when its Python object goes. It queues the object until
``PETSc.garbage_cleanup(comm)`` is called on that communicator by every rank together (a destroy
is collective, and Python frees objects at different moments on different ranks). Every dolfinx
mesh has a communicator of its own, freed with the mesh, so nothing cleans it up unless asked:
each dropped solver would keep its matrices and its MUMPS factor (gigabytes for a large P2 or P3
problem) until the process ends. ``ReferenceSolver.close`` and the pool of kept solvers
(``kept``) call ``release_petsc_garbage``.
"""
from __future__ import annotations

import gc

from petsc4py import PETSc

__all__ = ["release_petsc_garbage"]


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
