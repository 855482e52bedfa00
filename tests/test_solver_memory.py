"""Freeing a reference solver's PETSc memory (fem_reference.petsc_memory, fem_reference.kept): petsc4py queues a dropped
PETSc object of a parallel communicator until PETSc.garbage_cleanup runs on that communicator,
so a dropped solver keeps its matrices and factor for the life of the process. A closed or
forgotten solver leaves nothing queued; PETSc's own garbage listing is the witness."""
import gc

import pytest
from petsc4py import PETSc

import tissue_reference.fem_reference as fr
from tissue_reference.fem_reference import kept
from tissue_reference.fem_reference.discretization import Discretization
from tissue_reference.fem_reference.petsc_memory import release_petsc_garbage
from tissue_reference.model.case import load_case

CASE = "meshes/cases/phantom.toml"


def _queued(comm, capfd) -> int:
    """How many PETSc objects wait for a garbage cleanup on ``comm`` (PETSc's listing)."""
    capfd.readouterr()
    PETSc.garbage_view(comm)
    out = capfd.readouterr().out
    line = next(ln for ln in out.splitlines() if "Total entries:" in ln)
    return int(line.split("Total entries:")[1])


@pytest.fixture(scope="module")
def case():
    return load_case(CASE)


def test_a_dropped_solver_leaves_its_matrices_queued_and_a_closed_one_does_not(case, capfd):
    s = fr.ReferenceSolver(case, degree=1)
    s.solve({"A1": 1.0})
    dm, comm = s.dm, s.comm        # the mesh (with its communicator) outlives the solver here
    del s
    gc.collect()
    # the tangent (on the mesh's communicator) and the factorizing KSP (on the solver's)
    assert _queued(dm.mesh.comm, capfd) >= 1 and _queued(comm, capfd) >= 1
    release_petsc_garbage(dm.mesh.comm, comm)
    assert _queued(dm.mesh.comm, capfd) + _queued(comm, capfd) == 0

    with fr.ReferenceSolver(case, degree=1) as s:
        res = s.solve({"A1": 1.0})
        dm = s.dm
    assert res.converged
    assert _queued(dm.mesh.comm, capfd) + _queued(comm, capfd) == 0
    with pytest.raises(RuntimeError, match="was closed"):
        s.solve({"A1": 1.0})
    s.close()                      # closing twice is harmless


def test_a_forgotten_solver_serves_its_holder_and_is_freed_once_dropped(case, capfd):
    kept.forget_solvers()
    a = fr.solve(case, pushes={"A1": 1.0}, degree=1)
    s = kept.solver_for(case, 1)
    assert kept.solver_for(case, 1) is s            # kept for reuse
    dm, comm = s.dm, s.comm
    assert kept.forget_solvers(case.mesh) == 1
    held = s.solve({"A1": 1.0})                     # a caller that holds it still solves
    assert abs(held.probes["T1"] - a.probes["T1"]).max() <= 1e-9 * abs(a.probes["T1"]).max()
    assert kept.solver_for(case, 1) is not s        # the next caller gets a new one
    del s
    gc.collect()
    assert _queued(dm.mesh.comm, capfd) >= 1        # dropped: queued, not yet destroyed
    kept.forget_solvers()                           # the next release frees it
    assert _queued(dm.mesh.comm, capfd) + _queued(comm, capfd) == 0


def test_beyond_keep_the_least_recently_used_solver_is_forgotten(case, monkeypatch):
    kept.forget_solvers()
    monkeypatch.setattr(kept, "KEEP", 2)
    one = kept.solver_for(case, 1, quadrature_degree=1)
    two = kept.solver_for(case, 1, quadrature_degree=2)
    assert kept.solver_for(case, 1, quadrature_degree=1) is one     # now the most recent
    kept.solver_for(case, 1, quadrature_degree=3)                   # forgets ``two``
    assert kept.solver_for(case, 1, quadrature_degree=1) is one
    assert kept.solver_for(case, 1, quadrature_degree=2) is not two
    kept.forget_solvers()


def test_an_option_left_out_and_the_same_option_given_its_default_share_a_solver(case):
    kept.forget_solvers()
    s = kept.solver_for(case, None)                 # nu < 0.49: P1 displacement, 1-point rule
    assert kept.solver_for(case, 1, formulation="displacement", quadrature_degree=1,
                           linear_solver="auto", contact_quadrature=None) is s
    assert s.degree == 1 and s.qdeg == 1 and s.formulation == "displacement"
    assert kept.solver_for(case, 1, quadrature_degree=2) is not s
    d = Discretization.of(case, None)
    assert (d.degree, d.formulation, d.quadrature_degree, d.contact_rule) == \
        (1, "displacement", 1, "nodal")
    assert Discretization.of(case, 2) != d and hash(Discretization.of(case, 1)) == hash(d)
    kept.forget_solvers()
