"""The push-only MPC of seed 000 eq. 25: same QP answer from two casadi conic plugins and from an
independent bounded least-squares solve; constraints honoured; settings validated by name."""
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from tissue_reference.control.controllability import inverse_push
from tissue_reference.control.mpc import MPCSettings, PushOnlyMPC, quiet_qpoases
from tissue_reference.errors import CaseError

RNG = np.random.default_rng(7)
J = np.array([[-0.13, 0.005, 0.125, 0.001],
              [-0.005, -0.107, 0.006, 0.123],
              [0.01, 0.02, -0.01, 0.015]])


def reference_plan(J, x0, xr, mask, Np=5, q=3.0, r=2.0):
    """Bounded least squares of the stacked eq. 25 (du >= 0), solved by scipy BVLS."""
    _ny, na = J.shape
    W = np.sqrt(q) * np.diag(mask.astype(float))
    rows, rhs = [], []
    for h in range(Np):
        S = np.zeros((na, na * Np))
        for k in range(h + 1):
            S[:, k * na:(k + 1) * na] = np.eye(na)
        rows.append(W @ J @ S)
        rhs.append(W @ (xr - x0))
    A = np.vstack(rows + [np.sqrt(r) * np.eye(na * Np)])
    b = np.concatenate(rhs + [np.zeros(na * Np)])
    sol = lsq_linear(A, b, bounds=(0, np.inf), method="bvls", tol=1e-15)
    return sol.x.reshape(Np, na)


@pytest.mark.parametrize("mask", [[True, False, False], [False, True, False], [True, True, False]])
def test_qpoases_highs_and_bvls_agree(mask):
    mask = np.array(mask)
    x0 = np.array([0.0, 0.0, 15.0])
    for goal in ([-5.0, 0, 0], [0, -5.0, 0], [5.0, 5.0, 0], [2.0, -3.0, 0]):
        xr = x0 + np.array(goal)
        ref = reference_plan(J, x0, xr, mask)
        for plugin in ("qpoases", "highs", "daqp"):
            step = PushOnlyMPC(4, mask, MPCSettings(solver=plugin)).step(J, x0, xr)
            assert np.abs(step.plan - ref).max() <= 1e-6 * max(1.0, np.abs(ref).max()), plugin


def test_increments_are_never_negative_and_limits_hold():
    mpc = PushOnlyMPC(4, [True, True, False], MPCSettings(max_step=0.5, max_travel=3.0))
    x = np.array([0.0, 0.0, 15.0])
    s = np.zeros(4)
    xr = x + np.array([5.0, -5.0, 0.0])
    for _ in range(30):
        st = mpc.step(J, x, xr, s)
        assert st.du.min() >= 0.0 and st.du.max() <= 0.5 + 1e-9
        s = s + st.du
        x = x + J @ st.du
        assert s.max() <= 3.0 + 1e-9
    # the target cannot retract: an actuator pushing the wrong way is simply not used
    mpc2 = PushOnlyMPC(1, [True, False, False])
    st = mpc2.step(J[:, :1], x, x + [1.0, 0, 0])   # A1 moves the target along -x only
    assert np.all(st.du == 0.0)


def test_closed_loop_on_exact_linear_model_converges_to_goal():
    mpc = PushOnlyMPC(4, [True, False, False])
    x = np.array([0.0, 0.0, 15.0])
    xr = x + np.array([-5.0, 0, 0])
    for _ in range(100):
        x = x + J @ mpc.step(J, x, xr).du
    assert abs(x[0] - xr[0]) < 1e-3


def test_prediction_follows_eq23():
    mpc = PushOnlyMPC(4, [True, True, False])
    x = np.array([1.0, 2.0, 15.0])
    st = mpc.step(J, x, x + [3.0, 3.0, 0.0])
    assert np.allclose(st.predicted, x + np.cumsum(st.plan, axis=0) @ J.T, atol=1e-12)


@pytest.mark.parametrize("kw,name", [({"horizon": 0}, "horizon"), ({"horizon": 2.5}, "horizon"),
                                     ({"q": -1.0}, "q"), ({"r": float("nan")}, "r"),
                                     ({"max_travel": 0.0}, "max_travel"),
                                     ({"solver": "nope"}, "solver"),
                                     ({"weights": "relative"}, "weights")])
def test_bad_settings_are_named(kw, name):
    with pytest.raises(CaseError, match=name):
        MPCSettings(**kw)


def test_gain_weights_are_the_seed_weights_times_the_squared_gain():
    """weights="gain": the BVLS plan of eq. 25 with R = r g^2, g the largest singular value of
    the weighted rows of J_s (computed here with numpy's SVD)."""
    mask = np.array([True, True, False])
    x0 = np.array([0.0, 0.0, 15.0])
    g = np.linalg.svd(J[mask], compute_uv=False)[0]
    mpc = PushOnlyMPC(4, mask, MPCSettings(weights="gain"))
    for goal in ([-0.3, 0, 0], [0.3, 0.3, 0], [2.0, -3.0, 0]):
        xr = x0 + np.array(goal)
        ref = reference_plan(J, x0, xr, mask, r=2.0 * g * g)
        mpc.reset()
        plan = mpc.step(J, x0, xr).plan
        assert np.abs(plan - ref).max() <= 1e-6 * max(1.0, np.abs(ref).max())
        assert not np.allclose(ref, reference_plan(J, x0, xr, mask), atol=1e-3)


@pytest.mark.parametrize("scale", [0.05, 20.0])
def test_gain_weights_make_the_predicted_motion_independent_of_the_gain(scale):
    """A body c times stiffer in transfer (J_s / c) gets c times the pushes and the same predicted
    target motion with weights="gain"; with absolute weights the stiffer one moves less."""
    mask = np.array([True, True, False])
    x0, xr = np.array([0.0, 0.0, 15.0]), np.array([2.0, -3.0, 15.0])
    preds = {}
    for weights in ("gain", "absolute"):
        a = PushOnlyMPC(4, mask, MPCSettings(weights=weights)).step(J, x0, xr)
        b = PushOnlyMPC(4, mask, MPCSettings(weights=weights)).step(J / scale, x0, xr)
        preds[weights] = (a, b)
    a, b = preds["gain"]
    np.testing.assert_allclose(b.plan, scale * a.plan, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b.predicted, a.predicted, rtol=0, atol=1e-7)
    a, b = preds["absolute"]
    moved = [np.linalg.norm(s.predicted[0] - x0) for s in (a, b)]
    assert (moved[1] < moved[0]) == (scale > 1.0)


def test_wrong_jacobian_shape_is_refused():
    with pytest.raises(CaseError, match="J_s"):
        PushOnlyMPC(4, [True, False, False]).step(J[:, :3], np.zeros(3), np.ones(3))


def test_qpoases_banner_is_not_printed(capsys):
    x = np.array([0.0, 0.0, 15.0])
    PushOnlyMPC(4, [True, False, False]).step(J, x, x + [-1.0, 0, 0])
    inverse_push(J[:2], np.array([-1.0, -1.0]), solver="casadi:qpoases")
    out = capsys.readouterr()
    assert "qpOASES" not in out.out + out.err


def test_quiet_qpoases_passes_everything_but_the_banner(capsys):
    banner = ("\nqpOASES -- An Implementation of the Online Active Set Strategy.\nCopyright (C) "
              "2007-2015 by ...\n\nSee the GNU Lesser General Public License for more details.\n\n")
    with pytest.raises(RuntimeError, match="boom"), quiet_qpoases():
        print("before")
        print(banner, end="")
        print("after")
        raise RuntimeError("boom")
    assert capsys.readouterr().out == "before\nafter\n"
