"""Where an indenter starts: against the skin's nodes, or against its facets as the curved
geometry maps them (``tip_start = "surface"``). The exact start is computed here from the
dome's equation, not from the mesh."""
import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box, build
from tissue_reference.model.case import load_case

DOME_A, DOME_C = 50.0, 45.0   # mm: the phantom's base radius and height
HALF = Path("meshes/cases/phantom-indenter-half.toml")


def exact_start(site, d, radius):
    """How far along the axis d from ``site`` the sphere's front point is when it first
    touches the dome x^2/a^2 + y^2/a^2 + z^2/c^2 = 1: the least s + R - sqrt(R^2 - rho^2)
    over the dome, on a fine grid of its angles refined twice around the best point."""
    az0, el0 = math.atan2(site[1], site[0]), math.asin(site[2] / DOME_C)
    best, span = (az0, el0), 0.3
    for _ in range(4):
        az, el = np.meshgrid(np.linspace(best[0] - span, best[0] + span, 401),
                             np.linspace(best[1] - span, best[1] + span, 401))
        p = np.stack([DOME_A * np.cos(el) * np.cos(az), DOME_A * np.cos(el) * np.sin(az),
                      DOME_C * np.sin(el)], axis=-1) - site
        s = p @ d
        rho = np.linalg.norm(p - s[..., None] * d, axis=-1)
        t = np.where(rho <= radius, s + radius - np.sqrt(np.clip(radius ** 2 - rho ** 2, 0, None)),
                     np.inf)
        i = np.unravel_index(np.argmin(t), t.shape)
        best, value, span = (az[i], el[i]), t[i], span / 50
    return float(value)


@pytest.fixture(scope="module")
def wide_half():
    """The half phantom at level -1 of the convergence study (size 8.485, sites 4.525, paths
    2.263 mm) with tips of radius 8 mm: a mesh whose nodes miss A1's first contact."""
    case = load_case(HALF, mesh=build("phantom-half", 8.485281374238571,
                                      site_size=4.525483399593905, path_size=2.2627416997969525))
    return dataclasses.replace(case, actuators=tuple(dataclasses.replace(a, radius=8.0)
                                                     for a in case.actuators))


def start_along_axis(case, tip_start):
    import tissue_reference.fem_reference as fr

    s = fr.ReferenceSolver(case, degree=2, contact_quadrature=2, tip_start=tip_start)
    ind = next(i for i in s.contact.indenters if i.name == "A1")
    a1 = next(a for a in case.actuators if a.name == "A1")
    d = np.asarray(a1.direction, float) / np.linalg.norm(a1.direction)
    site = np.asarray(a1.point, float)
    return float((ind.q0 - site) @ d), site, d


def test_a_tip_started_on_the_curved_facets_meets_the_true_first_contact(wide_half):
    nodes, site, d = start_along_axis(wide_half, "nodes")
    surface, _, _ = start_along_axis(wide_half, "surface")
    exact = exact_start(site, d, 8.0)
    # the first contact lies below the site, 0.49 mm outside it along the axis
    assert -0.5 < exact < -0.48
    # the nodes start the tip deeper (they only sample the dome): by 0.019 mm on this mesh
    assert nodes - exact > 0.01
    # the curved facets are the dome to third order in the cell size: within 1e-3 mm
    assert abs(surface - exact) < 1e-3
    assert surface <= nodes + 1e-12


def test_an_unknown_tip_start_is_refused(wide_half):
    import tissue_reference.fem_reference as fr

    with pytest.raises(CaseError, match="tip_start must be one of"):
        fr.ReferenceSolver(wide_half, degree=2, tip_start="vertex")


def test_on_straight_cells_the_start_is_the_flat_facets(wide_half):
    """Degree 1 (straight cells): the facets are flat, so the start may only come out of the
    tip (never deeper than the nodes') by less than a flat facet's sag below the dome."""
    import tissue_reference.fem_reference as fr

    starts = {}
    for how in ("nodes", "surface"):
        s = fr.ReferenceSolver(wide_half, degree=1, tip_start=how)
        ind = next(i for i in s.contact.indenters if i.name == "A1")
        starts[how] = float((ind.q0 - ind.site) @ ind.d)
    sag = 4.525 ** 2 / (8 * 40.0)      # a facet of the site cells on the dome (radius >= 40 mm)
    assert starts["nodes"] - sag <= starts["surface"] <= starts["nodes"] + 1e-12


def coarse_half_text() -> str:
    """The half case file without its refined paths (these tests build solvers at size 16,
    where 1.6 mm paths would make 26k cells of 3.5k)."""
    text = HALF.read_text()
    assert "\npath_size = 1.6 " in text
    return text.replace("\npath_size = 1.6 ", "\n# path_size = 1.6 ", 1)


def test_a_case_file_names_its_tip_start(tmp_path):
    import tissue_reference.fem_reference as fr

    text = coarse_half_text()
    section = "[reference]\ndegree = 2"
    assert section in text and "tip_start" not in tomllib.loads(text)["reference"]

    def named(start):
        path = tmp_path / f"{start}.toml"
        path.write_text(text.replace(section, f'{section}\ntip_start = "{start}"', 1))
        return path

    case = load_case(named("surface"), size=16.0)
    assert case.reference_tip_start == "surface"
    s = fr.ReferenceSolver(case, degree=1)         # the nodal rule's own start would be nodes
    assert all(i.tip_start == "surface" for i in s.contact.indenters)
    with pytest.raises(CaseError, match=r"vertex.toml.*\[reference\]\.tip_start"):
        load_case(named("vertex"), size=16.0)


def test_without_a_named_start_each_contact_rule_has_its_own(tmp_path):
    """The nodal rule knows the gap only at the nodes and starts there; a Gauss rule samples the
    facets' interiors and starts on the surface; a start the case names overrides both."""
    import tissue_reference.fem_reference as fr

    path = tmp_path / "half.toml"
    path.write_text(coarse_half_text())
    case = load_case(path, size=16.0)
    assert case.reference_tip_start is None
    named = dataclasses.replace(case, reference_tip_start="nodes")
    for rule, start in (("nodal", "nodes"), (2, "surface")):
        s = fr.ReferenceSolver(case, degree=1, contact_quadrature=rule)
        assert {i.tip_start for i in s.contact.indenters} == {start}
        s = fr.ReferenceSolver(named, degree=1, contact_quadrature=rule)
        assert {i.tip_start for i in s.contact.indenters} == {"nodes"}
    gauss = dataclasses.replace(case, reference_contact_quadrature=2)
    s = fr.ReferenceSolver(gauss, degree=1)
    assert {i.tip_start for i in s.contact.indenters} == {"surface"}


def test_with_a_gauss_rule_a_tip_started_on_the_nodes_presses_at_rest():
    """Why a Gauss rule starts on the surface: on a block whose nodes miss the side tip's axis,
    the nodal start puts the tip inside the facets, so at push 0 it already pushes the skin;
    started on the surface it touches without force."""
    import tissue_reference.fem_reference as fr
    from tissue_reference.model.case import Actuator, Boundary, Case, Material

    block = Case(mesh=box(1.25), material=Material("neo-hookean", E=6.0, nu=0.3), name="side",
                 boundaries=(Boundary("zmin", "fixed"),),
                 actuators=(Actuator("S", "xmax", (-1.0, 0.0, 0.0), type="indenter",
                                     tip="sphere", radius=4.0, point=(10.0, 5.0, 6.0)),))
    force = {}
    for start in ("nodes", "surface"):
        res = fr.ReferenceSolver(block, contact_quadrature=2, tip_start=start).solve({"S": 0.0})
        force[start] = res.indenters["S"]["force"]
    assert force["surface"] == 0.0 and force["nodes"] > 1e-3
