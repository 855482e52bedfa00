"""The curvilinear trials of the contact Newton (``model.tips.curvilinear_shift``, used by
``fem_reference.contact.Contact.follow_tips``) against the geometry of a sphere written here:
a point at distance r from the sphere's centre o has the gap r - R, and a straight step s
perpendicular to o-y0 takes it to the distance sqrt(r^2 + s^2). Units: mm."""
import math

import numpy as np
import pytest

from tissue_reference.model.tips import SHORT_STEP, curvilinear_shift

R = 5.0
O = np.zeros(3)
D = np.array([0.0, 0.0, -1.0])   # the tip points down; its front is at o + R d


def sphere_shift(y0, y1):
    return curvilinear_shift(np.atleast_2d(y0), np.atleast_2d(y1), O, D, 0.0, R)[0]


@pytest.mark.parametrize("s", [0.05, 0.3, 1.0, 2.5])
@pytest.mark.parametrize("pen", [1e-3, 0.05])
def test_a_pressed_point_slid_along_a_sphere_keeps_its_gap(s, pen):
    """A point pressed pen into the sphere under its front, stepped s sideways: the straight
    step leaves it at the gap sqrt((R - pen)^2 + s^2) - R; the linearized gap is -pen (the step
    is tangential) and the shift brings the point back to it, along the radius."""
    r = R - pen
    y0 = O + r * D
    y1 = y0 + np.array([s, 0.0, 0.0])
    shift = sphere_shift(y0, y1)
    straight_gap = math.sqrt(r ** 2 + s ** 2) - R
    assert np.linalg.norm(shift) == pytest.approx(straight_gap + pen, rel=1e-12)
    y = y1 + shift
    assert np.linalg.norm(y - O) - R == pytest.approx(-pen, abs=1e-12)
    # along the radius through the straight trial: the shift is parallel to y1 - o
    assert np.linalg.norm(np.cross(shift, y1 - O)) < 1e-12 * np.linalg.norm(y1)
    # a second-order correction: s^2 / (2 r) for a short slide
    if s <= 0.05:
        assert np.linalg.norm(shift) == pytest.approx(s ** 2 / (2 * r), rel=1e-3)


def test_a_normal_step_needs_no_shift_and_a_combined_one_keeps_the_normal_part():
    """A step along the normal changes the gap as its linearization does (exactly, on a
    sphere): no shift. A step with normal part t and tangential part s ends at the gap
    at its linearized gap -pen + t whatever s."""
    pen = 0.02
    y0 = O + (R - pen) * D
    assert np.abs(sphere_shift(y0, y0 + 0.01 * D)).max() < 1e-15
    t, s = 0.005, 0.4   # outward by 0.005 (still inside) and 0.4 sideways
    y1 = y0 + t * D + np.array([0.0, s, 0.0])
    y = y1 + sphere_shift(y0, y1)
    assert np.linalg.norm(y - O) - R == pytest.approx(-pen + t, abs=1e-12)


def test_points_outside_entering_leaving_or_stepping_far_are_left_on_the_straight_line():
    """Only a point inside the tip before and, by its linearization, after a short step is
    moved: one outside (entering or not), one whose step takes it out and one stepping further
    than SHORT_STEP of the radius keep their straight trial."""
    y_out = O + (R + 0.1) * D
    y_in = O + (R - 0.01) * D
    steps = {
        "outside, stays out": (y_out, y_out + np.array([0.3, 0.0, 0.0])),
        "outside, enters": (y_out, y_out - 0.2 * D + np.array([0.3, 0.0, 0.0])),
        "inside, leaves": (y_in, y_in + 0.05 * D + np.array([0.3, 0.0, 0.0])),
        "inside, a long slide": (y_in, y_in + np.array([(SHORT_STEP + 1e-9) * R, 0.0, 0.0])),
    }
    y0 = np.array([a for a, _ in steps.values()])
    y1 = np.array([b for _, b in steps.values()])
    assert np.abs(curvilinear_shift(y0, y1, O, D, 0.0, R)).max() == 0.0
