"""The ADMM laws' single evaluation (``Law.evaluate``: psi, J, P and A from one computation of
the invariants and their derivatives) against their separate ``psi_J``, ``stress`` and
``tangent`` (each checked against the formulas in tests/test_admm_laws.py), for every law at
random deformation gradients in 2D and 3D, and for every subset of the three asked for."""
import itertools

import numpy as np
import pytest
from test_laws import LAWS

from tissue_reference.model.case import Material
from tissue_reference.solvers.admm.mechanics import ADMM_LAWS, Law

RTOL = 1e-12


def _close(got, want):
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * np.abs(want).max())


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("model", list(LAWS))
def test_single_evaluation_equals_the_separate_methods(model, d):
    assert model in ADMM_LAWS
    law = Law(Material(model, **LAWS[model]), d)
    H = np.random.default_rng(7).normal(scale=0.15, size=(64, 3, 3))[:, :d, :d]
    psi, J = law.psi_J(H)
    P, _ = law.stress(H)
    A = law.tangent(H)
    assert np.all(np.isfinite(psi)) and np.all(np.isfinite(A))
    for want in itertools.product([True, False], repeat=3):
        v = law.evaluate(H, *want)
        for flag, got, ref in zip(want, (v.psi, v.P, v.A), (psi, P, A)):
            if flag:
                _close(got, ref)
            else:
                assert got is None
        if J is None:
            assert v.J is None
        else:
            _close(v.J, J)


@pytest.mark.parametrize("model", [m for m in LAWS if m != "linear-elastic"])
def test_single_evaluation_gives_infinite_energy_of_inverted_cells(model):
    law = Law(Material(model, **LAWS[model]), 3)
    H = np.stack([np.zeros((3, 3)), np.diag([-2.0, 0.0, 0.0])])
    v = law.evaluate(H)
    assert np.isfinite(v.psi[0]) and v.psi[1] == np.inf
    np.testing.assert_array_equal(v.psi, law.psi_J(H)[0])
