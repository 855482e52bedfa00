"""Positive bases (seed 000 Definitions 1-4, Theory 1) on textbook sets, and the manipulability
index (eq. 21-22) with its least-travel tie-break, independent of the solver."""
import numpy as np
import pytest
from test_control_support import PHANTOM3, linear_p1_stiffness, phantom

from tissue_reference.control.controllability import (
    basis_kind,
    inverse_push,
    manipulability,
    manipulability_map,
    positively_independent,
    positively_spans,
    task_goal,
)
from tissue_reference.control.jacobian import dirichlet_jacobian
from tissue_reference.errors import CaseError

AXES2 = np.array([[1.0, 0, -1, 0], [0, 1, 0, -1]])
TRI = np.array([[np.cos(a), np.sin(a)] for a in np.radians([90, 210, 330])]).T


def test_four_axis_directions_are_a_maximal_positive_basis_of_R2():
    assert positively_spans(AXES2) and positively_independent(AXES2)
    assert basis_kind(AXES2) == "maximal"


def test_three_directions_120_deg_apart_are_a_minimal_positive_basis_of_R2():
    assert basis_kind(TRI) == "minimal"


def test_two_opposite_directions_do_not_positively_span_R2():
    assert not positively_spans(np.array([[1.0, -1.0], [0.0, 0.0]]))


def test_three_directions_in_a_half_plane_do_not_positively_span_R2():
    A = np.array([[1.0, 0.0, -1.0], [0.0, 1.0, 0.1]])
    assert not positively_spans(A)


def test_spanning_set_with_redundant_vector_is_not_positively_independent():
    A = np.column_stack([AXES2, [1.0, 1.0]])   # (1, 1) = e1 + e2
    assert positively_spans(A)
    assert not positively_independent(A)
    assert basis_kind(A) == "not a positive basis"


def test_coordinate_cross_in_R3_is_maximal_and_simplex_is_minimal():
    A = np.hstack([np.eye(3), -np.eye(3)])
    assert basis_kind(A) == "maximal"
    S = np.column_stack([np.eye(3), -np.ones(3)])
    assert basis_kind(S) == "minimal"
    assert not positively_spans(np.eye(3))


def test_inverse_push_least_travel_on_axis_basis():
    # p = (-5, 5) with axis directions: the exact minimum-travel solution pushes e3 and e2 by 5
    u, p_star, res = inverse_push(AXES2, [-5.0, 5.0])
    assert np.allclose(u, [0, 5, 5, 0], atol=1e-9)
    assert res < 1e-12 and np.allclose(p_star, [-5, 5])
    m = manipulability(AXES2, [-5.0, 5.0])
    assert m.reachable and m.index == pytest.approx(np.sqrt(50) / 10, rel=1e-12)


def test_unreachable_goal_reports_closest_point():
    A = np.array([[1.0, 0.0], [0.0, 1.0]])       # first quadrant only
    m = manipulability(A, [-3.0, 2.0])
    assert not m.reachable
    assert np.allclose(m.reached, [0.0, 2.0], atol=1e-12)
    assert m.residual == pytest.approx(3.0, rel=1e-12)


def test_task_goals_follow_the_seed():
    g, m = task_goal(1)
    assert g.tolist() == [-5, 0, 0] and m.tolist() == [True, False, False]
    g, m = task_goal(3)
    assert g.tolist() == [5, 5, 0] and m.tolist() == [True, True, False]
    with pytest.raises(CaseError, match="4"):
        task_goal(4)
    g, m = task_goal(3, distance=0.2)   # a shorter task, same directions
    assert g.tolist() == [0.2, 0.2, 0] and m.tolist() == [True, True, False]
    with pytest.raises(CaseError, match="task distance"):
        task_goal(1, distance=-1.0)


@pytest.fixture(scope="module")
def phantom_J():
    case = phantom()
    return case, dirichlet_jacobian(case, linear_p1_stiffness(case))


@pytest.mark.parametrize("target", ["T1", "T2", "T3", "T4", "T5"])
@pytest.mark.parametrize("task", [1, 2, 3])
def test_index_does_not_depend_on_the_solver(phantom_J, target, task):
    _, J = phantom_J
    goal, mask = task_goal(task)
    Js = J.block(target)[mask]
    vals = [manipulability(Js, goal[mask], solver=s).index
            for s in ("highs-ds", "highs-ipm", "casadi:qpoases", "casadi:highs")]
    assert np.ptp(vals) <= 1e-7 * max(vals)


def test_perturbed_axis_set_spans_but_is_no_longer_a_positive_basis():
    # a maximal positive basis of R^2 needs two exactly opposite pairs; rotate one vector by 2 deg
    # and three of the four already positively span R^2 (the fourth is in their cone)
    a = np.radians(2.0)
    A = AXES2.copy()
    A[:, 0] = [np.cos(a), np.sin(a)]
    assert positively_spans(A)
    assert not positively_independent(A)
    assert positively_spans(A[:, [0, 1, 3]]) or positively_spans(A[:, [1, 2, 3]]) \
        or positively_spans(A[:, [0, 2, 3]]) or positively_spans(A[:, [0, 1, 2]])


def test_phantom_actuators_positively_span_the_target_plane(phantom_J):
    case, J = phantom_J
    for t in case.probes:
        assert positively_spans(J.block(t.name)[:2])
    case3 = phantom(PHANTOM3)
    J3 = dirichlet_jacobian(case3, linear_p1_stiffness(case3))
    for t in case3.probes:
        assert basis_kind(J3.block(t.name)[:2]) == "minimal"


def test_map_matches_pointwise_index_at_centre(phantom_J):
    case, J = phantom_J
    K = linear_p1_stiffness(case)
    mp = manipulability_map(case, K, spacing=12.0, tasks=(1,))
    ix = int(np.argmin(np.abs(mp["x"])))
    iy = int(np.argmin(np.abs(mp["y"])))
    assert mp["x"][ix] == 0 and mp["y"][iy] == 0 and mp["inside"][iy, ix]
    goal, mask = task_goal(1)
    ref = manipulability(J.block("T1")[mask], goal[mask]).index
    assert mp["task1"]["index"][iy, ix] == pytest.approx(ref, rel=1e-9)
    assert not mp["inside"][0, 0]       # corner of the bounding box lies outside the dome


def test_manipulability_maps_of_a_box_complete_without_a_traceback(tmp_path, capsys):
    """A small box whose third task is reachable nowhere on the grid: the command writes its maps
    and says so (the least-travel LP on unscaled rows once failed here with a traceback)."""
    import json

    from test_cli_fuzz import BOX

    from tissue_reference.tissue.cli import main

    case = tmp_path / "box.toml"
    case.write_text(BOX.format(model="neo-hookean"))
    out = tmp_path / "maps"
    assert main(["manipulability", str(case), "--compare", "--plane-z", "5", "--spacing", "2.5",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "task 1 median index" in text and "nan" not in text
    d = json.loads(next(out.glob("manipulability_*.json")).read_text())
    assert all(v is None or v >= 0 for row in d["task1"]["index"] for v in np.ravel(row))
    assert (out / "manipulability.png").is_file()
