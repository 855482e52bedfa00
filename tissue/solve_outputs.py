"""What a solve writes, for every command that solves: the fields (XDMF + VTU), the JSON summary
with the settings the solver ran with, and the report page; rank 0 writes, each file whole or not
at all."""
from __future__ import annotations

import numpy as np

from tissue_reference.meshes.io import write_point_data
from tissue_reference.meshes.mesh import cell_jacobians
from tissue_reference.model.results import write_json
from tissue_reference.solvers.registry import solver

from .solve_report import write_solve_report

__all__ = ["rank", "solver_settings", "write_outputs"]


def rank() -> int:
    """This process's MPI rank (0 without MPI): rank 0 writes the outputs."""
    try:
        from mpi4py import MPI

        return MPI.COMM_WORLD.rank
    except ImportError:  # pragma: no cover
        return 0


def write_outputs(case, res, out_dir=None, json_file=None, stem="displacement", settings=None,
                  report=False):
    """Fields (XDMF + VTU: displacement, its magnitude, pressure for the mixed formulation, and
    per cell J = det F and ``inverted`` = 1 where J <= 0) and the JSON summary (with ``valid``
    and ``invalid_reason``, and ``settings`` as its ``solver_settings`` when given); with
    ``report`` also ``out_dir``/report.html (tissue.solve_report); rank 0 writes, each file
    whole or not at all."""
    if rank() != 0:
        return
    if out_dir:
        u = res.u
        fields = {"displacement": u, "displacement_magnitude": np.linalg.norm(u, axis=1)}
        if res.pressure is not None:  # mixed formulation, kPa
            fields["pressure"] = np.asarray(res.pressure, float)
        J = cell_jacobians(case.mesh.points, case.mesh.cells, u)
        write_point_data(case.mesh, out_dir, stem, fields,
                         cell_data={"J": J, "inverted": (~(J > 0)).astype(float)})
    data = res.to_json_dict(case)
    if settings is not None:
        data["solver_settings"] = settings
    if json_file:
        write_json(data, json_file)
    if out_dir and report:
        write_solve_report(case, res, out_dir, data=data, stem=stem)


def solver_settings(name: str, **given) -> dict:
    """The settings a solve by the built-in solver ``name`` ran with, JSON-ready
    (``SolverEntry.settings``): for the reference its Newton and load-stepping controls, for a
    fast solver the defaults of its ``solve`` keywords (null: the solver picks the value
    itself); ``given`` (what the command chose) goes over them."""
    return solver(name).settings(**given)
