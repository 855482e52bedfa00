"""The project's modules import one way, and static tools see the layers under their installed
names in the checkout.

- No import cycle among the project's modules, imports inside functions included (they hide a
  cycle, they do not remove one): ``tools/import_graph.py`` reads the source's AST.
- Every ``tissue_reference.*`` import of the tree, and every name such an import takes, resolves
  for jedi (the engine of editors' go-to-definition) from the checkout, as an editor opened on
  the repository sees it: through ``tissue_reference/<layer>``, links to the layers' folders.
"""
import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import import_graph

TREES = ("meshes", "fem_reference", "solvers", "control", "implant", "verification", "tissue",
         "tissue_reference", "tests", "bench", "tools", "examples")


def test_no_import_cycle_among_the_modules():
    graph = import_graph.build()
    assert len(graph.modules) > 100          # the layers were found
    assert graph.cycles() == []


def test_imports_point_down_the_layers():
    """A layer imports only the layers before it in ``import_graph.LAYERS``: the verification
    layer none of the command line (``tissue``), which calls it; the library none of either."""
    graph = import_graph.build()
    order = {name: k for k, name in enumerate(import_graph.LAYERS)}

    def layer(module):
        parts = module.split(".")
        return parts[1] if len(parts) > 1 and parts[1] in order else None

    up = sorted((a, b) for a, out in graph.edges.items() for b in out
                if layer(a) and layer(b) and order[layer(b)] > order[layer(a)])
    assert up == []


def test_the_cycle_check_sees_a_cycle_hidden_in_a_function(tmp_path):
    (tmp_path / "tissue_reference").mkdir()
    (tmp_path / "tissue_reference" / "__init__.py").write_text("")
    layer = tmp_path / "meshes"
    layer.mkdir()
    (layer / "__init__.py").write_text("")
    (layer / "a.py").write_text("from .b import B\nA = 1\n")
    (layer / "b.py").write_text("B = 2\n\n\ndef late():\n    from tissue_reference.meshes.a "
                                "import A\n    return A\n")
    (layer / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                "    from .a import A\n")
    graph = import_graph.build(tmp_path)
    assert graph.cycles() == [["tissue_reference.meshes.a", "tissue_reference.meshes.b"]]
    assert [(a, b) for a, _, b in graph.in_function()] == [
        ("tissue_reference.meshes.b", "tissue_reference.meshes.a")]


def _project_imports():
    """(file, line, column, what) of every module path and imported name of a
    ``from tissue_reference... import`` / ``import tissue_reference...`` in the tree."""
    out = []
    for tree in TREES:
        for path in sorted((ROOT / tree).rglob("*.py")):
            if tree == "tissue_reference" and path.parent != ROOT / tree:
                continue     # the links to the layers: their files are checked as the layers
            code = path.read_text()
            lines = code.splitlines()
            for node in ast.walk(ast.parse(code)):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                        "tissue_reference"):
                    line = lines[node.lineno - 1]
                    out.append((path, node.lineno, line.index(node.module) + len(node.module) - 1,
                                node.module))
                    for alias in node.names:
                        for k in range(node.lineno, (node.end_lineno or node.lineno) + 1):
                            text = lines[k - 1]
                            col = _word(text, alias.name)
                            if col >= 0 and not (k == node.lineno and col < line.index(" import ")):
                                out.append((path, k, col, f"{node.module}:{alias.name}"))
                                break
                elif isinstance(node, ast.Import):
                    for alias in node.names:
                        if alias.name.startswith("tissue_reference"):
                            text = lines[node.lineno - 1]
                            out.append((path, node.lineno, text.index(alias.name)
                                        + len(alias.name) - 1, alias.name))
    return out


def _word(text, name):
    """Column of ``name`` as a whole word in ``text``, -1 when absent."""
    i = text.find(name)
    while i >= 0:
        before = text[i - 1] if i else " "
        after = text[i + len(name)] if i + len(name) < len(text) else " "
        if not (before.isalnum() or before in "_.") and not (after.isalnum() or after == "_"):
            return i
        i = text.find(name, i + 1)
    return -1


@pytest.fixture(scope="module")
def jedi_project():
    jedi = pytest.importorskip("jedi")
    return jedi, jedi.Project(ROOT)


def _resolves(jedi, project, path, line, col, code=None):
    script = jedi.Script(path.read_text() if code is None else code, path=str(path),
                         project=project)
    return any(d.module_path is not None for d in script.goto(line, col, follow_imports=True))


def test_every_project_import_resolves_for_static_tools(jedi_project):
    jedi, project = jedi_project
    imports = _project_imports()
    assert len(imports) > 1000
    scripts = {}
    unresolved = []
    for path, line, col, what in imports:
        if path not in scripts:
            scripts[path] = jedi.Script(path.read_text(), path=str(path), project=project)
        found = scripts[path].goto(line, col, follow_imports=True)
        if not any(d.module_path is not None for d in found):
            unresolved.append(f"{path.relative_to(ROOT)}:{line}: {what}")
    assert unresolved == []


def test_the_static_check_sees_an_import_that_does_not_resolve(jedi_project, tmp_path):
    jedi, project = jedi_project
    path = ROOT / "tests" / "_probe_for_jedi.py"      # never written: jedi reads the code given
    good = "from tissue_reference.model.case import load_case\n"
    bad = "from tissue_reference.meshes.no_such_module import load_case\n"
    assert _resolves(jedi, project, path, 1, len("from tissue_reference.meshes.cas"), good)
    assert not _resolves(jedi, project, path, 1, len("from tissue_reference.meshes.no_such_modul"),
                         bad)


def test_an_import_inside_a_function_says_why():
    """Imports sit at the top of a module; one inside a function (for a start-up cost or an
    optional dependency) has a ``# lazy:`` comment above its group saying which."""
    graph = import_graph.build()
    silent = []
    for module, line, _ in graph.in_function():
        lines = graph.modules[module].read_text().splitlines()
        k = line - 2
        while k >= 0 and lines[k].strip().startswith(("from ", "import ", ")")) or (
                k >= 0 and lines[k].startswith(" ") and lines[k].strip().endswith(",")):
            k -= 1                                # the group's imports above this one
        if not (k >= 0 and lines[k].strip().startswith("# lazy:")):
            silent.append(f"{graph.modules[module].relative_to(ROOT)}:{line}")
    assert silent == []


def test_commands_share_helpers_through_modules_of_their_own():
    """A command module (``tissue/cmd_*.py``) imports no other command module: what two commands
    share lives in a module of its own (``tissue.common``, ``tissue.solve_outputs``,
    ``tissue.loop_options``, ...)."""
    graph = import_graph.build()
    prefix = "tissue_reference.tissue.cmd_"
    crossing = sorted((a, b) for a, out in graph.edges.items() if a.startswith(prefix)
                      for b in out if b.startswith(prefix))
    assert crossing == []


def test_a_fast_solve_on_the_command_line_loads_no_dolfinx():
    """`tissue solve --solver admm` and the modules of fem_reference that need no dolfinx
    (its CHOLMOD factorization, the measured rows, the settings) load neither dolfinx nor UFL:
    the package's names are imported on first use."""
    import subprocess

    code = ("import sys\n"
            "from tissue_reference.tissue.cli import main\n"
            "rc = main(['solve', 'phantom', '--size', '14', '--push', 'A1=1', '--solver', 'admm',"
            " '-q'])\n"
            "from tissue_reference.fem_reference import cholmod_factor\n"
            "import tissue_reference.fem_reference.measured, tissue_reference.fem_reference.newton_settings\n"
            "print('exit', rc, 'loaded', sorted(m for m in ('dolfinx', 'ufl', 'ffcx') "
            "if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         check=False,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "exit 0 loaded []" in out.stdout, out.stdout[-2000:]
    import tissue_reference.fem_reference as fr
    assert fr.solve.__module__ == "tissue_reference.fem_reference.answer"   # resolved lazily
    with pytest.raises(AttributeError, match="has no attribute 'nothing'"):
        fr.nothing  # noqa: B018
