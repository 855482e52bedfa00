"""The gmsh session shared by the mesh builders, and the step from a gmsh model to a MeshData.
Lengths in mm.

``gmsh_session`` opens one gmsh model with fixed meshing options (uniform characteristic
length ``size`` in mm, Delaunay 3D, one thread) and removes it afterwards; ``finish`` meshes
the model, writes a gmsh 4.1 .msh (to ``out`` or a temporary file) and reads it back through
``meshes.io.read_msh``.

The builders of ``meshes.builders_curved`` and ``meshes.builders_blocks`` open the session
through this module's attribute (``builders_gmsh.gmsh_session``), so replacing it here reaches
every one of them (tests do, to show that a refused build never starts gmsh). Other callers
import it from ``meshes.builders``.
"""
from __future__ import annotations

import contextlib
import math
import tempfile
from pathlib import Path

from tissue_reference.errors import CaseError

from .io import atomic_path, read_msh
from .mesh import MeshData

GMSH_STATE = {"on": False}


@contextlib.contextmanager
def gmsh_session(name: str, size: float, *, order: int = 1):
    import gmsh

    if size <= 0 or not math.isfinite(size):
        raise CaseError(f"mesh size must be a positive length in mm, got {size!r}")
    started = not GMSH_STATE["on"]
    if started:
        gmsh.initialize(readConfigFiles=False)
        GMSH_STATE["on"] = True
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMin", size)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", size)
        gmsh.option.setNumber("Mesh.CharacteristicLengthFromPoints", 0)
        gmsh.option.setNumber("Mesh.CharacteristicLengthExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)  # Delaunay
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.RandomFactor", 1e-9)
        yield gmsh
    finally:
        gmsh.model.remove()
        if started:
            gmsh.finalize()
            GMSH_STATE["on"] = False


def finish(gmsh, dim: int, out, *, curved: bool = False) -> MeshData:
    """Mesh, write a .msh (to ``out`` or a temporary) and read it back through ``read_msh``.
    curved: second-order mesh (mid-edge nodes on the true geometry), read as linear cells plus
    curved edges (meshes.curved)."""
    gmsh.model.mesh.generate(dim)
    if curved:
        gmsh.model.mesh.setOrder(2)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    # a file the user keeps is gmsh 2.2: pyvista opens it (its reading of a 4.1 file fails on
    # the bounding-entity sets meshio makes); the temporary one stays 4.1
    gmsh.option.setNumber("Mesh.MshFileVersion", 2.2 if out is not None else 4.1)
    if out is not None:
        with atomic_path(out, suffix=".msh") as tmp:
            gmsh.write(str(tmp))
        return read_msh(out, overlap_check=False)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "mesh.msh"
        gmsh.write(str(p))
        return read_msh(p, overlap_check=False)
