"""The gmsh-free structured block: a conforming, positively oriented tetrahedral mesh of the
block whose face regions are exactly its boundary, checked against the block's own volume and
face areas and against an affine displacement (which every P1 solver reproduces exactly)."""
import numpy as np
import pytest

from tissue_reference.meshes.builders import structured_box
from tissue_reference.meshes.mesh import boundary_facets, cell_volumes, check_cells
from tissue_reference.model.case import Boundary, Case, Material

L = (10.0, 20.0, 30.0)


def _key(f):
    return tuple(sorted(int(v) for v in f))


@pytest.mark.parametrize("n", [1, 3, (2, 4, 5)])
def test_structured_box_fills_the_block_and_names_its_faces(n):
    m = structured_box(n, lengths=L)
    nx, ny, nz = (n,) * 3 if np.ndim(n) == 0 else n
    assert m.n_cells == 6 * nx * ny * nz
    assert m.n_vertices == (nx + 1) * (ny + 1) * (nz + 1)
    v = cell_volumes(m.points, m.cells)
    assert v.min() > 0
    assert v.sum() == pytest.approx(L[0] * L[1] * L[2], rel=1e-12)
    check_cells(m)
    boundary = {_key(f) for f in boundary_facets(m.cells)}
    named = [_key(f) for name in m.facet_regions for f in m.facet_regions[name]]
    assert len(named) == len(set(named)) == len(boundary)     # a boundary facet once each
    assert set(named) == boundary
    area = {"x": L[1] * L[2], "y": L[0] * L[2], "z": L[0] * L[1]}
    for axis, name in enumerate("xyz"):
        for end, val in (("min", 0.0), ("max", L[axis])):
            f, a = m.facet_measures(f"{name}{end}")
            assert a.sum() == pytest.approx(area[name], rel=1e-12)
            assert np.allclose(m.points[f][..., axis], val)


def test_structured_box_refuses_an_empty_grid():
    with pytest.raises(ValueError, match="at least one cube"):
        structured_box((2, 0, 2))


def test_uniaxial_stretch_on_the_structured_box_is_the_closed_form():
    """Neo-Hookean uniaxial stress (sliding xmin/ymin/zmin, xmax pulled): the lateral stretch
    from zero lateral stress (root of the closed-form Piola stress) and the end force."""
    from scipy.optimize import brentq

    from tissue_reference.fem_reference import solve

    mat = Material(model="neo-hookean", E=6.0, nu=0.45)
    m = structured_box((2, 3, 2), lengths=L)
    s = 1.15
    bcs = [Boundary(f"{a}min", "sliding", normal=list(np.eye(3)[k])) for k, a in enumerate("xyz")]
    bcs.append(Boundary("xmax", "displacement", value=[(s - 1) * L[0], 0, 0], components=(0,)))
    res = solve(Case(mesh=m, material=mat, boundaries=bcs, name="uniaxial"), degree=1)

    def piola(F):
        J = np.linalg.det(F)
        Fit = np.linalg.inv(F).T
        return (mat.mu * J ** (-2 / 3) * (F - np.trace(F.T @ F) / 3 * Fit)
                + mat.kappa * J * (J - 1) * Fit)

    t = brentq(lambda t: piola(np.diag([s, t, t]))[1, 1], 0.5, 1.5, xtol=1e-15)
    F = np.diag([s, t, t])
    np.testing.assert_allclose(res.u, m.points @ (F - np.eye(3)).T, atol=1e-9)
    np.testing.assert_allclose(res.reactions["xmax"][0], piola(F)[0, 0] * L[1] * L[2], rtol=1e-9)
