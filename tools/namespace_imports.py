"""Rewrite references to the project's layers so that they go through its one installed name.

The layers (errors, meshes, model, fem_reference, solvers, control, implant, verification,
tissue) stay
top-level folders of the repository but are installed as ``tissue_reference.<layer>`` (see
pyproject.toml). This rewrites, in every tracked *.py and *.md file:

- imports: ``from meshes.case import X`` -> ``from tissue_reference.meshes.case import X``,
  ``import fem_reference as fr`` -> ``import tissue_reference.fem_reference as fr``,
  ``import solvers`` -> ``from tissue_reference import solvers`` (also the import lines of
  docstrings, of code kept in strings and of the documents' code blocks);
- strings that name a module or an object in one: ``"solvers.admm"``, ``f"tissue.{name}"``,
  ``"fem_reference.solver.X"`` (mock/monkeypatch targets), ``"meshes.case:load_case"``; with
  ``__import__("meshes.case").case`` -> ``__import__("tissue_reference.meshes.case").meshes.case``;
  a bare layer name only where it is one: after ``"-m"``, in ``import_module``/``find_spec``.
  Logger names (``getLogger("tissue.verify")``) are left alone;
- ``python -m tissue`` -> ``python -m tissue_reference`` (the package runs the command line),
  ``python -m implant.render`` -> ``python -m tissue_reference.implant.render``;
- in Markdown, inline code that names a module (`` `fem_reference.estimate` ``).

A dotted name counts as a module path only when its second part is a module or subpackage of the
layer in this tree, or a name its ``__init__.py`` defines: "tissue.solvers" (an entry-point group)
and "tissue.fem" (a logger) stay. Generated pages (``<!-- generated ... by tools/X.py``) are
rewritten by running their generator. Files with the line ``# namespace_imports: skip`` are
left alone. Running it twice changes nothing the second time.

    python tools/namespace_imports.py            # rewrite the tree in place
    python tools/namespace_imports.py --check    # list the files it would change; exit 1 if any
    python tools/namespace_imports.py FILE...    # only these files
"""
# namespace_imports: skip
from __future__ import annotations

import argparse
import ast
import io
import re
import shutil
import subprocess
import sys
import tokenize
from functools import cache
from itertools import pairwise
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NS = "tissue_reference"
LAYERS = ("errors", "meshes", "model", "fem_reference", "solvers", "control", "implant",
          "verification", "tissue")
SKIP_MARK = "# namespace_imports: skip"
WIDTH = 100  # pyproject.toml [tool.ruff] line-length
_L = "|".join(LAYERS)
_DOTTED = re.compile(rf"^({_L})((?:\.[A-Za-z_]\w*)+)(:[A-Za-z_][\w.]*)?$")
_FSTRING = re.compile(rf"^({_L})\.(\{{|$)")
_DASH_M = re.compile(rf"(\bpython[\d.]*\s+-m\s+|\{{sys\.executable\}}\s+-m\s+)({_L})(?![\w])"
                     rf"((?:\.\w+)*)")
_FROM_LINE = re.compile(rf"^(\s*(?:>>> |\.\.\. )?from\s+)({_L})(?=[\s.])")
_IMPORT_LINE = re.compile(rf"^(\s*(?:>>> |\.\.\. )?)import\s+((?:{_L})(?:\.\w+)*)"
                          rf"(?:\s+as\s+(\w+))?(\s*(?:#.*)?)$")
_GENERATED = re.compile(r"^<!-- generated .* by (tools/\w+\.py)")
_IMPORTERS = {"import_module", "find_spec", "__import__"}
TREE = [ROOT]  # the tree whose layers decide what a dotted name means (--root)


# --------------------------------------------------------------------------- what names a module
@cache
def _init_names(layer: str, root: Path) -> frozenset:
    """Names bound at the top level of ``layer/__init__.py`` (imports, defs, assignments)."""
    try:
        tree = ast.parse((root / layer / "__init__.py").read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return frozenset()
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names.update(n.id for n in ast.walk(t) if isinstance(n, ast.Name))
    return frozenset(names)


def names_module(dotted: str) -> bool:
    """Whether "layer.part[.more][:obj]" names a module of the layer or something in one."""
    m = _DOTTED.match(dotted)
    if not m:
        return False
    root = TREE[0]
    layer, part = m[1], m[2].split(".")[1]
    d = root / layer
    return (d / f"{part}.py").is_file() or (d / part / "__init__.py").is_file() \
        or part in _init_names(layer, root)


# --------------------------------------------------------------------------- line rules
def dash_m(text: str) -> str:
    """``python -m tissue`` -> ``python -m tissue_reference``; ``-m layer.mod`` -> under NS."""
    def sub(m):
        target = NS if m[2] == "tissue" and not m[3] else f"{NS}.{m[2]}{m[3]}"
        return m[1] + target
    return _DASH_M.sub(sub, text)


def import_line(line: str) -> str:
    """One line of code that imports a layer, rewritten (a line that does not is returned as is);
    ``import layer.sub`` (binds ``layer``) becomes two lines, the second ``layer = NS.layer``."""
    if (m := _FROM_LINE.match(line)):
        return f"{m[1]}{NS}.{m[2]}{line[m.end():]}"
    if not (m := _IMPORT_LINE.match(line)):
        return line
    lead, name, alias, tail = m[1], m[2], m[3], m[4]
    if alias:
        return f"{lead}import {NS}.{name} as {alias}{tail}"
    if "." not in name:
        return f"{lead}from {NS} import {name}{tail}"
    top = name.split(".")[0]  # the name the statement binds, and the code uses
    return f"{lead}import {NS}.{name}{tail}\n{lead}{top} = {NS}.{top}"


def import_lines(text: str) -> str:
    return "".join(import_line(line.removesuffix("\n"))
                   + ("\n" if line.endswith("\n") else "") for line in text.splitlines(True))


# --------------------------------------------------------------------------- Python source
def _offsets(src: str):
    starts, n = [0], 0
    for line in src.splitlines(True):
        n += len(line)
        starts.append(n)
    return lambda row, col: starts[row - 1] + col


def _wrap_from(indent: str, module: str, names: str, tail: str) -> str:
    """``from module import a, b`` over several lines, one name a line (as the code does)."""
    items = [n.strip() for n in names.split(",") if n.strip()]
    body = "".join(f"{indent}    {n},\n" for n in items)
    return f"{indent}from {module} import ({tail}\n{body}{indent})"


def _dotted_tops(node) -> set:
    """The layers an ``import layer.sub`` statement (without ``as``) binds."""
    if not isinstance(node, ast.Import):
        return set()
    return {a.name.split(".")[0] for a in node.names
            if not a.asname and "." in a.name and a.name.split(".")[0] in LAYERS}


def _import_edits(src: str, tree: ast.AST, at):
    """(start, end, text) edits for the import statements of ``tree`` that name a layer."""
    lines = src.splitlines()
    following = {}
    for node in ast.walk(tree):
        for field in ("body", "orelse", "finalbody"):
            stmts = getattr(node, field, None)
            if isinstance(stmts, list):
                following.update((id(a), b) for a, b in pairwise(stmts))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] in LAYERS:
            start = at(node.lineno, node.col_offset)
            m = re.match(r"from\s+", src[start:])
            a = start + m.end()
            module = f"{NS}.{node.module}"
            line = lines[node.lineno - 1]
            tail = line[node.end_col_offset:]
            one_line = node.lineno == node.end_lineno and "(" not in line[node.col_offset:] \
                and not line[:node.col_offset].strip() and re.fullmatch(r"\s*(#.*)?", tail)
            if one_line and len(line) + len(NS) + 1 > WIDTH:
                names = line[node.col_offset:node.end_col_offset].split(" import ", 1)[1]
                text = _wrap_from(line[:node.col_offset], module, names,
                                  "  " + tail.strip() if tail.strip() else "")
                yield at(node.lineno, 0), at(node.lineno, len(line)), text
            else:
                yield a, a + len(node.module.split(".")[0]), f"{NS}.{node.module.split('.')[0]}"
        elif isinstance(node, ast.Import) and any(a.name.split(".")[0] in LAYERS
                                                  for a in node.names):
            line = lines[node.lineno - 1]
            indent = line[:node.col_offset]
            if node.lineno != node.end_lineno or indent.strip() \
                    or not re.fullmatch(r"\s*(#.*)?", line[node.end_col_offset:]):
                raise ValueError(f"line {node.lineno}: import of a layer that is not alone on its "
                                 "line; split it and run again")
            out, bind = [], []
            for a in node.names:
                top = a.name.split(".")[0]
                if top not in LAYERS:
                    out.append(f"import {a.name}" + (f" as {a.asname}" if a.asname else ""))
                elif a.asname or "." not in a.name:
                    out.append(import_line(f"import {a.name}" + (f" as {a.asname}"
                                                                 if a.asname else "")))
                else:
                    out.append(f"import {NS}.{a.name}")
                    bind += [top] if top not in bind else []
            # ``import meshes.a`` then ``import meshes.b``: bind ``meshes`` once, after the last
            later = _dotted_tops(following.get(id(node)))
            out += [f"{top} = {NS}.{top}" for top in bind if top not in later]
            text = f"\n{indent}".join(out)
            yield at(node.lineno, node.col_offset), at(node.lineno, node.end_col_offset), text


def _significant(toks, i, k):
    """The ``k`` significant tokens before index ``i`` (nearest last)."""
    skip = (tokenize.NL, tokenize.NEWLINE, tokenize.COMMENT, tokenize.INDENT, tokenize.DEDENT)
    out, j = [], i - 1
    while j >= 0 and len(out) < k:
        if toks[j].type not in skip:
            out.append(toks[j])
        j -= 1
    return out[::-1]


def _string_edits(src: str, at):
    toks = list(tokenize.generate_tokens(io.StringIO(src).readline))
    fstart = getattr(tokenize, "FSTRING_START", None)
    for i, t in enumerate(toks):
        before = [b.string for b in _significant(toks, i, 3)]
        if t.type == tokenize.STRING:
            m = re.match(r"(?i)([rbuf]*)('''|\"\"\"|'|\")", t.string)
            prefix, q = m[1], m[2]
            body = t.string[len(prefix) + len(q):-len(q)]
            a = at(*t.start) + len(prefix) + len(q)
        elif fstart is not None and t.type == tokenize.FSTRING_MIDDLE \
                and toks[i - 1].type == fstart:
            prefix, body, a = "f", t.string, at(*t.start)
        else:
            continue
        if "\n" in body:  # docstrings and code kept in strings
            new = import_lines(body)
            if new != body:
                yield a, a + len(body), new
            continue
        if before[-2:] == ["getLogger", "("]:
            continue
        importer = before[-2] if len(before) >= 2 and before[-1] == "(" else None
        if "f" in prefix.lower() and _FSTRING.match(body) or names_module(body):
            yield a, a, f"{NS}."
            if importer == "__import__" and i + 1 < len(toks) and toks[i + 1].string == ")":
                end = at(*toks[i + 1].end)
                yield end, end, "." + body.split(".")[0]
        elif body in LAYERS and (importer in _IMPORTERS or before[-2:] in (["'-m'", ","],
                                                                          ['"-m"', ","])):
            if before[-2:] and before[-1] == ",":  # python -m <layer>
                yield a, a + len(body), NS if body == "tissue" else f"{NS}.{body}"
            else:
                yield a, a, f"{NS}."
                if importer == "__import__" and toks[i + 1].string == ")":
                    end = at(*toks[i + 1].end)
                    yield end, end, "." + body


def rewrite_python(src: str) -> str:
    at = _offsets(src)
    edits = sorted(list(_import_edits(src, ast.parse(src), at)) + list(_string_edits(src, at)),
                   key=lambda e: (e[0], e[1]))
    for (a, b, _), (c, _, _) in pairwise(edits):
        if c < b:
            raise ValueError(f"overlapping rewrites at offset {c}")
    for a, b, text in reversed(edits):
        src = src[:a] + text + src[b:]
    return dash_m(src)


# --------------------------------------------------------------------------- Markdown
def _inline(span: str) -> str:
    if names_module(span):
        return f"{NS}.{span}"
    return dash_m(import_line(span)) if "\n" not in import_line(span) else span


def rewrite_markdown(text: str) -> str:
    out, fence = [], None
    for line in text.splitlines(True):
        body, nl = (line[:-1], "\n") if line.endswith("\n") else (line, "")
        m = re.match(r"\s*(```+|~~~+)", body)
        if m and (fence is None or m[1][0] == fence[0] and len(m[1]) >= len(fence)):
            fence = None if fence else m[1]
            out.append(line)
            continue
        if fence:
            out.append(dash_m(import_line(body)) + nl)
        else:
            out.append(re.sub(r"(`+)([^`\n]+?)\1",
                              lambda m: m[1] + _inline(m[2]) + m[1], dash_m(body)) + nl)
    return "".join(out)


# --------------------------------------------------------------------------- files
def tracked_files(root: Path) -> list[Path]:
    try:
        names = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        names = [str(p.relative_to(root)) for p in root.rglob("*")
                 if not {".git", ".venv", "build"} & set(p.relative_to(root).parts)]
    return sorted(root / n for n in names if n.endswith((".py", ".md")) and (root / n).is_file())


def rewrite_file(path: Path) -> tuple[str, str, str | None]:
    """(old text, new text, generator script for a generated page or None)."""
    old = path.read_text(encoding="utf-8")
    if SKIP_MARK in old.splitlines():
        return old, old, None
    if path.suffix == ".md":
        gen = _GENERATED.match(old)
        if gen:
            return old, old, gen[1]
        return old, rewrite_markdown(old), None
    try:
        return old, rewrite_python(old), None
    except (SyntaxError, ValueError, tokenize.TokenError) as exc:
        raise SystemExit(f"{path}: {exc}") from None


def sort_imports(files: list[Path], root: Path) -> None:
    """Sort the import blocks of ``files`` as the linter wants them (ruff's isort rule, the
    project's settings): the layers' imports now sort under tissue_reference."""
    if not files:
        return
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        print("ruff not found: imports not re-sorted (run: ruff check --select I001 --fix)")
        return
    subprocess.run([ruff, "check", "--select", "I001", "--fix", "--quiet", "--exit-zero",
                    *map(str, files)], cwd=root, check=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path, help="only these (default: the whole tree)")
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if it would")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository (default: this one)")
    args = ap.parse_args(argv)
    root = TREE[0] = args.root.resolve()
    _init_names.cache_clear()
    files = [f.resolve() for f in args.files] or tracked_files(root)
    changed, generators = [], []
    for path in files:
        old, new, gen = rewrite_file(path)
        if gen and gen not in generators:
            generators.append(gen)
        if new != old:
            changed.append(path)
            if not args.check:
                path.write_text(new, encoding="utf-8")
    for path in changed:
        print(f"{'would rewrite' if args.check else 'rewrote'} {path.relative_to(root)}")
    if not args.check:
        sort_imports([p for p in changed if p.suffix == ".py"], root)
    stale = []
    for gen in generators:
        script = root / gen
        if script.is_file():
            p = subprocess.run([sys.executable, str(script)] + (["--check"] if args.check else []),
                               cwd=root, capture_output=True, text=True, check=False)
            if p.returncode:
                stale.append(gen)
                print(f"{gen}: {(p.stdout + p.stderr).strip().splitlines()[-1:]}")
    return 1 if args.check and (changed or stale) else (1 if stale and not args.check else 0)


if __name__ == "__main__":
    sys.exit(main())
