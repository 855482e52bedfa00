"""The project's import graph, read from the source (AST), not by importing anything.

Every module of the layers (errors, meshes, model, fem_reference, solvers, control, implant,
verification, tissue and the ``tissue_reference`` package itself) is a node; an edge a -> b is an
import in a of b or of a name b defines (``from .x import y`` where y is a module counts as an import of that
module). Imports inside functions count like module-level ones (they hide a cycle, they do not
remove it); those under ``if TYPE_CHECKING:`` are left out (they never run). A package's
``__init__`` is its own node: importing ``a.b.c`` imports ``a.b`` first, but that edge is
Python's, not the project's, and is left out.

    python tools/import_graph.py              # cycles, in-function imports, counts
    python tools/import_graph.py --cycles     # exit 1 when there is an import cycle
"""
from __future__ import annotations

import argparse
import ast
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NS = "tissue_reference"
LAYERS = ("errors", "meshes", "model", "fem_reference", "solvers", "control", "implant",
          "verification", "tissue")


@dataclass
class Graph:
    """modules: name -> file; edges: name -> {imported name: [(line, in a function)]}."""
    modules: dict[str, Path] = field(default_factory=dict)
    edges: dict[str, dict[str, list[tuple[int, bool]]]] = field(default_factory=dict)

    def in_function(self) -> list[tuple[str, int, str]]:
        """(module, line, imported module) of every import inside a function."""
        return sorted((a, line, b) for a, out in self.edges.items() for b, where in out.items()
                      for line, inner in where if inner)

    def cycles(self) -> list[list[str]]:
        """The strongly connected components with more than one module (each an import
        cycle), largest first; a module importing itself is one too."""
        index, low, stack, on, out = {}, {}, [], set(), []
        counter = [0]

        def visit(v):
            index[v] = low[v] = counter[0]
            counter[0] += 1
            stack.append(v)
            on.add(v)
            for w in self.edges.get(v, {}):
                if w not in index:
                    visit(w)
                    low[v] = min(low[v], low[w])
                elif w in on:
                    low[v] = min(low[v], index[w])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1 or v in self.edges.get(v, {}):
                    out.append(sorted(comp))

        sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))
        for v in sorted(self.modules):
            if v not in index:
                visit(v)
        return sorted(out, key=lambda c: (-len(c), c))


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Module name (``tissue_reference.model.case``) -> its file, for every module of the
    layers and of the ``tissue_reference`` package."""
    out = {}
    for f in sorted((root / NS).glob("*.py")):
        out[NS if f.stem == "__init__" else f"{NS}.{f.stem}"] = f
    for layer in LAYERS:
        for f in sorted((root / layer).rglob("*.py")):
            parts = f.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join((NS,) + parts)] = f
    return out


def _type_checking(node) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imports(tree):
    """(line, in a function, absolute-or-relative module, names, level) of every import."""
    out = []

    def walk(node, inner):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                for c in child.orelse:
                    walk(c, inner)
                continue
            deeper = inner or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                 ast.Lambda))
            if isinstance(child, ast.Import):
                for a in child.names:
                    out.append((child.lineno, inner, a.name, (), 0))
            elif isinstance(child, ast.ImportFrom):
                out.append((child.lineno, inner, child.module or "",
                            tuple(a.name for a in child.names), child.level))
            walk(child, deeper)

    walk(tree, False)
    return out


def build(root: Path = ROOT) -> Graph:
    g = Graph(modules=module_files(root))
    for name, path in g.modules.items():
        is_pkg = path.stem == "__init__"
        package = name if is_pkg else name.rpartition(".")[0]
        out = g.edges.setdefault(name, {})
        for line, inner, mod, names, level in _imports(ast.parse(path.read_text(), str(path))):
            if level:
                base = package.split(".")
                base = base[:len(base) - (level - 1)]
                mod = ".".join(base + ([mod] if mod else []))
            targets = []
            if names:
                for n in names:
                    sub = f"{mod}.{n}"
                    targets.append(sub if sub in g.modules else mod)
            else:
                targets.append(mod)
            for t in targets:
                while t and t not in g.modules:   # a name inside a module: the module
                    t = t.rpartition(".")[0]
                if t and t != name:
                    out.setdefault(t, []).append((line, inner))
    return g


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", action="store_true", help="exit 1 when there is an import cycle")
    args = ap.parse_args(argv)
    g = build()
    cycles = g.cycles()
    inner = g.in_function()
    n_edges = sum(len(v) for v in g.edges.values())
    print(f"{len(g.modules)} modules, {n_edges} imports between them, "
          f"{len(inner)} inside functions, {len(cycles)} import cycles"
          + (f" (largest {len(cycles[0])} modules)" if cycles else ""))
    for c in cycles:
        print("  cycle: " + ", ".join(m.removeprefix(NS + ".") for m in c))
    if not args.cycles:
        for a, line, b in inner:
            print(f"  in a function: {g.modules[a].relative_to(ROOT)}:{line} imports "
                  f"{b.removeprefix(NS + '.')}")
    return 1 if args.cycles and cycles else 0


if __name__ == "__main__":
    sys.exit(main())
