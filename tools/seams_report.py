"""Figures of how the project's parts meet, printed for a tree (this checkout by default):

- comparisons of a built-in solver's name (a string literal on a side of ==, !=, in, not in, is,
  or a ``case`` of a ``match``) in the library outside the solver registry;
- uses of ``.extra`` (a solver's free-form extras) in the library;
- back-references: attributes of the reference engine's parts (``fem_reference``, ``solver.py``
  left out) named ``solver``, and its functions that take the whole solver as a parameter;
- the ten longest functions of the library (lines, decorators excluded);
- the words of README.md;
- the route of one command, ``tissue solve phantom --push A1=5``, run in this process under
  ``sys.setprofile``: the project's files imported and those whose functions ran (per layer), the
  function calls from one module into another, and the re-entries into the command line (a call
  into ``tissue/`` whose nearest project caller is in another layer). A builtin mesh not yet in
  the mesh cache is built by gmsh on the way: run it twice for the figures of a warm cache.

The library is every layer but the command line (``tissue``); the layers are the folders that
``tissue_reference/`` links to. Read from the source (AST), except the route, which imports and
runs the tree given (put it first on ``PYTHONPATH``).

    python tools/seams_report.py                 # figures, then the route (one solve, ~30 s)
    python tools/seams_report.py --no-route      # the static figures only
    python tools/seams_report.py --root OTHER    # another checkout (PYTHONPATH=OTHER)
"""
from __future__ import annotations

import argparse
import ast
import os
import sys
import tempfile
from pathlib import Path

NS = "tissue_reference"
CLI = "tissue"


def layers(root: Path) -> list[str]:
    """The layers: the folders that ``tissue_reference/`` links to."""
    return sorted(p.name for p in (root / NS).iterdir() if p.is_symlink() and p.is_dir())


def library_files(root: Path) -> list[Path]:
    return [f for layer in layers(root) if layer != CLI
            for f in sorted((root / layer).rglob("*.py"))]


def solver_names(root: Path) -> set[str]:
    """The built-in solvers' names: the first argument of each ``SolverEntry(...)``."""
    tree = ast.parse((root / "solvers" / "registry.py").read_text())
    return {n.args[0].value for n in ast.walk(tree)
            if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "SolverEntry"
            and n.args and isinstance(n.args[0], ast.Constant)}


def name_comparisons(root: Path) -> list[str]:
    names = solver_names(root)

    def named(x):
        if isinstance(x, ast.Constant):
            return x.value in names
        if isinstance(x, (ast.Tuple, ast.List, ast.Set)):
            return any(named(e) for e in x.elts)
        return False

    found = []
    for f in library_files(root):
        if f == root / "solvers" / "registry.py":
            continue
        for n in ast.walk(ast.parse(f.read_text())):
            hit = isinstance(n, ast.Compare) and any(named(x) for x in (n.left, *n.comparators))
            hit = hit or (isinstance(n, ast.MatchValue) and named(n.value))
            if hit:
                found.append(f"{f.relative_to(root)}:{n.lineno}")
    return found


def extra_uses(root: Path) -> list[str]:
    return [f"{f.relative_to(root)}:{n.lineno}" for f in library_files(root)
            for n in ast.walk(ast.parse(f.read_text()))
            if isinstance(n, ast.Attribute) and n.attr == "extra"]


def back_references(root: Path) -> tuple[list[str], list[str]]:
    """(attributes named ``solver`` of the engine's parts, as ``file:line: x.solver``;
    the parts' functions with a parameter named ``solver``)."""
    attrs, params = [], []
    for f in sorted((root / "fem_reference").glob("*.py")):
        if f.name == "solver.py":
            continue
        tree = ast.parse(f.read_text())
        for n in ast.walk(tree):
            if isinstance(n, ast.Attribute) and n.attr == "solver" and \
                    isinstance(n.ctx, ast.Store):
                attrs.append(f"{f.relative_to(root)}:{n.lineno}: {ast.unparse(n)}")
            elif isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and "solver" in \
                    [a.arg for a in n.args.args + n.args.kwonlyargs + n.args.posonlyargs]:
                params.append(f"{f.relative_to(root)}:{n.lineno}: {n.name}")
    return attrs, params


def longest_functions(root: Path, k: int = 10) -> list[tuple[int, str]]:
    out = []
    for f in library_files(root):
        for n in ast.walk(ast.parse(f.read_text())):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                where = f"{f.relative_to(root)}:{n.lineno} {n.name}"
                out.append((n.end_lineno - n.lineno + 1, where))
    return sorted(out, key=lambda t: (-t[0], t[1]))[:k]


def readme_words(root: Path) -> int:
    return len((root / "README.md").read_text().split())


def route(root: Path, argv: list[str]) -> dict:
    """Run the command line on ``argv`` in this process and follow its calls."""
    real = {layer: (root / layer).resolve() for layer in layers(root)}

    cache: dict = {}

    def where(code):
        """(layer, file relative to the root) of a code object of the project, else None."""
        got = cache.get(code, False)
        if got is False:
            got = None
            path = Path(code.co_filename)
            if path.is_absolute():
                path = path.resolve()
                for layer, folder in real.items():
                    if path.is_relative_to(folder):
                        got = (layer, path.relative_to(root.resolve()).as_posix())
                        break
            cache[code] = got
        return got

    files: set[str] = set()
    called: set[str] = set()   # files whose functions ran (not only their module bodies)
    moves = {"calls between modules": 0, "re-entries into the command line": 0}
    reentries: dict[str, int] = {}

    def profile(frame, event, arg):
        if event != "call":
            return
        here = where(frame.f_code)
        if here is None:
            return
        files.add(here[1])
        if frame.f_code.co_name == "<module>":   # an import running a module's body
            return
        called.add(here[1])
        back = frame.f_back
        while back is not None and where(back.f_code) is None:
            back = back.f_back
        if back is None:
            return
        caller = where(back.f_code)
        if caller[1] != here[1]:
            moves["calls between modules"] += 1
            if here[0] == CLI and caller[0] != CLI:
                moves["re-entries into the command line"] += 1
                key = f"{caller[1]} -> {here[1]}:{frame.f_code.co_name}"
                reentries[key] = reentries.get(key, 0) + 1

    sys.path.insert(0, str(root))
    from tissue_reference.tissue.cli import main  # the tree given

    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        sys.setprofile(profile)
        try:
            status = main(argv)
        except SystemExit as e:
            status = e.code
        finally:
            sys.setprofile(None)
            os.chdir(cwd)
    per_layer: dict[str, int] = {}
    for f in called:
        per_layer[f.split("/")[0]] = per_layer.get(f.split("/")[0], 0) + 1
    return {"status": status, "imported": len(files), "files": len(called),
            "per_layer": per_layer, **moves, "reentries": reentries}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--no-route", action="store_true", help="the static figures only")
    args = ap.parse_args(argv)
    root = args.root.resolve()
    comps = name_comparisons(root)
    extra = extra_uses(root)
    attrs, params = back_references(root)
    print(f"tree: {root}")
    print(f"solver-name comparisons outside the registry (library): {len(comps)}")
    for c in comps:
        print(f"  {c}")
    print(f".extra uses (library): {len(extra)}")
    print(f"back-references in fem_reference's parts: {len(attrs)} attributes named solver, "
          f"{len(params)} functions taking the solver")
    for a in attrs:
        print(f"  {a}")
    print("longest library functions (lines):")
    for n, what in longest_functions(root):
        print(f"  {n:4d}  {what}")
    print(f"README words: {readme_words(root)}")
    if not args.no_route:
        cmd = ["solve", "phantom", "--push", "A1=5"]
        r = route(root, cmd)
        layers_ = ", ".join(f"{k} {v}" for k, v in sorted(r["per_layer"].items()))
        print(f"route of `tissue {' '.join(cmd)}` (exit status {r['status']}): "
              f"{r['imported']} project files imported, {r['files']} with functions called "
              f"({layers_}); {r['calls between modules']} function calls from one module into "
              f"another; {r['re-entries into the command line']} re-entries into the command "
              f"line")
        for k, v in sorted(r["reentries"].items(), key=lambda t: -t[1]):
            print(f"  {v:6d}  {k}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
