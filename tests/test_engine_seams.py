"""The reference engine's parts receive what they use: no part of ``fem_reference`` sets the
Newton's extra terms or the contact's line search of another object, no solve swaps a solver's
settings from outside ``solver.py``, no part keeps the solver as an attribute (the contact, its
indenters, the inertia of a dynamics step) and the energy forms take none (checked on the source,
with ``ast``; no dolfinx needed)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ENGINE = Path(__file__).resolve().parent.parent / "fem_reference"
MODULES = sorted(ENGINE.glob("*.py"))


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _assigned_attributes(tree: ast.Module):
    """(attribute node, line) of every attribute that is a target of an assignment."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for sub in ast.walk(target):
                    if isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store):
                        yield sub, node.lineno
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and \
                node.func.id == "setattr" and len(node.args) >= 2 and \
                isinstance(node.args[1], ast.Constant):
            yield ast.Attribute(value=node.args[0], attr=node.args[1].value), node.lineno


def _is_self(node: ast.expr) -> bool:
    return isinstance(node, ast.Name) and node.id == "self"


def test_the_engine_has_modules():
    assert {"newton.py", "contact.py", "contact_indenter.py", "solver.py"} <= \
        {p.name for p in MODULES}


@pytest.mark.parametrize("path", MODULES, ids=lambda p: p.name)
def test_no_part_sets_another_objects_extra_terms_or_line_search(path):
    bad = [f"{path.name}:{line}: .{attr.attr}" for attr, line in _assigned_attributes(_tree(path))
           if attr.attr in ("extra_terms", "accepts") and not _is_self(attr.value)]
    assert not bad, f"set from outside its owner (pass it as an argument instead): {bad}"


@pytest.mark.parametrize("path", [p for p in MODULES if p.name != "solver.py"],
                         ids=lambda p: p.name)
def test_no_solve_swaps_a_solvers_settings(path):
    bad = [f"{path.name}:{line}" for attr, line in _assigned_attributes(_tree(path))
           if attr.attr == "settings" and not _is_self(attr.value)]
    assert not bad, f"a solver's settings assigned (pass settings= to solve instead): {bad}"


@pytest.mark.parametrize("name", ["contact.py", "contact_indenter.py"])
def test_the_contact_holds_no_solver(name):
    tree = _tree(ENGINE / name)
    bad = [node.lineno for node in ast.walk(tree)
           if isinstance(node, ast.Attribute) and node.attr == "solver" and _is_self(node.value)]
    assert not bad, f"{name}: self.solver at lines {bad}"
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name in ("Contact", "Indenter"):
            init = next(f for f in node.body
                        if isinstance(f, ast.FunctionDef) and f.name == "__init__")
            args = [a.arg for a in init.args.args + init.args.kwonlyargs]
            assert "solver" not in args, f"{node.name}.__init__ takes the solver"


@pytest.mark.parametrize("path", [p for p in MODULES if p.name != "solver.py"],
                         ids=lambda p: p.name)
def test_no_part_keeps_the_solver(path):
    bad = [f"{path.name}:{line}: {ast.unparse(attr)}"
           for attr, line in _assigned_attributes(_tree(path)) if attr.attr == "solver"]
    assert not bad, f"a part holding the whole solver (pass it what it uses instead): {bad}"


def test_the_energy_forms_take_no_solver():
    tree = _tree(ENGINE / "energy_forms.py")
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            args = [a.arg for a in node.args.args + node.args.kwonlyargs]
            assert "solver" not in args, node.name


def _held_by_self(node: ast.expr) -> bool:
    """Whether ``node`` is ``self`` or reached from it (``self.part``, ``self.parts[k]``): what
    an object holds it may set; anything else is another object's."""
    while isinstance(node, (ast.Attribute, ast.Subscript)):
        node = node.value
    return _is_self(node)


RESTORED_HOOKS = {("__init__.py", "warnings.showwarning")}
"""Attributes of another module the engine sets, with why: the package's lazy import puts back
Python's warning display, which importing the form compiler replaces (``_import_keeping_warnings``)."""


def test_no_part_sets_an_attribute_of_an_object_it_does_not_hold():
    """Across the engine's modules an object changes another only through that object's methods
    (``ReferenceSolver.set_material``, ``set_load_fraction``, ``use_case``,
    ``LinearSolver.tangent_changed``, ``Indenter.place``): no assignment to an attribute of an
    object that is not ``self`` or held by it."""
    bad = []
    for path in MODULES:
        for attr, line in _assigned_attributes(_tree(path)):
            if _held_by_self(attr.value):
                continue
            if (path.name, ast.unparse(attr)) not in RESTORED_HOOKS:
                bad.append(f"{path.name}:{line}: {ast.unparse(attr)}")
    assert not bad, f"set from outside its owner (give the owner a method instead): {bad}"


def test_the_attribute_check_sees_another_objects_attribute():
    tree = ast.parse("def f(solver, self):\n    solver.load.value = 1.0\n    self.a.b = 2\n"
                     "    self.c[k].value = 3\n    other.x += 1\n")
    found = [ast.unparse(a) for a, _ in _assigned_attributes(tree) if not _held_by_self(a.value)]
    assert found == ["solver.load.value", "other.x"]
