"""The public entry points document every parameter (numpy style): an editor shows each one's
meaning and unit, and a parameter added without documentation fails here."""
from __future__ import annotations

import ast
import importlib
import inspect
import re
import textwrap

import pytest

PUBLIC = [
    "tissue_reference.fem_reference.answer:solve",
    "tissue_reference.fem_reference.kept:tangent_stiffness",
    "tissue_reference.fem_reference.solver:ReferenceSolver",
    "tissue_reference.fem_reference.solver:ReferenceSolver.solve",
    "tissue_reference.fem_reference.solver:ReferenceSolver.tangent",
    "tissue_reference.fem_reference.newton_settings:NewtonSettings",
    "tissue_reference.fem_reference.convergence:run_study",
    "tissue_reference.fem_reference.richardson:assess",
    "tissue_reference.solvers.admm:solve",
    "tissue_reference.solvers.mass_tensor:solve",
    "tissue_reference.solvers.registry:entries",
    "tissue_reference.solvers.registry:names",
    "tissue_reference.solvers.registry:control_names",
    "tissue_reference.solvers.registry:dynamics_names",
    "tissue_reference.solvers.registry:solver",
    "tissue_reference.solvers.registry:reference",
    "tissue_reference.solvers.registry:is_reference",
    "tissue_reference.solvers.registry:SolverEntry.solve",
    "tissue_reference.solvers.registry:SolverEntry.settings",
    "tissue_reference.solvers.registry:SolverEntry.describe",
    "tissue_reference.solvers.registry:SolverEntry.simulate",
    "tissue_reference.model.case:load_case",
    "tissue_reference.model.case:Case",
    "tissue_reference.model.case:Material",
    "tissue_reference.model.results:SolveResult",
    "tissue_reference.verification.verify:verify",
    "tissue_reference.verification.verify:tolerance_failures",
    "tissue_reference.verification.verify:invalid_runs",
    "tissue_reference.verification.plugins:resolve_solver",
    "tissue_reference.verification.plugins:run_plugin",
    "tissue_reference.verification.plugins:entry_point_solvers",
    "tissue_reference.verification.closed_forms:thick_sphere",
    "tissue_reference.control.jacobian:dirichlet_jacobian",
    "tissue_reference.control.jacobian:force_jacobian",
    "tissue_reference.control.jacobian:admm_indenter_jacobian",
    "tissue_reference.control.jacobian:full_pushes",
    "tissue_reference.control.jacobian:fd_jacobian",
    "tissue_reference.control.jacobian:max_rel_error",
    "tissue_reference.control.dof_maps:probe_matrix",
    "tissue_reference.control.dof_maps:point_matrix",
    "tissue_reference.control.dof_maps:p2_interpolation",
    "tissue_reference.control.dof_maps:p2_region_nodes",
    "tissue_reference.control.jacobian:target_rows",
    "tissue_reference.control.plants:build_loop",
    "tissue_reference.control.plants:LoopSetup.run",
    "tissue_reference.control.loop:LoopSettings",
    "tissue_reference.control.mpc:MPCSettings",
]

_HEADER = re.compile(r"^(\w[\w ]*)\n-{3,}$", re.MULTILINE)


def _load(spec: str):
    module, name = spec.split(":")
    obj = importlib.import_module(module)
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


def sections(doc: str | None) -> dict:
    """Section title -> the names its entries document ("a, b : type" gives a and b)."""
    text = inspect.cleandoc(doc or "")
    heads = list(_HEADER.finditer(text))
    out = {}
    for k, m in enumerate(heads):
        end = heads[k + 1].start() if k + 1 < len(heads) else len(text)
        names = set()
        for line in text[m.end():end].splitlines():
            if line and not line[0].isspace():
                for n in line.split(" : ")[0].split(","):
                    names.add(n.strip().lstrip("*"))
        out[m.group(1)] = names
    return out


def _parameters(obj):
    sig = inspect.signature(obj)
    return [n for n, p in sig.parameters.items()
            if n not in ("self", "cls")
            and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


def _returns_value(func) -> bool:
    tree = ast.parse(textwrap.dedent(inspect.getsource(func)))
    top = tree.body[0]
    todo = list(top.body)
    while todo:   # the function's own returns, not those of functions nested in it
        node = todo.pop()
        if isinstance(node, ast.Return) and node.value is not None:
            return True
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda,
                                 ast.ClassDef)):
            todo.extend(ast.iter_child_nodes(node))
    return False


@pytest.mark.parametrize("spec", PUBLIC)
def test_public_callable_documents_its_parameters(spec):
    obj = _load(spec)
    found = sections(obj.__doc__)
    if inspect.isclass(obj):
        # a class's constructor parameters: as Parameters or, for records, as Attributes
        documented = found.get("Parameters", set()) | found.get("Attributes", set())
        assert documented, f"{spec}: no Parameters or Attributes section"
        missing = [n for n in _parameters(obj) if n not in documented]
        assert not missing, f"{spec}: undocumented constructor parameters {missing}"
        return
    params = _parameters(obj)
    if params:
        assert "Parameters" in found, f"{spec}: no Parameters section"
        missing = [n for n in params if n not in found["Parameters"]]
        assert not missing, f"{spec}: undocumented parameters {missing}"
    if _returns_value(obj):
        assert "Returns" in found, f"{spec}: returns a value but has no Returns section"


def test_sections_reader_finds_a_missing_parameter():
    def f(a, b, *args, c=1, **kw):
        """Something.

        Parameters
        ----------
        a, b : float
            Lengths (mm).

        Returns
        -------
        float
        """
        return a
    assert sections(f.__doc__)["Parameters"] == {"a", "b"}
    assert [n for n in _parameters(f) if n not in sections(f.__doc__)["Parameters"]] == ["c"]
    assert _returns_value(f)
