"""What every caller reads of a SolveResult is a field (validity, warnings, discretization, the
tips, the error estimates), set by the solver that computed it; ``extra`` holds the solver's
own figures, and the JSON form keys the fields as it always has."""
import ast
import dataclasses
import json
from pathlib import Path

import numpy as np

from tissue_reference.model.results import SolveResult

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("meshes", "fem_reference", "solvers", "control", "implant", "verification",
            "tissue")
TYPED = ("valid", "invalid_reason", "warnings", "discretization", "indenters",
         "probe_error_estimates", "reaction_error_estimates", "estimate_note",
         "no_converged_value", "min_J", "model", "model_note", "symmetry", "node_u", "node_points",
         "pressure")
"""Fields of SolveResult that a producer sets itself, never through ``extra``."""


def _result(**kw):
    return SolveResult(u=np.zeros((2, 3)), converged=True, iterations=1, residual=0.0,
                       wall_time_s=0.0, solver="plug-in", probes={"T": np.array([0.0, 0.0, 1.0])},
                       **kw)


def test_the_json_form_keys_the_fields():
    given = {"valid": False, "invalid_reason": "runaway", "warnings": ["w"],
             "discretization": {"degree": 2, "dofs": 10}, "indenters": {"A1": {"force": 1.0}},
             "probe_error_estimates": {"T": 0.02}, "reaction_error_estimates": {"base": 0.5},
             "estimate_note": "not estimated",
             "symmetry": {"solved_on": "whole", "why": "symmetry=False"}}
    r = _result(**given, extra={"own": 3})
    d = json.loads(json.dumps(r.to_json_dict()))
    for key, value in given.items():
        assert d[key] == value, key
    assert d["own"] == 3 and r.entries()["own"] == 3
    assert d["probes"]["T"]["error_estimate"] == 0.02
    assert r.warnings == ("w",)


def test_a_result_that_checked_nothing_says_so():
    r = _result()
    assert r.valid is None and r.warnings == () and r.discretization is None
    d = r.to_json_dict()
    assert "valid" not in d and "invalid_reason" not in d and d["warnings"] == []


def test_replace_updates_only_the_fields_it_names():
    r = _result(valid=True, warnings=["first"], extra={"own": 1})
    later = dataclasses.replace(r, warnings=(*r.warnings, "second"))
    assert later.warnings == ("first", "second") and later.valid is True
    assert later.extra == {"own": 1}
    flagged = dataclasses.replace(r, valid=False, invalid_reason="folded")
    assert flagged.valid is False and flagged.to_json_dict()["invalid_reason"] == "folded"


def test_every_field_is_a_field_of_solve_result():
    names = {f.name for f in dataclasses.fields(SolveResult)}
    assert set(TYPED) <= names


def _extra_keys(tree):
    """(line, key) for each constant key a module puts in an ``extra``: ``extra={...}`` in a
    call (a DynamicsResult's own ``extra`` apart), ``extra = {...}``, ``extra[key] = ...`` / ``x.extra[key] = ...``."""
    def named_extra(node):
        return (isinstance(node, ast.Name) and node.id == "extra") or \
            (isinstance(node, ast.Attribute) and node.attr == "extra")

    for node in ast.walk(tree):
        dicts = []
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) != "DynamicsResult":
            dicts += [k.value for k in node.keywords if k.arg == "extra"]
        elif isinstance(node, ast.Assign):
            for t in node.targets:
                if named_extra(t):
                    dicts.append(node.value)
                elif isinstance(t, ast.Subscript) and named_extra(t.value) and \
                        isinstance(t.slice, ast.Constant):
                    yield node.lineno, t.slice.value
        for d in dicts:
            if isinstance(d, ast.Dict):
                for k in d.keys:
                    if isinstance(k, ast.Constant):
                        yield d.lineno, k.value


def test_no_producer_passes_a_field_through_extra():
    found = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            found += [f"{path.relative_to(ROOT)}:{line}: {key}"
                      for line, key in _extra_keys(tree) if key in TYPED]
    assert not found, found
