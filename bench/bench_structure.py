"""How the reference reads, measured on this tree and on an earlier revision, in one run: import
cycles (modules in the largest), imports inside functions (of the project's modules), imports of
private names across modules, classes assembled from mixins defined in other files, the
``tissue_reference.*`` imports that jedi (editors' go-to-definition) resolves from the checkout,
and the modules that one ``tissue solve`` imports.

    python bench/bench_structure.py                  # this tree against edd4af4
    python bench/bench_structure.py --base HEAD~3
"""
import argparse
import ast
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import import_graph


def _private_imports(graph) -> int:
    n = 0
    for path in graph.modules.values():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                n += sum(a.name.startswith("_") and not a.name.startswith("__")
                         for a in node.names)
    return n


def _mixin_classes(graph) -> list[str]:
    """Classes with a base class named *Mixin (each base defined in a file of its own)."""
    out = []
    for path in graph.modules.values():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                mixins = [b.id for b in node.bases if isinstance(b, ast.Name)
                          and b.id.endswith("Mixin")]
                if mixins:
                    out.append(f"{node.name} ({len(mixins)} mixins)")
    return out


def _jedi_resolved(root: Path) -> tuple[int, int]:
    """(resolved, all) of the tree's tissue_reference imports (module paths), for jedi."""
    import jedi

    project = jedi.Project(root)
    done = total = 0
    for folder in ("meshes", "fem_reference", "solvers", "control", "implant", "tissue"):
        for path in sorted((root / folder).rglob("*.py")):
            code = path.read_text()
            lines = code.splitlines()
            script = None
            for node in ast.walk(ast.parse(code)):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                        "tissue_reference."):
                    total += 1
                    script = script or jedi.Script(code, path=str(path), project=project)
                    col = lines[node.lineno - 1].index(node.module) + len(node.module) - 1
                    found = script.goto(node.lineno, col, follow_imports=True)
                    done += any(d.module_path is not None for d in found)
    return done, total


def _solve_route(root: Path) -> int:
    """Project modules a ``tissue solve`` of the glued phantom imports (a fresh process)."""
    code = ("import sys, runpy; sys.argv = ['tissue', 'solve', 'phantom', '--size', '10', "
            "'--push', 'A1=2', '--no-estimate', '-q']\n"
            "from tissue_reference.tissue.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "print(sum(1 for m in sys.modules if m.startswith('tissue_reference.')))")
    env = dict(os.environ, PYTHONPATH=str(root))
    out = subprocess.run([sys.executable, "-c", code], cwd=tempfile.gettempdir(), env=env,
                         capture_output=True, text=True, timeout=600, check=False)
    return int(out.stdout.strip().splitlines()[-1])


def measure(root: Path) -> dict:
    graph = import_graph.build(root)
    cycles = graph.cycles()
    return {"modules": len(graph.modules), "cycles": len(cycles),
            "largest cycle": len(cycles[0]) if cycles else 0,
            "imports inside functions": len({(a, line) for a, line, _ in graph.in_function()}),
            "private names imported across modules": _private_imports(graph),
            "classes from mixins": len(_mixin_classes(graph)),
            "jedi-resolved tissue_reference imports": "{} of {}".format(*_jedi_resolved(root)),
            "modules imported by one tissue solve": _solve_route(root)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="edd4af4", help="the earlier revision (default edd4af4)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "base"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(base),
                        args.base], check=True)
        try:
            before, after = measure(base), measure(ROOT)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)],
                           check=False)
    width = max(map(len, before))
    print(f"{'':{width}s}  {args.base:>22s}  {'this tree':>22s}")
    for key in before:
        print(f"{key:{width}s}  {before[key]!s:>22s}  {after[key]!s:>22s}")


if __name__ == "__main__":
    main()
