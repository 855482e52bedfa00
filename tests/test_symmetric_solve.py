"""A symmetric load on a mirrored mesh (meshes.mirror) is solved on the symmetric part with its
planes sliding and mirrored back (fem_reference.symmetric): the same discrete problem as the
whole mesh's, so the whole mesh's solve is the independent answer it must equal (fields, tip
forces, targets, reactions, unknowns); a load symmetric about one plane only is solved on the
half, an asymmetric one and ``symmetry=False`` / ``--no-symmetry`` on the whole mesh."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from tissue_reference.meshes.builders import build
from tissue_reference.model.case import load_case
from tissue_reference.model.symmetry import Reduction, reduction

CASES = Path(__file__).resolve().parents[1] / "meshes" / "cases"
SIZE, SITE = 16.0, 8.0     # mm: a coarse phantom-indenter (about 9,400 P2 unknowns)
RTOL = 1e-8


@pytest.fixture(scope="module")
def case():
    return load_case(CASES / "phantom-indenter.toml",
                     mesh=build("phantom-symmetric", SIZE, site_size=SITE))


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


def _same_answer(red, whole):
    """``red`` (solved on a part) equals ``whole`` (the whole mesh solved) to RTOL."""
    assert np.abs(red.u - whole.u).max() <= RTOL * np.abs(whole.u).max()
    assert red.u.shape == whole.u.shape
    assert sorted(red.probes) == sorted(whole.probes)
    for k, v in whole.probes.items():
        assert _rel(red.probes[k], v) <= RTOL, k
    assert sorted(red.reactions) == sorted(whole.reactions)
    for k, v in whole.reactions.items():
        assert np.linalg.norm(red.reactions[k] - v) <= RTOL * np.linalg.norm(v), k
    assert sorted(red.indenters) == sorted(whole.indenters)
    for k, ind in whole.indenters.items():
        got = red.indenters[k]
        assert abs(got["force"] - ind["force"]) <= RTOL * abs(ind["force"]), k
        assert _rel(got["force_vector"], ind["force_vector"]) <= RTOL, k
        assert abs(got["contact_area"] - ind["contact_area"]) <= RTOL * ind["contact_area"], k
        assert _rel(got["tip_start"], ind["tip_start"]) <= RTOL, k
    assert red.strain_energy == pytest.approx(whole.strain_energy, rel=RTOL)
    assert red.discretization["dofs"] == whole.discretization["dofs"]
    assert red.discretization["cells"] == whole.discretization["cells"]
    assert (red.valid, red.converged) == (whole.valid, whole.converged)
    assert red.min_J == pytest.approx(whole.min_J, rel=RTOL)
    assert sorted(red.warnings) == sorted(whole.warnings)
    # the node state (warm starts, the error estimate's lift) holds the whole mesh's nodes
    if whole.node_points is not None:
        assert red.node_points.shape == whole.node_points.shape


def test_four_equal_pushes_are_solved_on_the_quarter_and_equal_the_whole_mesh_solve(case):
    import tissue_reference.fem_reference as fr

    pushes = {a.name: 4.0 for a in case.actuators}
    red = fr.solve(case, pushes=pushes, degree=2)
    whole = fr.solve(case, pushes=pushes, degree=2, symmetry=False)
    sym = red.symmetry
    assert sym["solved_on"] == "part" and sym["planes"] == ["sym_y0", "sym_x0"]
    assert 3.0 * sym["part_dofs"] < whole.discretization["dofs"]   # about a quarter
    assert whole.symmetry == {"solved_on": "whole", "why": "symmetry=False"}
    assert whole.indenters["A1"]["force"] > 10.0                    # mN: the tips press
    _same_answer(red, whole)


def test_a_load_symmetric_about_one_plane_is_solved_on_the_half(case):
    """A1 and A3 pushed differently: symmetric about y = 0 only (A2 and A4 both at rest)."""
    import tissue_reference.fem_reference as fr

    pushes = {"A1": 4.0, "A3": 2.0}
    red = fr.solve(case, pushes=pushes, degree=2)
    whole = fr.solve(case, pushes=pushes, degree=2, symmetry=False)
    assert red.symmetry["planes"] == ["sym_y0"]
    _same_answer(red, whole)


def test_an_asymmetric_push_solves_the_whole_mesh_and_says_why(case):
    import tissue_reference.fem_reference as fr

    res = fr.solve(case, pushes={"A2": 3.0}, degree=1)
    sym = res.symmetry
    assert sym["solved_on"] == "whole"
    assert "'A2'" in sym["why"] and "sym_y0" in sym["why"]
    assert res.discretization["dofs"] == 3 * case.mesh.n_vertices


@pytest.mark.parametrize("change, why", [
    (lambda c: c.with_pushes({"A1": 2.0, "A3": 2.0, "A2": 1.0}), "'A2'"),
    (lambda c: __import__("dataclasses").replace(c, gravity=(0.0, 9810.0, 0.0)), "gravity"),
])
def test_a_load_not_symmetric_about_the_last_plane_is_not_reduced(case, change, why):
    plan = reduction(change(case))
    assert not isinstance(plan, Reduction)
    assert why in plan


def test_a_mesh_not_mirrored_is_not_reduced():
    quarter = load_case(CASES / "phantom-indenter-quarter.toml",
                        mesh=build("phantom-quarter", SIZE, site_size=SITE))
    assert "not joined" in reduction(quarter, {"A1": 1.0, "A2": 1.0})


def _case_file(tmp_path: Path) -> Path:
    """phantom-indenter.toml at the coarse size (its measured rows are of the default mesh)."""
    text = (CASES / "phantom-indenter.toml").read_text()
    text = re.sub(r"(?m)^size = .*$", f"size = {SIZE}", text)
    text = re.sub(r"(?m)^site_size = .*$", f"site_size = {SITE}", text)
    text = re.sub(r"(?m)^path_size = .*$", "", text)
    path = tmp_path / "coarse.toml"
    path.write_text(text)
    return path


def test_tissue_solve_reduces_by_default_and_no_symmetry_solves_the_whole_mesh(tmp_path,
                                                                              capsys):
    from tissue_reference.tissue.cli import main

    toml = _case_file(tmp_path)
    pushes = [x for a in ("A1", "A2", "A3", "A4") for x in ("--push", f"{a}=3")]
    out = {}
    for flag in ("--symmetry", "--no-symmetry"):
        js = tmp_path / f"{flag}.json"
        assert main(["solve", str(toml), "--degree", "1", "-q", *pushes, "--json", str(js),
                     flag]) == 0
        out[flag] = json.loads(js.read_text())
        printed = capsys.readouterr().out
        assert ("symmetric part" in printed) == (flag == "--symmetry")
    red, whole = out["--symmetry"], out["--no-symmetry"]
    assert red["symmetry"]["solved_on"] == "part"
    assert whole["symmetry"] == {"solved_on": "whole", "why": "symmetry=False"}
    for k, p in whole["probes"].items():
        assert _rel(red["probes"][k]["displacement"], p["displacement"]) <= RTOL
    for k, ind in whole["indenters"].items():
        assert abs(red["indenters"][k]["force"] - ind["force"]) <= RTOL * abs(ind["force"])
    assert red["discretization"]["dofs"] == whole["discretization"]["dofs"]


def test_the_error_estimate_of_a_reduced_answer_is_the_whole_mesh_ones(case):
    """The degree + 1 solve of the estimate runs on the part too, and gives the whole mesh's
    estimate of every target and reaction."""
    import tissue_reference.fem_reference as fr

    pushes = {a.name: 3.0 for a in case.actuators}
    red = fr.solve(case, pushes=pushes, degree=1, estimate=True)
    whole = fr.solve(case, pushes=pushes, degree=1, estimate=True, symmetry=False)
    assert red.extra["estimate_discretization"]["dofs"] == \
        whole.extra["estimate_discretization"]["dofs"]
    for k, e in whole.probe_error_estimates.items():
        assert red.probe_error_estimates[k] == pytest.approx(e, rel=RTOL), k
    for k, e in whole.reaction_error_estimates.items():
        assert red.reaction_error_estimates[k] == pytest.approx(e, rel=RTOL), k
    assert sorted(red.reaction_error_estimates) == sorted(whole.reaction_error_estimates)


def test_the_mesh_cache_keeps_how_a_mirrored_mesh_was_joined(case):
    from tissue_reference.meshes import mesh_cache

    built = mesh_cache.builds()
    again = build("phantom-symmetric", SIZE, site_size=SITE)    # read from the cache
    assert mesh_cache.builds() == built
    assert again is not case.mesh and again.mirrored == case.mesh.mirrored
    assert [r.plane for r in again.mirrored] == ["sym_y0", "sym_x0"]
    assert dict(again.mirrored[0].renames) == {"act_py": "act_ny", "T3": "T5"}


def test_the_part_s_vertex_field_and_validity_map_onto_the_whole_mesh(case):
    """A part's field u(X) = X mirrored back is X on the whole mesh (every image vertex gets its
    part vertex's value mirrored); a part with inverted cells has twice as many on the whole."""
    from tissue_reference.fem_reference.symmetric import mirrored_result
    from tissue_reference.model.results import SolveResult

    plan = reduction(case, {a.name: 1.0 for a in case.actuators})
    assert isinstance(plan, Reduction) and plan.plane == "sym_y0"
    pts = plan.part.mesh.points
    part = SolveResult(u=pts.copy(), converged=True, iterations=1, residual=0.0,
                       wall_time_s=0.0, solver="fem", degree=1, valid=False,
                       invalid_reason="3 inverted cells (J <= 0; worst cell 5 at (1, 2, 3) mm, "
                                      "J = -0.1)",
                       extra={"inverted_cells": 3}, discretization={"formulation":
                                                                    "displacement"})
    whole = mirrored_result(plan, part)
    assert np.array_equal(whole.u, case.mesh.points)
    assert whole.extra["inverted_cells"] == 6
    assert whole.invalid_reason.startswith("6 inverted cells (J <= 0; worst cell 5 ")
    assert whole.discretization["dofs"] == 3 * case.mesh.n_vertices
