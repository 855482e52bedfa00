"""What every caller reads of a SolveResult is a field (validity, warnings, discretization, the
tips, the error estimates); a solver that reports those in ``extra`` (a plug-in, an older
caller) has them moved there, and the JSON form keys them as before."""
import dataclasses
import json

import numpy as np

from tissue_reference.meshes.results import TYPED_EXTRAS, SolveResult


def _result(**kw):
    return SolveResult(u=np.zeros((2, 3)), converged=True, iterations=1, residual=0.0,
                       wall_time_s=0.0, solver="plug-in", probes={"T": np.array([0.0, 0.0, 1.0])},
                       **kw)


def test_entries_reported_in_extra_become_fields():
    r = _result(extra={"valid": False, "invalid_reason": "3 inverted cells",
                       "warnings": ["patch A1 is glued"], "indenters": {"A1": {"force": 2.5}},
                       "probe_error_estimates": {"T": 0.01}, "estimate_note": None,
                       "solver_iterations": 7})
    assert r.valid is False and r.invalid_reason == "3 inverted cells"
    assert r.warnings == ("patch A1 is glued",)
    assert r.indenters == {"A1": {"force": 2.5}} and r.probe_error_estimates == {"T": 0.01}
    assert r.extra == {"solver_iterations": 7}   # what is left is the solver's own


def test_the_json_form_keys_the_fields_as_extra_did():
    given = {"valid": False, "invalid_reason": "runaway", "warnings": ["w"],
             "discretization": {"degree": 2, "dofs": 10}, "indenters": {"A1": {"force": 1.0}},
             "probe_error_estimates": {"T": 0.02}, "reaction_error_estimates": {"base": 0.5},
             "estimate_note": "not estimated", "own": 3}
    d = json.loads(json.dumps(_result(extra=given).to_json_dict()))
    for key, value in given.items():
        assert d[key] == value, key
    assert d["probes"]["T"]["error_estimate"] == 0.02


def test_a_result_that_checked_nothing_says_so():
    r = _result()
    assert r.valid is None and r.warnings == () and r.discretization is None
    d = r.to_json_dict()
    assert "valid" not in d and "invalid_reason" not in d and d["warnings"] == []
    assert not set(TYPED_EXTRAS) & set(r.extra)


def test_replace_with_new_extras_updates_only_the_fields_it_names():
    r = _result(extra={"valid": True, "warnings": ["first"], "own": 1})
    later = dataclasses.replace(r, extra={**r.extra, "warnings": [*r.warnings, "second"]})
    assert later.warnings == ("first", "second") and later.valid is True
    assert later.extra == {"own": 1}
    flagged = dataclasses.replace(r, valid=False, invalid_reason="folded")
    assert flagged.valid is False and flagged.to_json_dict()["invalid_reason"] == "folded"
