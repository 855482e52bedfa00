"""The commonest gmsh mistake named as such: a 3D model saved with a Physical Surface for its
skin but no Physical Volume holds no tetrahedra (gmsh saves only the elements of physical
groups), and the reader says to add one instead of talking about planarity."""
import gmsh
import pytest

from tissue_reference.errors import ReadError
from tissue_reference.meshes.io import read_msh


def _box(path, volume: bool):
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("box")
        gmsh.model.occ.addBox(0, 0, 0, 10, 10, 10)
        gmsh.model.occ.synchronize()
        surfaces = [t for _, t in gmsh.model.getEntities(2)]
        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, surfaces), "skin")
        if volume:
            gmsh.model.setPhysicalName(3, gmsh.model.addPhysicalGroup(3, [1]), "tissue")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 5.0)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def test_a_model_without_a_physical_volume_is_told_to_add_one(tmp_path):
    _box(tmp_path / "no_volume.msh", volume=False)
    with pytest.raises(ReadError, match="add a Physical Volume") as exc:
        read_msh(tmp_path / "no_volume.msh")
    assert "no_volume.msh" in str(exc.value) and "not planar" not in str(exc.value)
    _box(tmp_path / "with_volume.msh", volume=True)
    m = read_msh(tmp_path / "with_volume.msh")
    assert m.n_cells > 0 and "skin" in m.facet_regions
