"""The solver registry (``solvers.registry``): every built-in solver, the reference included, one
entry with the same face, loaded on first use; and no library code outside the registry decides
by comparing a solver's name with the reference's."""
import ast
import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from tissue_reference.control.plants import ADMM_CONTROL_OPTIONS, control_solver, solver_description
from tissue_reference.errors import CaseError
from tissue_reference.model.case_parts import Material
from tissue_reference.solvers import SOLVERS, registry
from tissue_reference.solvers.registry import is_reference, reference, solver
from tissue_reference.verification.verify import FAST_SOLVERS

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("errors", "meshes", "model", "fem_reference", "solvers", "control", "implant",
          "verification", "tissue")

ADMM_SETTINGS = {"tol_mm": 1e-4, "max_iter": None, "rho": None, "polish": True,
                 "polish_tol_mm": None, "polish_max_iter": 25, "load_steps": None,
                 "step_mm": 3.0, "intermediate_tol_mm": 1e-2, "lift": "auto",
                 "handoff_mm": None, "tip_step": 0.5, "device": "cpu",
                 "contact_quadrature": None, "contact_penalty": None, "tip_start": None,
                 "initial_pushes": None, "anderson": 0}
MASS_TENSOR_SETTINGS = {"method": "direct", "stop_mm": 0.01, "max_iter": 200000,
                        "step_scale": None, "contact_quadrature": None, "contact_penalty": None,
                        "tip_start": None, "contact_tol_mm": 1e-10}


def _case(nu=0.45, degree=None, cells=12):
    """What ``describe`` reads of a Case: its material, cell count and [reference] degree."""
    return SimpleNamespace(material=Material(E=6.0, nu=nu), mesh=SimpleNamespace(n_cells=cells),
                           reference_degree=degree)


def test_every_registered_name_resolves_to_its_entry():
    assert registry.names() == ("fem", "admm", "mass-tensor")
    for name in registry.names():
        entry = solver(name)
        assert entry.name == name
        assert entry in registry.entries()
    assert reference() is solver("fem")
    assert [e.name for e in registry.entries() if e.reference] == ["fem"]
    assert registry.control_names() == ("fem", "admm")
    assert registry.dynamics_names() == ("fem", "admm")
    assert [e.name for e in registry.entries() if "gpu" in e.devices] == ["admm"]
    assert SOLVERS == {"admm": "tissue_reference.solvers.admm",
                       "mass-tensor": "tissue_reference.solvers.mass_tensor"}


@pytest.mark.parametrize("name", ["femm", "", "admm-plain", None])
def test_an_unknown_name_raises_case_error_naming_the_known_ones(name):
    with pytest.raises(CaseError) as err:
        solver(name)
    for known in registry.names():
        assert repr(known) in str(err.value)


def test_control_refuses_a_solver_that_plays_no_plant():
    with pytest.raises(CaseError, match="choose fem or admm"):
        control_solver("mass-tensor")
    assert control_solver("admm") is solver("admm")


def test_is_reference_takes_any_name():
    assert is_reference("fem")
    assert not any(is_reference(n) for n in ("admm", "mass-tensor", "plug-in", None, print))


def test_importing_the_registry_loads_no_dolfinx_nor_petsc():
    code = ("import sys, json; from tissue_reference.solvers import registry; "
            "e = registry.solver('fem'); e.settings(); "
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('dolfinx', 'petsc4py', 'ufl', 'ffcx') or m.startswith("
            "'tissue_reference.fem_reference.solver'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert json.loads(out.stdout) == []


def test_settings_of_each_builtin():
    from tissue_reference.fem_reference.newton_settings import settings_json

    newton = settings_json()
    assert list(newton) == ["newton"] and newton["newton"]["max_iterations"] == 25
    assert solver("fem").settings() == newton
    assert solver("fem").settings(estimate="auto", mass="lumped") == {
        "newton": newton["newton"], "estimate": "auto", "mass": "lumped"}
    assert solver("admm").settings() == ADMM_SETTINGS
    assert solver("admm").settings(device="gpu") == {**ADMM_SETTINGS, "device": "gpu"}
    assert solver("mass-tensor").settings() == MASS_TENSOR_SETTINGS


def test_the_command_lines_settings_are_the_registrys():
    from tissue_reference.tissue.solve_outputs import solver_settings

    for name in registry.names():
        assert solver_settings(name, x=1) == solver(name).settings(x=1)


def test_describe_of_each_builtin():
    from tissue_reference.fem_reference.newton_settings import settings_json

    newton = settings_json()
    assert solver("fem").describe(_case()) == {
        "solver": "fem", "settings": newton,
        "discretization": {"formulation": "displacement", "degree": 1, "pressure_degree": None,
                           "cells": 12}}
    assert solver("fem").describe(_case(nu=0.495))["discretization"] == {
        "formulation": "mixed", "degree": 2, "pressure_degree": 1, "cells": 12}
    assert solver("fem").describe(_case(degree=3))["discretization"]["degree"] == 3
    assert solver("fem").describe(_case(nu=0.495), degree=3, formulation="displacement")[
        "discretization"] == {"formulation": "displacement", "degree": 3,
                              "pressure_degree": None, "cells": 12}
    p1 = {"formulation": "displacement", "degree": 1, "pressure_degree": None, "cells": 12}
    assert solver("admm").describe(_case(nu=0.495)) == {
        "solver": "admm", "discretization": p1, "settings": ADMM_SETTINGS}
    assert solver("mass-tensor").describe(_case()) == {
        "solver": "mass-tensor", "discretization": p1, "settings": MASS_TENSOR_SETTINGS}
    # the control layer's plants: ADMM with its control options
    assert solver_description("admm", _case()) == {
        "solver": "admm", "discretization": p1, "settings": dict(ADMM_CONTROL_OPTIONS)}
    assert solver_description("fem", _case()) == solver("fem").describe(_case())


def test_a_fast_solver_refuses_the_references_discretizations():
    for name in ("admm", "mass-tensor"):
        with pytest.raises(CaseError, match="P1 displacement solver.*--solver fem"):
            solver(name).solve(None, degree=2)
        with pytest.raises(CaseError, match="P1 displacement solver"):
            solver(name).solve(None, formulation="mixed")
    with pytest.raises(CaseError, match="lumped mass.*--solver fem"):
        solver("admm").check_dynamics(mass="consistent")
    with pytest.raises(CaseError, match="has no dynamics"):
        solver("mass-tensor").check_dynamics()
    solver("fem").check_dynamics(degree=2, mass="consistent", ramp_steps=3)


def test_the_factorization_hook_is_given_to_the_factorized_solvers_only():
    mine = object()
    assert solver("admm").with_factorization({"factorize": mine}) == {"factorize": mine}
    assert solver("fem").with_factorization({"a": 1}) == {"a": 1}
    from tissue_reference.fem_reference import cholmod_factor

    for name in ("admm", "mass-tensor"):
        assert solver(name).with_factorization({"a": 1}) == {"a": 1,
                                                             "factorize": cholmod_factor}


SOLVER_NAMES = frozenset((*registry.names(), *FAST_SOLVERS))
"""Every name a solver goes by: the registry's and the scored variants' (``verify``)."""


def _compares_a_solver_name(node) -> bool:
    """Whether ``node`` is a comparison (==, !=, in, not in, is) with a solver's name as a
    string on a side, or with a literal collection that holds one."""
    if not isinstance(node, ast.Compare):
        return False

    def name(x):
        if isinstance(x, ast.Constant):
            return x.value in SOLVER_NAMES
        if isinstance(x, (ast.Tuple, ast.List, ast.Set)):
            return any(name(e) for e in x.elts)
        return False
    return any(name(x) for x in (node.left, *node.comparators))


def test_the_compare_check_sees_a_comparison():
    found = [_compares_a_solver_name(n) for n in ast.walk(ast.parse(
        'a == "fem"\n"admm" != b\nc in ("fem", "admm")\n"mass-tensor" in d\ne = "fem"\n'
        'f("fem")\ng == "direct"\nh == "admm-chord"\n'))]
    assert sum(found) == 5


def test_no_library_code_outside_the_registry_compares_a_solver_name():
    found = []
    for layer in LAYERS:
        for path in sorted((ROOT / layer).rglob("*.py")):
            if path == ROOT / "solvers" / "registry.py":
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if _compares_a_solver_name(node):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert found == []
