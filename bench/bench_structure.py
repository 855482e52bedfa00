"""How the reference reads, measured on this tree and on an earlier revision, in one run: import
cycles (modules in the largest), imports inside functions (of the project's modules), imports of
private names across modules, classes assembled from mixins defined in other files, the most
files one class's methods come from (its own and its project base classes'), the
``tissue_reference.*`` imports that jedi (editors' go-to-definition) resolves from the checkout,
and the route of one ``tissue solve`` (glued phantom, size 10, A1 = 2 mm, no estimate): the
project modules it imports, the project files its calls enter, the calls that cross from one
project file into another, and the re-entries (a crossing into a file the route entered
before).

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


def _widest_class(graph) -> str:
    """The class whose methods come from the most files: its own and those of its base classes
    defined in the project (by name, transitively), as "Name (n files)"."""
    classes = {}
    for path in graph.modules.values():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                bases = [b.id for b in node.bases if isinstance(b, ast.Name)]
                classes.setdefault(node.name, (path, bases))

    def files(name, seen=()):
        path, bases = classes[name]
        out = {path}
        for b in bases:
            if b in classes and b not in seen:
                out |= files(b, (*seen, name))
        return out

    name = max(classes, key=lambda n: len(files(n)))
    return f"{name} ({len(files(name))} files)"


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


ROUTE = """
import os, sys
root = os.path.realpath(sys.argv[1])
sys.argv = ["tissue", "solve", "phantom", "--size", "10", "--push", "A1=2", "--no-estimate",
            "-q", "--out", sys.argv[2]]
entered, crossings, reentries = set(), 0, 0
def project(frame):
    f = os.path.realpath(frame.f_code.co_filename)
    return f if f.startswith(root) and "/.venv/" not in f else None
def profile(frame, event, arg):
    global crossings, reentries
    if event != "call":
        return
    callee = project(frame)
    caller = project(frame.f_back) if frame.f_back is not None else None
    if callee is None or callee == caller or caller is None:
        return
    crossings += 1
    reentries += callee in entered
    entered.add(callee)
from tissue_reference.tissue.cli import main
sys.setprofile(profile)
try:
    main()
except SystemExit:
    pass
sys.setprofile(None)
print(sum(1 for m in sys.modules if m.startswith("tissue_reference.")), len(entered),
      crossings, reentries)
"""


def _solve_route(root: Path) -> dict:
    """The route of one ``tissue solve`` in a fresh process (module docstring)."""
    env = dict(os.environ, PYTHONPATH=str(root))
    with tempfile.TemporaryDirectory() as out_dir:
        out = subprocess.run([sys.executable, "-c", ROUTE, str(root), out_dir],
                             cwd=tempfile.gettempdir(), env=env, capture_output=True, text=True,
                             timeout=900, check=False)
    modules, files, crossings, reentries = map(int, out.stdout.strip().splitlines()[-1].split())
    return {"modules imported by one tissue solve": modules,
            "project files its calls enter": files,
            "calls crossing between project files": crossings,
            "re-entries into a file entered before": reentries}


def measure(root: Path) -> dict:
    graph = import_graph.build(root)
    cycles = graph.cycles()
    return {"modules": len(graph.modules), "cycles": len(cycles),
            "largest cycle": len(cycles[0]) if cycles else 0,
            "imports inside functions": len({(a, line) for a, line, _ in graph.in_function()}),
            "private names imported across modules": _private_imports(graph),
            "classes from mixins": len(_mixin_classes(graph)),
            "files of the widest class": _widest_class(graph),
            "jedi-resolved tissue_reference imports": "{} of {}".format(*_jedi_resolved(root)),
            **_solve_route(root)}


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
